// canopy.plugins.obj — Canopy's Wavefront OBJ + MTL reader; the default loader for .obj.
//
// ### Wavefront OBJ + MTL (`obj` plugin: `.obj`, the default)
//
// The `obj` plugin (`plugins/obj/`, module `canopy.plugins.obj`) is Canopy's own OBJ reader and the
// default loader for `.obj` (the `openmesh` and `bench` plugins also read `.obj`, registered as alternatives:
// ask for them by name). It has no parameters. A file becomes one group named after it, holding **one mesh node per
// material** the faces use: meshes in the order their material is first used, triangles of a mesh in
// file order. A convex polygon is fanned as (v0 vi vi+1) in order; a non-convex one is ear-clipped in
// the plane of its Newell normal, so that no triangle leaves it (`canopy::triangulate_polygon`). A file without `usemtl` is one mesh in
// which triangle i comes from the i-th `f` line when every face is a triangle, so the benchmark OBJ
// subset (`bench/FORMATS.md`) reads identically. Each mesh keeps only the vertices its faces use.
// `o` and `g` do not split meshes. A face the triangulation has to fan although the fan may cover
// more than the face (self-intersecting, all corners collinear, or non-convex with more than 256
// corners) is counted in its mesh (`mesh_data::fanned_faces`, the first one's line in
// `first_fanned`) and reported by `compile()` (a line of `canopy info`'s decisions).
//
// | OBJ | read as |
// | --- | --- |
// | `v x y z [w]`, `v x y z r g b [a]` | a position (3 to 7 numbers; x y z are used) |
// | `vt u [v [w]]` | a texture coordinate, stored as (u, 1 − v): Canopy's v = 0 is the image's top row |
// | `vn x y z` | a normal, per corner as written |
// | `f c1 c2 c3 ...` | a polygon of 3 or more corners `v`, `v/vt`, `v//vn` or `v/vt/vn`; indices 1-based, negative ones relative to the count so far; every corner of a face has the same form |
// | `usemtl NAME` | the material of the faces that follow (NAME: the rest of the line, trimmed) |
// | `mtllib FILE ...` | material libraries, relative to the `.obj` (the whole rest of the line if it names an existing file, else one file per word) |
// | anything else | ignored: `o`, `g`, `s`, `l`, `p`, curves and surfaces, unknown statements; `#` starts a comment |
//
// In a mesh where some faces have texture coordinates (or normals) and others not, the others get
// (0, 0) (or their geometric normal). A `usemtl` name that no library defines gives its mesh the
// default material: exporters often write `usemtl` without shipping the library.
//
// | MTL | read as |
// | --- | --- |
// | `newmtl NAME` | starts a material (NAME may hold spaces, may be empty); the first definition of a name wins |
// | `Kd r g b` (or `Kd r`) | the colour; without `Kd`: white if there is a `map_Kd`, Canopy's grey otherwise |
// | `map_Kd [options] FILE` | the colour texture, read through the registry's image loaders (`registry::load_image`), relative to the `.mtl`; backslashes are folder separators |
// | `map_d [options] FILE` | an alpha texture: its red channel becomes the alpha of the material's texture (resampled nearest to `map_Kd`'s size; a white texture of its own size without `map_Kd`) and the material is `alpha_mode::mask`, cutoff 0.5 |
// | `map_Kd` whose image has a texel with alpha < 1 | also `alpha_mode::mask`, cutoff 0.5 |
// | texture options | `-blendu -blendv -bm -boost -cc -mm -texres` skipped; `-o -s -t -clamp -imfchan` (they change the lookup) refused |
// | anything else | ignored: `Ka Ks Ns Ni illum`, the scalars `d` and `Tr` (Canopy has no translucency), other maps |
//
// Only the materials the faces use are added to the scene, and only their textures are loaded;
// materials naming the same texture files share one image. A library is read once however often
// `mtllib` names it.
// Texels come as the image loader returns them: 8- and 16-bit files are marked sRGB-encoded
// (`image_data::srgb`) and `compile()` decodes their colour to linear; the alpha map's red channel is
// used as stored.
//
// Only regular files are read (the `.obj`, its libraries, their textures): a folder, a device
// (`/dev/zero`, also through a symbolic link) or a FIFO is named as such before it is opened, and a
// file over the limit of bytes per file (`--max-file-bytes`) is refused. The `.obj` and `.mtl` must
// be text: a NUL or other control byte (but tab, CR, LF, VT, FF) or a UTF-16/32 byte-order mark is
// refused with its offset and line. A file with no face is refused too: there is nothing to trace
// (an empty file, one without any OBJ statement, a point cloud, lines). Vertices, texture
// coordinates, normals and triangles are each limited by `--max-triangles` as they grow.
//
// Errors (`scene_error`, `file:line: problem`; the scene is left as it was; input is quoted by its
// first 40 bytes at most):
//
//     tree.obj:12: bad number '0.5x'
//     tree.obj:3: number 'nan' is not finite
//     tree.obj:4: value 1e300 overflows a float
//     tree.obj:40: vertex index 4000000000 is out of range (812 vertices so far)
//     tree.obj:41: vertex index 0 is not valid (OBJ indices start at 1)
//     tree.obj:42: face has 2 corners; at least 3 are needed
//     tree.obj:43: corner '2' has another form than the face's first corner '1/1'
//     tree.obj:2: material library 'tree.mtl': file not found
//     tree.obj:2: material library 'tree.mtl': is a FIFO, not a regular file
//     /scenes/tree.mtl:7: texture 'bark.png': /scenes/bark.png: file not found (texture)
//     /scenes/tree.mtl:9: texture option -s is not supported
//     tree.obj:812: 268435457 triangles exceed the limit of 268435456 (--max-triangles)
//     box_UTF16BE.obj: not a text OBJ file: UTF-16 byte-order mark (only ASCII or UTF-8 text is read)
//     random.obj:3: not a text OBJ file: NUL byte at offset 130
//     point_cloud.obj: no faces ('f' lines): nothing to trace
//
// The parser is a function over a buffer, `parse_obj(text, file_name, registry*, scene&, parent)`
// (and `parse_mtl(text, file_name)`); with a null registry texture statements are checked but not
// loaded. It is linear in the input (also for 10⁵ `usemtl` or `mtllib` lines): nothing is allocated
// by a count read from the file. It is fuzzed (`fuzz/obj_fuzzer.cpp`, `scripts/fuzz.sh`).
//
// Example:
//
// ```cpp
// import canopy.plugins;
//
// canopy::registry& r = canopy::builtin_registry();
// canopy::scene s = canopy::load_scene("tree.obj", r);        // group "tree": a mesh per material
// canopy::compiled_scene c = canopy::compile(s, {.plugins = &r});
// ```
module;
#include <array>
#include <cstddef>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>
export module canopy.plugins.obj;
import canopy.scene;

export namespace canopy {

// A material of an MTL file as written (before its textures are loaded).
struct mtl_material {
    std::string name;
    std::size_t line = 0;                  // of its newmtl statement
    std::optional<vec3<float>> colour;     // Kd
    std::string colour_texture;            // map_Kd, as written (backslashes turned into slashes)
    std::size_t colour_texture_line = 0;
    std::string alpha_texture;             // map_d
    std::size_t alpha_texture_line = 0;
};

// Parses MTL text; file_name names the library in errors.
std::vector<mtl_material> parse_mtl(std::string_view text, std::string const& file_name);

// Parses OBJ text into s under parent (no_node: free-standing) and returns the group it made.
// file_name names the file in errors; material libraries and textures are found relative to its
// folder. Textures load through r; with r == nullptr texture statements are checked but not
// loaded (for syntax checks and fuzzing). On error s is left as it was.
node_id parse_obj(std::string_view text, std::string const& file_name, registry const* r, scene& s, node_id parent);

// The file loader registered for ".obj".
node_id load_obj(scene& s, std::filesystem::path const& file, node_id parent, registry const& r);

void register_obj_plugin(registry& r);

} // namespace canopy
