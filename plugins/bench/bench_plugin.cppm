// canopy.plugins.bench — the benchmark scene formats (bench/FORMATS.md of the shared
// specification) as scene-graph content; its partition :formats (bench_formats.cppm, exported)
// reads and writes the files.
//
// ### Benchmark scenes (`bench` plugin: `.inst`, and `.obj` by name)
//
// The `bench` plugin (`plugins/bench/bench_plugin.cppm`, module `canopy.plugins.bench`) loads the
// benchmark formats of `bench/FORMATS.md` (read by its partition `canopy.plugins.bench:formats`,
// exported with it) into the scene graph, so that the benchmark scenes can be combined with other content and go through `compile()`:
// `canopy trace` and the Embree benchmark load their files this way. It has no parameters. Each file
// becomes a group named after it; `add_bench_scene` lays out bench content made in code (the
// benchmarks' generated scenes) the same way.
//
// - **`.inst`**: the shared mesh (the `mesh PATH` line, relative to the `.inst` file) becomes one
//   mesh and one free-standing prototype mesh node; every matrix line becomes an instance node of it,
//   in file order, with `instance_id` = its index among the matrix lines. `compile()` builds the mesh
//   once and places the instances in node order, so a hit's `inst_id` is the instance's line index
//   and `prim_id` its triangle's `f` line index, when the file is the whole scene. A file with a
//   single identity instance compiles to a plain mesh (levels 0, no top level), whose hits carry
//   `inst_id = invalid_id`, unless `compile_options::keep_single_instance` is set: then the top level
//   is kept and hits carry `inst_id = 0`, as the formats require (`canopy trace` compiles with it).
//   With other content placed before the file, placement indices (and so `inst_id`) shift;
//   `compiled_scene::instance_id(hit)` still returns the line index.
// - **`.obj`** under the plugin name `bench`: the strict OBJ subset (`v` and triangular `f` lines,
//   everything else ignored), triangle i = the i-th `f` line. The plugin registers it as an alternative
//   (`loader_rank::alternative`), so a general OBJ loader stays the default for `.obj`, whatever the
//   order of registration; ask for this one by name:
//   `registry.load(s, "bunny.obj", parent, "bench")`.
//
// Vertices are not shared between triangles (three per triangle, as the subset reader returns them).
// Tokens, numbers and indices are read by the rules of `canopy.scene:text` (one set for every text
// loader): a number is read straight to the nearest float, hexadecimal, `inf` and `nan` are refused,
// a UTF-8 byte-order mark is skipped.
//
// Errors name the file at fault (the `.inst`, or the mesh it refers to) and the line: files that are
// not regular files (a folder, a device, a FIFO: refused before they are opened) or are over
// `--max-file-bytes`, text that is not text (a NUL or other control byte, a UTF-16/32 byte-order
// mark), faces that are not triangles, bad or non-finite numbers, numbers that overflow a float,
// zero or out-of-range vertex indices, instance lines without 12 numbers, singular transforms, a missing or
// second `mesh` line, an `.inst` naming itself as its mesh, files with nothing to trace (a mesh
// without `f` lines, an `.inst` without instance lines), and counts over the limits (vertices and
// triangles: `--max-triangles`, instances: `--max-placements`). A file that fails leaves the scene as
// it was. `canopy trace` reports the same errors, and refuses a ray file that is not a regular file
// or whose size is not a multiple of 32 bytes.
//
//     scene/trees.inst:3: instance line needs 12 numbers (3x4 row-major matrix), found 11
//     scene/trees.inst:2: singular instance transform
//     scene/tree.obj:5: face has 4 vertices; only triangles are supported
//     scene/tree.obj:7: value 1e300 overflows a float
//     scene/nowhere.obj: file not found (mesh of trees.inst)
//     scene/empty.inst: no instance lines (12 numbers each): nothing to trace
//     scene/self.inst: names itself as its mesh ('mesh self.inst'); the mesh is an .obj file
//     scene/random.obj:1: not a text OBJ file: NUL byte at offset 12
//
// Example: a benchmark forest with a procedural terrain under it.
//
// ```cpp
// import canopy.plugins;
//
// canopy::registry& r = canopy::builtin_registry();
// canopy::scene s = canopy::load_scene("forest.inst", r);   // group "forest.inst": N instance nodes
// r.generate(s, "terrain", {{"size", "200"}, {"amplitude", "2"}});
// canopy::compiled_scene c = canopy::compile(s, {.plugins = &r});
// ```
module;
#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <utility>
export module canopy.plugins.bench;
import canopy.scene;
export import :formats;

export namespace canopy {

void register_bench_plugin(registry& r);

// Bench content under `parent`, laid out as the plugin lays out its files: a group named after
// `file`; in it the mesh (triangle i = prim_id i, named after `mesh_file`) as a mesh node, or,
// when `instances` is not empty, one instance node per transform (instance_id = its index) of a
// free-standing prototype mesh node. Nodes take `file` as their source, the mesh `mesh_file`.
// Returns the group. Throws scene_error for a mesh over 32-bit vertex indices.
node_id add_bench_scene(scene& s, node_id parent, std::span<triangle const> mesh,
                        std::span<affine_transform<float> const> instances, std::filesystem::path const& file,
                        std::filesystem::path const& mesh_file);

} // namespace canopy

namespace canopy {

namespace {

mesh_data to_mesh(std::span<triangle const> in, std::filesystem::path const& file) {
    if (in.size() > (std::size_t(1) << 32) / 3 - 1)
        throw scene_error(file.string(), "", std::to_string(in.size()) +
                                                 " triangles: more than 32-bit vertex indices reach (three per triangle)");
    mesh_data m;
    m.name = file.filename().string();
    m.source = file.string();
    m.positions.reserve(3 * in.size());
    m.triangles.reserve(in.size());
    for (auto const& t : in) {
        auto const first = std::uint32_t(m.positions.size());
        m.positions.insert(m.positions.end(), {t.v0, t.v1, t.v2});
        m.triangles.push_back({first, first + 1, first + 2});
    }
    return m;
}

node_id load_inst(scene& s, std::filesystem::path const& file, node_id parent, registry const&) {
    bench_instanced_scene const in = read_bench_inst(file);
    return add_bench_scene(s, parent, in.mesh.triangles, in.instances, file, in.mesh_path);
}

node_id load_obj(scene& s, std::filesystem::path const& file, node_id parent, registry const&) {
    return add_bench_scene(s, parent, read_bench_obj(file).triangles, {}, file, file);
}

} // namespace

node_id add_bench_scene(scene& s, node_id parent, std::span<triangle const> mesh,
                        std::span<affine_transform<float> const> instances, std::filesystem::path const& file,
                        std::filesystem::path const& mesh_file) {
    std::uint32_t const m = s.add_mesh(to_mesh(mesh, mesh_file));
    std::string const mesh_name = mesh_file.filename().string();
    node_id const prototype = instances.empty() ? no_node : s.add_mesh_node(no_node, m, mesh_name);
    if (prototype != no_node) s.at(prototype).source = file.string();
    node_id const group = s.add_group(parent, file.filename().string());
    s.at(group).source = file.string();
    if (instances.empty()) {
        s.at(s.add_mesh_node(group, m, mesh_name)).source = file.string();
        return group;
    }
    for (std::size_t k = 0; k < instances.size(); ++k)
        s.at(s.add_instance(group, prototype, instances[k], std::uint32_t(k))).source = file.string();
    return group;
}

void register_bench_plugin(registry& r) {
    r.add_loader(".inst", "bench", "benchmark instanced scene: one shared .obj mesh, one 3×4 matrix per instance",
                 load_inst);
    r.add_loader(".obj", "bench", "benchmark OBJ subset: v and triangular f lines only, prim_id = f line order",
                 load_obj, loader_rank::alternative);
}

} // namespace canopy
