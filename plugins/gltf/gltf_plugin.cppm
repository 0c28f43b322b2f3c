// canopy.plugins.gltf — glTF 2.0 scenes (.gltf with external or embedded buffers, .glb) through
// tinygltf.
//
// ### glTF 2.0 (`gltf` plugin: `.gltf`, `.glb`)
//
// The `gltf` plugin (`plugins/gltf/`, module `canopy.plugins.gltf`) loads glTF 2.0 files through
// tinygltf: JSON `.gltf` files with external `.bin` buffers or embedded `data:` URIs, and binary
// `.glb` files. It has no parameters. It loads the default scene (or scene 0; a file without scenes
// gives every node that is no other node's child) under one group named after the file.
//
// | glTF | canopy |
// | --- | --- |
// | node | a transform node (its `matrix`, or `translation` · `rotation` · `scale` in that order) holding its mesh, camera and children |
// | mesh primitive | one canopy mesh, built once and shared by every node that uses the glTF mesh: a mesh used by N nodes is one BVH placed N times |
// | node with a one-primitive mesh | one mesh node |
// | node with a several-primitive mesh | a group holding one mesh node per primitive (`name.primitives[k]`) |
// | `TRIANGLES`, `TRIANGLE_STRIP`, `TRIANGLE_FAN` | triangles (strips and fans in the glTF specification's order and winding) |
// | indices | none, or unsigned byte/short/int |
// | `POSITION`, `NORMAL` | float `VEC3` |
// | `TEXCOORD_n` | float, or normalized unsigned byte/short, `VEC2`; n is the `texCoord` of the material's base colour texture (0 without one) |
// | sparse accessors | supported |
// | `baseColorFactor` | the material's linear colour (its alpha multiplies the texture's: a mask compares the texture's alpha with cutoff / factor alpha, so one image serves every material) |
// | `baseColorTexture` | the material's image, decoded once however many materials and glTF images (of the same bytes or file) use it: a file (uri relative to the `.gltf`) read through the registry's image loaders, or an embedded image (`data:` URI, `.glb` buffer view) decoded by tinygltf; RGB converted from sRGB to linear, alpha kept linear |
// | `alphaMode: MASK`, `alphaCutoff` (default 0.5) | `alpha_mode::mask` with that cutoff: the alpha-mask intersector (`texture_alpha_mask`) cuts the holes |
// | `alphaMode: BLEND` | treated as `MASK` with cutoff 0.5: a ray sees a surface or a hole, never a fraction |
// | `MASK` without a texture | masked by the factor's alpha alone (a 1×1 image) |
// | perspective camera | a camera at the node's origin looking down its −Z, up +Y, `fovy` = `yfov` |
//
// Texture coordinates need no flip: glTF and `canopy.texture` both put (0, 0) at the top-left
// corner of the image.
//
// Not loaded: skins and morph targets (meshes come in their base pose), animations, lights and the
// other material properties. Refused with an error: points and lines, orthographic cameras, zero
// scales (canopy places geometry only with invertible transforms), and files whose
// `extensionsRequired` lists any extension (Draco, quantised meshes, texture transforms, ...).
//
// Nothing is dropped or guessed. Before tinygltf reads the file, its JSON is checked against the
// glTF 2.0 core schema: every property's JSON type, its range or allowed values, the element each
// index refers to, and every accessor, sparse accessor and buffer view inside its buffer view or
// buffer (without overflow). A texture index of −1, an array where an object belongs or a
// `"mesh": 1.0` is refused with its JSON path, not ignored as tinygltf would. The node hierarchy
// must be what glTF allows (disjoint trees: one parent per node, no node its own descendant) and no
// deeper than `--max-depth`; it is walked without recursion, so a chain of 100,000 nodes is refused
// in a moment. A `.glb` file (or any file that starts with `glTF`) has its layout checked before
// anything reads it: the header (magic `glTF`, version 2, a length equal to the file's), each chunk
// inside the file and padded to 4 bytes, the JSON chunk first, at most one BIN chunk, second (chunks
// of other types are skipped), and a BIN chunk at least as long as `buffers[0]` when that buffer has
// no uri (only a `.glb`'s first buffer may go without one). Files are read only if they are regular files within `--max-file-bytes` (the `.gltf`
// or `.glb`, its external buffers, looked for in its own folder only, and its images, read through
// the registry's image loaders); an embedded image must be PNG or JPEG and is refused by its header,
// before it is decoded, when it claims more than `--max-texels` texels or would bring the texels of
// the scene's images over `--max-total-texels` (an embedded image counts from when it is decoded,
// an image file from its header, before it is read); the scene's meshes are held
// to `--max-triangles` together (before a primitive's data is read: primitives may share one large
// accessor) and the mesh nodes the file makes to `--max-placements`.
//
// Errors name the file and the element (a JSON path), for example
//
//     forest.gltf: materials[0].pbrMetallicRoughness: expected an object, got an array
//     forest.gltf: materials[0].pbrMetallicRoughness.baseColorTexture.index: index -1 is out of range (1 textures)
//     forest.gltf: accessors[1]: 7 elements of 2 bytes, 2 apart from byte 0, do not fit in bufferViews[1] (12 bytes)
//     forest.gltf: meshes[2].primitives[0]: index 7 at position 5 is out of range (4 vertices)
//     forest.gltf: meshes[0].primitives[0]: POSITION (accessors[3]): vertex 1 has a value that is not finite
//     forest.gltf: meshes[1].primitives[0]: mode LINES is not supported (TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN are)
//     forest.gltf: nodes[0]: is its own descendant (nodes[0] → nodes[1] → nodes[0])
//     forest.gltf: nodes[2]: is a child of both nodes[0] and nodes[1] (a glTF node has at most one parent)
//     forest.gltf: nodes[4096]: is 4097 levels deep in the node hierarchy, over the limit of 4096 (--max-depth)
//     forest.glb: images[0]: embedded image is 16384 × 16384 (268435456 texels), over the limit of 67108864 texels (--max-texels)
//     forest.glb: GLB header: magic is 'abcd', expected 'glTF'
//     forest.glb: chunk 1: length 99999 runs past the end of the file (1234 bytes)
//     forest.glb: buffers[0]: has no uri and the file has no BIN chunk
//     forest.gltf: images[0]: 'leaves.png': /scenes/leaves.png: file not found
//     forest.gltf: buffers[0]: /scenes/forest.bin: is a character device, not a regular file (buffer)
//
// Strings from the file are quoted by a short prefix. A file that fails leaves the scene as it was.
//
// Example: two trees sharing one alpha-masked quad, traced with the paper's texture alpha mask.
//
// ```cpp
// import canopy.plugins;
//
// canopy::registry& r = canopy::builtin_registry();
// canopy::scene s = canopy::load_scene("forest.gltf", r);
// canopy::compiled_scene c = canopy::compile(s, {.plugins = &r});
// // c.meshes: one per primitive; c.top_meshes: one placement per mesh node;
// // c.statistics.alpha_mask_needed: true (the leaves material has alphaMode MASK).
// canopy::texture_alpha_mask mask;
// mask.scene = &c;
// canopy::ray r{{0.0f, 1.0f, 8.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, 1e30f};
// auto hit = c.closest_hit(r, mask); // passes through the texture's transparent texels
// ```
//
// ```json
// {
//   "asset": {"version": "2.0"},
//   "scene": 0,
//   "scenes": [{"nodes": [0, 1, 2]}],
//   "nodes": [
//     {"name": "tree_1", "mesh": 0, "translation": [-2, 0, 0]},
//     {"name": "tree_2", "mesh": 0, "translation": [2, 0, 0], "rotation": [0, 0.7071068, 0, 0.7071068]},
//     {"name": "eye", "camera": 0, "translation": [0, 1, 8]}
//   ],
//   "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}],
//   "meshes": [{"name": "billboard", "primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
//   "materials": [{"name": "leaves", "alphaMode": "MASK", "alphaCutoff": 0.5,
//                  "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
//   "textures": [{"source": 0}],
//   "images": [{"uri": "leaves.png"}],
//   "buffers": [{"uri": "forest.bin", "byteLength": 92}],
//   "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48},
//                   {"buffer": 0, "byteOffset": 48, "byteLength": 32},
//                   {"buffer": 0, "byteOffset": 80, "byteLength": 12}],
//   "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
//                  "min": [-1, 0, 0], "max": [1, 2, 0]},
//                 {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
//                 {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}]
// }
// ```
module;
#include <filesystem>
#include <string_view>
export module canopy.plugins.gltf;
import canopy.scene;

export namespace canopy {

// Loads a .gltf or .glb file under `parent`; returns the group it made. Images referred to by
// uri are read through `r`'s image loaders.
node_id load_gltf(scene& s, std::filesystem::path const& file, node_id parent, registry const& r);

// The same from the file's bytes (.gltf JSON text, or .glb); `file` names it in messages and
// locates its external buffers and images.
node_id parse_gltf(std::string_view bytes, std::filesystem::path const& file, scene& s, node_id parent,
                   registry const& r);

void register_gltf_plugin(registry& r);

} // namespace canopy
