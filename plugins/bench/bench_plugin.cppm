// canopy.plugins.bench — the benchmark scene formats (bench/FORMATS.md of the shared
// specification) as scene-graph content; its partition :formats (bench_formats.cppm, exported)
// reads and writes the files.
//
// Loads:
//   .inst  one shared mesh (the `mesh PATH` line, an .obj of the subset below) and one instance
//          node per matrix line, in file order, all of one free-standing prototype mesh node.
//          Instance k has instance_id k; compile() places the instances in node order, so the
//          inst_id of a hit is the instance's line index among the matrix lines (when the file is
//          the only content of the scene; a file with a single identity instance compiles to a
//          plain mesh, levels 0, whose hits carry no inst_id).
//   .obj   (plugin name "bench", registered before the general OBJ loaders, which stay the
//          default: load(s, file, parent, "bench") picks this one) the strict OBJ subset: `v` and
//          triangular `f` lines only; triangle i is the i-th `f` line (its prim_id).
// Vertices are not shared between triangles (three per triangle, as the subset reader returns
// them). Each file becomes a group named after it. Parameters: none. add_bench_scene lays out
// bench content made in code (the benchmarks' generated scenes) the same way; compiled with
// compile_options::keep_single_instance, a file gives what the formats require of `canopy trace`:
// prim = the triangle's `f` line, inst = the matrix line (none for an .obj), also for a single
// identity instance.
// Errors: the format reader's scene_errors, passed on as they are, naming the file at fault (the
// .inst or its mesh) and the line: files that are not text, faces that are not triangles, bad or
// non-finite numbers, numbers that overflow a float, zero or out-of-range indices, a missing or
// second `mesh` line, an .inst naming itself as its mesh, singular transforms, files that hold
// nothing to trace (a mesh without `f` lines, an .inst without instance lines), unreadable files,
// files over a limit.
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
                 load_obj);
}

} // namespace canopy
