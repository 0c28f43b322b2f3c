// canopy.plugins.gltf — implementation: tinygltf's model → canopy's scene graph (see the module
// interface for what is loaded and how). tinygltf is Debian's shared library (libtinygltf, which
// holds the implementation, nlohmann json and stb_image); its header stays in this unit.
module;
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <map>
#include <limits>
#include <new>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>
#include <tiny_gltf.h>

#include "gltf_schema.hpp"
module canopy.plugins.gltf;
import canopy.math;
import canopy.scene;

namespace canopy {

namespace {

namespace fs = std::filesystem;

// A string from the file, quoted and cut to a short prefix.
std::string shown(std::string_view s) {
    constexpr std::size_t longest = 40;
    return "'" + std::string(s.substr(0, longest)) + (s.size() > longest ? "…'" : "'");
}

// What tinygltf may read besides the file itself, and what it was refused. tinygltf reads external
// buffers and images through these callbacks: each file must be a regular file within
// --max-file-bytes in the glTF file's folder (tinygltf would also look in the working folder);
// images referred to by uri are not read here but later, through the registry's image loaders.
struct file_access {
    std::string base_dir;                 // as tinygltf joins uris to it
    std::vector<std::string> buffer_paths; // buffers[i]'s file, as tinygltf names it ("" for data: URIs)
    std::set<std::string> image_paths;    // images' files, as tinygltf names them
    std::optional<scene_error> refused;   // the first file or embedded image refused
    std::string refused_where;            // its element ("buffers[0]", "images[2]")
    // Images that are another's bytes (the same buffer bytes, data: URI or file): not decoded
    // again, but shared (image index → the first image of those bytes).
    std::map<int, int> same_as;
    // The texel budget (--max-total-texels): the texels of the scene's images before this file,
    // and of the embedded images decoded so far.
    std::uint64_t texels_held = 0, embedded_texels = 0;
};

// tinygltf's own path of a uri: dlib::urldecode ('+' is a space) joined to the base folder.
std::string tinygltf_path(std::string const& base_dir, std::string const& uri) {
    auto const hex = [](char c) {
        if (c >= '0' && c <= '9') return c - '0';
        if (c >= 'a' && c <= 'f') return c - 'a' + 10;
        if (c >= 'A' && c <= 'F') return c - 'A' + 10;
        return 0;
    };
    std::string decoded;
    for (std::size_t i = 0; i < uri.size(); ++i) {
        if (uri[i] == '+') {
            decoded += ' ';
        } else if (uri[i] == '%' && uri.size() > i + 2) {
            decoded += char(hex(uri[i + 1]) << 4 | hex(uri[i + 2]));
            i += 2;
        } else {
            decoded += uri[i];
        }
    }
    if (base_dir.empty()) return decoded;
    return base_dir.back() == '/' ? base_dir + decoded : base_dir + "/" + decoded;
}

bool file_exists(std::string const& path, void* user) {
    auto const& access = *static_cast<file_access const*>(user);
    if (!access.base_dir.empty() && !path.starts_with(access.base_dir)) return false;
    std::error_code ec;
    return fs::exists(path, ec);
}

std::string expand_file_path(std::string const& path, void*) { return path; }

bool read_whole_file(std::vector<unsigned char>* out, std::string* err, std::string const& path, void* user) {
    auto& access = *static_cast<file_access*>(user);
    if (access.image_paths.contains(path)) {
        *err = "read later through the image loaders";
        return false;
    }
    std::string where = "buffers";
    for (std::size_t i = 0; i < access.buffer_paths.size(); ++i)
        if (access.buffer_paths[i] == path) where = "buffers[" + std::to_string(i) + "]";
    try {
        std::uint64_t const size = require_regular_file(path, default_limits().max_file_bytes, "buffer");
        out->resize(std::size_t(size));
        std::ifstream in(path, std::ios::binary);
        in.read(reinterpret_cast<char*>(out->data()), std::streamsize(size));
        if (!in || std::uint64_t(in.gcount()) != size) throw scene_error(path, "", "cannot be read (buffer)");
        return true;
    } catch (scene_error const& e) {
        if (!access.refused) access.refused = e, access.refused_where = where;
    } catch (std::bad_alloc const&) {
        if (!access.refused) access.refused = scene_error(path, "", "out of memory while reading it (buffer)"), access.refused_where = where;
    }
    *err = access.refused->what();
    return false;
}

bool write_whole_file(std::string* err, std::string const&, std::vector<unsigned char> const&, void*) {
    *err = "not written";
    return false;
}

// Width and height from a PNG or JPEG header (the formats glTF allows for images), without
// decoding; nullopt for any other data.
std::optional<std::pair<std::uint32_t, std::uint32_t>> image_size(unsigned char const* p, std::size_t n) {
    auto const be16 = [&](std::size_t i) { return std::uint32_t(p[i]) << 8 | p[i + 1]; };
    auto const be32 = [&](std::size_t i) { return be16(i) << 16 | be16(i + 2); };
    static constexpr unsigned char png[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    if (n >= 24 && std::memcmp(p, png, 8) == 0 && std::memcmp(p + 12, "IHDR", 4) == 0) return std::pair(be32(16), be32(20));
    if (n < 4 || p[0] != 0xFF || p[1] != 0xD8) return std::nullopt;
    // JPEG: the first start-of-frame segment (SOF0 to SOF15 but DHT, JPG and DAC) holds the size.
    std::size_t i = 2;
    while (i + 3 < n) {
        if (p[i] != 0xFF) return std::nullopt;
        unsigned char const marker = p[i + 1];
        if (marker == 0xFF) {
            ++i;
            continue;
        }
        if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD9)) {
            i += 2;
            continue;
        }
        std::size_t const length = be16(i + 2);
        bool const frame = marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC;
        if (frame) return i + 8 < n ? std::optional(std::pair(be16(i + 7), be16(i + 5))) : std::nullopt;
        if (length < 2) return std::nullopt;
        i += 2 + length;
    }
    return std::nullopt;
}

// tinygltf's image callback: embedded images (data: URIs, buffer views) are checked by their
// header (PNG or JPEG, at most --max-texels texels) and decoded by tinygltf's stb_image decoder;
// images referred to by uri are left undecoded and read later through the registry's image loaders.
bool decode_embedded_image(tinygltf::Image* image, int index, std::string* err, std::string* warn, int width,
                           int height, unsigned char const* bytes, int size, void* user) {
    if (!image->uri.empty()) return true;
    auto& access = *static_cast<file_access*>(user);
    if (access.same_as.contains(index)) return true;
    std::string const where = "images[" + std::to_string(index) + "]";
    auto const refuse = [&](std::string const& problem) {
        if (!access.refused) access.refused = scene_error("", "", problem), access.refused_where = where;
        *err = problem;
        return false;
    };
    auto const dimensions = image_size(bytes, size < 0 ? 0 : std::size_t(size));
    if (!dimensions) return refuse("embedded image is neither PNG nor JPEG");
    auto const [w, h] = *dimensions;
    if (w == 0 || h == 0) return refuse("embedded image has no pixels (" + std::to_string(w) + " × " + std::to_string(h) + ")");
    std::string problem = texel_problem(w, h, access.texels_held + access.embedded_texels, default_limits().max_texels,
                                        default_limits().max_total_texels);
    if (problem.empty() && (w > (1u << 24) || h > (1u << 24)))
        problem = "image is " + std::to_string(w) + " × " + std::to_string(h) + ", over the 2^24 texels per side stb_image decodes";
    if (!problem.empty()) return refuse("embedded " + problem);
    access.embedded_texels += std::uint64_t(w) * h;
    try {
        return tinygltf::LoadImageData(image, index, err, warn, width, height, bytes, size, nullptr);
    } catch (std::bad_alloc const&) {
        return refuse("out of memory while decoding the embedded image");
    }
}

// tinygltf's messages: lines joined with "; ", without the trailing newline, each cut to a
// short prefix (tinygltf quotes whole data: URIs).
std::string tidy(std::string const& message) {
    std::string out;
    std::size_t start = 0;
    while (start < message.size()) {
        std::size_t end = message.find('\n', start);
        if (end == std::string::npos) end = message.size();
        std::string line = message.substr(start, end - start);
        while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
        constexpr std::size_t longest = 160;
        if (line.size() > longest) line = line.substr(0, longest) + "…";
        if (!line.empty()) out += (out.empty() ? "" : "; ") + line;
        start = end + 1;
    }
    return out.empty() ? std::string("tinygltf could not load the file") : out;
}

// "%20" → " " (glTF URIs are percent-encoded).
std::string decode_uri(std::string const& uri) {
    std::string out;
    for (std::size_t i = 0; i < uri.size(); ++i) {
        auto const hex = [](char c) {
            if (c >= '0' && c <= '9') return c - '0';
            if (c >= 'a' && c <= 'f') return c - 'a' + 10;
            if (c >= 'A' && c <= 'F') return c - 'A' + 10;
            return -1;
        };
        if (uri[i] == '%' && i + 2 < uri.size() && hex(uri[i + 1]) >= 0 && hex(uri[i + 2]) >= 0) {
            out += char(hex(uri[i + 1]) * 16 + hex(uri[i + 2]));
            i += 2;
        } else {
            out += uri[i];
        }
    }
    return out;
}

std::string mode_name(int mode) {
    switch (mode) {
    case TINYGLTF_MODE_POINTS: return "POINTS";
    case TINYGLTF_MODE_LINE: return "LINES";
    case TINYGLTF_MODE_LINE_LOOP: return "LINE_LOOP";
    case TINYGLTF_MODE_LINE_STRIP: return "LINE_STRIP";
    default: return std::to_string(mode);
    }
}

// Bytes of one component of a glTF component type, 0 for types glTF 2.0 does not allow.
std::size_t component_size(int type) {
    switch (type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return 1;
    case TINYGLTF_COMPONENT_TYPE_SHORT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: return 2;
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
    case TINYGLTF_COMPONENT_TYPE_FLOAT: return 4;
    default: return 0;
    }
}

// One component at p; normalized integers map to [0, 1] (unsigned) or [-1, 1] (signed).
double read_component(unsigned char const* p, int type, bool normalized) {
    switch (type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE: {
        std::int8_t v;
        std::memcpy(&v, p, 1);
        return normalized ? std::max(double(v) / 127.0, -1.0) : double(v);
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: {
        std::uint8_t v;
        std::memcpy(&v, p, 1);
        return normalized ? double(v) / 255.0 : double(v);
    }
    case TINYGLTF_COMPONENT_TYPE_SHORT: {
        std::int16_t v;
        std::memcpy(&v, p, 2);
        return normalized ? std::max(double(v) / 32767.0, -1.0) : double(v);
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
        std::uint16_t v;
        std::memcpy(&v, p, 2);
        return normalized ? double(v) / 65535.0 : double(v);
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
        std::uint32_t v;
        std::memcpy(&v, p, 4);
        return double(v);
    }
    default: {
        float v;
        std::memcpy(&v, p, 4);
        return double(v);
    }
    }
}

template <typename T>
std::string index_name(char const* array, T i) {
    return std::string(array) + "[" + std::to_string(i) + "]";
}

// The conversion of one loaded model into a scene.
class converter {
public:
    converter(tinygltf::Model const& model, fs::path const& file, scene& s, registry const& r,
              std::map<int, int> const& same_as, std::uint64_t embedded_texels)
        : model_(model), file_(file), name_(file.string()), s_(s), r_(r), same_as_(same_as),
          materials_(model.materials.size()), meshes_(model.meshes.size()), embedded_pending_(embedded_texels) {
        for (auto const& m : s.meshes()) {
            held_vertices_ += m.positions.size();
            held_triangles_ += m.triangles.size();
        }
    }

    node_id run(node_id parent) {
        for (auto const& ext : model_.extensionsRequired)
            fail("extensionsRequired", "the file requires extension " + shown(ext) + ", which this loader does not support");

        // The schema check has made the nodes disjoint trees (one parent each, no cycle) no
        // deeper than max_depth, and each scene's nodes roots.
        std::vector<bool> is_child(model_.nodes.size(), false);
        for (auto const& n : model_.nodes)
            for (int c : n.children)
                if (c >= 0 && std::size_t(c) < is_child.size()) is_child[std::size_t(c)] = true;
        std::vector<int> roots;
        std::string roots_where;
        if (!model_.scenes.empty()) {
            int const chosen = model_.defaultScene >= 0 ? model_.defaultScene : 0;
            if (std::size_t(chosen) >= model_.scenes.size())
                fail("scene", "scene " + std::to_string(chosen) + " does not exist (" +
                                  std::to_string(model_.scenes.size()) + " scenes)");
            roots = model_.scenes[std::size_t(chosen)].nodes;
            roots_where = index_name("scenes", chosen) + ".nodes";
        } else {
            // No scene: every node that is no node's child.
            for (std::size_t n = 0; n < model_.nodes.size(); ++n)
                if (!is_child[n]) roots.push_back(int(n));
            roots_where = "nodes";
        }

        node_id const group = s_.add_group(parent, file_.filename().string());
        struct pending {
            int node;
            node_id parent;
        };
        std::vector<pending> stack;
        std::vector<bool> visited(model_.nodes.size(), false);
        auto const push_children = [&](std::vector<int> const& children, node_id under, std::string const& where) {
            for (auto it = children.rbegin(); it != children.rend(); ++it) {
                if (*it < 0 || std::size_t(*it) >= model_.nodes.size())
                    fail(where, "node " + std::to_string(*it) + " does not exist (" +
                                    std::to_string(model_.nodes.size()) + " nodes)");
                stack.push_back({*it, under});
            }
        };
        push_children(roots, group, roots_where);
        while (!stack.empty()) {
            pending const p = stack.back();
            stack.pop_back();
            std::string const where = index_name("nodes", p.node);
            if (visited[std::size_t(p.node)]) fail(where, "is reached twice (it is listed twice)");
            visited[std::size_t(p.node)] = true;
            tinygltf::Node const& n = model_.nodes[std::size_t(p.node)];
            std::string const name = n.name.empty() ? where : n.name;
            node_id const t = guarded(where, [&] { return s_.add_transform(p.parent, transform_of(n, where), name); });
            if (n.mesh >= 0 || n.mesh < -1) place_mesh(n.mesh, t, where, name);
            if (n.camera >= 0 || n.camera < -1) place_camera(n.camera, t, where, name);
            push_children(n.children, t, where + ".children");
        }
        return group;
    }

private:
    [[noreturn]] void fail(std::string const& where, std::string const& problem) const {
        throw scene_error(name_, where, problem);
    }

    // Runs f (a call into the scene graph) and gives its scene_error this file and element.
    template <typename F>
    auto guarded(std::string const& where, F&& f) -> decltype(f()) {
        try {
            return f();
        } catch (scene_error const& e) {
            fail(where, e.problem());
        }
    }

    // ---- Nodes ----------------------------------------------------------------------------------

    affine_transform<float> transform_of(tinygltf::Node const& n, std::string const& where) const {
        affine_transform<double> xf = affine_transform<double>::identity();
        bool const trs = !n.translation.empty() || !n.rotation.empty() || !n.scale.empty();
        auto const all_finite = [](std::vector<double> const& v) {
            return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
        };
        if (!n.matrix.empty()) {
            if (trs) fail(where, "has both a matrix and translation/rotation/scale");
            if (n.matrix.size() != 16)
                fail(where, "matrix has " + std::to_string(n.matrix.size()) + " values (16 needed)");
            if (!all_finite(n.matrix)) fail(where, "matrix has a value that is not finite");
            auto const& m = n.matrix; // column-major
            if (m[3] != 0.0 || m[7] != 0.0 || m[11] != 0.0 || m[15] != 1.0)
                fail(where, "matrix is not affine (its last row is not 0 0 0 1)");
            xf.linear = mat3<double>{vec3<double>(m[0], m[1], m[2]), vec3<double>(m[4], m[5], m[6]),
                                     vec3<double>(m[8], m[9], m[10])};
            xf.translation = vec3<double>(m[12], m[13], m[14]);
        } else if (trs) {
            auto const check = [&](std::vector<double> const& v, std::size_t size, char const* what) {
                if (!v.empty() && v.size() != size)
                    fail(where, std::string(what) + " has " + std::to_string(v.size()) + " values (" +
                                    std::to_string(size) + " needed)");
                if (!all_finite(v)) fail(where, std::string(what) + " has a value that is not finite");
            };
            check(n.translation, 3, "translation");
            check(n.rotation, 4, "rotation");
            check(n.scale, 3, "scale");
            // T · R · S, in that order (glTF 2.0, §3.5.3): canopy.math's from_trs, in double.
            mat3<double> rotation = mat3<double>::identity();
            if (!n.rotation.empty()) {
                double x = n.rotation[0], y = n.rotation[1], z = n.rotation[2], w = n.rotation[3];
                double const norm = std::sqrt(x * x + y * y + z * z + w * w);
                if (!(norm > 0.0)) fail(where, "rotation is not a unit quaternion (its length is 0)");
                x /= norm, y /= norm, z /= norm, w /= norm;
                rotation = mat3<double>{vec3<double>(1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)),
                                      vec3<double>(2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w)),
                                      vec3<double>(2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y))};
            }
            vec3<double> scale{1.0}, translation{0.0};
            if (!n.scale.empty()) {
                if (n.scale[0] == 0.0 || n.scale[1] == 0.0 || n.scale[2] == 0.0)
                    fail(where, "scale has a zero component: canopy places geometry only with invertible transforms");
                scale = vec3<double>(n.scale[0], n.scale[1], n.scale[2]);
            }
            if (!n.translation.empty()) translation = vec3<double>(n.translation[0], n.translation[1], n.translation[2]);
            xf = from_trs(translation, rotation, scale);
        }
        affine_transform<float> const out = convert<float>(xf);
        if (!canopy::all_finite(out)) fail(where, "transform has a value beyond the range of a float");
        return out;
    }

    void place_mesh(int mesh, node_id under, std::string const& where, std::string const& name) {
        if (mesh < 0 || std::size_t(mesh) >= model_.meshes.size())
            fail(where, "mesh " + std::to_string(mesh) + " does not exist (" + std::to_string(model_.meshes.size()) +
                            " meshes)");
        // Each placed primitive is a mesh node, placed once by compile(): held to --max-placements
        // as they are made (a mesh of many primitives on many nodes multiplies).
        placements_ += model_.meshes[std::size_t(mesh)].primitives.size();
        check_limit(name_, where, placements_, default_limits().max_placements, "mesh placements", "--max-placements");
        std::vector<std::uint32_t> const& prims = mesh_of(mesh);
        if (prims.size() == 1) {
            s_.add_mesh_node(under, prims[0], name + " (mesh)");
            return;
        }
        node_id const group = s_.add_group(under, name + " (mesh)");
        for (std::uint32_t m : prims) s_.add_mesh_node(group, m, s_.meshes()[m].name);
    }

    void place_camera(int camera, node_id under, std::string const& where, std::string const& name) {
        if (camera < 0 || std::size_t(camera) >= model_.cameras.size())
            fail(where, "camera " + std::to_string(camera) + " does not exist (" +
                            std::to_string(model_.cameras.size()) + " cameras)");
        std::string const cwhere = index_name("cameras", camera);
        tinygltf::Camera const& c = model_.cameras[std::size_t(camera)];
        if (c.type != "perspective")
            fail(cwhere, "camera type '" + c.type + "' is not supported (canopy cameras are perspective)");
        double const yfov = c.perspective.yfov;
        if (!(yfov > 0.0 && yfov < 3.141592653589793))
            fail(cwhere, "yfov " + std::to_string(yfov) + " is not in (0, π) radians");
        camera_data data;
        data.eye = {0.0f, 0.0f, 0.0f};
        data.target = {0.0f, 0.0f, -1.0f};
        data.up = {0.0f, 1.0f, 0.0f};
        data.fovy_degrees = float(yfov * (180.0 / 3.141592653589793));
        guarded(cwhere, [&] { return s_.add_camera(under, data, c.name.empty() ? name + " (camera)" : c.name); });
    }

    // ---- Accessors --------------------------------------------------------------------------------

    // `count` elements of `element_size` bytes, `stride` apart from `offset` in bufferView `view`:
    // the first one, after checking that all lie inside the view and the view inside its buffer.
    unsigned char const* view_data(int view, std::size_t offset, std::size_t count, std::size_t element_size,
                                   std::size_t stride, std::string const& where, std::string const& what) const {
        if (view < 0 || std::size_t(view) >= model_.bufferViews.size())
            fail(where, what + ": bufferView " + std::to_string(view) + " does not exist (" +
                            std::to_string(model_.bufferViews.size()) + " buffer views)");
        tinygltf::BufferView const& bv = model_.bufferViews[std::size_t(view)];
        std::string const vname = index_name("bufferViews", view);
        if (bv.buffer < 0 || std::size_t(bv.buffer) >= model_.buffers.size())
            fail(where, what + ": " + vname + " refers to buffer " + std::to_string(bv.buffer) + ", which does not exist");
        std::vector<unsigned char> const& data = model_.buffers[std::size_t(bv.buffer)].data;
        if (bv.byteOffset > data.size() || bv.byteLength > data.size() - bv.byteOffset)
            fail(where, what + ": " + vname + " (bytes " + std::to_string(bv.byteOffset) + " + " +
                            std::to_string(bv.byteLength) + ") lies outside " + index_name("buffers", bv.buffer) +
                            " (" + std::to_string(data.size()) + " bytes)");
        if (count > 0) {
            bool const inside = offset <= bv.byteLength && element_size <= bv.byteLength - offset &&
                                count - 1 <= (bv.byteLength - offset - element_size) / stride;
            if (!inside)
                fail(where, what + ": " + std::to_string(count) + " elements of " + std::to_string(element_size) +
                                " bytes, " + std::to_string(stride) + " apart from byte " + std::to_string(offset) +
                                ", do not fit in " + vname + " (" + std::to_string(bv.byteLength) + " bytes)");
        }
        return data.data() + bv.byteOffset + offset;
    }

    // The values of accessor `index` (count × its component count), sparse substitution applied.
    // `what` names the use ("POSITION (accessors[3])") in messages at `where`.
    std::vector<double> read_accessor(int index, int components, std::string const& where, std::string const& what,
                                      std::size_t& count) const {
        tinygltf::Accessor const& a = model_.accessors[std::size_t(index)];
        std::size_t const size = component_size(a.componentType);
        if (size == 0) fail(where, what + ": component type " + std::to_string(a.componentType) + " is not allowed");
        if (tinygltf::GetNumComponentsInType(std::uint32_t(a.type)) != components)
            fail(where, what + ": has " + std::to_string(tinygltf::GetNumComponentsInType(std::uint32_t(a.type))) +
                            " components per element (" + std::to_string(components) + " needed)");
        std::size_t const element = size * std::size_t(components);
        count = a.count;
        if (count > std::size_t(UINT32_MAX))
            fail(where, what + ": count " + std::to_string(count) + " exceeds 2^32 - 1 elements");
        std::vector<double> values;
        if (a.bufferView >= 0) {
            tinygltf::BufferView const& bv = a.bufferView < int(model_.bufferViews.size())
                                                 ? model_.bufferViews[std::size_t(a.bufferView)]
                                                 : tinygltf::BufferView{};
            std::size_t const stride = bv.byteStride == 0 ? element : bv.byteStride;
            if (stride < element)
                fail(where, what + ": byteStride " + std::to_string(stride) + " is smaller than an element (" +
                                std::to_string(element) + " bytes)");
            unsigned char const* p = view_data(a.bufferView, a.byteOffset, count, element, stride, where, what);
            values.resize(count * std::size_t(components));
            for (std::size_t i = 0; i < count; ++i)
                for (int c = 0; c < components; ++c)
                    values[i * std::size_t(components) + std::size_t(c)] =
                        read_component(p + i * stride + std::size_t(c) * size, a.componentType, a.normalized);
        } else {
            if (!a.sparse.isSparse) fail(where, what + ": has neither a bufferView nor sparse values");
            values.assign(count * std::size_t(components), 0.0);
        }
        if (a.sparse.isSparse) {
            auto const& sp = a.sparse;
            if (sp.count < 1 || std::size_t(sp.count) > count)
                fail(where, what + ": sparse count " + std::to_string(sp.count) + " is not in [1, " +
                                std::to_string(count) + "]");
            int const itype = sp.indices.componentType;
            if (itype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE && itype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
                itype != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)
                fail(where, what + ": sparse indices have component type " + std::to_string(itype) +
                                " (unsigned byte, short or int needed)");
            if (sp.indices.byteOffset < 0 || sp.values.byteOffset < 0)
                fail(where, what + ": sparse byteOffset is negative");
            std::size_t const n = std::size_t(sp.count);
            std::size_t const isize = component_size(itype);
            unsigned char const* ip = view_data(sp.indices.bufferView, std::size_t(sp.indices.byteOffset), n, isize,
                                                isize, where, what + " sparse indices");
            unsigned char const* vp = view_data(sp.values.bufferView, std::size_t(sp.values.byteOffset), n, element,
                                                element, where, what + " sparse values");
            double previous = -1.0;
            for (std::size_t k = 0; k < n; ++k) {
                double const i = read_component(ip + k * isize, itype, false);
                if (i <= previous || i >= double(count))
                    fail(where, what + ": sparse index " + std::to_string(std::uint64_t(i)) + " at position " +
                                    std::to_string(k) + " is out of range or not increasing (" +
                                    std::to_string(count) + " elements)");
                previous = i;
                for (int c = 0; c < components; ++c)
                    values[std::size_t(i) * std::size_t(components) + std::size_t(c)] =
                        read_component(vp + k * element + std::size_t(c) * size, a.componentType, a.normalized);
            }
        }
        return values;
    }

    int accessor_index(std::map<std::string, int> const& attributes, std::string const& key,
                       std::string const& where) const {
        auto it = attributes.find(key);
        if (it == attributes.end()) return -1;
        if (it->second < 0 || std::size_t(it->second) >= model_.accessors.size())
            fail(where, key + ": accessor " + std::to_string(it->second) + " does not exist (" +
                            std::to_string(model_.accessors.size()) + " accessors)");
        return it->second;
    }

    // A float VEC2/VEC3 attribute with `vertices` elements (or normalized u8/u16 when allowed).
    std::vector<double> read_attribute(int accessor, std::string const& key, int components, bool normalized_ok,
                                       std::size_t vertices, std::string const& where) const {
        std::string const what = key + " (" + index_name("accessors", accessor) + ")";
        tinygltf::Accessor const& a = model_.accessors[std::size_t(accessor)];
        bool const normalized_int = a.normalized && (a.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE ||
                                                     a.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT);
        if (a.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT && !(normalized_ok && normalized_int))
            fail(where, what + ": component type " + std::to_string(a.componentType) + " is not supported (float" +
                            (normalized_ok ? std::string(", or normalized unsigned byte or short,") : std::string()) +
                            " needed)");
        std::size_t count = 0;
        std::vector<double> values = read_accessor(accessor, components, where, what, count);
        if (vertices != std::size_t(-1) && count != vertices)
            fail(where, what + ": has " + std::to_string(count) + " elements for " + std::to_string(vertices) +
                            " vertices");
        for (std::size_t i = 0; i < values.size(); ++i)
            if (!std::isfinite(values[i]))
                fail(where, what + ": vertex " + std::to_string(i / std::size_t(components)) +
                                " has a value that is not finite");
        return values;
    }

    // ---- Meshes -----------------------------------------------------------------------------------

    std::vector<std::uint32_t> const& mesh_of(int mesh) {
        auto& slot = meshes_[std::size_t(mesh)];
        if (slot) return *slot;
        tinygltf::Mesh const& m = model_.meshes[std::size_t(mesh)];
        std::vector<std::uint32_t> prims;
        for (std::size_t p = 0; p < m.primitives.size(); ++p) prims.push_back(primitive(mesh, p));
        slot = std::move(prims);
        return *slot;
    }

    std::uint32_t primitive(int mesh, std::size_t index) {
        tinygltf::Mesh const& m = model_.meshes[std::size_t(mesh)];
        tinygltf::Primitive const& p = m.primitives[index];
        std::string const where = index_name("meshes", mesh) + "." + index_name("primitives", index);
        if (p.mode < TINYGLTF_MODE_TRIANGLES || p.mode > TINYGLTF_MODE_TRIANGLE_FAN)
            fail(where, "mode " + mode_name(p.mode) +
                            " is not supported (TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN are)");

        // Positions.
        int const position = accessor_index(p.attributes, "POSITION", where);
        if (position < 0) fail(where, "has no POSITION attribute");
        // The scene's meshes together (those already in it, and this file's) are held to
        // --max-triangles, vertices and triangles, before anything is read: primitives of one
        // file may share one large accessor.
        resource_limits const& limits = default_limits();
        std::uint64_t const declared = model_.accessors[std::size_t(position)].count;
        check_limit(name_, where, held_vertices_ + declared, limits.max_triangles, "vertices in the scene's meshes",
                    "--max-triangles");
        std::vector<double> const xyz = read_attribute(position, "POSITION", 3, false, std::size_t(-1), where);
        std::size_t const vertices = xyz.size() / 3;
        if (vertices > std::size_t(UINT32_MAX)) fail(where, "has more than 2^32 - 1 vertices");

        // Indices, in range.
        std::vector<std::uint32_t> indices;
        if (p.indices >= 0) {
            if (std::size_t(p.indices) >= model_.accessors.size())
                fail(where, "indices: accessor " + std::to_string(p.indices) + " does not exist");
            std::string const what = "indices (" + index_name("accessors", p.indices) + ")";
            int const type = model_.accessors[std::size_t(p.indices)].componentType;
            if (type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE && type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
                type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)
                fail(where, what + ": component type " + std::to_string(type) +
                                " is not allowed (unsigned byte, short or int needed)");
            std::size_t count = 0;
            check_limit(name_, where, model_.accessors[std::size_t(p.indices)].count, 3 * limits.max_triangles, "indices",
                        "--max-triangles");
            std::vector<double> const raw = read_accessor(p.indices, 1, where, what, count);
            indices.reserve(raw.size());
            for (std::size_t k = 0; k < raw.size(); ++k) {
                if (raw[k] >= double(vertices))
                    fail(where, "index " + std::to_string(std::uint64_t(raw[k])) + " at position " + std::to_string(k) +
                                    " is out of range (" + std::to_string(vertices) + " vertices)");
                indices.push_back(std::uint32_t(raw[k]));
            }
        } else {
            indices.resize(vertices);
            for (std::size_t k = 0; k < vertices; ++k) indices[k] = std::uint32_t(k);
        }

        // Triangles, as the glTF specification lists them for each mode (§3.7.2.1).
        mesh_data md;
        md.source = name_;
        std::string const mesh_name = m.name.empty() ? index_name("meshes", mesh) : m.name;
        md.name = m.primitives.size() == 1 ? mesh_name : mesh_name + "." + index_name("primitives", index);
        std::size_t const n = indices.size();
        std::uint64_t const triangles = p.mode == TINYGLTF_MODE_TRIANGLES ? n / 3 : n < 3 ? 0 : n - 2;
        check_limit(name_, where, held_triangles_ + triangles, limits.max_triangles, "triangles in the scene's meshes",
                    "--max-triangles");
        held_vertices_ += vertices;
        held_triangles_ += triangles;
        if (p.mode == TINYGLTF_MODE_TRIANGLES) {
            if (n % 3 != 0) fail(where, "has " + std::to_string(n) + " vertices in TRIANGLES mode (not a multiple of 3)");
            for (std::size_t k = 0; k < n; k += 3) md.triangles.push_back({indices[k], indices[k + 1], indices[k + 2]});
        } else if (p.mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
            for (std::size_t k = 0; k + 2 < n; ++k)
                md.triangles.push_back(k % 2 == 0 ? std::array{indices[k], indices[k + 1], indices[k + 2]}
                                                  : std::array{indices[k], indices[k + 2], indices[k + 1]});
        } else {
            for (std::size_t k = 0; k + 2 < n; ++k) md.triangles.push_back({indices[k + 1], indices[k + 2], indices[0]});
        }
        md.positions.reserve(vertices);
        for (std::size_t v = 0; v < vertices; ++v)
            md.positions.push_back(vec3<float>(float(xyz[3 * v]), float(xyz[3 * v + 1]), float(xyz[3 * v + 2])));
        for (std::size_t v = 0; v < vertices; ++v)
            if (!std::isfinite(md.positions[v].x) || !std::isfinite(md.positions[v].y) || !std::isfinite(md.positions[v].z))
                fail(where, "POSITION: vertex " + std::to_string(v) + " does not fit in a float");

        // Material, and the texture coordinates its base colour texture reads.
        int uv_set = 0;
        bool uv_required = false;
        bool const has_material = p.material >= 0 || p.material < -1;
        if (has_material) {
            if (std::size_t(p.material) >= model_.materials.size())
                fail(where, "material " + std::to_string(p.material) + " does not exist (" +
                                std::to_string(model_.materials.size()) + " materials)");
            auto const& info = model_.materials[std::size_t(p.material)].pbrMetallicRoughness.baseColorTexture;
            if (info.index >= 0 || info.index < -1) {
                uv_set = info.texCoord;
                uv_required = true;
            }
        }
        std::string const uv_key = "TEXCOORD_" + std::to_string(uv_set);
        int const uv = accessor_index(p.attributes, uv_key, where);
        if (uv < 0 && uv_required)
            fail(where, "its material's base colour texture reads " + uv_key + ", which the primitive does not have");
        if (has_material) md.material = material(p.material);
        if (uv >= 0) {
            std::vector<double> const st = read_attribute(uv, uv_key, 2, true, vertices, where);
            md.uvs.reserve(md.triangles.size());
            for (auto const& t : md.triangles) {
                std::array<vec2<float>, 3> corners;
                for (std::size_t k = 0; k < 3; ++k)
                    corners[k] = vec2<float>(float(st[2 * t[k]]), float(st[2 * t[k] + 1]));
                md.uvs.push_back(corners);
            }
        }
        int const normal = accessor_index(p.attributes, "NORMAL", where);
        if (normal >= 0) {
            std::vector<double> const nxyz = read_attribute(normal, "NORMAL", 3, false, vertices, where);
            md.normals.reserve(md.triangles.size());
            for (auto const& t : md.triangles) {
                std::array<vec3<float>, 3> corners;
                for (std::size_t k = 0; k < 3; ++k)
                    corners[k] =
                        vec3<float>(float(nxyz[3 * t[k]]), float(nxyz[3 * t[k] + 1]), float(nxyz[3 * t[k] + 2]));
                md.normals.push_back(corners);
            }
        }
        return guarded(where, [&] { return s_.add_mesh(std::move(md)); });
    }

    // ---- Materials and images ---------------------------------------------------------------------

    int material(int index) {
        auto& slot = materials_[std::size_t(index)];
        if (slot) return *slot;
        std::string const where = index_name("materials", index);
        tinygltf::Material const& m = model_.materials[std::size_t(index)];
        auto const& pbr = m.pbrMetallicRoughness;
        std::array<double, 4> factor{1.0, 1.0, 1.0, 1.0};
        if (!pbr.baseColorFactor.empty()) {
            if (pbr.baseColorFactor.size() != 4)
                fail(where, "baseColorFactor has " + std::to_string(pbr.baseColorFactor.size()) + " values (4 needed)");
            for (std::size_t k = 0; k < 4; ++k) {
                factor[k] = pbr.baseColorFactor[k];
                if (!(factor[k] >= 0.0 && factor[k] <= 1.0))
                    fail(where, "baseColorFactor has a value outside [0, 1]");
            }
        }
        material_data md;
        md.name = m.name.empty() ? where : m.name;
        md.colour = vec3<float>(float(factor[0]), float(factor[1]), float(factor[2]));
        bool masked = false;
        if (m.alphaMode == "MASK") {
            masked = true;
            if (!(m.alphaCutoff >= 0.0 && m.alphaCutoff <= 1.0))
                fail(where, "alphaCutoff " + std::to_string(m.alphaCutoff) + " is not in [0, 1]");
            md.alpha_cutoff = float(m.alphaCutoff);
        } else if (m.alphaMode == "BLEND") {
            masked = true;
            md.alpha_cutoff = 0.5f;
        } else if (m.alphaMode != "OPAQUE") {
            fail(where, "alphaMode '" + m.alphaMode + "' is not OPAQUE, MASK or BLEND");
        }
        md.alpha = masked ? alpha_mode::mask : alpha_mode::opaque;

        int const texture = pbr.baseColorTexture.index;
        if (texture >= 0 || texture < -1) {
            std::string const twhere = where + ".pbrMetallicRoughness.baseColorTexture";
            if (std::size_t(texture) >= model_.textures.size())
                fail(twhere, "texture " + std::to_string(texture) + " does not exist (" +
                                 std::to_string(model_.textures.size()) + " textures)");
            if (pbr.baseColorTexture.texCoord < 0) fail(twhere, "texCoord is negative");
            int const source = model_.textures[std::size_t(texture)].source;
            if (source < 0 || std::size_t(source) >= model_.images.size())
                fail(index_name("textures", texture), "has no image source this loader reads (source " +
                                                          std::to_string(source) + ", " +
                                                          std::to_string(model_.images.size()) + " images)");
            // The factor's alpha multiplies the texture's, and a mask compares the product with
            // the cutoff: the texture's alpha is compared with cutoff / factor instead, so that
            // one image serves every material; below the cutoff, a factor leaves only holes.
            double const alpha = masked ? factor[3] : 1.0;
            if (alpha < md.alpha_cutoff) {
                md.image = image(-1, 0.0);
            } else {
                md.image = image(source, 1.0);
                if (alpha > 0.0 && alpha < 1.0) md.alpha_cutoff = float(double(md.alpha_cutoff) / alpha);
            }
        } else if (masked) {
            // No texture: the factor's alpha alone decides, through a 1×1 image.
            md.image = image(-1, factor[3]);
        }
        int const id = guarded(where, [&] { return s_.add_material(std::move(md)); });
        slot = id;
        return id;
    }

    // Scene image of glTF image `index` with alpha scaled by `alpha` (index -1: one white texel).
    // Scene image of glTF image `index`, made once however many materials use it (and once for
    // all glTF images of the same bytes or file); index -1: one white texel of alpha `alpha`.
    int image(int index, double alpha) {
        if (auto it = same_as_.find(index); it != same_as_.end()) index = it->second;
        auto const key = std::make_pair(index, index < 0 ? alpha : 1.0);
        if (auto it = images_.find(key); it != images_.end()) return it->second;
        std::optional<fs::path> file;
        if (index >= 0 && !model_.images[std::size_t(index)].uri.empty()) {
            file = file_.parent_path() / decode_uri(model_.images[std::size_t(index)].uri);
            if (auto it = image_files_.find(*file); it != image_files_.end()) return images_[key] = it->second;
        }
        image_data img;
        if (index < 0) {
            img.source = name_;
            img.width = img.height = 1;
            img.texels = {vec4<float>(1.0f, 1.0f, 1.0f, float(alpha))};
        } else {
            img = decoded_image(index);
        }
        // An embedded image was counted when it was decoded: now the scene holds it.
        if (index >= 0 && !file) embedded_pending_ -= std::min<std::uint64_t>(embedded_pending_, img.texels.size());
        std::string const where = index < 0 ? std::string("materials") : index_name("images", index);
        int const id = guarded(where, [&] { return s_.add_image(std::move(img)); });
        images_.emplace(key, id);
        if (file) image_files_.emplace(*file, id);
        return id;
    }

    // glTF image `index` as linear RGBA.
    image_data decoded_image(int index) const {
        std::string const where = index_name("images", index);
        tinygltf::Image const& im = model_.images[std::size_t(index)];
        image_data out;
        if (!im.uri.empty()) {
            if (im.uri.starts_with("data:"))
                fail(where, "data: URI " + shown(im.uri) + " is not one tinygltf decodes (PNG or JPEG, base64)");
            fs::path const path = file_.parent_path() / decode_uri(im.uri);
            try {
                out = r_.load_image(path, s_.texels() + embedded_pending_);
            } catch (scene_error const& e) {
                fail(where, shown(im.uri) + ": " + e.what());
            }
            // baseColorTexture is sRGB by the glTF specification, whatever the file's tags.
            for (auto& t : out.texels) t = vec4<float>(srgb_to_linear(t.x), srgb_to_linear(t.y), srgb_to_linear(t.z), t.w);
            out.srgb = false;
            return out;
        }
        if (im.image.empty()) fail(where, "has no image data that could be decoded");
        if (im.width <= 0 || im.height <= 0 || im.component < 1 || im.component > 4 || (im.bits != 8 && im.bits != 16))
            fail(where, "decoded image has an unsupported layout (" + std::to_string(im.width) + "x" +
                            std::to_string(im.height) + ", " + std::to_string(im.component) + " channels, " +
                            std::to_string(im.bits) + " bits)");
        std::size_t const channels = std::size_t(im.component), bytes = std::size_t(im.bits / 8);
        std::size_t const texels = std::size_t(im.width) * std::size_t(im.height);
        if (im.image.size() != texels * channels * bytes) fail(where, "decoded image has the wrong number of bytes");
        std::array<float, 256> srgb8{};
        for (std::size_t v = 0; v < 256; ++v) srgb8[v] = srgb_to_linear(double(v) / 255.0);
        auto const value = [&](std::size_t i, std::size_t c) {
            unsigned char const* p = im.image.data() + (i * channels + c) * bytes;
            if (bytes == 1) return double(p[0]) / 255.0;
            std::uint16_t v;
            std::memcpy(&v, p, 2);
            return double(v) / 65535.0;
        };
        auto const colour = [&](std::size_t i, std::size_t c) {
            if (bytes == 1) return srgb8[im.image[i * channels + c]];
            return srgb_to_linear(value(i, c));
        };
        out.source = name_ + " " + where;
        out.width = im.width;
        out.height = im.height;
        out.texels.resize(texels);
        for (std::size_t i = 0; i < texels; ++i) {
            if (channels >= 3)
                out.texels[i] = vec4<float>(colour(i, 0), colour(i, 1), colour(i, 2),
                                            channels == 4 ? float(value(i, 3)) : 1.0f);
            else
                out.texels[i] = vec4<float>(colour(i, 0), colour(i, 0), colour(i, 0),
                                            channels == 2 ? float(value(i, 1)) : 1.0f);
        }
        return out;
    }

    tinygltf::Model const& model_;
    fs::path file_;
    std::string name_;
    scene& s_;
    registry const& r_;
    std::map<int, int> const& same_as_;
    std::vector<std::optional<int>> materials_;
    std::vector<std::optional<std::vector<std::uint32_t>>> meshes_;
    std::uint64_t held_vertices_ = 0, held_triangles_ = 0; // in the scene's meshes, this file's included
    std::uint64_t placements_ = 0;                         // mesh nodes this file made
    std::map<std::pair<int, double>, int> images_;
    std::map<fs::path, int> image_files_;
    std::uint64_t embedded_pending_; // texels of embedded images decoded, not yet in the scene
};

// The chunks of a .glb file that are read: the JSON chunk, and the BIN chunk when there is one.
struct glb_chunks {
    std::string_view json;
    std::optional<std::string_view> bin;
};

// Four bytes of a header, quoted: printable ASCII as it is, other bytes as \xNN.
std::string quoted_tag(std::string_view tag) {
    std::string out = "'";
    for (char const c : tag) {
        auto const b = static_cast<unsigned char>(c);
        if (b >= 0x20 && b < 0x7F && c != '\'' && c != '\\') {
            out += c;
        } else {
            char hex[8];
            std::snprintf(hex, sizeof hex, "\\x%02X", unsigned(b));
            out += hex;
        }
    }
    return out + "'";
}

// The layout of a .glb file, checked before anything else reads it (glTF 2.0, §4.4): a 12-byte
// header (magic 'glTF', version 2, the length of the whole file), then chunks, each an 8-byte
// header (length, type) and its data, inside the file: the JSON chunk first, a BIN chunk second
// if there is one, chunks of other types after them (skipped, as the specification asks). Each
// fault names the header or the chunk (counted from 0) and the sizes at stake, as
//   "x.glb: GLB header: magic is 'abcd', expected 'glTF'"
//   "x.glb: chunk 1: length 99999 runs past the end of the file (1234 bytes)"
glb_chunks glb_layout(std::string_view bytes, std::string const& name) {
    auto const u32 = [&](std::uint64_t i) {
        std::uint32_t v = 0;
        for (std::size_t k = 0; k < 4; ++k) v |= std::uint32_t(static_cast<unsigned char>(bytes[i + k])) << (8 * k);
        return std::uint64_t(v);
    };
    auto const fail = [&](std::string const& where, std::string const& problem) { throw scene_error(name, where, problem); };
    std::uint64_t const size = bytes.size();
    std::string const file_size = " (" + std::to_string(size) + " bytes)";
    if (size < 12) fail("GLB header", "the file has " + std::to_string(size) + " bytes, fewer than the header's 12");
    if (bytes.substr(0, 4) != "glTF") fail("GLB header", "magic is " + quoted_tag(bytes.substr(0, 4)) + ", expected 'glTF'");
    if (u32(4) != 2) fail("GLB header", "version is " + std::to_string(u32(4)) + ", expected 2");
    std::uint64_t const length = u32(8);
    if (length > size) fail("GLB header", "length " + std::to_string(length) + " runs past the end of the file" + file_size);
    if (length < size)
        fail("GLB header", "length " + std::to_string(length) + " ends before the end of the file" + file_size);
    if (length == 12) fail("GLB header", "no chunk follows the header (the JSON chunk is required)");
    glb_chunks out;
    std::uint64_t at = 12;
    for (std::uint64_t k = 0; at < length; ++k) {
        std::string const where = "chunk " + std::to_string(k);
        if (length - at < 8)
            fail(where, "its 8-byte header at byte " + std::to_string(at) + " runs past the end of the file" + file_size);
        std::uint64_t const chunk = u32(at);
        std::string_view const type = bytes.substr(std::size_t(at + 4), 4);
        if (chunk > length - at - 8)
            fail(where, "length " + std::to_string(chunk) + " runs past the end of the file" + file_size);
        if (chunk % 4 != 0) fail(where, "length " + std::to_string(chunk) + " is not a multiple of 4 (chunks are padded)");
        std::string_view const data = bytes.substr(std::size_t(at + 8), std::size_t(chunk));
        if (k == 0) {
            if (type != "JSON") fail(where, "type is " + quoted_tag(type) + ", expected 'JSON' (the JSON chunk comes first)");
            if (chunk == 0) fail(where, "the JSON chunk is empty");
            out.json = data;
        } else if (type == "JSON") {
            fail(where, "a second JSON chunk (there is one, the first)");
        } else if (type == std::string_view("BIN\0", 4)) {
            if (k != 1) fail(where, "a BIN chunk after chunk 1 (there is at most one, the second)");
            out.bin = data;
        }
        at += 8 + chunk;
    }
    return out;
}

// Buffers without a uri: only a .glb file's buffers[0], which is its BIN chunk, may have none.
void check_buffer_sources(gltf_schema::document_uris const& uris, std::optional<glb_chunks> const& glb,
                          std::string const& name) {
    for (std::size_t i = 0; i < uris.buffers.size(); ++i) {
        if (!uris.buffers[i].empty()) continue;
        std::string const where = "buffers[" + std::to_string(i) + "]";
        if (!glb) throw scene_error(name, where, "has no uri (only the first buffer of a .glb file, its BIN chunk, may go without)");
        if (i > 0) throw scene_error(name, where, "has no uri (only buffers[0] may go without: it is the BIN chunk)");
        if (!glb->bin) throw scene_error(name, where, "has no uri and the file has no BIN chunk");
        if (glb->bin->size() < uris.buffer_lengths[i])
            throw scene_error(name, where, "byteLength " + std::to_string(uris.buffer_lengths[i]) + " is more than the " +
                                               std::to_string(glb->bin->size()) + " bytes of the BIN chunk");
    }
}

node_id parse(std::string_view bytes, fs::path const& file, scene& s, node_id parent, registry const& r) {
    std::string const name = file.string();
    if (bytes.size() > std::numeric_limits<unsigned int>::max())
        throw scene_error(name, "", "is " + std::to_string(bytes.size()) + " bytes, more than tinygltf reads (4 GiB)");
    // A .glb file, or any file that starts as one, is read as one: its layout is checked first.
    bool const binary = extension_of(file) == ".glb" || bytes.starts_with("glTF");
    std::optional<glb_chunks> glb;
    if (binary) glb = glb_layout(bytes, name);
    std::string_view const json = binary ? glb->json : bytes;
    gltf_schema::document_uris const uris = gltf_schema::check_document(json, name, default_limits().max_depth);
    check_buffer_sources(uris, glb, name);

    // The files tinygltf will ask for, as it names them.
    file_access access;
    access.base_dir = file.parent_path().string();
    access.texels_held = s.texels();
    for (auto const& uri : uris.buffers)
        access.buffer_paths.push_back(uri.empty() || uri.starts_with("data:") ? "" : tinygltf_path(access.base_dir, uri));
    for (auto const& uri : uris.images)
        if (!uri.empty() && !uri.starts_with("data:")) access.image_paths.insert(tinygltf_path(access.base_dir, uri));
    for (auto const& b : access.buffer_paths) access.image_paths.erase(b);
    {
        // Images of the same bytes: decoded and held once.
        std::map<std::array<std::int64_t, 3>, int> by_bytes;
        std::map<std::string_view, int> by_uri;
        for (std::size_t i = 0; i < uris.images.size(); ++i) {
            int const first = uris.images[i].empty() ? by_bytes.try_emplace(uris.image_bytes[i], int(i)).first->second
                                                     : by_uri.try_emplace(uris.images[i], int(i)).first->second;
            if (first != int(i)) access.same_as[int(i)] = first;
        }
    }
    // External buffers: there, regular files within the size limit, of their declared length.
    for (std::size_t i = 0; i < access.buffer_paths.size(); ++i) {
        std::string const& path = access.buffer_paths[i];
        if (path.empty()) continue;
        std::string const where = "buffers[" + std::to_string(i) + "]";
        std::uint64_t size = 0;
        try {
            size = require_regular_file(path, default_limits().max_file_bytes, "buffer");
        } catch (scene_error const& e) {
            throw scene_error(name, where, e.what());
        }
        if (size != uris.buffer_lengths[i])
            throw scene_error(name, where, path + ": has " + std::to_string(size) + " bytes, its byteLength says " +
                                               std::to_string(uris.buffer_lengths[i]));
    }

    tinygltf::Model model;
    std::string err, warn;
    bool loaded = false;
    try {
        tinygltf::TinyGLTF loader;
        loader.SetImageLoader(decode_embedded_image, &access);
        loader.SetFsCallbacks({file_exists, expand_file_path, read_whole_file, write_whole_file, &access});
        auto const* data = reinterpret_cast<unsigned char const*>(bytes.data());
        auto const size = static_cast<unsigned int>(bytes.size());
        loaded = binary ? loader.LoadBinaryFromMemory(&model, &err, &warn, data, size, access.base_dir)
                        : loader.LoadASCIIFromString(&model, &err, &warn, bytes.data(), size, access.base_dir);
    } catch (std::bad_alloc const&) {
        throw;
    } catch (std::exception const& e) {
        throw scene_error(name, "", "tinygltf: " + tidy(e.what()));
    }
    if (access.refused) {
        std::string const problem = access.refused->file().empty() ? access.refused->problem() : access.refused->what();
        throw scene_error(name, access.refused_where, problem);
    }
    if (!loaded) throw scene_error(name, "", tidy(err.empty() ? warn : err));
    if (!model.asset.version.starts_with("2"))
        throw scene_error(name, "asset.version",
                          "glTF " + shown(model.asset.version) + " is not supported (this loader reads glTF 2.0)");
    scene::mark const mark = s.make_mark();
    try {
        return converter(model, file, s, r, access.same_as, access.embedded_texels).run(parent);
    } catch (...) {
        s.roll_back(mark);
        throw;
    }
}

} // namespace

node_id parse_gltf(std::string_view bytes, fs::path const& file, scene& s, node_id parent, registry const& r) {
    try {
        return parse(bytes, file, s, parent, r);
    } catch (std::bad_alloc const&) {
        throw scene_error(file.string(), "", "out of memory while loading");
    }
}

node_id load_gltf(scene& s, fs::path const& file, node_id parent, registry const& r) {
    std::string bytes;
    try {
        std::uint64_t const size = require_regular_file(file);
        bytes.resize(std::size_t(size));
        std::ifstream in(file, std::ios::binary);
        in.read(bytes.data(), std::streamsize(size));
        if (!in || std::uint64_t(in.gcount()) != size) throw scene_error(file.string(), "", "cannot be read");
    } catch (std::bad_alloc const&) {
        throw scene_error(file.string(), "", "out of memory while reading the file");
    }
    return parse_gltf(bytes, file, s, parent, r);
}

void register_gltf_plugin(registry& r) {
    r.add_loader(".gltf", "gltf", "glTF 2.0 scenes: node hierarchy, shared meshes, materials with alpha masks, cameras",
                 load_gltf);
    r.add_loader(".glb", "gltf", "binary glTF 2.0 scenes (as .gltf)", load_gltf);
}

} // namespace canopy
