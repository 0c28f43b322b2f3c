// canopy.plugins.json — implementation: nlohmann-json parses, this file checks every key and
// builds the scene (docs/scene/json.md is the format's reference).
module;
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <map>
#include <numbers>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
module canopy.plugins.json;

namespace canopy {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

// Nodes nested deeper than this are refused (the builder recurses once per level).
constexpr int max_depth = 256;

std::string type_name(json const& j) {
    switch (j.type()) {
    case json::value_t::null: return "null";
    case json::value_t::object: return "an object";
    case json::value_t::array: return "an array";
    case json::value_t::string: return "a string";
    case json::value_t::boolean: return "a boolean";
    case json::value_t::number_integer:
    case json::value_t::number_unsigned:
    case json::value_t::number_float: return "a number";
    default: return "binary data";
    }
}

std::string at_index(std::string const& path, std::size_t i) { return path + "[" + std::to_string(i) + "]"; }
std::string at_key(std::string const& path, std::string const& key) { return path.empty() ? key : path + "." + key; }

// Files being loaded by this plugin on this thread (a scene referring to itself is refused).
thread_local std::vector<std::string> files_in_progress;

// A file's name for comparisons: canonical where it can be made so, else as given.
std::string canonical_name(fs::path const& file) {
    std::error_code ec;
    auto const canonical = fs::weakly_canonical(file, ec);
    return (ec ? file : canonical).string();
}

// The mesh files and textures loaded while one scene is loaded, nested scene files included: each
// mesh file (with its loader) is loaded once, and every mesh node that places it shares its node
// tree; each texture is loaded once, and every material naming it shares the image. So memory and
// work stay linear in the distinct files however often, and however deeply nested, they are
// referred to. Keyed by canonical file name (and loader); held by the outermost parse_json_scene
// of a scene (active_files), on this thread.
struct shared_files {
    scene const* s = nullptr;
    std::map<std::string, node_id> loaded;
    std::map<std::string, int> images;
};
thread_local shared_files* active_files = nullptr;

class builder {
public:
    builder(std::string const& file, registry const* r, scene& s)
        : file_(file), folder_(fs::path(file).parent_path()), r_(r), s_(s) {}

    node_id run(std::string_view text, node_id parent) {
        json doc;
        try {
            // Arrays and objects nested deeper than --max-depth are refused on the text, before
            // parsing: one linear pass (a parser callback would make nlohmann-json 3.11.2 rescan
            // the enclosing array at each object's end, quadratic in an array of 10^5 nodes).
            std::uint64_t const max_nesting = default_limits().max_depth;
            if (json_nesting_over(text, max_nesting) != std::string_view::npos)
                check_limit(file_, "", max_nesting + 1, max_nesting, "levels of nested arrays and objects", "--max-depth");
            doc = json::parse(text.begin(), text.end());
        } catch (json::exception const& e) { // syntax errors, numbers that overflow a double
            throw scene_error(file_, "", parser_message(e.what()));
        }
        if (!doc.is_object()) fail("", "the document must be a JSON object, not " + type_name(doc));
        check_keys(doc, "", {"version", "materials", "meshes", "prototypes", "nodes"});
        if (doc.contains("version")) {
            json const& v = doc["version"];
            if (!v.is_number_integer() || v.get<std::int64_t>() != 1) fail("version", "must be 1 (the only version)");
        }
        if (json const* m = optional(doc, "materials", "")) for_each(*m, "materials", [&](json const& e, std::string const& p) { material(e, p); });
        if (json const* m = optional(doc, "meshes", "")) for_each(*m, "meshes", [&](json const& e, std::string const& p) { mesh(e, p); });
        if (json const* p = optional(doc, "prototypes", "")) prototypes(*p);
        node_id const group = s_.add_group(parent, fs::path(file_).stem().string());
        if (json const* n = optional(doc, "nodes", ""))
            for_each(*n, "nodes", [&](json const& e, std::string const& p) { node(e, p, group, 1); });
        return group;
    }

private:
    // nlohmann-json's message without its "[json.exception.…] " tag, and the input it quotes last
    // ("…; last read: '<token>'", "number overflow parsing '<token>'") cut to a short prefix.
    static std::string parser_message(std::string what) {
        if (auto const close = what.find("] "); what.starts_with("[json.exception") && close != std::string::npos)
            what = what.substr(close + 2);
        std::size_t const open = what.find('\'');
        if (what.ends_with('\'') && open != std::string::npos && open + 1 < what.size())
            what = what.substr(0, open + 1) + excerpt(std::string_view(what).substr(open + 1, what.size() - open - 2)) + "'";
        return what;
    }

    [[noreturn]] void fail(std::string const& path, std::string const& problem) const {
        throw scene_error(file_, path, problem);
    }

    // Runs f; a scene_error without a file (from the scene's checks) is given this file and
    // path; one from another file (a mesh file, a texture, a generator) is wrapped with the path.
    template <typename F>
    auto at(std::string const& path, F&& f) {
        try {
            return f();
        } catch (scene_error const& e) {
            if (e.file() == file_) throw;
            if (e.file().empty()) fail(path, e.where().empty() ? e.problem() : e.where() + ": " + e.problem());
            fail(path, e.what());
        }
    }

    template <typename F>
    void for_each(json const& list, std::string const& path, F&& f) {
        if (!list.is_array()) fail(path, "must be an array, not " + type_name(list));
        for (std::size_t i = 0; i < list.size(); ++i) f(list[i], at_index(path, i));
    }

    void check_keys(json const& obj, std::string const& path, std::initializer_list<std::string_view> allowed) const {
        for (auto const& [key, value] : obj.items())
            if (std::find(allowed.begin(), allowed.end(), key) == allowed.end()) {
                std::string list;
                for (auto a : allowed) list += (list.empty() ? "" : ", ") + std::string(a);
                fail(at_key(path, excerpt(key)), "unknown key (known here: " + list + ")");
            }
    }

    json const* optional(json const& obj, char const* key, std::string const&) const {
        auto it = obj.find(key);
        return it == obj.end() ? nullptr : &*it;
    }

    json const& required(json const& obj, char const* key, std::string const& path) const {
        auto it = obj.find(key);
        if (it == obj.end()) fail(path, std::string("needs the key '") + key + "'");
        return *it;
    }

    void require_object(json const& j, std::string const& path) const {
        if (!j.is_object()) fail(path, "must be an object, not " + type_name(j));
    }

    std::string string(json const& j, std::string const& path) const {
        if (!j.is_string()) fail(path, "must be a string, not " + type_name(j));
        return j.get<std::string>();
    }

    // A number that is finite as a float (1e300 is a finite double but overflows a float; a
    // number too small for a float rounds to zero).
    float number(json const& j, std::string const& path) const {
        if (!j.is_number()) fail(path, "must be a number, not " + type_name(j));
        double const v = j.get<double>();
        if (!std::isfinite(v)) fail(path, "value " + j.dump() + " is not finite");
        float const rounded = float(v);
        if (!std::isfinite(rounded)) fail(path, "value " + j.dump() + " overflows a float");
        return rounded;
    }

    std::uint32_t index(json const& j, std::string const& path, std::uint64_t limit, std::string const& what) const {
        if (!j.is_number_integer()) fail(path, "must be an integer, not " + (j.is_number() ? j.dump() : type_name(j)));
        if (j.is_number_unsigned() ? j.get<std::uint64_t>() >= limit : (j.get<std::int64_t>() < 0 || std::uint64_t(j.get<std::int64_t>()) >= limit))
            fail(path, j.dump() + " is out of range (" + what + ")");
        return std::uint32_t(j.get<std::uint64_t>());
    }

    std::vector<float> numbers(json const& j, std::string const& path, std::size_t count) const {
        if (!j.is_array() || (count != 0 && j.size() != count))
            fail(path, count == 0 ? "must be an array of numbers"
                                  : "must be an array of " + std::to_string(count) + " numbers");
        std::vector<float> out;
        out.reserve(j.size());
        for (std::size_t i = 0; i < j.size(); ++i) out.push_back(number(j[i], at_index(path, i)));
        return out;
    }

    vec3<float> vec(json const& j, std::string const& path) const {
        auto const v = numbers(j, path, 3);
        return {v[0], v[1], v[2]};
    }

    // A file the scene names, relative to its folder; a name longer than any path can be
    // (canopy.scene:text's max_path_bytes) is refused by length rather than quoted whole.
    fs::path relative(std::string const& p, std::string const& path) const {
        check_path_length(p, file_, path, "file name");
        return folder_ / fs::path(p);
    }

    registry const& plugins(std::string const& path, char const* what) const {
        if (r_ == nullptr) fail(path, std::string(what) + " needs a plugin registry (none was given)");
        return *r_;
    }

    template <typename Map>
    std::string name_of(json const& e, std::string const& path, Map const& taken, char const* section) const {
        std::string name = string(required(e, "name", path), at_key(path, "name"));
        if (taken.contains(name)) fail(at_key(path, "name"), std::string("duplicate ") + section + " name '" + excerpt(name) + "'");
        return name;
    }

    void material(json const& e, std::string const& path) {
        require_object(e, path);
        check_keys(e, path, {"name", "colour", "texture", "alphaMode", "alphaCutoff"});
        material_data m;
        m.name = name_of(e, path, materials_, "material");
        if (json const* c = optional(e, "colour", path)) {
            m.colour = vec(*c, at_key(path, "colour"));
            if (m.colour.x < 0.0f || m.colour.y < 0.0f || m.colour.z < 0.0f)
                fail(at_key(path, "colour"), "has a negative component");
        }
        if (json const* a = optional(e, "alphaMode", path)) {
            std::string const mode = string(*a, at_key(path, "alphaMode"));
            if (mode == "MASK") m.alpha = alpha_mode::mask;
            else if (mode != "OPAQUE") fail(at_key(path, "alphaMode"), "'" + excerpt(mode) + "' is not OPAQUE or MASK");
        }
        if (json const* c = optional(e, "alphaCutoff", path)) {
            m.alpha_cutoff = number(*c, at_key(path, "alphaCutoff"));
            if (!(m.alpha_cutoff >= 0.0f && m.alpha_cutoff <= 1.0f)) fail(at_key(path, "alphaCutoff"), "must be in [0, 1]");
        }
        if (json const* t = optional(e, "texture", path)) {
            std::string const p = at_key(path, "texture");
            std::string const texture = string(*t, p);
            registry const& r = plugins(p, "a texture");
            fs::path const file = relative(texture, p);
            m.image = at(p, [&] { return shared_image(r, file); });
        } else if (m.alpha == alpha_mode::mask) {
            fail(at_key(path, "alphaMode"), "MASK needs a texture (its alpha is the mask)");
        }
        std::string name = m.name;
        int const id = at(path, [&] { return s_.add_material(std::move(m)); });
        materials_.emplace(std::move(name), id);
    }

    void mesh(json const& e, std::string const& path) {
        require_object(e, path);
        std::string name = name_of(e, path, meshes_, "mesh");
        mesh_entry entry;
        if (e.contains("file")) {
            check_keys(e, path, {"name", "file", "loader"});
            std::string const p = at_key(path, "file");
            std::string const file = string(e["file"], p);
            std::string loader;
            if (json const* l = optional(e, "loader", path)) loader = string(*l, at_key(path, "loader"));
            registry const& r = plugins(p, "a mesh file");
            fs::path const mesh_file = relative(file, p);
            entry.loaded = at(p, [&] { return shared_load(r, mesh_file, loader, name); });
        } else {
            check_keys(e, path, {"name", "positions", "indices", "uvs", "material"});
            mesh_data m;
            m.name = name;
            m.source = file_;
            std::string const pp = at_key(path, "positions"), ip = at_key(path, "indices"), up = at_key(path, "uvs");
            // Counts against --max-triangles (vertices and triangles alike) before anything is built.
            std::uint64_t const max_elements = default_limits().max_triangles;
            json const& position_list = required(e, "positions", path);
            if (position_list.is_array()) check_limit(file_, pp, position_list.size() / 3, max_elements, "vertices", "--max-triangles");
            if (json const* i = optional(e, "indices", path); i != nullptr && i->is_array())
                check_limit(file_, ip, i->size() / 3, max_elements, "triangles", "--max-triangles");
            auto const positions = numbers(position_list, pp, 0);
            if (positions.size() % 3 != 0) fail(pp, "must hold 3 numbers per vertex (" + std::to_string(positions.size()) + " given)");
            for (std::size_t i = 0; i < positions.size(); i += 3)
                m.positions.push_back({positions[i], positions[i + 1], positions[i + 2]});
            if (m.positions.size() >= std::numeric_limits<std::uint32_t>::max()) fail(pp, "too many vertices");
            json const& indices = required(e, "indices", path);
            if (!indices.is_array()) fail(ip, "must be an array of integers, not " + type_name(indices));
            if (indices.size() % 3 != 0) fail(ip, "must hold 3 vertex indices per triangle (" + std::to_string(indices.size()) + " given)");
            std::string const range = std::to_string(m.positions.size()) + " vertices";
            for (std::size_t i = 0; i < indices.size(); i += 3)
                m.triangles.push_back({index(indices[i], at_index(ip, i), m.positions.size(), range),
                                       index(indices[i + 1], at_index(ip, i + 1), m.positions.size(), range),
                                       index(indices[i + 2], at_index(ip, i + 2), m.positions.size(), range)});
            if (json const* u = optional(e, "uvs", path)) {
                auto const uvs = numbers(*u, up, 0);
                if (uvs.size() != 2 * m.positions.size())
                    fail(up, "must hold 2 numbers per vertex (" + std::to_string(uvs.size()) + " given for " + range + ")");
                for (auto const& t : m.triangles)
                    m.uvs.push_back({vec2<float>{uvs[2 * t[0]], uvs[2 * t[0] + 1]}, vec2<float>{uvs[2 * t[1]], uvs[2 * t[1] + 1]},
                                     vec2<float>{uvs[2 * t[2]], uvs[2 * t[2] + 1]}});
            }
            if (json const* mat = optional(e, "material", path)) {
                std::string const mp = at_key(path, "material");
                std::string const mname = string(*mat, mp);
                auto it = materials_.find(mname);
                if (it == materials_.end()) fail(mp, "material '" + excerpt(mname) + "' is not defined");
                m.material = it->second;
            }
            entry.mesh = at(path, [&] { return s_.add_mesh(std::move(m)); });
        }
        meshes_.emplace(std::move(name), entry);
    }

    void prototypes(json const& list) {
        // Every prototype's root exists before any is built: instances may refer forwards, or in a cycle.
        for_each(list, "prototypes", [&](json const& e, std::string const& path) {
            require_object(e, path);
            std::string name = name_of(e, path, prototypes_, "prototype");
            node_id const root = s_.add_group(no_node, name);
            s_.at(root).source = file_;
            prototypes_.emplace(std::move(name), root);
        });
        for_each(list, "prototypes", [&](json const& e, std::string const& path) {
            node(e, path, prototypes_.at(e["name"].get<std::string>()), 1);
        });
    }

    // The placement keys of transform and instance nodes: "matrix", or translate · rotate · scale.
    affine_transform<float> placement(json const& e, std::string const& path) const {
        bool const trs = e.contains("translate") || e.contains("rotate") || e.contains("scale");
        if (json const* m = optional(e, "matrix", path)) {
            if (trs) fail(at_key(path, "matrix"), "cannot be combined with translate, rotate or scale");
            auto const v = numbers(*m, at_key(path, "matrix"), 12);
            std::array<float, 12> rows{};
            std::copy(v.begin(), v.end(), rows.begin());
            return affine_transform<float>::from_rows(rows);
        }
        // Composed in double, rounded to float once (canopy.math's from_trs and convert).
        vec3<double> t{0.0}, s{1.0};
        mat3<double> r = mat3<double>::identity();
        if (json const* j = optional(e, "translate", path)) t = vec3<double>(vec(*j, at_key(path, "translate")));
        if (json const* j = optional(e, "rotate", path)) {
            std::string const p = at_key(path, "rotate");
            auto const v = numbers(*j, p, 4);
            double const angle = double(v[0]) * std::numbers::pi / 180.0;
            double x = v[1], y = v[2], z = v[3];
            double const length = std::sqrt(x * x + y * y + z * z);
            if (!(length > 0.0) || !std::isfinite(length)) fail(p, "the rotation axis must not be zero");
            x /= length;
            y /= length;
            z /= length;
            // Rodrigues: R = cos θ I + sin θ [k]× + (1 − cos θ) k kᵀ.
            double const c = std::cos(angle), sn = std::sin(angle), cc = 1.0 - c;
            r = {{c + x * x * cc, y * x * cc + z * sn, z * x * cc - y * sn}, // columns
                 {x * y * cc - z * sn, c + y * y * cc, z * y * cc + x * sn},
                 {x * z * cc + y * sn, y * z * cc - x * sn, c + z * z * cc}};
        }
        if (json const* j = optional(e, "scale", path)) {
            std::string const p = at_key(path, "scale");
            vec3<float> v;
            if (j->is_number()) {
                float const k = number(*j, p);
                v = {k, k, k};
            } else {
                v = vec(*j, p);
            }
            s = vec3<double>(v);
        }
        return convert<float>(from_trs(t, r, s));
    }

    void children(json const& e, std::string const& path, node_id parent, int depth) {
        if (json const* c = optional(e, "children", path))
            for_each(*c, at_key(path, "children"), [&](json const& child, std::string const& p) { node(child, p, parent, depth + 1); });
    }

    parameters params(json const& e, std::string const& path) const {
        parameters out;
        json const* p = optional(e, "params", path);
        if (p == nullptr) return out;
        std::string const pp = at_key(path, "params");
        require_object(*p, pp);
        auto const scalar = [&](json const& v, std::string const& vp) -> std::string {
            if (v.is_string()) return v.get<std::string>();
            if (v.is_boolean()) return v.get<bool>() ? "true" : "false";
            if (v.is_number()) {
                number(v, vp);
                return v.dump();
            }
            fail(vp, "must be a string, number, boolean or an array of those, not " + type_name(v));
        };
        for (auto const& [key, value] : p->items()) {
            std::string const vp = at_key(pp, excerpt(key));
            if (value.is_array()) {
                std::string joined;
                for (std::size_t i = 0; i < value.size(); ++i) {
                    if (value[i].is_array()) fail(at_index(vp, i), "nested arrays are not parameters");
                    joined += (i ? " " : "") + scalar(value[i], at_index(vp, i));
                }
                out.set(key, joined);
            } else {
                out.set(key, scalar(value, vp));
            }
        }
        return out;
    }

    void node(json const& e, std::string const& path, node_id parent, int depth) {
        if (depth > max_depth) fail(path, "nodes are nested deeper than " + std::to_string(max_depth) + " levels");
        require_object(e, path);
        std::string const type = string(required(e, "type", path), at_key(path, "type"));
        std::string name;
        if (json const* n = optional(e, "name", path)) name = string(*n, at_key(path, "name"));
        node_id made = no_node;
        if (type == "group") {
            check_keys(e, path, {"type", "name", "children"});
            made = at(path, [&] { return s_.add_group(parent, name); });
            children(e, path, made, depth);
        } else if (type == "transform") {
            check_keys(e, path, {"type", "name", "children", "matrix", "translate", "rotate", "scale"});
            auto const xf = placement(e, path);
            made = at(path, [&] { return s_.add_transform(parent, xf, name); });
            children(e, path, made, depth);
        } else if (type == "mesh") {
            check_keys(e, path, {"type", "name", "mesh"});
            std::string const mesh = string(required(e, "mesh", path), at_key(path, "mesh"));
            auto it = meshes_.find(mesh);
            if (it == meshes_.end()) fail(path, "mesh '" + excerpt(mesh) + "' is not defined");
            if (it->second.loaded == no_node) {
                made = at(path, [&] { return s_.add_mesh_node(parent, it->second.mesh, name.empty() ? mesh : name); });
            } else {
                // A group of the node's own, holding the file's node tree: shared, not copied.
                made = at(path, [&] {
                    node_id const g = s_.add_group(parent, name.empty() ? mesh : name);
                    s_.attach(g, it->second.loaded);
                    return g;
                });
            }
        } else if (type == "instance") {
            check_keys(e, path, {"type", "name", "target", "id", "matrix", "translate", "rotate", "scale"});
            std::string const target = string(required(e, "target", path), at_key(path, "target"));
            auto it = prototypes_.find(target);
            if (it == prototypes_.end()) fail(path, "instance target '" + excerpt(target) + "' is not defined");
            std::uint32_t id = instances_;
            if (json const* i = optional(e, "id", path))
                id = index(*i, at_key(path, "id"), std::uint64_t(std::numeric_limits<std::uint32_t>::max()) + 1, "ids are 32-bit");
            ++instances_;
            auto const xf = placement(e, path);
            made = at(path, [&] { return s_.add_instance(parent, it->second, xf, id, name); });
        } else if (type == "camera") {
            check_keys(e, path, {"type", "name", "eye", "target", "up", "fovy"});
            camera_data c;
            if (json const* j = optional(e, "eye", path)) c.eye = vec(*j, at_key(path, "eye"));
            if (json const* j = optional(e, "target", path)) c.target = vec(*j, at_key(path, "target"));
            if (json const* j = optional(e, "up", path)) c.up = vec(*j, at_key(path, "up"));
            if (json const* j = optional(e, "fovy", path)) c.fovy_degrees = number(*j, at_key(path, "fovy"));
            made = at(path, [&] { return s_.add_camera(parent, c, name); });
        } else if (type == "light") {
            check_keys(e, path, {"type", "name", "light", "position", "direction", "colour"});
            light_data l;
            if (json const* j = optional(e, "light", path)) {
                std::string const kind = string(*j, at_key(path, "light"));
                if (kind == "point") l.kind = light_data::point;
                else if (kind != "directional") fail(at_key(path, "light"), "'" + excerpt(kind) + "' is not point or directional");
            }
            if (json const* j = optional(e, "position", path)) l.position = vec(*j, at_key(path, "position"));
            if (json const* j = optional(e, "direction", path)) {
                vec3<float> const d = vec(*j, at_key(path, "direction"));
                float const length = std::sqrt(dot(d, d));
                if (!(length > 0.0f) || !std::isfinite(length)) fail(at_key(path, "direction"), "must not be zero");
                l.direction = d / length;
            }
            if (json const* j = optional(e, "colour", path)) l.colour = vec(*j, at_key(path, "colour"));
            made = at(path, [&] { return s_.add_light(parent, l, name); });
        } else if (type == "generator") {
            check_keys(e, path, {"type", "name", "generator", "params"});
            std::string const generator = string(required(e, "generator", path), at_key(path, "generator"));
            parameters const p = params(e, path);
            registry const& r = plugins(path, "a generator");
            if (!r.has_generator(generator)) fail(at_key(path, "generator"), "generator '" + excerpt(generator) + "' is not registered");
            made = at(path, [&] { return r.generate(s_, generator, p, parent); });
            if (!name.empty() && made != no_node) s_.at(made).name = name;
        } else {
            check_keys(e, path, {"type", "name", "params"});
            parameters p = params(e, path);
            if (r_ == nullptr || !r_->has_node_type(type))
                fail(at_key(path, "type"), "'" + excerpt(type) +
                                               "' is neither a built-in node type (group, transform, mesh, instance, "
                                               "camera, light, generator) nor one a plugin registers");
            made = at(path, [&] { return s_.add_custom(parent, type, std::move(p), name); });
        }
        if (made != no_node && s_.at(made).source.empty()) s_.at(made).source = file_;
    }

    // The node tree of `file` as `loader` (empty: the extension's default) makes it, loaded once
    // for the whole load (see shared_files): a later mesh entry naming the same file, in this
    // scene file or in any file it loads, gets the same node.
    node_id shared_load(registry const& r, fs::path const& file, std::string const& loader, std::string const& name) {
        std::string plugin = loader;
        if (plugin.empty()) {
            std::string const ext = extension_of(file);
            for (auto const& l : r.loaders())
                if (l.name == ext) {
                    plugin = l.plugin; // the default comes first
                    break;
                }
        }
        std::string const key = canonical_name(file) + '\0' + plugin;
        if (auto it = shared_files_->loaded.find(key); it != shared_files_->loaded.end()) return it->second;
        node_id const holder = s_.add_group(no_node, "mesh '" + name + "'");
        node_id const loaded = r.load(s_, file, holder, loader);
        shared_files_->loaded.emplace(key, loaded);
        return loaded;
    }

    // The image of `file`, loaded once for the whole load (see shared_files), within the texel
    // budget of the scene's images (--max-total-texels).
    int shared_image(registry const& r, fs::path const& file) {
        std::string const key = canonical_name(file);
        if (auto it = shared_files_->images.find(key); it != shared_files_->images.end()) return it->second;
        int const image = s_.add_image(r.load_image(file, s_.texels()));
        shared_files_->images.emplace(key, image);
        return image;
    }

    struct mesh_entry {
        std::uint32_t mesh = 0;
        node_id loaded = no_node; // file meshes: the node the file's loader made (kept out of the tree)
    };

    std::string const& file_;
    fs::path folder_;
    registry const* r_;
    scene& s_;
    std::map<std::string, int> materials_;
    std::map<std::string, mesh_entry> meshes_;
    std::map<std::string, node_id> prototypes_;
    std::uint32_t instances_ = 0;
    shared_files* shared_files_ = active_files;
};

} // namespace

node_id parse_json_scene(std::string_view text, std::string const& file_name, registry const* r, scene& s,
                         node_id parent) {
    // The outermost load into `s` holds the shared files of every nested one.
    shared_files own{&s, {}, {}};
    shared_files* const outer = active_files;
    if (outer == nullptr || outer->s != &s) active_files = &own;
    auto const mark = s.make_mark();
    auto const fail = [&] {
        s.roll_back(mark);
        std::erase_if(active_files->loaded, [&](auto const& e) { return e.second >= mark.nodes; });
        std::erase_if(active_files->images, [&](auto const& e) { return std::size_t(e.second) >= mark.images; });
        active_files = outer;
    };
    try {
        node_id const n = builder(file_name, r, s).run(text, parent);
        active_files = outer;
        return n;
    } catch (scene_error const&) {
        fail();
        throw;
    } catch (json::exception const& e) {
        fail();
        throw scene_error(file_name, "", excerpt(e.what(), 200));
    } catch (...) {
        fail();
        throw;
    }
}

node_id load_json_scene(scene& s, std::filesystem::path const& file, node_id parent, registry const& r) {
    std::string const key = canonical_name(file);
    if (std::find(files_in_progress.begin(), files_in_progress.end(), key) != files_in_progress.end())
        throw scene_error(file.string(), "", "the scene refers to itself (through the files it loads)");
    std::string const content = read_regular_file(file);
    files_in_progress.push_back(key);
    try {
        node_id const n = parse_json_scene(content, file.string(), &r, s, parent);
        files_in_progress.pop_back();
        return n;
    } catch (...) {
        files_in_progress.pop_back();
        throw;
    }
}

void register_json_plugin(registry& r) {
    r.add_loader(".json", "json", "Canopy JSON scene (materials, meshes, prototypes, instances, cameras, lights)",
                 load_json_scene);
}

} // namespace canopy
