// canopy.plugins.gltf — glTF 2.0 scenes (.gltf with external or embedded buffers, .glb) through
// tinygltf.
//
// Loads the default scene (or scene 0; with no scenes, every node that is no other node's child)
// under one group named after the file:
//   nodes       each glTF node → a transform node (its matrix, or T·R·S) holding its mesh, its
//               camera and its children, in the file's hierarchy
//   meshes      each primitive → one canopy mesh, built once and shared by every node that uses
//               the glTF mesh (so a mesh used by N nodes is one BVH placed N times). A node's mesh
//               with one primitive is one mesh node; with several, a group holding one mesh node
//               per primitive. Modes: TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN (triangulated
//               as the glTF specification lists them); indices u8/u16/u32 or none; POSITION float
//               VEC3; NORMAL float VEC3; TEXCOORD_n float, or normalized u8/u16, VEC2 (n = the
//               texCoord of the material's base colour texture, 0 without one); sparse
//               accessors. Texture coordinates are kept as they are: glTF and canopy.texture
//               both put (0, 0) at the top-left of the image.
//   materials   pbrMetallicRoughness.baseColorFactor (linear RGB) → colour; baseColorTexture →
//               the material's image: a file (uri relative to the .gltf) read through the
//               registry's image loaders, or an embedded image (data: URI, .glb buffer view)
//               decoded by tinygltf; texel RGB is sRGB-encoded (glTF's rule for base colour) and
//               converted to linear, alpha is linear and multiplied by the factor's alpha.
//               alphaMode MASK (alphaCutoff, default 0.5) → alpha_mode::mask; BLEND is treated
//               as MASK with cutoff 0.5 (ray queries see a surface or a hole, never a fraction);
//               a masked material without a texture masks by its factor's alpha (a 1×1 image).
//               A mask compares texture alpha × factor alpha with the cutoff, that is texture
//               alpha with cutoff / factor: each image is decoded and held once, however many
//               materials use it (and once for all glTF images of the same bytes or file).
//   cameras     perspective: eye at the node's origin, looking down the node's −Z, up +Y,
//               fovy = yfov (aspect ratio and clip planes are not used)
// Ignored: skins and morph targets (the meshes are loaded in their base pose), animations,
// lights, the other material properties. Not supported (scene_error): points and lines,
// orthographic cameras, files whose extensionsRequired lists any extension.
// Zero scales are refused: canopy places geometry only with invertible transforms.
//
// Parameters: none. Errors (scene_error) name the file and the element, as
//   "scene.gltf: meshes[2].primitives[0]: index 7 at position 5 is out of range (4 vertices)"
//   "model.gltf: materials[0].pbrMetallicRoughness: expected an object, got an array"
// Nothing is dropped or guessed: before tinygltf reads the JSON, every property of the glTF 2.0
// core schema is checked (its JSON type, its range or allowed values, the element an index refers
// to, accessors and buffer views inside their buffer views and buffers, without overflow), so a
// texture index of -1 or an object where an array belongs is refused with its JSON path, not
// ignored. A .glb file's layout is checked before anything reads it (glb_layout: the header's magic,
// version and length, each chunk inside the file, JSON first, BIN second, a BIN chunk for a
// buffers[0] without uri), each fault named as "GLB header", "chunk N" or "buffers[0]". Also
// refused: malformed JSON, JSON nested deeper than --max-depth (at
// most 512), missing buffers and images, files that are not regular files or are over
// --max-file-bytes (external buffers and images included; a file is looked for in the glTF file's
// folder only), embedded images that are not PNG or JPEG or whose header claims more than
// --max-texels texels or would bring the scene's images over --max-total-texels together (checked
// before decoding; embedded images count from when they are decoded), meshes over --max-triangles (the scene's meshes
// together, checked before a primitive is read), mesh placements over --max-placements, indices out of
// range, NaN or infinite values, values beyond the float range, unsupported modes and component
// types, a node with two parents, a node that is its own descendant (the message lists the
// cycle), and node hierarchies deeper than --max-depth (walked without recursion).
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
