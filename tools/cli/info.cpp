// canopy info: a scene's statistics, compile decisions and BVH statistics, or the registered
// plugins (--plugins).
#include <cstddef>
#include <span>
#include <string>
#include <vector>
#include <fmt/core.h>
#include "commands.hpp"
#include "options.hpp"
#include "scenes.hpp"
import canopy;
import canopy.scene;

namespace cli {

namespace {

constexpr char const* info_options_usage =
    "usage: canopy info SCENE [--plugin FILE]... [--quality Q] [limits]\n"
    "       canopy info --plugins [--plugin FILE]...\n"
    "  SCENE      a file any registered plugin loads, or gen:NAME[:KEY=VALUE,...]\n"
    "  --plugins  list the registered loaders, image loaders, generators and node types\n"
    "  --plugin FILE  load a shared-library plugin first (may be repeated)\n";

void print_stats(char const* name, canopy::bvh_stats const& s) {
    fmt::print("{}: {} primitives, {} nodes ({} leaves, largest {}), depth {}, SAH cost {:.2f}, {:.1f} bytes/primitive\n",
               name, s.primitive_count, s.node_count, s.leaf_count, s.max_leaf_size, s.depth, s.sah_cost,
               s.bytes_per_primitive);
}

void print_registered(char const* what, std::vector<canopy::registered> const& list) {
    fmt::print("{}:\n", what);
    if (list.empty()) fmt::print("  (none)\n");
    for (auto const& e : list)
        fmt::print("  {:<20} {:<12} {}\n", e.name, e.plugin, e.description);
}

} // namespace

std::string info_usage() { return std::string(info_options_usage) + quality_usage + limits_usage; }

int run_info(std::span<char*> all_args) {
    arguments const args = parse_arguments(all_args, {{"--plugins", false}, {"--plugin", true, true}, {"--quality"}});
    if (args.help) {
        std::fputs(info_usage().c_str(), stdout);
        return 0;
    }
    if (args.positional.size() > 1)
        throw usage_error("info takes one scene, not " + std::to_string(args.positional.size()) + " (" +
                          quote(args.positional[0]) + ", " + quote(args.positional[1]) + ", ...)");
    bool const list_plugins = args.has("--plugins");
    if (list_plugins == !args.positional.empty()) throw usage_error("info takes exactly one scene, or --plugins");
    if (!list_plugins) parse_generator(args.positional.front()); // usage errors before any work
    canopy::build_quality const quality = quality_option(args);
    if (list_plugins && args.has("--quality")) throw usage_error("--quality applies to a SCENE, not to --plugins");
    apply_limits(args);
    canopy::registry const& registry = plugin_registry(args.values("--plugin"));
    if (list_plugins) {
        print_registered("file loaders (the first of an extension is its default)", registry.loaders());
        print_registered("image loaders", registry.image_loaders());
        print_registered("generators", registry.generators());
        print_registered("node types", registry.node_types());
        fmt::print("shared-library plugins loaded:{}\n", registry.plugins().empty() ? " none" : "");
        for (auto const& p : registry.plugins()) fmt::print("  {}\n", p);
        return 0;
    }
    std::string const scene_path = args.positional.front();
    auto const loaded = load_and_compile(scene_path, registry, quality);
    canopy::scene const& g = loaded.graph;
    canopy::compiled_scene const& c = loaded.compiled;
    auto const& st = c.statistics;
    fmt::print("scene {}: loaded in {:.3f} ms\n", scene_path, loaded.load_seconds * 1e3);
    fmt::print("graph: {} nodes, {} meshes, {} materials, {} images, {} cameras, {} lights\n", g.nodes().size(),
               g.meshes().size(), g.materials().size(), g.images().size(), st.cameras, st.lights);
    fmt::print("compiled in {:.3f} ms: {} instance level{}, {} meshes built ({} triangles stored), {} placements "
               "({} triangles placed), {} groups, {} group instances\n",
               st.build_seconds * 1e3, st.levels, st.levels == 1 ? "" : "s", st.meshes_built, st.triangles_stored,
               st.placements, st.triangles_placed, st.groups, st.group_instances);
    fmt::print("decisions:\n");
    for (auto const& d : st.decisions) fmt::print("  - {}\n", d);
    std::size_t mesh_nodes = 0, mesh_prims = 0;
    double mesh_bytes = 0.0, mesh_sah = 0.0;
    for (auto const& m : c.meshes) {
        auto const ms = canopy::compute_stats(m.accel);
        mesh_nodes += ms.node_count;
        mesh_prims += ms.primitive_count;
        mesh_bytes += double(ms.bytes);
        mesh_sah += ms.sah_cost * double(ms.primitive_count);
    }
    double const per_triangle = mesh_prims ? 1.0 / double(mesh_prims) : 0.0;
    std::size_t meshes_high = 0;
    for (auto const& m : c.meshes) meshes_high += m.accel.quality == canopy::build_quality::high ? 1 : 0;
    std::string quality_text = quality_name(st.quality);
    if (st.quality == canopy::build_quality::automatic)
        quality_text += fmt::format(" (high for {} of {} mesh{})", meshes_high, c.meshes.size(),
                                    c.meshes.size() == 1 ? "" : "es");
    fmt::print("mesh BVH build: quality {}, {:.3f} ms, SAH cost {:.2f}{}, {:.1f} bytes/triangle\n",
               quality_text, st.mesh_build_seconds * 1e3, mesh_sah * per_triangle,
               c.meshes.size() == 1 ? "" : " (mean over triangles)", mesh_bytes * per_triangle);
    canopy::build_phase_times phases;
    for (auto const& m : c.meshes) {
        phases.references += m.accel.build_phases.references;
        phases.tree += m.accel.build_phases.tree;
        phases.wide_nodes += m.accel.build_phases.wide_nodes;
        phases.leaves += m.accel.build_phases.leaves;
    }
    fmt::print("mesh BVH build phases{}: references {:.3f} ms, binary tree {:.3f} ms, wide nodes {:.3f} ms, leaves "
               "{:.3f} ms\n",
               c.meshes.size() == 1 ? "" : " (summed over the meshes)", phases.references * 1e3, phases.tree * 1e3,
               phases.wide_nodes * 1e3, phases.leaves * 1e3);
    if (c.meshes.size() == 1) {
        print_stats("mesh BVH", canopy::compute_stats(c.meshes[0].accel));
    } else {
        fmt::print("mesh BVHs: {} BVHs, {} primitives, {} nodes, {:.1f} bytes/primitive\n", c.meshes.size(), mesh_prims,
                   mesh_nodes, mesh_bytes * per_triangle);
    }
    for (auto const& grp : c.groups) print_stats(fmt::format("group '{}' BVH", grp.name).c_str(), canopy::compute_stats(grp.accel));
    if (c.levels > 0) c.visit_root([](auto const& root) { print_stats("top-level BVH", canopy::compute_stats(root)); });
    return 0;
}

} // namespace cli
