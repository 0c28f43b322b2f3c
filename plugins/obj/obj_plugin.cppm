// canopy.plugins.obj — Canopy's Wavefront OBJ + MTL reader; the default loader for .obj.
//
// Loads: `.obj` files with their `.mtl` material libraries into one group named after the file,
// holding one mesh node per material the faces use (meshes in order of first use; triangles of a
// mesh in file order; a convex polygon fanned (v0 vi vi+1) in order, a non-convex one ear-clipped,
// see canopy.scene:polygon). A file without `usemtl` is one
// mesh whose triangle i comes from the i-th `f` line when every face is a triangle: the benchmark
// OBJ subset (bench/FORMATS.md) reads identically. Parameters: none.
//
// OBJ statements read:
//   v x y z [w | r g b [a]]   position (3 to 7 numbers; only x y z are used)
//   vt u [v [w]]              texture coordinate; stored as (u, 1 − v): Canopy's v = 0 is the top row
//   vn x y z                  normal (per corner, as written)
//   f a b c ...               polygon of ≥ 3 corners: v, v/vt, v//vn or v/vt/vn; 1-based, negative
//                             = relative to the count so far; every corner of a face has the same form
//   usemtl NAME               material of the following faces (NAME = rest of the line, trimmed)
//   mtllib FILE ...           material libraries, relative to the .obj (the whole rest of the line
//                             when it names an existing file, else one file per word)
// Everything else (o, g, s, l, p, curves, comments after #) is ignored. `o` and `g` do not split
// meshes. A `usemtl` name that no library defines gives that mesh the default material (exporters
// often write `usemtl` without shipping the library); faces without texture coordinates in a mesh
// whose other faces have them get (0, 0).
//
// MTL statements read (everything else ignored; `d`/`Tr` scalars are ignored: no translucency):
//   newmtl NAME               starts a material (NAME = rest of the line, trimmed; may be empty)
//   Kd r g b                  colour (default (1, 1, 1) with map_Kd, Canopy's grey without)
//   map_Kd [opts] FILE        colour texture, through registry::load_image, relative to the .mtl
//   map_d [opts] FILE         alpha texture: its red channel becomes the alpha of the material's
//                             texture (resampled nearest to map_Kd's size) and the material is
//                             alpha_mode::mask with cutoff 0.5
// A map_Kd image with any texel alpha below 1 also makes the material a mask (cutoff 0.5).
// Texture paths: backslashes are read as folder separators. Options -blendu -blendv -bm -boost
// -cc -mm -texres are skipped; -o -s -t -clamp -imfchan change the lookup and are errors.
//
// Only regular files are read (canopy.scene's read_regular_file: a folder, a device or a FIFO is
// named before it is opened); a library is read once however often `mtllib` names it, and
// materials naming the same texture files share one image. A polygon face fanned by
// triangulate_polygon's fallback is counted in mesh_data::fanned_faces (compile() reports it).
//
// Lines, tokens, numbers and indices are read by canopy.scene:text's rules (a number is read
// straight to the nearest float; hexadecimal, "inf" and "nan" are refused; a UTF-8 byte-order mark
// is skipped).
//
// Errors (scene_error, "file:line: problem"; input quoted by a short prefix): bad or non-finite
// numbers, numbers that overflow a float ("value 1e300 overflows a float"), zero or out-of-range
// indices, faces with fewer than 3 corners, corners of mixed forms, a missing, unreadable or
// non-regular material library (named with the .obj line that asks for it), a texture that does
// not load (named with its .mtl line; over --max-texels, or over --max-total-texels with the
// scene's images and the material's colour image), input that is not text ("not a text OBJ file: NUL byte at
// offset 12", a UTF-16 byte-order mark), a file without faces (nothing to trace), vertices, texture
// coordinates, normals or triangles over --max-triangles.
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
