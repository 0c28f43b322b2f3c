// canopy.plugins.json — Canopy's own scene description: a JSON file of materials, meshes (from
// files or inline), prototypes for instancing, and a node tree (docs/scene/json.md: every key).
//
// ### JSON scenes (`json` plugin: `.json`)
//
// The `json` plugin (`plugins/json/`, module `canopy.plugins.json`) reads Canopy's own scene
// description: materials, meshes (from files through any loader of the registry, or inline),
// prototypes for instancing, and a tree of nodes. It has no parameters. A file becomes one group
// named after it, holding its `nodes`. The file is parsed by nlohmann-json; every key is then
// checked: unknown keys, wrong types and missing required keys are errors.
//
// #### The document
//
// | key | type | default | meaning |
// | --- | --- | --- | --- |
// | `version` | integer | 1 | must be 1 if given |
// | `materials` | array of materials | `[]` | made in order; referred to by name from inline meshes |
// | `meshes` | array of meshes | `[]` | made in order; referred to by name from `mesh` nodes |
// | `prototypes` | array of nodes, each with a `name` | `[]` | free-standing subtrees; referred to by name from `instance` nodes |
// | `nodes` | array of nodes | `[]` | the scene: children of the file's group |
//
// Names are per section (a material and a mesh may share a name); a name given twice in one section
// is an error. References must name an entry of the section (any position in it: a mesh may only
// refer to a material, a node to a mesh or prototype, so the order of the sections is the order of
// definition). Paths (`texture`, `file`) are relative to the JSON file, or absolute.
//
// #### Materials
//
// | key | type | default | meaning |
// | --- | --- | --- | --- |
// | `name` | string | required | |
// | `colour` | [r, g, b], numbers ≥ 0 | [0.7, 0.7, 0.7] | linear base colour (multiplies the texture) |
// | `texture` | string (path) | none | base-colour image, read by the registry's image loaders (`registry::load_image`), once per load however many materials name it; colour decoded to linear by `compile()` when the file stores it sRGB-encoded (8/16-bit files) |
// | `alphaMode` | `"OPAQUE"` or `"MASK"` | `"OPAQUE"` | `MASK`: texels whose alpha is below the cutoff are holes; needs a `texture` |
// | `alphaCutoff` | number in [0, 1] | 0.5 | |
//
// #### Meshes
//
// A mesh is either a **file** or **inline**.
//
// | key | type | default | meaning |
// | --- | --- | --- | --- |
// | `name` | string | required | |
// | `file` | string (path) | — | a file any loader of the registry reads (`.obj`, `.ply`, `.gltf`, another `.json`, ...), loaded once; its materials come with it |
// | `loader` | string | the extension's default | the plugin that loads it (e.g. `"openmesh"` for `.obj`) |
// | `positions` | array of numbers, 3 per vertex | required (inline) | x y z of each vertex |
// | `indices` | array of integers, 3 per triangle | required (inline) | 0-based vertex indices |
// | `uvs` | array of numbers, 2 per vertex | none | texture coordinates per vertex (v = 0 is the image's top row) |
// | `material` | string (material name) | the default material | |
//
// A file is loaded once per load, however many `meshes` entries name it (with the same loader, by
// default or by name), in this file or in the scene files it loads. A `mesh` node placing a file
// mesh is a group of its own (named after the node, or after the mesh) whose one child is the node
// tree the file's loader made, **shared** by every node that places the file: a file placed 10^5
// times costs 10^5 small groups, not 10^5 copies of its tree, and scene files nesting references
// (a file placing another 100 times, which places a mesh 100 times) grow by one node per reference.
// `compile()` builds each mesh once and places it once per path (the placements, and so `inst_id`,
// in graph order, exactly as if the tree were copied), counting the placements before making any
// (`--max-placements`). A scene that loads itself (directly or through other files) is an error.
//
// #### Nodes
//
// Every node is an object with `type` (string, required) and `name` (string, optional, default
// empty). The other keys depend on the type:
//
// | `type` | keys | meaning |
// | --- | --- | --- |
// | `group` | `children` (array of nodes, default `[]`) | a group |
// | `transform` | `children`; `matrix`, or any of `translate`, `rotate`, `scale` | children placed by an affine transform |
// | `mesh` | `mesh` (string, required: a mesh name) | places the mesh; the node's name defaults to the mesh's |
// | `instance` | `target` (string, required: a prototype name); `id` (integer in [0, 2³²), default: the number of `instance` nodes read before it, prototypes first, then `nodes`, depth first); `matrix` or `translate` / `rotate` / `scale` | a reference to a prototype, with its own transform and id |
// | `camera` | `eye` [x, y, z] (default [0, 0, 5]), `target` (default [0, 0, 0]), `up` (default [0, 1, 0]), `fovy` degrees in (0, 180) (default 45) | a pinhole camera, placed by the transforms above it |
// | `light` | `light`: `"directional"` (default) or `"point"`; `position` (default [0, 10, 0]); `direction` towards the light, normalised, not zero (default (−0.4, 1, 0.5) normalised); `colour` (default [1, 1, 1]) | a light, placed by the transforms above it |
// | `generator` | `generator` (string, required: a registered generator); `params` (object) | what the generator builds (`registry::generate`), under the node's parent; `name` renames the node it returns |
// | any other | `params` (object) | a custom node of a type a plugin registers (`registry::add_node_type`); `compile()` expands it |
//
// Transforms: `matrix` is 12 numbers, a 3×4 row-major object→parent matrix
// (`p' = M[:, 0:3] · p + M[:, 3]`), and cannot be combined with the others. Otherwise the transform is
// `translate · rotate · scale` (scale first): `translate` [x, y, z]; `rotate` [angle in degrees,
// axis x, y, z] (right-handed, axis not zero, normalised); `scale` a number or [x, y, z]. Composed in
// double, rounded once to float; it must be invertible.
//
// Params: each value becomes the parameter's text: strings as they are, numbers as JSON writes them
// (`2.5`, `3`), booleans as `true` / `false`, arrays of those joined by spaces (`[1, 0.5]` → `"1 0.5"`).
// Objects and nested arrays are errors.
//
// Prototypes are made before any node, so instances may refer to a prototype defined later, and
// prototypes may instance each other. The loader never follows instance targets: a cycle of
// instances is loaded as written and reported by `compile()`. Nodes nested deeper than 256 levels are
// refused, and arrays and objects nested deeper than `--max-depth` (4096) while the file is parsed.
//
// Only regular files are read (the scene, its mesh files, its textures): a folder, a device or a
// FIFO is named as such before it is opened; a file over `--max-file-bytes` is refused, and a texture
// over `--max-texels`, or one that would bring the scene's images over `--max-total-texels` together,
// by its header before it is decoded. The vertex
// and triangle counts an inline mesh declares (`positions`, `indices`) are checked against
// `--max-triangles` before the mesh is built. Numbers must be finite as floats: `1e300` is a finite
// double but overflows a float, and is refused as such.
//
// Chains of prototypes instancing each other are not nested in the file: `compile()` limits
// them (`--max-depth`; each prototype of a chain adds three levels: the prototype, its node, the
// instance), and counts the placements they multiply into before making any (`--max-placements`).
//
// #### Errors
//
// Errors (`scene_error`) name the file and the JSON path of the element at fault; the scene is left
// as it was:
//
//     forest.json: nodes[3].children[1]: instance target 'oak' is not defined
//     forest.json: materials[0].alphaCutoff: must be in [0, 1]
//     forest.json: materials[1].name: duplicate material name 'bark'
//     forest.json: meshes[0].indices[5]: 4000000000 is out of range (4 vertices)
//     forest.json: meshes[2].positions[7]: value 1e+39 overflows a float
//     forest.json: meshes[0].file: /scenes/trunk: is a folder, not a regular file
//     forest.json: meshes[2].positions: 300000000 vertices exceed the limit of 268435456 (--max-triangles)
//     forest.json: nodes[0]: needs the key 'type'
//     forest.json: nodes[2].tranlate: unknown key (known here: type, name, children, matrix, translate, rotate, scale)
//     forest.json: meshes[1].file: /scenes/trunk.obj:12: bad number 'q'
//     forest.json: parse error at line 3, column 22: syntax error while parsing object key - unexpected ']'; expected string literal
//
// JSON syntax errors keep nlohmann-json's line and column. Errors in a file the scene refers to (a
// mesh file, a texture) or from a generator are wrapped with the path of the element that asked for it.
// Input quoted in a message (a name, a key, the token a syntax error stopped at) is cut to its first
// 40 bytes.
//
// The parser is a function over a buffer, `parse_json_scene(text, file_name, registry*, scene&,
// parent)`; with a null registry, files, textures, generators and custom node types are errors. It
// is fuzzed (`fuzz/json_fuzzer.cpp`, `scripts/fuzz.sh`).
//
// #### Example
//
// `examples/scenes/forest.json` (with `trunk.obj` and `trunk.mtl` beside it): a ground quad, a tree
// prototype (an OBJ trunk and two crossed alpha-masked billboards), a grove prototype of three trees,
// two groves and a lone tree, a camera and a sun. It compiles to two instance levels: the groves and
// the tree are groups (the grove's three trees flattened into it), 13 mesh placements built, 114
// triangles placed in the world from 16 stored.
//
// ```json
// {
//   "version": 1,
//   "materials": [
//     {"name": "leaves", "colour": [1, 1, 1], "texture": "../../assets/tree.png", "alphaMode": "MASK", "alphaCutoff": 0.5},
//     {"name": "grass", "colour": [0.3, 0.5, 0.2]}
//   ],
//   "meshes": [
//     {"name": "trunk", "file": "trunk.obj", "loader": "obj"},
//     {"name": "billboard", "material": "leaves",
//      "positions": [-1, 0, 0,  1, 0, 0,  1, 2, 0,  -1, 2, 0],
//      "uvs":       [0, 1,  1, 1,  1, 0,  0, 0],
//      "indices":   [0, 1, 2,  0, 2, 3]},
//     {"name": "ground", "material": "grass",
//      "positions": [-20, 0, -20,  20, 0, -20,  20, 0, 20,  -20, 0, 20],
//      "indices":   [0, 2, 1,  0, 3, 2]}
//   ],
//   "prototypes": [
//     {"name": "tree", "type": "group", "children": [
//       {"type": "mesh", "mesh": "trunk"},
//       {"type": "transform", "translate": [0, 1, 0], "children": [
//         {"type": "mesh", "mesh": "billboard"}]},
//       {"type": "transform", "translate": [0, 1, 0], "rotate": [90, 0, 1, 0], "children": [
//         {"type": "mesh", "mesh": "billboard"}]}
//     ]},
//     {"name": "grove", "type": "group", "children": [
//       {"type": "instance", "target": "tree", "translate": [-2, 0, 0]},
//       {"type": "instance", "target": "tree", "translate": [2, 0, 1], "rotate": [30, 0, 1, 0]},
//       {"type": "instance", "target": "tree", "translate": [0, 0, -2], "scale": 1.3}
//     ]}
//   ],
//   "nodes": [
//     {"type": "mesh", "name": "ground", "mesh": "ground"},
//     {"type": "instance", "name": "west grove", "target": "grove", "id": 100, "translate": [-6, 0, 0]},
//     {"type": "instance", "name": "east grove", "target": "grove", "id": 101,
//      "matrix": [0, 0, 1, 6,  0, 1, 0, 0,  -1, 0, 0, 0]},
//     {"type": "instance", "name": "lone tree", "target": "tree", "translate": [0, 0, 4], "scale": [1.5, 2, 1.5]},
//     {"type": "camera", "eye": [0, 4, 16], "target": [0, 1.5, 0], "fovy": 50},
//     {"type": "light", "light": "directional", "direction": [-0.4, 1, 0.5], "colour": [1, 0.95, 0.9]}
//   ]
// }
// ```
//
// ```cpp
// import canopy.plugins;
//
// canopy::registry& r = canopy::builtin_registry();
// canopy::scene s = canopy::load_scene("examples/scenes/forest.json", r);
// canopy::compiled_scene c = canopy::compile(s, {.plugins = &r});   // c.statistics.levels == 2
// ```
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
