// canopy.scene:graph — the scene graph: what loaders and generators build and compile() reads.
//
// A scene is a tree of nodes below root(), plus shared data the nodes refer to by index: meshes,
// materials and images. A subtree may also be shared through children (attach() puts an existing
// node under another parent, as the JSON loader does for a mesh file placed many times): it is
// stored once and placed once per path, as if copied. Node kinds:
//   group      children, nothing else
//   transform  children placed by an affine object→parent transform
//   mesh       one mesh (by index); several mesh nodes may share a mesh: it is built once
//   instance   a reference to a shared subtree (any node, usually one outside the tree, see
//              add_prototype) with its own transform and a user id
//   camera     a pinhole camera, placed by the transforms above it
//   light      a point or directional light, placed by the transforms above it
//   custom     a node type registered by a plugin: expanded into the kinds above at compile time
// The graph must be acyclic through children and instance targets; compile() reports a cycle as
// an error naming the nodes on it.
//
// Bad data is refused where it enters: add_mesh() checks that every index is in range, every
// position finite and every per-corner attribute array matches the triangle count, and throws
// scene_error naming the mesh's source file and the element at fault.
module;
#include <array>
#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>
export module canopy.scene:graph;
import canopy.math;
import :error;

namespace canopy {

// What is wrong with a float transform, or nullptr: a value that is not finite, or a linear part
// that cannot be inverted in float (zero determinant, or an inverse — computed in double, rounded
// to float once as the traversal does — that is not finite). Rays through such a transform would
// miss silently. Shared by the graph's checks and compile()'s checks of composed placements.
char const* transform_problem(affine_transform<float> const& xf) {
    if (!all_finite(xf)) return "transform has a value that is not finite";
    double const det = determinant(convert<double>(xf.linear));
    if (!(std::abs(det) > 0.0) || !all_finite(inverse(xf))) return "transform is singular (it cannot be inverted)";
    return nullptr;
}

} // namespace canopy

export namespace canopy {

using node_id = std::uint32_t;
inline constexpr node_id no_node = ~node_id(0);

enum class node_kind : std::uint8_t { group, transform, mesh, instance, camera, light, custom };

char const* to_string(node_kind k) {
    switch (k) {
    case node_kind::group: return "group";
    case node_kind::transform: return "transform";
    case node_kind::mesh: return "mesh";
    case node_kind::instance: return "instance";
    case node_kind::camera: return "camera";
    case node_kind::light: return "light";
    case node_kind::custom: return "custom";
    }
    return "?";
}

// Triangles with optional per-corner attributes. Corner arrays are empty or hold one entry per
// triangle (corner k of triangles[i] has uvs[i][k]), so loaders never split vertices.
struct mesh_data {
    std::string name;
    std::string source; // file it came from (for error messages and statistics); may be empty
    std::vector<vec3<float>> positions;
    std::vector<std::array<std::uint32_t, 3>> triangles;
    std::vector<std::array<vec2<float>, 3>> uvs;
    std::vector<std::array<vec3<float>, 3>> normals;
    int material = -1; // index into scene::materials; -1 = the default material
    // Polygon faces the loader fanned although the fan may cover more than the face
    // (triangulate_polygon's fanned_fallback), reported by compile(); first_fanned: where the
    // first of them is in the source ("12": a line, or "face 7"), or empty.
    std::size_t fanned_faces = 0;
    std::string first_fanned;
};

enum class alpha_mode : std::uint8_t { opaque, mask };

struct material_data {
    std::string name;
    vec3<float> colour{0.7f, 0.7f, 0.7f}; // linear base colour
    int image = -1;                        // base-colour texture: index into scene::images, or -1
    alpha_mode alpha = alpha_mode::opaque; // mask: texels whose alpha < alpha_cutoff are holes
    float alpha_cutoff = 0.5f;             // glTF's default
};

// An RGBA image, float texels, row 0 at the top (texture coordinate v = 0). Alpha is linear
// coverage. RGB is linear, or sRGB-encoded when `srgb` is set (the values of 8- and 16-bit image
// files, as stored): compile() decodes colour textures to linear then, so that shading sees linear
// colours whatever the file; loaders that read other data from an image (an alpha map's red
// channel) use the stored values as they are.
struct image_data {
    std::string source;
    int width = 0, height = 0;
    std::vector<vec4<float>> texels;
    bool srgb = false;
};

// An sRGB-encoded value in [0, 1] to linear (IEC 61966-2-1), in double, rounded once.
float srgb_to_linear(double encoded) {
    return float(encoded <= 0.04045 ? encoded / 12.92 : std::pow((encoded + 0.055) / 1.055, 2.4));
}

struct camera_data {
    // In the camera node's frame: looks from eye towards target. Placed by the transforms above.
    vec3<float> eye{0.0f, 0.0f, 5.0f};
    vec3<float> target{0.0f, 0.0f, 0.0f};
    vec3<float> up{0.0f, 1.0f, 0.0f};
    float fovy_degrees = 45.0f;
};

struct light_data {
    enum kind_t : std::uint8_t { point, directional } kind = directional;
    vec3<float> position{0.0f, 10.0f, 0.0f};                  // point lights
    vec3<float> direction = normalize(vec3<float>(-0.4f, 1.0f, 0.5f)); // directional: towards the light
    vec3<float> colour{1.0f, 1.0f, 1.0f};                     // radiance scale (point: intensity)
};

// Parameters of generators and custom nodes: named values kept as text, read with a type and a
// default; a value that does not parse names the parameter and the context in the error.
class parameters {
public:
    parameters() = default;
    parameters(std::initializer_list<std::pair<std::string const, std::string>> values) : values_(values) {}

    void set(std::string key, std::string value) { values_[std::move(key)] = std::move(value); }
    bool has(std::string const& key) const { return values_.contains(key); }
    std::map<std::string, std::string> const& values() const { return values_; }

    std::string get_string(std::string const& key, std::string const& fallback) const {
        auto it = values_.find(key);
        return it == values_.end() ? fallback : it->second;
    }
    double get_number(std::string const& key, double fallback, std::string const& context) const {
        auto it = values_.find(key);
        if (it == values_.end()) return fallback;
        std::size_t used = 0;
        double v = 0.0;
        try {
            v = std::stod(it->second, &used);
        } catch (...) {
            used = 0;
        }
        if (used == 0 || used != it->second.size() || !std::isfinite(v))
            throw scene_error(context, "parameter '" + key + "'", "'" + excerpt(it->second) + "' is not a finite number");
        return v;
    }
    long long get_integer(std::string const& key, long long fallback, long long lo, long long hi,
                          std::string const& context) const {
        if (!has(key)) return fallback;
        double const v = get_number(key, double(fallback), context);
        if (v != std::floor(v) || v < double(lo) || v > double(hi))
            throw scene_error(context, "parameter '" + key + "'",
                              "'" + excerpt(get_string(key, "")) + "' is not an integer in [" + std::to_string(lo) + ", " +
                                  std::to_string(hi) + "]");
        return static_cast<long long>(v);
    }

private:
    std::map<std::string, std::string> values_;
};

struct node {
    node_kind kind = node_kind::group;
    std::string name;
    std::vector<node_id> children;                                                // group, transform, custom
    affine_transform<float> transform = affine_transform<float>::identity();     // transform, instance: object → parent
    std::uint32_t mesh = 0;                                                       // mesh
    node_id target = no_node;                                                     // instance
    std::uint32_t instance_id = 0;                                                // instance: the user's id
    camera_data camera;                                                           // camera
    light_data light;                                                             // light
    std::string custom_type;                                                      // custom
    parameters params;                                                            // custom
    std::string source;                                                           // file that made it
};

class scene {
public:
    scene() { nodes_.push_back(make(node_kind::group, "root")); }

    node_id root() const { return 0; }
    std::vector<node> const& nodes() const { return nodes_; }
    node const& at(node_id n) const { return nodes_.at(n); }
    node& at(node_id n) { return nodes_.at(n); }
    std::vector<mesh_data> const& meshes() const { return meshes_; }
    std::vector<material_data> const& materials() const { return materials_; }
    std::vector<image_data> const& images() const { return images_; }
    // Texels of all the images together (what --max-total-texels limits).
    std::uint64_t texels() const { return texels_; }
    material_data& material(std::size_t i) { return materials_.at(i); }

    // Shared data. add_mesh validates (see the file comment) and returns the mesh index.
    std::uint32_t add_mesh(mesh_data m) {
        validate(m);
        meshes_.push_back(std::move(m));
        return std::uint32_t(meshes_.size() - 1);
    }
    int add_material(material_data m) {
        if (m.image >= int(images_.size()) || m.image < -1)
            throw scene_error("", "material '" + m.name + "'", "image index " + std::to_string(m.image) + " does not exist");
        if (!(m.alpha_cutoff >= 0.0f && m.alpha_cutoff <= 1.0f))
            throw scene_error("", "material '" + m.name + "'", "alpha cutoff must be in [0, 1]");
        if (!all_finite(m.colour))
            throw scene_error("", "material '" + m.name + "'", "colour is not finite");
        materials_.push_back(std::move(m));
        return int(materials_.size() - 1);
    }
    int add_image(image_data i) {
        if (i.width <= 0 || i.height <= 0 || i.texels.size() != std::size_t(i.width) * std::size_t(i.height))
            throw scene_error(i.source, "", "image has no texels or a size that does not match them");
        texels_ += i.texels.size();
        images_.push_back(std::move(i));
        return int(images_.size() - 1);
    }

    // Nodes. parent = no_node makes a free-standing node (a prototype for instances).
    node_id add_group(node_id parent, std::string name = {}) {
        return add(parent, make(node_kind::group, std::move(name)));
    }
    node_id add_transform(node_id parent, affine_transform<float> const& object_to_parent, std::string name = {}) {
        check_transform(object_to_parent, name);
        node n = make(node_kind::transform, std::move(name));
        n.transform = object_to_parent;
        return add(parent, std::move(n));
    }
    node_id add_mesh_node(node_id parent, std::uint32_t mesh, std::string name = {}) {
        if (mesh >= meshes_.size())
            throw scene_error("", "node '" + name + "'", "mesh index " + std::to_string(mesh) + " does not exist");
        node n = make(node_kind::mesh, std::move(name));
        n.mesh = mesh;
        return add(parent, std::move(n));
    }
    node_id add_instance(node_id parent, node_id target, affine_transform<float> const& object_to_parent, std::uint32_t id,
                         std::string name = {}) {
        if (target >= nodes_.size())
            throw scene_error("", "node '" + name + "'", "instance target " + std::to_string(target) + " does not exist");
        check_transform(object_to_parent, name);
        node n = make(node_kind::instance, std::move(name));
        n.transform = object_to_parent;
        n.target = target;
        n.instance_id = id;
        return add(parent, std::move(n));
    }
    node_id add_camera(node_id parent, camera_data const& c, std::string name = {}) {
        if (!all_finite(c.eye) || !all_finite(c.target) || !all_finite(c.up) || !(c.fovy_degrees > 0.0f && c.fovy_degrees < 180.0f))
            throw scene_error("", "camera '" + name + "'", "needs finite eye/target/up and a field of view in (0, 180) degrees");
        if (c.eye.x == c.target.x && c.eye.y == c.target.y && c.eye.z == c.target.z)
            throw scene_error("", "camera '" + name + "'", "eye and target coincide");
        node n = make(node_kind::camera, std::move(name));
        n.camera = c;
        return add(parent, std::move(n));
    }
    node_id add_light(node_id parent, light_data const& l, std::string name = {}) {
        if (!all_finite(l.position) || !all_finite(l.direction) || !all_finite(l.colour))
            throw scene_error("", "light '" + name + "'", "has a value that is not finite");
        node n = make(node_kind::light, std::move(name));
        n.light = l;
        return add(parent, std::move(n));
    }
    // A node of a plugin's type (registry::add_node_type); compile() expands it.
    node_id add_custom(node_id parent, std::string type, parameters params, std::string name = {}) {
        node n = make(node_kind::custom, std::move(name));
        n.custom_type = std::move(type);
        n.params = std::move(params);
        return add(parent, std::move(n));
    }
    // Attaches an existing free-standing node under parent.
    void attach(node_id parent, node_id child) {
        check_parent(parent);
        nodes_.at(child);
        append_child(parent, child);
    }

    // Rolls the scene back to a mark: loaders that fail leave nothing behind. Both take constant
    // time (a mark is five sizes; rolling back undoes only what was added since), so that nested
    // loads and custom-node expansions stay linear in the size of the scene.
    struct mark {
        std::size_t nodes, meshes, materials, images;
        std::size_t appended; // entries of the child log (see append_child)
    };
    mark make_mark() const { return {nodes_.size(), meshes_.size(), materials_.size(), images_.size(), appended_to_.size()}; }
    void roll_back(mark const& m) {
        nodes_.resize(m.nodes);
        meshes_.resize(m.meshes);
        materials_.resize(m.materials);
        for (std::size_t i = m.images; i < images_.size(); ++i) texels_ -= images_[i].texels.size();
        images_.resize(m.images);
        // Children appended since the mark come off their parents' lists, newest first.
        while (appended_to_.size() > m.appended) {
            node_id const parent = appended_to_.back();
            appended_to_.pop_back();
            if (parent < nodes_.size()) nodes_[parent].children.pop_back();
        }
    }

private:
    static node make(node_kind kind, std::string name) {
        node n;
        n.kind = kind;
        n.name = std::move(name);
        return n;
    }

    static bool all_finite(vec3<float> v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

    static void check_transform(affine_transform<float> const& object_to_parent, std::string const& name) {
        if (char const* problem = transform_problem(object_to_parent)) throw scene_error("", "node '" + name + "'", problem);
    }

    void check_parent(node_id parent) const {
        if (parent >= nodes_.size()) throw scene_error("", "", "parent node " + std::to_string(parent) + " does not exist");
        auto k = nodes_[parent].kind;
        if (k != node_kind::group && k != node_kind::transform && k != node_kind::custom)
            throw scene_error("", "node '" + nodes_[parent].name + "'",
                              std::string("a ") + to_string(k) + " node cannot have children");
    }

    node_id add(node_id parent, node n) {
        if (parent != no_node) check_parent(parent);
        nodes_.push_back(std::move(n));
        node_id const id = node_id(nodes_.size() - 1);
        if (parent != no_node) append_child(parent, id);
        return id;
    }

    // Every child list grows only here, and the log of parents lets roll_back undo it.
    void append_child(node_id parent, node_id child) {
        nodes_[parent].children.push_back(child);
        appended_to_.push_back(parent);
    }

    void validate(mesh_data const& m) const {
        std::string const what = "mesh '" + m.name + "'";
        for (std::size_t i = 0; i < m.positions.size(); ++i)
            if (!all_finite(m.positions[i]))
                throw scene_error(m.source, what, "vertex " + std::to_string(i) + " has a coordinate that is not finite");
        for (std::size_t f = 0; f < m.triangles.size(); ++f)
            for (std::uint32_t v : m.triangles[f])
                if (v >= m.positions.size())
                    throw scene_error(m.source, what,
                                      "triangle " + std::to_string(f) + " uses vertex " + std::to_string(v) + " of " +
                                          std::to_string(m.positions.size()));
        if (!m.uvs.empty() && m.uvs.size() != m.triangles.size())
            throw scene_error(m.source, what, "has texture coordinates for " + std::to_string(m.uvs.size()) + " of " +
                                                  std::to_string(m.triangles.size()) + " triangles");
        if (!m.normals.empty() && m.normals.size() != m.triangles.size())
            throw scene_error(m.source, what, "has normals for " + std::to_string(m.normals.size()) + " of " +
                                                  std::to_string(m.triangles.size()) + " triangles");
        for (std::size_t f = 0; f < m.uvs.size(); ++f)
            for (auto uv : m.uvs[f])
                if (!std::isfinite(uv.x) || !std::isfinite(uv.y))
                    throw scene_error(m.source, what, "triangle " + std::to_string(f) + " has a texture coordinate that is not finite");
        if (m.material < -1 || m.material >= int(materials_.size()))
            throw scene_error(m.source, what, "material index " + std::to_string(m.material) + " does not exist");
    }

    std::vector<node> nodes_;
    std::vector<mesh_data> meshes_;
    std::vector<material_data> materials_;
    std::vector<image_data> images_;
    std::uint64_t texels_ = 0; // of images_
    std::vector<node_id> appended_to_; // the parent of every child appended, in order
};

} // namespace canopy
