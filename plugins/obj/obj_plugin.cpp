// canopy.plugins.obj — implementation: the OBJ and MTL parsers (see obj_plugin.cppm for the
// statements read and the errors reported). Everything is linear in the input: no allocation is
// sized by a number read from the file.
module;
#include <algorithm>
#include <array>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <iterator>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>
module canopy.plugins.obj;

namespace canopy {

namespace {

namespace fs = std::filesystem;

constexpr std::uint32_t absent = ~std::uint32_t(0);

[[noreturn]] void fail(std::string const& file, std::size_t line, std::string const& problem) {
    throw scene_error(file, line_where(line), problem);
}

bool equals_ignoring_case(std::string_view a, std::string_view b) {
    return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
               return std::tolower(static_cast<unsigned char>(x)) == std::tolower(static_cast<unsigned char>(y));
           });
}

// The lines of an OBJ or MTL text (`format`), after require_text (canopy.scene:limits: "not a text
// OBJ file: NUL byte at offset 12", a UTF-16 byte-order mark) and without a UTF-8 byte-order mark.
line_reader text_lines(std::string_view text, std::string const& file, char const* format) {
    require_text(text, file, format);
    return line_reader(skip_utf8_bom(text));
}

// Reads `count_min`..`count_max` numbers from tokens[1..].
template <std::size_t N>
std::size_t parse_floats(std::vector<std::string_view> const& tokens, std::size_t count_min, std::array<float, N>& out,
                         std::string const& file, std::size_t line, char const* expected) {
    std::size_t const n = tokens.size() - 1;
    if (n < count_min || n > N)
        fail(file, line, "'" + excerpt(tokens[0]) + "' needs " + expected + ", found " + std::to_string(n) + " values");
    for (std::size_t k = 0; k < n; ++k) out[k] = parse_float(tokens[k + 1], file, line);
    return n;
}

struct corner {
    std::uint32_t v = absent, vt = absent, vn = absent;
};

// The faces of one material, as triangles (canopy.scene:polygon), in file order.
struct bucket {
    std::string material;
    std::vector<std::array<corner, 3>> triangles;
    bool any_uv = false, any_normal = false;
    std::size_t fanned_faces = 0; // triangulate_polygon's fallback: fanned, may cover more than the face
    std::size_t first_fanned_line = 0;
};

// A texture statement's file, after its options. Options that change the lookup are refused.
std::string texture_path(std::string_view line, std::vector<std::string_view> const& tokens, std::string const& file,
                         std::size_t line_number) {
    std::size_t k = 1;
    while (k < tokens.size() && tokens[k].size() > 1 && tokens[k][0] == '-') {
        std::string_view const option = tokens[k];
        std::size_t arguments = 0;
        if (option == "-blendu" || option == "-blendv" || option == "-cc" || option == "-texres" || option == "-bm" ||
            option == "-boost")
            arguments = 1;
        else if (option == "-mm")
            arguments = 2;
        else if (option == "-o" || option == "-s" || option == "-t" || option == "-clamp" || option == "-imfchan")
            fail(file, line_number, "texture option " + excerpt(option) + " is not supported");
        else
            fail(file, line_number, "unknown texture option " + excerpt(option));
        if (k + arguments >= tokens.size())
            fail(file, line_number, "texture option " + excerpt(option) + " needs " + std::to_string(arguments) +
                                        " value" + (arguments == 1 ? "" : "s") + " and a file name");
        k += 1 + arguments;
    }
    if (k >= tokens.size()) fail(file, line_number, "'" + excerpt(tokens[0]) + "' needs a file name");
    std::string path(rest_from(line, tokens[k]));
    check_path_length(path, file, line_number, "texture file name");
    std::replace(path.begin(), path.end(), '\\', '/');
    return path;
}

// The material's texture: map_Kd, with map_d's red channel as alpha when given. texels_held: those
// of the scene's images (the budget of --max-total-texels); the alpha image counts the colour's.
std::optional<image_data> material_texture(mtl_material const& m, fs::path const& mtl_file, registry const& r,
                                           std::uint64_t texels_held, bool& mask) {
    auto const load = [&](std::string const& relative, std::size_t line) {
        try {
            return r.load_image(mtl_file.parent_path() / fs::path(relative), texels_held);
        } catch (scene_error const& e) {
            fail(mtl_file.string(), line, "texture '" + excerpt(relative) + "': " + e.what());
        }
    };
    std::optional<image_data> colour, alpha;
    if (!m.colour_texture.empty()) colour = load(m.colour_texture, m.colour_texture_line);
    if (colour) texels_held += colour->texels.size();
    if (!m.alpha_texture.empty()) alpha = load(m.alpha_texture, m.alpha_texture_line);
    auto const valid = [&](image_data const& img, std::size_t line) {
        if (img.width <= 0 || img.height <= 0 || img.texels.size() != std::size_t(img.width) * std::size_t(img.height))
            fail(mtl_file.string(), line, "texture '" + excerpt(img.source) + "' has no texels");
    };
    if (colour) valid(*colour, m.colour_texture_line);
    if (alpha) valid(*alpha, m.alpha_texture_line);
    if (!alpha) {
        if (colour)
            mask = std::any_of(colour->texels.begin(), colour->texels.end(), [](vec4<float> t) { return t.w < 1.0f; });
        return colour;
    }
    mask = true;
    image_data out;
    if (colour) {
        out = std::move(*colour);
    } else {
        out.source = alpha->source;
        out.width = alpha->width;
        out.height = alpha->height;
        out.texels.assign(alpha->texels.size(), vec4<float>{1.0f, 1.0f, 1.0f, 1.0f});
    }
    // Nearest resampling of the alpha image onto the colour image's texels.
    for (std::int64_t y = 0; y < out.height; ++y)
        for (std::int64_t x = 0; x < out.width; ++x) {
            std::int64_t const ax = x * alpha->width / out.width, ay = y * alpha->height / out.height;
            out.texels[std::size_t(y * out.width + x)].w = alpha->texels[std::size_t(ay * alpha->width + ax)].x;
        }
    out.source += " (alpha: " + alpha->source + ")";
    return out;
}

vec3<float> geometric_normal(vec3<float> a, vec3<float> b, vec3<float> c) {
    vec3<float> const n = cross(b - a, c - a);
    float const len = std::sqrt(dot(n, n));
    return len > 0.0f && std::isfinite(len) ? n / len : vec3<float>{0.0f, 0.0f, 0.0f};
}

class obj_parser {
public:
    obj_parser(std::string const& file, registry const* r, scene& s)
        : file_(file), r_(r), s_(s), max_elements_(std::min<std::uint64_t>(default_limits().max_triangles, absent - 1)) {}

    node_id run(std::string_view text, node_id parent) {
        std::vector<std::string_view> tokens;
        std::vector<corner> face;
        bool any_statement = false, points_or_lines = false; // of OBJ's geometry and grouping statements
        line_reader lines = text_lines(text, file_, "OBJ");
        while (lines.next(tokens)) {
            std::size_t const line = lines.number();
            std::string_view const content = lines.line();
            std::string_view const op = tokens[0];
            if (op == "v") {
                std::array<float, 7> c{};
                parse_floats(tokens, 3, c, file_, line, "3 to 7 numbers (x y z [w] or x y z r g b [a])");
                grow(positions_.size(), line, "vertices");
                positions_.push_back({c[0], c[1], c[2]});
            } else if (op == "vt") {
                std::array<float, 3> c{};
                parse_floats(tokens, 1, c, file_, line, "1 to 3 numbers (u [v [w]])");
                grow(uvs_.size(), line, "texture coordinates");
                uvs_.push_back({c[0], 1.0f - c[1]});
            } else if (op == "vn") {
                std::array<float, 3> c{};
                parse_floats(tokens, 3, c, file_, line, "3 numbers (x y z)");
                grow(normals_.size(), line, "normals");
                normals_.push_back({c[0], c[1], c[2]});
            } else if (op == "f") {
                read_face(tokens, face, line);
            } else if (op == "usemtl") {
                use_material(std::string(rest_after(content, op)));
            } else if (op == "mtllib") {
                read_libraries(content, tokens, line);
            } else if (op == "l" || op == "p") {
                points_or_lines = true;
            } else if (!(op == "o" || op == "g" || op == "s" || op == "vp")) {
                continue;
            }
            any_statement = true;
        }
        if (triangles_ == 0)
            fail(file_, 0, text.find_first_not_of(" \t\r\n\v\f") == std::string_view::npos ? "is empty: nothing to trace"
                           : !any_statement   ? "not an OBJ file: no OBJ statement (v, f, ...) in it, nothing to trace"
                           : points_or_lines ? "no faces ('f' lines), only points or lines: nothing to trace"
                                             : "no faces ('f' lines): nothing to trace");
        return build(parent);
    }

private:
    // Vertices, texture coordinates, normals and triangles each up to --max-triangles (and 32-bit
    // indices), checked as they grow.
    void grow(std::uint64_t count, std::size_t line, char const* what, std::uint64_t added = 1) const {
        check_limit(file_, std::to_string(line), count + added, max_elements_, what, "--max-triangles");
    }

    void use_material(std::string name) {
        auto [it, inserted] = bucket_of_.try_emplace(name, buckets_.size());
        if (inserted) buckets_.push_back({std::move(name), {}, false, false});
        current_ = it->second;
    }

    void read_face(std::vector<std::string_view> const& tokens, std::vector<corner>& face, std::size_t line) {
        if (tokens.size() < 4)
            fail(file_, line, "face has " + std::to_string(tokens.size() - 1) + " corners; at least 3 are needed");
        face.clear();
        for (std::size_t k = 1; k < tokens.size(); ++k) {
            std::string_view const token = tokens[k];
            obj_corner const read = read_obj_corner(token, {positions_.size(), uvs_.size(), normals_.size()}, file_, line);
            // Each count is below max_elements_ < 2^32 - 1 (grow), so every index fits 32 bits.
            corner c;
            c.v = std::uint32_t(read.v);
            if (read.vt) c.vt = std::uint32_t(*read.vt);
            if (read.vn) c.vn = std::uint32_t(*read.vn);
            if (!face.empty() && ((c.vt == absent) != (face[0].vt == absent) || (c.vn == absent) != (face[0].vn == absent)))
                fail(file_, line, "corner '" + excerpt(token) + "' has another form than the face's first corner '" +
                                      excerpt(tokens[1]) + "'");
            face.push_back(c);
        }
        grow(triangles_, line, "triangles", face.size() - 2);
        triangles_ += face.size() - 2;
        if (current_ == absent) use_material({});
        bucket& b = buckets_[current_];
        b.any_uv = b.any_uv || face[0].vt != absent;
        b.any_normal = b.any_normal || face[0].vn != absent;
        if (face.size() == 3) {
            b.triangles.push_back({face[0], face[1], face[2]});
            return;
        }
        points_.clear();
        for (corner const& c : face) points_.push_back(positions_[c.v]);
        polygon_triangles const cut = triangulate_polygon(points_);
        if (cut.fanned_fallback && b.fanned_faces++ == 0) b.first_fanned_line = line;
        for (auto const& t : cut.triangles) b.triangles.push_back({face[t[0]], face[t[1]], face[t[2]]});
    }

    // Each library is read once, however often `mtllib` names it (the first definition of a
    // material wins, so reading it again would add nothing).
    void read_libraries(std::string_view content, std::vector<std::string_view> const& tokens, std::size_t line) {
        if (tokens.size() < 2) fail(file_, line, "'mtllib' needs a file name");
        fs::path const folder = fs::path(file_).parent_path();
        std::vector<std::string> names;
        std::string whole(rest_after(content, tokens[0]));
        std::replace(whole.begin(), whole.end(), '\\', '/');
        std::error_code ec;
        if (tokens.size() > 2 && whole.size() <= max_path_bytes && fs::is_regular_file(folder / whole, ec)) names.push_back(whole);
        else
            for (std::size_t k = 1; k < tokens.size(); ++k) {
                std::string name(tokens[k]);
                std::replace(name.begin(), name.end(), '\\', '/');
                names.push_back(std::move(name));
            }
        for (auto const& name : names) {
            check_path_length(name, file_, line, "material library name");
            fs::path const library = folder / fs::path(name);
            auto const canonical = fs::weakly_canonical(library, ec);
            if (!libraries_read_.insert((ec ? library.lexically_normal() : canonical).string()).second) continue;
            std::string text;
            try {
                text = read_regular_file(library);
            } catch (scene_error const& e) {
                fail(file_, line, "material library '" + excerpt(name) + "': " + e.problem());
            }
            for (auto& m : parse_mtl(text, library.string())) {
                std::string key = m.name;
                materials_.try_emplace(std::move(key), std::move(m), library); // the first definition wins
            }
        }
    }

    int material_index(std::string const& name) {
        auto it = materials_.find(name);
        if (it == materials_.end()) return -1;
        auto const& [m, library] = it->second;
        material_data md;
        md.name = m.name;
        if (m.colour) md.colour = *m.colour;
        else if (!m.colour_texture.empty()) md.colour = {1.0f, 1.0f, 1.0f};
        if (r_ != nullptr && (!m.colour_texture.empty() || !m.alpha_texture.empty())) {
            // Materials naming the same texture files share one image.
            fs::path const folder = library.parent_path();
            std::pair<std::string, std::string> key{
                m.colour_texture.empty() ? std::string() : (folder / m.colour_texture).lexically_normal().string(),
                m.alpha_texture.empty() ? std::string() : (folder / m.alpha_texture).lexically_normal().string()};
            auto shared = images_.find(key);
            if (shared == images_.end()) {
                bool mask = false;
                std::optional<image_data> img = material_texture(m, library, *r_, s_.texels(), mask);
                shared = images_.emplace(std::move(key), std::pair{img ? s_.add_image(std::move(*img)) : -1, mask}).first;
            }
            md.image = shared->second.first;
            if (md.image >= 0 && shared->second.second) {
                md.alpha = alpha_mode::mask;
                md.alpha_cutoff = 0.5f;
            }
        }
        return s_.add_material(std::move(md));
    }

    node_id build(node_id parent) {
        std::string const stem = fs::path(file_).stem().string();
        node_id const group = s_.add_group(parent, stem);
        std::vector<std::uint32_t> local(positions_.size(), absent);
        for (bucket& b : buckets_) {
            if (b.triangles.empty()) continue; // a `usemtl` no face follows
            mesh_data m;
            m.name = b.material.empty() && bucket_of_.size() == 1 ? stem : b.material;
            m.source = file_;
            m.fanned_faces = b.fanned_faces;
            if (b.fanned_faces > 0) m.first_fanned = std::to_string(b.first_fanned_line);
            m.triangles.reserve(b.triangles.size());
            for (auto const& t : b.triangles) {
                std::array<std::uint32_t, 3> tri{};
                for (std::size_t k = 0; k < 3; ++k) {
                    std::uint32_t& l = local[t[k].v];
                    if (l == absent) {
                        l = std::uint32_t(m.positions.size());
                        m.positions.push_back(positions_[t[k].v]);
                    }
                    tri[k] = l;
                }
                m.triangles.push_back(tri);
                if (b.any_uv) {
                    std::array<vec2<float>, 3> uv{};
                    for (std::size_t k = 0; k < 3; ++k)
                        if (t[k].vt != absent) uv[k] = uvs_[t[k].vt];
                    m.uvs.push_back(uv);
                }
                if (b.any_normal) {
                    std::array<vec3<float>, 3> n{};
                    vec3<float> const g = t[0].vn == absent ? geometric_normal(positions_[t[0].v], positions_[t[1].v],
                                                                               positions_[t[2].v])
                                                            : vec3<float>{};
                    for (std::size_t k = 0; k < 3; ++k) n[k] = t[k].vn != absent ? normals_[t[k].vn] : g;
                    m.normals.push_back(n);
                }
            }
            for (auto const& t : b.triangles)
                for (auto const& c : t) local[c.v] = absent;
            b.triangles = {};
            m.material = material_index(b.material);
            std::string const name = m.name;
            std::uint32_t const mesh = s_.add_mesh(std::move(m));
            s_.add_mesh_node(group, mesh, name);
        }
        return group;
    }

    std::string const& file_;
    registry const* r_;
    scene& s_;
    std::vector<vec3<float>> positions_, normals_;
    std::vector<vec3<float>> points_; // the corners of the face being triangulated
    std::vector<vec2<float>> uvs_;
    std::vector<bucket> buckets_;
    std::map<std::string, std::size_t> bucket_of_;
    std::size_t current_ = absent;
    std::map<std::string, std::pair<mtl_material, fs::path>> materials_;
    std::set<std::string> libraries_read_;
    std::map<std::pair<std::string, std::string>, std::pair<int, bool>> images_; // (map_Kd, map_d) → image, mask
    std::uint64_t const max_elements_;
    std::uint64_t triangles_ = 0;
};

} // namespace

std::vector<mtl_material> parse_mtl(std::string_view text, std::string const& file_name) {
    std::vector<mtl_material> out;
    std::vector<std::string_view> tokens;
    line_reader lines = text_lines(text, file_name, "MTL");
    while (lines.next(tokens)) {
        std::size_t const line = lines.number();
        std::string_view const content = lines.line();
        std::string_view const op = tokens[0];
        if (equals_ignoring_case(op, "newmtl")) {
            out.push_back({});
            out.back().name = std::string(rest_after(content, op));
            out.back().line = line;
            continue;
        }
        bool const kd = equals_ignoring_case(op, "Kd"), map_kd = equals_ignoring_case(op, "map_Kd"),
                   map_d = equals_ignoring_case(op, "map_d");
        if (!kd && !map_kd && !map_d) continue;
        if (out.empty()) fail(file_name, line, "'" + excerpt(op) + "' before any 'newmtl'");
        mtl_material& m = out.back();
        if (kd) {
            if (tokens.size() > 1 && (equals_ignoring_case(tokens[1], "spectral") || equals_ignoring_case(tokens[1], "xyz")))
                fail(file_name, line, "'Kd " + excerpt(tokens[1]) + "' is not supported; give r g b");
            std::array<float, 3> c{};
            std::size_t const n = parse_floats(tokens, 1, c, file_name, line, "1 or 3 numbers (r [g b])");
            if (n == 2) fail(file_name, line, "'Kd' needs 1 or 3 numbers (r [g b]), found 2 values");
            if (n == 1) c[1] = c[2] = c[0];
            if (c[0] < 0.0f || c[1] < 0.0f || c[2] < 0.0f) fail(file_name, line, "colour has a negative component");
            m.colour = vec3<float>{c[0], c[1], c[2]};
        } else if (map_kd) {
            m.colour_texture = texture_path(content, tokens, file_name, line);
            m.colour_texture_line = line;
        } else {
            m.alpha_texture = texture_path(content, tokens, file_name, line);
            m.alpha_texture_line = line;
        }
    }
    return out;
}

node_id parse_obj(std::string_view text, std::string const& file_name, registry const* r, scene& s, node_id parent) {
    auto const mark = s.make_mark();
    try {
        return obj_parser(file_name, r, s).run(text, parent);
    } catch (scene_error const& e) {
        s.roll_back(mark);
        if (!e.file().empty()) throw;
        throw scene_error(file_name, e.where(), e.problem());
    } catch (...) {
        s.roll_back(mark);
        throw;
    }
}

node_id load_obj(scene& s, std::filesystem::path const& file, node_id parent, registry const& r) {
    std::string const text = read_regular_file(file);
    return parse_obj(text, file.string(), &r, s, parent);
}

void register_obj_plugin(registry& r) {
    r.add_loader(".obj", "obj", "Wavefront OBJ + MTL (Canopy's reader: polygons, materials, alpha masks)", load_obj);
}

} // namespace canopy
