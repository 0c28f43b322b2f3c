// canopy.plugins.openmesh — triangle meshes through OpenMesh 9: .ply .off .stl .om .obj
//
// Loads: one file into one mesh_data (name = the file's stem, source = the file's path) under a
// group node named after the file. Parameters: none. Plugin name "openmesh"; for .obj it is not
// the default loader (the "obj" plugin is): choose it with registry::load(s, file, parent,
// "openmesh").
//
// What is read:
//   positions     every vertex of the file, in file order (no vertex is merged or split; STL is
//                 the exception: OpenMesh's STL reader merges equal corners into one vertex)
//   triangles     every face of the file, in file order; a face of n > 3 corners becomes n − 2
//                 triangles (canopy.scene:polygon: the fan (c0, c_k, c_k+1) when convex,
//                 ear-clipped when not); a face that repeats a vertex is kept as it is (its degenerate
//                 triangles are never hit). STL: OpenMesh's STL reader skips a facet two of
//                 whose corners are equal before any importer sees it; such facets (no area)
//                 are counted here and reported in degenerate_faces
//   normals       per corner, when the file has vertex normals (PLY nx/ny/nz, NOFF, OBJ vn,
//                 OM vertex normals); OBJ's per-corner vn are kept per corner
//   uvs           per corner, when the file has texture coordinates: per corner (OBJ vt, OM
//                 halfedge texture coordinates) or per vertex (PLY u/v or s/t, STOFF, OM)
// STL facet normals and colours of any format are not read.
//
// No face is lost on the way. OpenMesh's importer drops faces with a vertex index out of range
// or a repeated vertex, and re-adds a face it cannot connect ("complex edge", non-manifold) on
// copies of its vertices, both with a note on std::cerr only. This loader records each face as
// the reader hands it over, before OpenMesh's connectivity, so non-manifold faces keep their
// vertices; it checks the number of faces read against the number the file declares (PLY and
// OFF headers, binary STL and OM headers, `f` lines of OBJ, `facet`s of ASCII STL) and throws
// if they differ.
//
// Before OpenMesh sees a file it is checked (the :checks partition, openmesh_checks.cppm; text by
// canopy.scene:text's rules), walked as OpenMesh's reader of its format will
// read it, so that bad input gives a clear message with a line (text formats) or an element
// (binary formats) instead of OpenMesh's silent misreads, endless loops or allocations sized by a
// count in the file. OpenMesh's readers trust counts (they reserve for them, and loop over them
// with no end-of-file check) and read numbers through C++ streams, which stop at a value they
// cannot read (a float beyond 3.4e38, "nan", "0x10"), after which every read fails while the loops
// go on. So, for every format: the file must be a regular file within --max-file-bytes; the
// declared vertex and face counts must fit the file's size (binary files must hold what they
// declare) and --max-triangles; every value OpenMesh reads as a float must be a decimal number
// that fits a float (else "overflows a float"), every integer an integer in range; and:
//   OFF (ASCII)   header [ST][C][N]OFF, counts, every vertex line (coordinates, normals, STOFF's
//                 texture coordinates after COFF's colour), every face (corner count, indices in
//                 range, truncation); the checked text is then handed to OpenMesh's importer here,
//                 as OpenMesh's OFF reader would (that reader takes no comments, and reading from
//                 memory it would keep the [ST][C][N] flags of the last OFF file it opened)
//   OFF BINARY    counts against the bytes that follow, every vertex's floats finite, every
//                 face's corner count and indices
//   PLY           the header as OpenMesh parses it (format on line 2, element counts below 2^32,
//                 list count types it reads, vertex x/y/z, face vertex_indices, no other list in the
//                 elements it reads, binary types it converts, and a binary header laid out as its
//                 seek to the data expects), then every element walked: truncation, values, face
//                 indices in range
//   STL           binary size against its triangle count and finite coordinates; ASCII: the three
//                 lines OpenMesh reads after each "outer loop" are "vertex x y z"
//   OBJ           v, vt and vn values, face corners of at most three parts with indices in range,
//                 faces of fewer than three corners, no UTF-8 byte-order mark (OpenMesh would read it
//                 as part of the first statement)
//   OM            header present, counts against the file's size
//
// A file with vertices but no faces (a PLY point cloud) loads as a mesh without triangles:
// compile() drops it, and reports "nothing to trace" when nothing else is in the scene.
// OpenMesh's messages (its omerr() stream) are captured during the read, kept off std::cerr,
// and quoted in the error when reading fails. Reads are serialised (OpenMesh's reader registry
// and message streams are process-wide).
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
