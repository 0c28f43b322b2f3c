// canopy.plugins.openmesh — implementation: the checks of each format (the :checks partition,
// openmesh_checks.cppm), then OpenMesh's readers through an importer that records every face as the
// reader hands it over.
module;
#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cfloat>
#include <climits>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <mutex>
#include <new>
#include <optional>
#include <span>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include <OpenMesh/Core/IO/IOManager.hh>
#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>
module canopy.plugins.openmesh;
import :checks;

namespace canopy {

namespace {

using namespace openmesh_checks;

using om_mesh = OpenMesh::PolyMesh_ArrayKernelT<>;

// ---------------------------------------------------------------------------------------------
// The importer: OpenMesh's own, plus a record of every face and per-corner attribute as the
// reader hands them over.

struct face_record {
    std::vector<int> corners; // vertex indices as the file gives them
    std::vector<std::optional<OpenMesh::Vec2f>> uvs;
    std::vector<std::optional<OpenMesh::Vec3f>> normals;
    bool nonmanifold = false;
};

class recording_importer : public OpenMesh::IO::ImporterT<om_mesh> {
    using base = OpenMesh::IO::ImporterT<om_mesh>;

public:
    explicit recording_importer(om_mesh& m) : base(m), mesh_(m) {}

    std::vector<face_record> faces;
    std::size_t halfedge_faces = 0; // faces the reader built from halfedges (OM files)
    bool vertex_normals = false, vertex_texcoords = false;

    OpenMesh::FaceHandle add_face(VHandles const& indices) override {
        face_record r;
        r.corners.reserve(indices.size());
        for (auto v : indices) r.corners.push_back(v.idx());
        // Normals set since the previous face belong to this face's corners (OBJ's f v//n).
        r.normals.resize(indices.size());
        for (std::size_t k = 0; k < indices.size(); ++k) {
            auto it = pending_normals_.find(indices[k].idx());
            if (it != pending_normals_.end()) r.normals[k] = it->second;
        }
        pending_normals_.clear();
        r.uvs.resize(indices.size());
        std::size_t const vertices_before = mesh_.n_vertices();
        OpenMesh::FaceHandle const fh = base::add_face(indices);
        r.nonmanifold = fh.is_valid() && mesh_.n_vertices() != vertices_before;
        if (fh.is_valid()) face_of_handle_[fh.idx()] = faces.size();
        faces.push_back(std::move(r));
        return fh;
    }

    OpenMesh::FaceHandle add_face(OpenMesh::HalfedgeHandle heh) override {
        ++halfedge_faces;
        return base::add_face(heh);
    }

    void add_face_texcoords(OpenMesh::FaceHandle fh, OpenMesh::VertexHandle first,
                            std::vector<OpenMesh::Vec2f> const& uvs) override {
        auto it = face_of_handle_.find(fh.idx());
        if (it == face_of_handle_.end() || uvs.empty()) return;
        face_record& r = faces[it->second];
        // uvs[i] belongs to the corner i places after `first` (ImporterT's convention).
        auto const start = std::find(r.corners.begin(), r.corners.end(), first.idx());
        std::size_t const s = start == r.corners.end() ? 0 : std::size_t(start - r.corners.begin());
        for (std::size_t i = 0; i < uvs.size() && i < r.corners.size(); ++i) r.uvs[(s + i) % r.corners.size()] = uvs[i];
    }

    void set_normal(OpenMesh::VertexHandle vh, OpenMesh::Vec3f const& n) override {
        vertex_normals = true;
        pending_normals_[vh.idx()] = n;
        base::set_normal(vh, n);
    }
    void set_normal(OpenMesh::VertexHandle vh, OpenMesh::Vec3d const& n) override {
        set_normal(vh, OpenMesh::Vec3f(n));
    }
    void set_texcoord(OpenMesh::VertexHandle vh, OpenMesh::Vec2f const& uv) override {
        vertex_texcoords = true;
        base::set_texcoord(vh, uv);
    }

private:
    om_mesh& mesh_;
    std::map<int, OpenMesh::Vec3f> pending_normals_;
    std::map<int, std::size_t> face_of_handle_;
};

// OpenMesh's message streams (omerr, omlog) captured for the lifetime of this object: their
// stream buffers are swapped for a string buffer. (Connecting and disconnecting targets of
// OpenMesh's multiplexing buffer would leak one object per call in OpenMesh 9.)
class captured_omerr {
public:
    captured_omerr() : old_err_(::omerr().rdbuf(&text_)), old_log_(::omlog().rdbuf(&text_)) {}
    ~captured_omerr() {
        ::omerr().rdbuf(old_err_);
        ::omlog().rdbuf(old_log_);
    }
    captured_omerr(captured_omerr const&) = delete;
    captured_omerr& operator=(captured_omerr const&) = delete;

    // The distinct messages, in order, on one line.
    std::string messages() const {
        std::string out, line;
        std::istringstream in(text_.str());
        std::vector<std::string> seen;
        while (std::getline(in, line)) {
            if (line.empty() || std::find(seen.begin(), seen.end(), line) != seen.end()) continue;
            seen.push_back(line);
            out += (out.empty() ? "" : "; ") + line;
        }
        return out;
    }

private:
    std::stringbuf text_;
    std::streambuf* old_err_;
    std::streambuf* old_log_;
};

std::mutex& openmesh_mutex() {
    static std::mutex m;
    return m;
}

vec3<float> to_vec3(OpenMesh::Vec3f const& v) { return {v[0], v[1], v[2]}; }
vec2<float> to_vec2(OpenMesh::Vec2f const& v) { return {v[0], v[1]}; }

// ASCII OFF, checked and cleaned by check_off, into OpenMesh's importer as OpenMesh's OFF reader
// would put it: the reader itself cannot be given it, since it takes the header's [ST][C][N]
// flags from the last file it was asked about by name (a stream read keeps another file's).
bool import_off_text(std::string_view clean, recording_importer& importer) {
    line_reader lines(clean, '\0');
    std::vector<std::string_view> t;
    lines.next(t);
    off_header const h = *parse_off_header(t[0]);
    lines.next(t);
    std::size_t const vertices = std::size_t(read_integer(t[0]).value), faces = std::size_t(read_integer(t[1]).value);
    auto const number = [](std::string_view token) { return read_float(token).value; };
    std::size_t const values = h.normals ? 6 : 3;
    std::vector<OpenMesh::VertexHandle> corners;
    for (std::size_t v = 0; v < vertices; ++v) {
        lines.next(t);
        OpenMesh::VertexHandle const vh = importer.add_vertex(OpenMesh::Vec3f(number(t[0]), number(t[1]), number(t[2])));
        if (h.normals) importer.set_normal(vh, OpenMesh::Vec3f(number(t[3]), number(t[4]), number(t[5])));
        if (h.texcoords) {
            // After the colour (COFF: the last two values), else right after the position.
            std::size_t const at = h.colours ? t.size() - 2 : values;
            importer.set_texcoord(vh, OpenMesh::Vec2f(number(t[at]), number(t[at + 1])));
        }
    }
    for (std::size_t f = 0; f < faces; ++f) {
        lines.next(t);
        std::size_t const n = std::size_t(read_integer(t[0]).value);
        corners.clear();
        for (std::size_t k = 1; k <= n; ++k) corners.push_back(OpenMesh::VertexHandle(int(read_integer(t[k]).value)));
        importer.add_face(corners);
    }
    return true;
}

openmesh_read_result read_checked(std::filesystem::path const& path) {
    std::string const file = path.string();
    std::string const ext = extension_of(path);

    // The file's bytes are let go once checked: OpenMesh reads the file itself (ASCII OFF: clean_off,
    // through import_off_text).
    checked_input const checked = check_input(read_regular_file(path), file, ext);
    // checked: OpenMesh reads the file itself (ASCII OFF: clean_off, through import_off_text)
    std::optional<std::size_t> declared = checked.faces;
    std::string const& clean_off = checked.clean_off;

    om_mesh mesh;
    mesh.request_vertex_normals();
    mesh.request_vertex_texcoords2D();
    mesh.request_halfedge_texcoords2D();
    recording_importer importer(mesh);
    OpenMesh::IO::Options options = OpenMesh::IO::Options::VertexNormal | OpenMesh::IO::Options::VertexTexCoord |
                                    OpenMesh::IO::Options::FaceTexCoord;
    std::string messages;
    {
        std::lock_guard const lock(openmesh_mutex());
        captured_omerr capture;
        bool ok = false;
        if (clean_off.empty()) ok = OpenMesh::IO::IOManager().read(file, importer, options);
        else ok = import_off_text(clean_off, importer);
        messages = capture.messages();
        if (!ok)
            throw scene_error(file, "", "OpenMesh cannot read it" + (messages.empty() ? std::string() : ": " + messages));
    }

    openmesh_read_result result;
    mesh_data& out = result.mesh;
    out.name = path.stem().string();
    out.source = file;

    // Faces as recorded, or (OM files, built from halfedges) as the mesh holds them.
    std::vector<face_record>& faces = importer.faces;
    bool const from_halfedges = faces.empty() && importer.halfedge_faces > 0;
    bool normals = importer.vertex_normals, vertex_uvs = importer.vertex_texcoords;
    bool corner_uvs = std::any_of(faces.begin(), faces.end(), [](face_record const& r) {
        return std::any_of(r.uvs.begin(), r.uvs.end(), [](auto const& uv) { return uv.has_value(); });
    });
    if (from_halfedges) {
        normals = options.vertex_has_normal();
        vertex_uvs = options.vertex_has_texcoord();
        corner_uvs = options.face_has_texcoord();
        for (auto fh : mesh.faces()) {
            face_record r;
            for (auto heh : mesh.fh_range(fh)) {
                r.corners.push_back(mesh.to_vertex_handle(heh).idx());
                r.uvs.emplace_back(corner_uvs ? std::optional(mesh.texcoord2D(heh)) : std::nullopt);
                r.normals.emplace_back(std::nullopt);
            }
            faces.push_back(std::move(r));
        }
    }

    std::size_t dropped = 0;
    std::string reason;
    for (std::size_t f = 0; f < faces.size(); ++f) {
        auto const& c = faces[f].corners;
        bool const in_range = std::all_of(c.begin(), c.end(), [&](int v) { return v >= 0 && std::size_t(v) < mesh.n_vertices(); });
        if (c.size() < 3 || !in_range) {
            if (dropped++ == 0)
                reason = "face " + std::to_string(f) + (c.size() < 3 ? " has fewer than 3 corners" : " has a vertex index out of range");
        }
    }
    if (declared && ext == ".stl") *declared -= std::min(*declared, checked.stl_degenerate);
    if (dropped > 0 || (declared && *declared != faces.size())) {
        std::size_t const expected = declared ? *declared : faces.size();
        std::size_t const lost = expected >= faces.size() ? expected - faces.size() + dropped : dropped;
        throw scene_error(file, "", std::to_string(lost) + " of " + std::to_string(expected) +
                                        " faces were dropped while reading" + (reason.empty() ? "" : " (" + reason + ")") +
                                        (messages.empty() ? "" : "; OpenMesh says: " + messages));
    }

    // Positions: the file's vertices (copies OpenMesh made for non-manifold faces come after
    // them and are not referenced by the recorded faces).
    std::size_t vertex_count = 0;
    for (auto const& r : faces)
        for (int v : r.corners) vertex_count = std::max(vertex_count, std::size_t(v) + 1);
    if (from_halfedges || faces.empty()) vertex_count = mesh.n_vertices();
    else {
        // Vertices read before the first copy: everything up to the largest index a face uses,
        // and any unreferenced vertices the file declares after it.
        std::size_t copies = 0;
        for (auto const& r : faces)
            if (r.nonmanifold) copies += r.corners.size();
        vertex_count = std::max(vertex_count, mesh.n_vertices() - copies);
    }
    out.positions.reserve(vertex_count);
    for (std::size_t v = 0; v < vertex_count; ++v)
        out.positions.push_back(to_vec3(mesh.point(OpenMesh::VertexHandle(int(v)))));

    bool const has_uvs = corner_uvs || vertex_uvs;
    result.vertex_normals = normals;
    result.texcoords = has_uvs;
    result.faces = faces.size();
    result.degenerate_faces = checked.stl_degenerate;
    std::vector<vec3<float>> points; // the corners of the face being triangulated
    for (auto const& r : faces) {
        std::size_t const n = r.corners.size();
        result.polygons += n > 3;
        result.nonmanifold_faces += r.nonmanifold;
        std::vector<int> sorted = r.corners;
        std::sort(sorted.begin(), sorted.end());
        result.degenerate_faces += std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end();

        auto const uv_at = [&](std::size_t k) {
            if (r.uvs[k]) return to_vec2(*r.uvs[k]);
            if (vertex_uvs) return to_vec2(mesh.texcoord2D(OpenMesh::VertexHandle(r.corners[k])));
            return vec2<float>{0.0f, 0.0f};
        };
        auto const normal_at = [&](std::size_t k) {
            if (r.normals[k]) return to_vec3(*r.normals[k]);
            return to_vec3(mesh.normal(OpenMesh::VertexHandle(r.corners[k])));
        };
        // Triangle t of the face, given by its corners' positions in the face.
        auto const emit = [&](std::array<std::uint32_t, 3> const& t) {
            out.triangles.push_back({std::uint32_t(r.corners[t[0]]), std::uint32_t(r.corners[t[1]]), std::uint32_t(r.corners[t[2]])});
            if (has_uvs) out.uvs.push_back({uv_at(t[0]), uv_at(t[1]), uv_at(t[2])});
            if (normals) out.normals.push_back({normal_at(t[0]), normal_at(t[1]), normal_at(t[2])});
        };
        if (n == 3) {
            emit({0, 1, 2});
            continue;
        }
        points.clear();
        for (int v : r.corners) points.push_back(out.positions[std::size_t(v)]);
        polygon_triangles const cut = triangulate_polygon(points);
        result.concave_polygons += cut.ear_clipped;
        if (cut.fanned_fallback && out.fanned_faces++ == 0)
            out.first_fanned = "face " + std::to_string(std::size_t(&r - faces.data()));
        for (auto const& t : cut.triangles) emit(t);
    }
    return result;
}

} // namespace

std::optional<std::size_t> check_openmesh_input(std::string_view data, std::string const& file, std::string const& ext) {
    return check_input(data, file, ext).faces;
}

openmesh_read_result read_openmesh(std::filesystem::path const& path) {
    try {
        return read_checked(path);
    } catch (std::bad_alloc const&) {
        throw scene_error(path.string(), "", "out of memory while reading");
    }
}

node_id load_openmesh(scene& s, std::filesystem::path const& file, node_id parent) {
    openmesh_read_result r = read_openmesh(file);
    node_id const group = s.add_group(parent, file.filename().string());
    std::string const name = r.mesh.name;
    std::uint32_t const mesh = s.add_mesh(std::move(r.mesh));
    s.add_mesh_node(group, mesh, name);
    s.at(group).source = file.string();
    return group;
}

void register_openmesh_plugin(registry& r) {
    for (char const* ext : {".ply", ".off", ".stl", ".om", ".obj"})
        // .obj has its own reader (the obj plugin): this one is an alternative, chosen by name.
        r.add_loader(ext, "openmesh", "triangle mesh through OpenMesh (polygons triangulated)",
                     [](scene& s, std::filesystem::path const& file, node_id parent, registry const&) {
                         return load_openmesh(s, file, parent);
                     },
                     std::string_view(ext) == ".obj" ? loader_rank::alternative : loader_rank::standard);
}

} // namespace canopy
