// canopy.plugins.openmesh — implementation: checks of each format, then OpenMesh's readers
// through an importer that records every face as the reader hands it over.
module;
#include <algorithm>
#include <array>
#include <bit>
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
#include <optional>
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

namespace canopy {

namespace {

using om_mesh = OpenMesh::PolyMesh_ArrayKernelT<>;

// ---------------------------------------------------------------------------------------------
// Text helpers

std::string shown(std::string_view token) {
    constexpr std::size_t longest = 24;
    return "'" + std::string(token.substr(0, longest)) + (token.size() > longest ? "…'" : "'");
}

// A number as C's strtod reads it (a leading '+' allowed); nullopt when the token is not one.
std::optional<double> parse_number(std::string_view t) {
    if (!t.empty() && t.front() == '+') t.remove_prefix(1);
    double v = 0.0;
    auto const [end, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
    if (ec == std::errc::result_out_of_range) return std::strtod(std::string(t).c_str(), nullptr); // ±HUGE_VAL or tiny
    if (ec != std::errc() || end != t.data() + t.size() || t.empty()) return std::nullopt;
    return v;
}

std::optional<long long> parse_integer(std::string_view t) {
    if (!t.empty() && t.front() == '+') t.remove_prefix(1);
    long long v = 0;
    auto const [end, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
    if (ec != std::errc() || end != t.data() + t.size() || t.empty()) return std::nullopt;
    return v;
}

std::uint32_t little_endian_u32(char const* p) {
    auto const b = [&](int i) { return std::uint32_t(static_cast<unsigned char>(p[i])); };
    return b(0) | b(1) << 8 | b(2) << 16 | b(3) << 24;
}

// Lines of a text with their numbers (from 1); `comment` starts a comment to the end of a line.
class line_reader {
public:
    line_reader(std::string_view text, char comment) : text_(text), comment_(comment) {}

    // The next line that holds tokens (comments and blank lines skipped), split into tokens.
    bool next(std::vector<std::string_view>& tokens) {
        while (position_ < text_.size()) {
            std::size_t const end = std::min(text_.find('\n', position_), text_.size());
            std::string_view line = text_.substr(position_, end - position_);
            position_ = end + 1;
            ++number_;
            if (comment_ != '\0') line = line.substr(0, line.find(comment_));
            split(line, tokens);
            if (!tokens.empty()) return true;
        }
        return false;
    }
    std::size_t number() const { return number_; }
    std::string where() const { return std::to_string(number_); }

    static void split(std::string_view line, std::vector<std::string_view>& tokens) {
        tokens.clear();
        std::size_t i = 0;
        auto const space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; };
        while (i < line.size()) {
            while (i < line.size() && space(line[i])) ++i;
            std::size_t const start = i;
            while (i < line.size() && !space(line[i])) ++i;
            if (i > start) tokens.push_back(line.substr(start, i - start));
        }
    }

private:
    std::string_view text_;
    char comment_;
    std::size_t position_ = 0, number_ = 0;
};

// ---------------------------------------------------------------------------------------------
// Checks before OpenMesh: each returns the number of faces the file declares.

struct file_checker {
    std::string file; // for messages
    std::string_view data;

    [[noreturn]] void fail(std::string const& where, std::string const& problem) const {
        throw scene_error(file, where, problem);
    }

    double finite_number(std::string_view token, std::string const& where, std::string const& what) const {
        auto const v = parse_number(token);
        if (!v) fail(where, what + " " + shown(token) + " is not a number");
        if (!std::isfinite(*v)) fail(where, what + " " + shown(token) + " is not a finite number");
        return *v;
    }

    // --- OFF (ASCII): header, counts, vertex and face lines. `clean` receives the text without
    // comments and blank lines (OpenMesh's OFF reader takes none).
    std::optional<std::size_t> check_off(std::string& clean) const {
        std::optional<std::size_t> const faces = check_off_lines();
        if (!faces) return faces;
        line_reader lines(data, '#');
        std::vector<std::string_view> t;
        while (lines.next(t)) {
            for (auto token : t) clean.append(token).push_back(' ');
            clean.back() = '\n';
        }
        return faces;
    }

    std::optional<std::size_t> check_off_lines() const {
        line_reader lines(data, '#');
        std::vector<std::string_view> t;
        if (!lines.next(t)) fail("", "file holds no OFF header");
        std::string_view const keyword = t[0];
        if (keyword.size() < 3 || keyword.substr(keyword.size() - 3) != "OFF")
            fail(lines.where(), "expected an OFF header, found " + shown(keyword));
        std::string_view const prefix = keyword.substr(0, keyword.size() - 3);
        if (prefix.find('4') != std::string_view::npos || prefix.find('n') != std::string_view::npos)
            fail(lines.where(), "OFF files of other than three dimensions (" + shown(keyword) + ") are not supported");
        for (char c : prefix)
            if (std::string_view("STCN").find(c) == std::string_view::npos)
                fail(lines.where(), "unknown OFF header " + shown(keyword));
        if (t.size() > 1 && t[1] == "BINARY") return std::nullopt; // handed over unchecked
        if (t.size() > 1)
            fail(lines.where(), "the OFF header line holds more than its keyword (OpenMesh reads the counts from the next line)");
        bool const normals = prefix.find('N') != std::string_view::npos;

        std::vector<std::string_view> counts;
        if (!lines.next(counts)) fail(lines.where(), "file ends before the OFF counts");
        if (counts.size() != 3)
            fail(lines.where(), "the OFF counts line must hold three numbers (vertices faces edges), it holds " +
                                    std::to_string(counts.size()));
        std::array<long long, 3> n{};
        for (int i = 0; i < 3; ++i) {
            auto const v = parse_integer(counts[std::size_t(i)]);
            if (!v || *v < 0) fail(lines.where(), "OFF count " + shown(counts[std::size_t(i)]) + " is not a count");
            n[std::size_t(i)] = *v;
        }
        long long const vertices = n[0], faces = n[1];

        for (long long v = 0; v < vertices; ++v) {
            if (!lines.next(t))
                fail(lines.where(), "file ends after " + std::to_string(v) + " of " + std::to_string(vertices) + " vertices");
            std::size_t const needed = normals ? 6 : 3;
            if (t.size() < needed)
                fail(lines.where(), "vertex " + std::to_string(v) + " has " + std::to_string(t.size()) + " values, needs " +
                                        std::to_string(needed));
            for (std::size_t i = 0; i < needed; ++i)
                finite_number(t[i], lines.where(), "vertex " + std::to_string(v) + (i < 3 ? ": coordinate" : ": normal"));
        }
        for (long long f = 0; f < faces; ++f) {
            if (!lines.next(t))
                fail(lines.where(), "file ends after " + std::to_string(f) + " of " + std::to_string(faces) + " faces");
            std::string const face = "face " + std::to_string(f);
            auto const corners = parse_integer(t[0]);
            if (!corners) fail(lines.where(), face + ": corner count " + shown(t[0]) + " is not an integer");
            if (*corners < 3) fail(lines.where(), face + " has " + std::to_string(*corners) + " corners (at least 3 needed)");
            if (std::size_t(*corners) + 1 > t.size())
                fail(lines.where(), face + " announces " + std::to_string(*corners) + " corners but lists " +
                                        std::to_string(t.size() - 1));
            for (std::size_t k = 1; k <= std::size_t(*corners); ++k) {
                auto const index = parse_integer(t[k]);
                if (!index) fail(lines.where(), face + ": vertex index " + shown(t[k]) + " is not an integer");
                if (*index < 0 || *index >= vertices)
                    fail(lines.where(), face + ": vertex index " + std::to_string(*index) + " is out of range (" +
                                            std::to_string(vertices) + " vertices)");
            }
        }
        return std::size_t(faces);
    }

    // --- PLY: header, then every element walked (ASCII tokens or binary values).
    struct ply_property {
        std::string name;
        std::string type;       // value type
        std::string count_type; // list count type; empty for a scalar
    };
    struct ply_element {
        std::string name;
        long long count = 0;
        std::vector<ply_property> properties;
    };

    static int ply_size(std::string_view type) {
        if (type == "char" || type == "uchar" || type == "int8" || type == "uint8") return 1;
        if (type == "short" || type == "ushort" || type == "int16" || type == "uint16") return 2;
        if (type == "int" || type == "uint" || type == "int32" || type == "uint32" || type == "float" || type == "float32")
            return 4;
        if (type == "double" || type == "float64") return 8;
        return 0;
    }

    // Binary values of a PLY body, in the file's byte order.
    struct ply_binary_source {
        std::string_view body;
        bool big_endian;
        std::size_t offset = 0;

        std::optional<double> value(std::string_view type) {
            int const size = ply_size(type);
            if (offset + std::size_t(size) > body.size()) return std::nullopt;
            std::array<unsigned char, 8> b{};
            std::memcpy(b.data(), body.data() + offset, std::size_t(size));
            offset += std::size_t(size);
            if (big_endian != (std::endian::native == std::endian::big)) std::reverse(b.begin(), b.begin() + size);
            auto const as = [&]<typename T>(T) {
                T v;
                std::memcpy(&v, b.data(), sizeof v);
                return double(v);
            };
            if (type == "char" || type == "int8") return as(std::int8_t{});
            if (type == "uchar" || type == "uint8") return as(std::uint8_t{});
            if (type == "short" || type == "int16") return as(std::int16_t{});
            if (type == "ushort" || type == "uint16") return as(std::uint16_t{});
            if (type == "int" || type == "int32") return as(std::int32_t{});
            if (type == "uint" || type == "uint32") return as(std::uint32_t{});
            if (type == "float" || type == "float32") return as(float{});
            return as(double{});
        }
        // Binary data has no lines: the messages name the element and its index themselves.
        std::string where(std::string const&, long long) const { return {}; }
        std::string describe(double v) const {
            std::ostringstream s;
            s.precision(9);
            s << v;
            return s.str();
        }
    };

    // ASCII values of a PLY body: whitespace-separated tokens, with line numbers.
    struct ply_ascii_source {
        file_checker const& checker;
        std::string_view body;
        std::size_t first_line;
        std::size_t offset = 0, line = 0;
        std::string_view last;

        std::optional<double> value(std::string_view) {
            auto const space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v'; };
            while (offset < body.size() && space(body[offset])) line += body[offset++] == '\n';
            if (offset == body.size()) return std::nullopt;
            std::size_t const start = offset;
            while (offset < body.size() && !space(body[offset])) ++offset;
            last = body.substr(start, offset - start);
            auto const v = parse_number(last);
            if (!v) checker.fail(std::to_string(first_line + line), "value " + shown(last) + " is not a number");
            return v;
        }
        std::string where(std::string const&, long long) const { return std::to_string(first_line + line); }
        std::string describe(double) const { return shown(last); }
    };

    template <typename Source>
    void walk_ply(std::vector<ply_element> const& elements, Source& source) const {
        long long vertices = 0;
        for (auto const& e : elements)
            if (e.name == "vertex") vertices = e.count;
        for (auto const& e : elements) {
            bool const is_vertex = e.name == "vertex", is_face = e.name == "face";
            for (long long i = 0; i < e.count; ++i) {
                auto const read = [&](std::string_view type) {
                    auto const v = source.value(type);
                    if (!v)
                        fail(source.where(e.name, i), "file ends in " + e.name + " " + std::to_string(i) + " of " +
                                                          std::to_string(e.count));
                    return *v;
                };
                for (auto const& p : e.properties) {
                    if (p.count_type.empty()) {
                        double const v = read(p.type);
                        if (is_vertex && (p.name == "x" || p.name == "y" || p.name == "z") && !std::isfinite(v))
                            fail(source.where(e.name, i), "vertex " + std::to_string(i) + ": coordinate " + p.name + " = " +
                                                              source.describe(v) + " is not finite");
                        continue;
                    }
                    double const n = read(p.count_type);
                    if (!(n >= 0.0) || n != std::floor(n))
                        fail(source.where(e.name, i), e.name + " " + std::to_string(i) + ": list length " +
                                                          source.describe(n) + " is not a count");
                    bool const indices = is_face && (p.name == "vertex_indices" || p.name == "vertex_index");
                    if (indices && n < 3.0)
                        fail(source.where(e.name, i), "face " + std::to_string(i) + " has " + std::to_string(long(n)) +
                                                          " corners (at least 3 needed)");
                    for (long long k = 0; k < static_cast<long long>(n); ++k) {
                        double const v = read(p.type);
                        if (indices && (v < 0.0 || v >= double(vertices) || v != std::floor(v)))
                            fail(source.where(e.name, i), "face " + std::to_string(i) + ": vertex index " +
                                                              source.describe(v) + " is out of range (" +
                                                              std::to_string(vertices) + " vertices)");
                    }
                }
            }
        }
    }

    std::optional<std::size_t> check_ply() const {
        std::size_t const end = data.find("end_header");
        if (data.substr(0, 3) != "ply") fail("1", "not a PLY file (it does not begin with 'ply')");
        if (end == std::string_view::npos) fail("", "PLY header has no end_header");
        std::size_t body_start = data.find('\n', end);
        body_start = body_start == std::string_view::npos ? data.size() : body_start + 1;

        line_reader lines(data.substr(0, body_start), '\0');
        std::vector<std::string_view> t;
        std::vector<ply_element> elements;
        std::string format;
        while (lines.next(t)) {
            std::string const where = lines.where();
            if (t[0] == "ply" || t[0] == "comment" || t[0] == "obj_info") continue;
            if (t[0] == "end_header") break;
            if (t[0] == "format") {
                if (t.size() < 2) fail(where, "format line without a format");
                format = std::string(t[1]);
                if (format != "ascii" && format != "binary_little_endian" && format != "binary_big_endian")
                    fail(where, "unknown PLY format " + shown(t[1]));
            } else if (t[0] == "element") {
                std::optional<long long> const count = t.size() == 3 ? parse_integer(t[2]) : std::nullopt;
                if (!count || *count < 0) fail(where, "element line needs a name and a count");
                elements.push_back({std::string(t[1]), *count, {}});
            } else if (t[0] == "property") {
                if (elements.empty()) fail(where, "property before any element");
                bool const list = t.size() == 5 && t[1] == "list";
                if (!(list || t.size() == 3)) fail(where, "malformed property line");
                ply_property p{std::string(t.back()), std::string(list ? t[3] : t[1]), list ? std::string(t[2]) : ""};
                if (ply_size(p.type) == 0 || (list && ply_size(p.count_type) == 0))
                    fail(where, "unknown PLY type in property " + shown(p.name));
                elements.back().properties.push_back(std::move(p));
            } else {
                fail(where, "unknown PLY header line " + shown(t[0]));
            }
        }
        if (format.empty()) fail("", "PLY header has no format line");
        std::string_view const body = data.substr(body_start);
        if (format == "ascii") {
            ply_ascii_source source{*this, body, lines.number() + 1, 0, 0, {}};
            walk_ply(elements, source);
        } else {
            ply_binary_source source{body, format == "binary_big_endian"};
            walk_ply(elements, source);
        }
        for (auto const& e : elements)
            if (e.name == "face") return std::size_t(e.count);
        return 0;
    }

    // OpenMesh's STL reader merges equal corners into one vertex and skips a facet two of whose
    // corners are equal, before its importer sees it.
    static bool stl_facet_is_degenerate(std::array<float, 9> const& c) {
        auto const same = [&](std::size_t a, std::size_t b) {
            return c[3 * a] == c[3 * b] && c[3 * a + 1] == c[3 * b + 1] && c[3 * a + 2] == c[3 * b + 2];
        };
        return same(0, 1) || same(0, 2) || same(1, 2);
    }
    mutable std::size_t stl_degenerate = 0;

    // --- STL: binary when the size matches its triangle count, else ASCII beginning with "solid".
    std::optional<std::size_t> check_stl() const {
        constexpr std::size_t header = 84, record = 50;
        std::optional<std::size_t> announced;
        if (data.size() >= header) {
            std::uint32_t const n = little_endian_u32(data.data() + 80);
            announced = n;
            if (header + record * std::size_t(n) == data.size()) {
                for (std::size_t i = 0; i < n; ++i) {
                    std::array<float, 9> corners{};
                    for (std::size_t c = 0; c < 9; ++c) {
                        corners[c] = std::bit_cast<float>(little_endian_u32(data.data() + header + record * i + 12 + 4 * c));
                        if (!std::isfinite(corners[c]))
                            fail("triangle " + std::to_string(i),
                                 "corner " + std::to_string(c / 3) + " has a coordinate that is not finite");
                    }
                    stl_degenerate += stl_facet_is_degenerate(corners);
                }
                return std::size_t(n);
            }
        }
        std::size_t const first = data.find_first_not_of(" \t\r\n");
        if (first == std::string_view::npos || data.substr(first, 5) != "solid") {
            if (announced)
                fail("", "not an STL file: as binary STL its header announces " + std::to_string(*announced) +
                             " triangles (" + std::to_string(header + record * *announced) + " bytes), the file has " +
                             std::to_string(data.size()) + " bytes (truncated?); as ASCII STL it does not begin with 'solid'");
            fail("", "not an STL file: too short for binary STL (" + std::to_string(data.size()) +
                         " bytes, the header alone has 84) and not ASCII STL (it does not begin with 'solid')");
        }
        line_reader lines(data, '\0');
        std::vector<std::string_view> t;
        std::size_t facets = 0, corner = 0;
        std::array<float, 9> corners{};
        while (lines.next(t)) {
            if (t[0] == "facet") ++facets, corner = 0;
            if (t[0] != "vertex") continue;
            if (t.size() != 4) fail(lines.where(), "vertex line needs three coordinates");
            for (std::size_t i = 1; i < 4; ++i) {
                float const v = float(finite_number(t[i], lines.where(), "coordinate"));
                if (corner < 9) corners[corner++] = v;
            }
            if (corner == 9) stl_degenerate += stl_facet_is_degenerate(corners), corner = 10;
        }
        return facets;
    }

    // --- OBJ: v lines finite, face corners in range; returns the number of f lines.
    std::optional<std::size_t> check_obj() const {
        line_reader lines(data, '#');
        std::vector<std::string_view> t;
        std::size_t positions = 0, texcoords = 0, normals = 0, faces = 0;
        auto const check_index = [&](std::string_view token, std::size_t defined, char const* what) {
            auto const i = parse_integer(token);
            if (!i) fail(lines.where(), std::string(what) + " index " + shown(token) + " is not an integer");
            long long const n = static_cast<long long>(defined);
            if (*i == 0 || *i > n || *i < -n)
                fail(lines.where(), std::string(what) + " index " + std::to_string(*i) + " is out of range (" +
                                        std::to_string(defined) + " defined before this line)");
        };
        while (lines.next(t)) {
            if (t[0] == "v") {
                if (t.size() < 4) fail(lines.where(), "vertex needs three coordinates");
                for (std::size_t i = 1; i < 4; ++i) finite_number(t[i], lines.where(), "vertex coordinate");
                ++positions;
            } else if (t[0] == "vt") {
                ++texcoords;
            } else if (t[0] == "vn") {
                ++normals;
            } else if (t[0] == "f") {
                if (t.size() < 4)
                    fail(lines.where(), "face has " + std::to_string(t.size() - 1) + " corners (at least 3 needed)");
                for (std::size_t k = 1; k < t.size(); ++k) {
                    std::string_view c = t[k];
                    std::array<std::string_view, 3> parts{};
                    for (int part = 0; part < 3; ++part) {
                        std::size_t const slash = c.find('/');
                        parts[std::size_t(part)] = c.substr(0, slash);
                        if (slash == std::string_view::npos) break;
                        c.remove_prefix(slash + 1);
                    }
                    check_index(parts[0], positions, "vertex");
                    if (!parts[1].empty()) check_index(parts[1], texcoords, "texture coordinate");
                    if (!parts[2].empty()) check_index(parts[2], normals, "normal");
                }
                ++faces;
            }
        }
        return faces;
    }

    // --- OM: the header (magic, counts).
    std::optional<std::size_t> check_om() const {
        if (data.size() < 16 || data.substr(0, 2) != "OM")
            fail("", "not an OpenMesh .om file (no 16-byte header beginning with 'OM')");
        return little_endian_u32(data.data() + 8);
    }
};

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

} // namespace

openmesh_read_result read_openmesh(std::filesystem::path const& path) {
    std::string const file = path.string();
    std::string const ext = extension_of(path);

    std::string data;
    {
        std::ifstream in(path, std::ios::binary);
        if (!in) throw scene_error(file, "", std::filesystem::exists(path) ? "cannot be opened" : "file not found");
        data.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
        if (in.bad()) throw scene_error(file, "", "cannot be read");
    }
    if (data.find_first_not_of(" \t\r\n") == std::string::npos) throw scene_error(file, "", "file is empty");

    file_checker const checker{file, data};
    std::optional<std::size_t> declared;
    std::string clean_off;
    if (ext == ".off") declared = checker.check_off(clean_off);
    else if (ext == ".ply") declared = checker.check_ply();
    else if (ext == ".stl") declared = checker.check_stl();
    else if (ext == ".obj") declared = checker.check_obj();
    else if (ext == ".om") declared = checker.check_om();
    else throw scene_error(file, "", "extension '" + ext + "' is not one OpenMesh reads here (.ply .off .stl .om .obj)");

    std::string().swap(data); // checked: OpenMesh reads the file (or clean_off) itself

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
        if (clean_off.empty()) {
            ok = OpenMesh::IO::IOManager().read(file, importer, options);
        } else {
            std::istringstream text(clean_off);
            ok = OpenMesh::IO::IOManager().read(text, "off", importer, options);
        }
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
    if (declared && ext == ".stl") *declared -= std::min(*declared, checker.stl_degenerate);
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
    result.degenerate_faces = checker.stl_degenerate;
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
        r.add_loader(ext, "openmesh", "triangle mesh through OpenMesh (polygons triangulated)",
                     [](scene& s, std::filesystem::path const& file, node_id parent, registry const&) {
                         return load_openmesh(s, file, parent);
                     });
}

} // namespace canopy
