// canopy.plugins.json — Canopy's own scene description: a JSON file of materials, meshes (from
// files or inline), prototypes for instancing, and a node tree (docs/scene/json.md: every key).
//
// Loads: `.json` scenes into one group named after the file. Parameters: none.
//
//   {
//     "materials":  [{"name": "leaf", "colour": [0.2, 0.6, 0.2], "texture": "leaf.png",
//                     "alphaMode": "MASK", "alphaCutoff": 0.5}],
//     "meshes":     [{"name": "trunk", "file": "trunk.obj", "loader": "obj"},
//                    {"name": "quad", "positions": [...], "indices": [...], "uvs": [...],
//                     "material": "leaf"}],
//     "prototypes": [{"name": "tree", "type": "group", "children": [...]}],
//     "nodes":      [{"type": "instance", "target": "tree", "translate": [4, 0, 0], "id": 7}, ...]
//   }
//
// Node types: group, transform (matrix, or translate / rotate / scale), mesh, instance (of a
// prototype, by name), camera, light, generator (a registered generator, by name, with params),
// and any custom node type a plugin registers (with params). Paths (files, textures) are relative
// to the JSON file. Names are resolved per section (materials, meshes, prototypes); instance
// targets may form cycles in the file: the loader makes each prototype once and never follows
// targets, compile() reports the cycle.
//
// Mesh files are loaded once per load: every (file, loader) pair, however many "meshes" entries
// name it, in this file or in the scene files it loads, is loaded at its first mention, and each
// mesh node placing it is a group of its own (named after the node, or the mesh) whose one child
// is the file's node tree, shared (scene::attach). So nodes and memory grow by one node per
// reference and linearly in the distinct files, however often and however deeply nested the
// references; compile() builds each mesh once and counts the placements the references multiply
// into against --max-placements before making any.
//
// Errors (scene_error) name the file and the JSON path of the element at fault, as
//   "forest.json: nodes[3].children[1]: instance target 'oak' is not defined"
//   "forest.json: materials[0].alphaCutoff: must be a number in [0, 1]"
// for unknown names, duplicate names, wrong types, missing required keys, unknown keys, values
// that are not finite or overflow a float ("value 1e+300 overflows a float"), inline meshes whose
// counts exceed --max-triangles (checked before they are built), arrays and objects nested deeper
// than --max-depth; JSON syntax errors keep the parser's line and column; errors in files the
// scene refers to are wrapped with the element that refers to them. Only regular files are read
// (the scene, its mesh files, its textures). Input quoted in a message is cut to a short prefix.
module;
#include <filesystem>
#include <string>
#include <string_view>
export module canopy.plugins.json;
import canopy.scene;

export namespace canopy {

// Parses a JSON scene from text into s under parent (no_node: free-standing); returns the group
// it made. file_name names the file in errors; relative paths are resolved against its folder.
// Files, textures, generators and custom node types go through r; with r == nullptr they are
// errors (the rest is checked). On error s is left as it was.
node_id parse_json_scene(std::string_view text, std::string const& file_name, registry const* r, scene& s,
                         node_id parent);

// The file loader registered for ".json". A scene that refers to itself, directly or through
// other files, is an error.
node_id load_json_scene(scene& s, std::filesystem::path const& file, node_id parent, registry const& r);

void register_json_plugin(registry& r);

} // namespace canopy
