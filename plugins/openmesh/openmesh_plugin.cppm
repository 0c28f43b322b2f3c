// canopy.plugins.openmesh — triangle meshes through OpenMesh 9: .ply .off .stl .om .obj
//
// ### Meshes through OpenMesh (`openmesh` plugin: `.ply` `.off` `.stl` `.om`, and `.obj` by name)
//
// The `openmesh` plugin (`plugins/openmesh/`, module `canopy.plugins.openmesh`) reads triangle and
// polygon meshes with OpenMesh 9 (Debian's `libopenmesh-dev`). It has no parameters. Each file
// becomes one mesh (named after the file's stem, `source` = its path) under a group named after the
// file. For `.obj` the `obj` plugin is the default loader (this one registers `.obj` as
// `loader_rank::alternative`) and this one is chosen by name:
// `registry.load(s, "bunny.obj", parent, "openmesh")`.
//
// - **Faces**: every face of the file, in file order (a triangle's `prim_id` is its face's index in
//   triangle-only files). A face of n > 3 corners becomes n − 2 triangles with its winding: the fan
//   (c0, c_k, c_k+1), k = 1 … n−2, when it is convex; ear-clipped in the plane of its Newell normal
//   when it is not, so that no triangle leaves the face (`canopy::triangulate_polygon`).
//   `read_openmesh()` reports the faces read, how many had more than three corners (`polygons`), how
//   many of those were non-convex (`concave_polygons`), non-manifold and degenerate faces.
// - **Normals and texture coordinates**, per corner, when the file has them: PLY `nx ny nz` and
//   `u v`/`s t`, NOFF/STOFF, OBJ `vn`/`vt` (kept per corner: a vertex may carry different ones in
//   different faces), OM vertex normals and vertex or halfedge texture coordinates. STL facet normals
//   and colours are not read.
// - **No face lost**: OpenMesh's importer drops faces with an index out of range or a repeated
//   vertex, and re-adds faces it cannot connect ("complex edge", non-manifold) on copies of their
//   vertices, with a note on `std::cerr` only. The plugin records each face as the reader hands it
//   over, before OpenMesh's connectivity, so non-manifold faces keep their own vertices and
//   degenerate faces are kept (they are never hit); the count read is compared with the count the
//   file declares (PLY/OFF/OM headers, binary STL count, ASCII STL `facet`s, OBJ `f` lines) and a
//   difference is an error saying how many faces were dropped. One exception, by OpenMesh's STL
//   reader: STL facets two of whose corners are equal are skipped before any importer sees them;
//   they have no area, and are counted in `degenerate_faces`.
// - **Checked before OpenMesh reads**, walked as OpenMesh's reader of the format will read it,
//   because OpenMesh trusts what a file says: it reserves for the counts and loops over them with no
//   end-of-file check, and it reads numbers through C++ streams, which stop at a value they cannot
//   read (a float beyond 3.4·10³⁸, `nan`, `0x10`) while the loops go on (an ASCII PLY with a
//   `double` of 1e300 made it grow a vector to 4 GB; an `OFF BINARY` header claiming 2·10⁹ vertices,
//   9.8 GB). So every file must be a regular file within `--max-file-bytes`; the declared vertex and
//   face counts must fit the file (a binary file must hold what it declares) and `--max-triangles`;
//   every value OpenMesh reads as a float must be a decimal number that fits a float (else
//   "overflows a float"), every integer an integer in range. Per format: ASCII OFF (header
//   `[ST][C][N]OFF`, counts, every vertex line with its normals and STOFF texture coordinates, every
//   face, truncation; the checked text then goes to OpenMesh's importer from here, since OpenMesh's
//   OFF reader takes no comments and, reading from memory, keeps another file's NOFF/STOFF flags);
//   `OFF BINARY` (counts against the bytes that follow, finite values, corner counts, indices); PLY
//   (the header as OpenMesh parses it: `format` on line 2, element counts below 2³², the list count
//   types it reads, `x y z`, `vertex_indices`, no other list property in the elements it reads,
//   binary property types it converts, a binary header laid out as its seek to the data expects,
//   e.g. no comment right before `end_header`; then every element walked: truncation, values, face
//   indices in range, one entry a line); STL (binary size against its triangle count, finite
//   coordinates; ASCII: the three lines after each `outer loop` are `vertex x y z`, the last line
//   `endsolid`); OBJ (`v`, `vt`, `vn` values, `f` corners of at most three parts with indices in
//   range, faces of fewer than three corners, no UTF-8 byte-order mark, which OpenMesh's OBJ reader
//   would read as part of the first statement); OM (header, counts against the file's size). The
//   checks are `plugins/openmesh/openmesh_checks.cppm`; they read text by the rules of
//   `canopy.scene:text`, the same as the OBJ and benchmark readers (integers must fit 64 bits, a
//   value PLY reads and drops must still be a decimal number, an integer for an integer type).
// - A file with vertices but no faces (a PLY point cloud) is a mesh without triangles: `compile()`
//   drops it, and reports "nothing to trace" when the scene holds nothing else.
// - OpenMesh's messages are kept off the console while a file is read and quoted in the error when
//   reading fails. Reads through OpenMesh are serialised (its reader registry and message streams
//   are process-wide).
//
// Errors name the file, and the line (text) or element (binary) where known:
//
//     meshes/bad.off:4: vertex 1: coordinate 'nan' is not a finite number
//     meshes/bad.off:6: face 0: vertex index 3 is out of range (3 vertices)
//     meshes/big.ply:10: vertex 0: coordinate x = '1e300' overflows a float
//     meshes/huge.off: 2000000000 vertices exceed the limit of 268435456 (--max-triangles)
//     meshes/short.off: the header declares 1000 vertices of 12 bytes, more than the 52 bytes after it hold
//     meshes/cut.ply: file ends in face 4 of 5
//     meshes/cut.stl: not an STL file: as binary STL its header announces 1368 triangles (68484 bytes), the file has 68454 bytes (truncated?); as ASCII STL it does not begin with 'solid'
//     meshes/line.obj:3: face has 2 corners (at least 3 needed)
//     meshes/empty.ply: file is empty
//
// Example: the Stanford bunny of `glmark2-data` through OpenMesh, and what the reading did.
//
// ```cpp
// import canopy.plugins;
// import canopy.plugins.openmesh;
//
// canopy::registry& r = canopy::builtin_registry();
// canopy::scene s;
// r.load(s, "/usr/share/glmark2/models/bunny.obj", s.root(), "openmesh"); // 69 666 triangles
// r.load(s, "part.ply");                                                  // default loader for .ply
// canopy::compiled_scene c = canopy::compile(s, {.plugins = &r});
//
// auto const info = canopy::read_openmesh("room.off");
// std::printf("%zu faces, %zu fanned\n", info.faces, info.polygons);
// ```
module;
#include <cstddef>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
export module canopy.plugins.openmesh;
import canopy.scene;

export namespace canopy {

// One file read, and what the reading did.
struct openmesh_read_result {
    mesh_data mesh;
    std::size_t faces = 0;            // faces read: all of the file's (STL: less the skipped degenerate facets)
    std::size_t polygons = 0;         // faces of more than three corners (canopy.scene:polygon)
    std::size_t concave_polygons = 0; // of which non-convex, ear-clipped rather than fanned
    std::size_t degenerate_faces = 0; // faces that repeat a vertex (kept), or STL facets with equal corners (skipped)
    std::size_t nonmanifold_faces = 0; // faces OpenMesh could not connect (kept on their own vertices)
    bool vertex_normals = false;      // the file has normals (mesh.normals is filled)
    bool texcoords = false;           // the file has texture coordinates (mesh.uvs is filled)
};

// The checks above on a file's bytes `data` (a file named `file`, of extension `ext`: ".ply",
// ".off", ".stl", ".obj" or ".om"); returns the number of faces the file declares. Throws
// scene_error on bad input.
std::optional<std::size_t> check_openmesh_input(std::string_view data, std::string const& file, std::string const& ext);

// Reads a .ply .off .stl .om or .obj file (by extension, case-insensitive). Throws scene_error
// naming the file, and the line or element where known, on any bad input (see above).
openmesh_read_result read_openmesh(std::filesystem::path const& file);

// The loader: the mesh under a group named after the file; returns the group.
node_id load_openmesh(scene& s, std::filesystem::path const& file, node_id parent);

void register_openmesh_plugin(registry& r);

} // namespace canopy
