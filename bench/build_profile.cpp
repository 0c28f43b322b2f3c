// build_profile — one scene's mesh BVH built alone, for profilers and for comparing trees:
// callgrind counts the builder's instructions (toggle on build_mesh), and the fingerprint tells
// whether two builds (two binaries, one and two threads) gave the same tree.
//
//   canopy_bench_build SCENE [--quick] [--quality automatic|fast|high] [--split-budget F]
//                      [--split-overlap F] [--split-node-overlap F] [--split-min-gain F] [--split-min-references N] [--parallel-threshold N] [--threads T]
//                      [--rounds R] [--embree]
//   SCENE  a name of canopy.bench_scenes (sphere, terrain, soup, forest, engine, bunny, slivers);
//          the forest builds its tree's mesh
//   --embree  builds the same mesh with Embree 3 instead (one triangle geometry, committed in
//             build_embree: fast and automatic → RTC_BUILD_QUALITY_MEDIUM, high → HIGH), so that
//             callgrind counts both builders the same way (toggle on build_embree); Embree picks
//             its kernels by the CPU valgrind reports.
//
// Builds R times (default 1) with T worker threads (default: all cores) and prints the tree's
// triangles, references, nodes, depth, SAH cost, a 64-bit fingerprint of its structure (fingerprint),
// and the build time of each round (wall clock: meaningless on a busy machine).
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <stdexcept>
#include <span>
#include <string>
#include <thread>
#include <vector>
#include <tbb/global_control.h>
#include "embree_support.hpp"
import canopy.bench_tracing;

namespace {

[[gnu::noinline]] canopy::bvh<canopy::triangle> build_mesh(std::vector<canopy::triangle> const& mesh,
                                                            canopy::bvh_build_options const& options) {
    return canopy::build_binned_sah(std::span<canopy::triangle const>(mesh), options);
}

// The mesh as an Embree scene, built (rtcCommitScene) at `quality`; the caller releases it.
[[gnu::noinline]] RTCScene build_embree(RTCDevice device, std::vector<canopy::triangle> const& mesh,
                                        RTCBuildQuality quality) {
    RTCScene scene = rtcNewScene(device);
    RTCGeometry geom = canopy_bench::embree_triangles(device, mesh);
    rtcSetSceneBuildQuality(scene, quality);
    rtcSetGeometryBuildQuality(geom, quality);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);
    return scene;
}

// FNV-1a over the wide tree in depth-first order: each slot's box and primitive count, each
// leaf's primitive ids (not the nodes' positions in the array, which depend on thread scheduling).
std::uint64_t fingerprint(canopy::bvh<canopy::triangle> const& b) {
    std::uint64_t h = 14695981039346656037ull;
    auto const mix = [&](void const* data, std::size_t size) {
        auto const* p = static_cast<unsigned char const*>(data);
        for (std::size_t i = 0; i < size; ++i) h = (h ^ p[i]) * 1099511628211ull;
    };
    if (b.empty()) return h;
    std::vector<std::uint32_t> stack{0};
    while (!stack.empty()) {
        auto const& w = b.wide_nodes[stack.back()];
        stack.pop_back();
        for (int k = canopy::bvh_width; k-- > 0;) {
            if (!w.used(k)) continue;
            auto const slot = std::size_t(k);
            auto const box = w.child_bounds(k);
            mix(&box, sizeof box);
            mix(&w.count[slot], sizeof w.count[slot]);
            if (w.count[slot] != 0) {
                canopy::for_each_leaf_primitive(b, w.child[slot], w.count[slot], [&](canopy::triangle const& t) {
                    mix(&t.prim_id, sizeof t.prim_id);
                });
            } else {
                stack.push_back(w.child[slot]);
            }
        }
    }
    return h;
}

int usage(char const* program) {
    std::fprintf(stderr,
                 "usage: %s SCENE [--quick] [--quality automatic|fast|high] [--split-budget F] [--threads T] "
                 "[--rounds R] [--split-overlap F] [--split-node-overlap F] [--split-min-gain F] [--split-min-references N] [--parallel-threshold N] [--embree]\n",
                 program);
    return 2;
}

} // namespace

int main(int argc, char** argv) {
    using namespace canopy::bench;
    if (argc < 2) return usage(argv[0]);
    std::string const scene_name = argv[1];
    bool quick = false, embree = false;
    int rounds = 1;
    std::size_t threads = std::thread::hardware_concurrency();
    canopy::bvh_build_options options;
    for (int i = 2; i < argc; ++i) {
        std::string const a = argv[i];
        if (a == "--quick") quick = true;
        else if (a == "--quality" && i + 1 < argc) {
            if (!parse_quality(argv[++i], options.quality)) return usage(argv[0]);
        } else if (a == "--split-budget" && i + 1 < argc) options.split_budget = float(std::atof(argv[++i]));
        else if (a == "--split-overlap" && i + 1 < argc) options.split_overlap = float(std::atof(argv[++i]));
        else if (a == "--parallel-threshold" && i + 1 < argc)
            options.parallel_threshold = std::size_t(std::max(1L, std::atol(argv[++i])));
        else if (a == "--split-node-overlap" && i + 1 < argc)
            options.split_node_overlap = float(std::atof(argv[++i]));
        else if (a == "--split-min-gain" && i + 1 < argc)
            options.split_min_gain = float(std::atof(argv[++i]));
        else if (a == "--split-min-references" && i + 1 < argc)
            options.split_min_references = std::uint32_t(std::clamp(std::atol(argv[++i]), 0L, long(UINT32_MAX)));
        else if (a == "--embree") embree = true;
        else if (a == "--threads" && i + 1 < argc) threads = std::size_t(std::max(1, std::atoi(argv[++i])));
        else if (a == "--rounds" && i + 1 < argc) rounds = std::max(1, std::atoi(argv[++i]));
        else return usage(argv[0]);
    }
    std::optional<canopy::bench::bench_scene> made;
    try {
        made = make_bench_scene(scene_name, quick);
    } catch (std::invalid_argument const& e) { // an unknown scene name
        std::fprintf(stderr, "%s\n", e.what());
        return usage(argv[0]);
    }
    auto const& scene = *made;
    if (!scene.skipped.empty()) {
        std::fprintf(stderr, "%s: %s\n", scene_name.c_str(), scene.skipped.c_str());
        return 1;
    }
    if (embree) {
        std::string const config = "threads=" + std::to_string(threads);
        RTCDevice device = rtcNewDevice(config.c_str());
        if (!device) {
            std::fprintf(stderr, "Embree: no device (%s)\n", config.c_str());
            return 1;
        }
        bool const high = options.quality == canopy::build_quality::high;
        for (int r = 0; r < rounds; ++r) {
            auto const start = std::chrono::steady_clock::now();
            RTCScene built = build_embree(device, scene.mesh, high ? RTC_BUILD_QUALITY_HIGH : RTC_BUILD_QUALITY_MEDIUM);
            double const ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
            std::printf("%s (Embree %s, %zu threads): %zu triangles, %.1f ms (geometry set-up and build)\n",
                        scene_name.c_str(), high ? "HIGH" : "MEDIUM", threads, scene.mesh.size(), ms);
            rtcReleaseScene(built);
        }
        rtcReleaseDevice(device);
        return 0;
    }
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    for (int r = 0; r < rounds; ++r) {
        auto const start = std::chrono::steady_clock::now();
        auto const built = build_mesh(scene.mesh, options);
        double const ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        auto const st = canopy::compute_stats(built);
        std::size_t const references = st.reference_count;
        std::printf("%s (%s, %zu threads): %zu triangles, %zu references, %zu nodes, depth %d, SAH %.4f, "
                    "fingerprint %016llx, %.1f ms (references %.1f, tree %.1f, wide nodes %.1f, leaves %.1f)\n",
                    scene_name.c_str(), built.quality == canopy::build_quality::high ? "high" : "fast", threads,
                    st.primitive_count, references, st.node_count, st.depth, st.sah_cost,
                    static_cast<unsigned long long>(fingerprint(built)), ms, built.build_phases.references * 1e3,
                    built.build_phases.tree * 1e3, built.build_phases.wide_nodes * 1e3, built.build_phases.leaves * 1e3);
    }
    return 0;
}
