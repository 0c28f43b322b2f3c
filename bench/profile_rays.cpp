// profile_rays — one scene, one ray set, one query, traced in one function, for profilers:
// callgrind counts instructions per ray (--toggle-collect on trace_rays, docs/performance.md), perf
// samples where the time goes.
//
//   canopy_bench_profile SCENE RAYS QUERY [--quick] [--from I] [--count N] [--alpha | --alpha-hook] [--passes P]
//                        [--quality automatic|fast|high] [--split-budget F] [--split-min-references N]
//                        [--bins B] [--max-leaf L] [--batch [--packets-always]] [--compare-packing] [--tiles]
//   SCENE  a name of canopy.bench_scenes (sphere, terrain, soup, forest, engine, bunny, slivers)
//   RAYS   primary | random | shadow | vertices | inside (canopy.bench_tracing)        QUERY  closest | any
//
// Traces N rays of the set from its I-th (default: all, from the first) P times (default 1) inside trace_rays, the
// only function a profiler needs to look at, then prints the ray count, hits, nanoseconds per ray
// (the fastest pass) and, from an untimed pass with a counting intersector, box and triangle
// tests per ray. The mesh BVH is built at --quality (default fast; high: spatial splits, with
// --split-budget, default 0.3, in nodes of at least --split-min-references, default 16), with B SAH bins per axis and leaves of at most L primitives (the
// defaults of bvh_build_options unless given); its statistics line gives the references its leaves hold, its SAH
// cost and its build time. --batch traces the set through the batch queries (canopy.query:batch,
// packets of 8 coherent rays) instead, and prints how many packets and single rays they traced, with
// the tests per packet (one box or triangle test for its 8 lanes) and per single ray, and the
// packets' occupancy (canopy.bvh:traverse, packet_occupancy) on which the adaptive policy decides;
// --packets-always makes every coherent group a packet (batch_packing::always). --compare-packing
// first times single rays, the batch with packets always and the adaptive batch in turn, P rounds,
// and prints the medians. --tiles orders the camera's pixels in tiles of 4 × 4 instead of row by
// row (the primary and shadow sets; canopy.bench_tracing, pixel_order).
#include <algorithm>
#include <chrono>
#include <span>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>
import canopy.bench_tracing;

namespace {

using namespace canopy::bench;

// Both ways write every ray's hit record into `out`, allocated once by the caller: a batch query
// must write its results, and a fresh 10 MB buffer per pass would time page faults.
template <typename Isect>
[[gnu::noinline]] std::size_t trace_rays(canopy_scene const& s, std::vector<canopy::ray> const& rays, bool closest,
                                         Isect& isect, std::vector<canopy::basic_hit_record<float>>& out) {
    std::size_t hits = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
        out[i] = canopy_trace_record(s, rays[i], closest, isect);
        hits += out[i].hit;
    }
    return hits;
}

template <typename Isect>
[[gnu::noinline]] std::size_t trace_batch(canopy_scene const& s, std::vector<canopy::ray> const& rays, bool closest,
                                          Isect& isect, std::vector<canopy::basic_hit_record<float>>& out,
                                          canopy::batch_packing packing) {
    canopy_trace_batch(s, rays, closest, isect, out, packing);
    return std::size_t(std::count_if(out.begin(), out.end(), [](auto const& hr) { return bool(hr.hit); }));
}

int usage(char const* program) {
    std::fprintf(stderr, "usage: %s SCENE primary|random|shadow|vertices|inside closest|any [--quick] [--from I] [--count N] [--alpha | --alpha-hook] [--passes P] [--quality automatic|fast|high] [--split-budget F] [--split-min-references N] [--bins B] [--max-leaf L] [--batch [--packets-always]] [--compare-packing] [--tiles]\n",
                 program);
    return 2;
}

template <typename Isect>
int run(canopy_scene const& s, std::vector<canopy::ray> const& rays, bool closest, int passes, bool batch,
        canopy::batch_packing packing, bool compare_modes) {
    Isect isect;
    std::size_t hits = 0;
    double seconds = 1e30;
    std::vector<canopy::basic_hit_record<float>> records(rays.size());
    if (compare_modes) {
        // Single rays, batch with every coherent group a packet, batch adaptive: one pass of each in
        // turn, medians over the rounds.
        std::vector<double> times[3];
        for (int p = 0; p < passes; ++p) {
            for (int mode = 0; mode < 3; ++mode) {
                auto const start = std::chrono::steady_clock::now();
                if (mode == 0) trace_rays(s, rays, closest, isect, records);
                else trace_batch(s, rays, closest, isect, records,
                                 mode == 1 ? canopy::batch_packing::always : canopy::batch_packing::adaptive);
                times[mode].push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
            }
        }
        double median[3];
        for (int mode = 0; mode < 3; ++mode) {
            std::sort(times[mode].begin(), times[mode].end());
            median[mode] = times[mode][times[mode].size() / 2] * 1e9 / double(rays.size());
        }
        std::printf("medians of %d rounds, ns/ray: single %.1f, batch always %.1f, batch adaptive %.1f; "
                    "single/always %.3f, single/adaptive %.3f\n",
                    passes, median[0], median[1], median[2], median[0] / median[1], median[0] / median[2]);
    }
    for (int p = 0; p < passes; ++p) {
        auto const start = std::chrono::steady_clock::now();
        hits = batch ? trace_batch(s, rays, closest, isect, records, packing) : trace_rays(s, rays, closest, isect, records);
        seconds = std::min(seconds, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    }
    counting_intersector<Isect> counter;
    for (auto const& r : rays) canopy_trace(s, r, closest, counter);
    double const n = double(rays.size());
    std::printf("rays %zu, hits %zu, %.1f ns/ray, %.2f box tests/ray, %.2f triangle tests/ray\n", rays.size(), hits,
                seconds * 1e9 / n, double(counter.boxes) / n, double(counter.triangles) / n);
    if (batch) {
        // Packets of 8 and of 16 rays (squares of 4 × 4, where 16-lane vectors are native).
        auto const all_packets = [](canopy::batch_stats const& b) { return b.packets + b.wide_packets; };
        canopy::detail::packet_occupancy_tally = {};
        auto const traced = canopy_trace_batch(s, rays, closest, isect, records, packing);
        auto const o = canopy::detail::packet_occupancy_tally;
        auto const per = [](std::uint64_t a, std::uint64_t b) { return double(a) / double(std::max<std::uint64_t>(1, b)); };
        std::printf("packet occupancy: %.2f node visits and %.2f leaf visits per packet, %.2f lanes per node visit, "
                    "%.2f per leaf visit, %.2f lanes alone per packet; %zu packets, %zu rays of coherent groups "
                    "traced one by one\n",
                    per(o.node_visits, all_packets(traced)), per(o.leaf_visits, all_packets(traced)),
                    per(o.node_lanes, o.node_visits), per(o.leaf_lanes, o.leaf_visits),
                    per(o.lanes_alone, all_packets(traced)), all_packets(traced), traced.unpacked_rays);
        counting_intersector<Isect> packed;
        std::vector<canopy::basic_hit_record<float>> out(rays.size());
        auto const stats = canopy_trace_batch(s, rays, closest, packed, out, packing);
        double const p = double(all_packets(stats));
        std::printf("batch: %zu packets of 8, %zu packets of 16, %zu single rays (rows of %zu rays; 0: none found); "
                    "per packet %.2f box tests, %.2f triangle tests; per single ray %.2f box tests, %.2f triangle tests\n",
                    stats.packets, stats.wide_packets, stats.single_rays, stats.row_length, p > 0 ? double(packed.packet_boxes) / p : 0.0,
                    p > 0 ? double(packed.packet_triangles) / p : 0.0,
                    stats.single_rays > 0 ? double(packed.boxes) / double(stats.single_rays) : 0.0,
                    stats.single_rays > 0 ? double(packed.triangles) / double(stats.single_rays) : 0.0);
    }
    return 0;
}

} // namespace

int main(int argc, char** argv) {
    if (argc < 4) return usage(argv[0]);
    std::string const scene_name = argv[1], set_name = argv[2], query = argv[3];
    bool quick = false, alpha = false, alpha_hook = false, batch = false, compare_modes = false;
    std::size_t count = 0, from = 0;
    int passes = 1;
    auto order = canopy::bench::pixel_order::rows;
    canopy::batch_packing packing = canopy::batch_packing::adaptive;
    canopy::bvh_build_options options;
    for (int i = 4; i < argc; ++i) {
        std::string const a = argv[i];
        if (a == "--quick") quick = true;
        else if (a == "--alpha") alpha = true;
        else if (a == "--alpha-hook") alpha_hook = true;
        else if (a == "--batch") batch = true;
        else if (a == "--packets-always") packing = canopy::batch_packing::always;
        else if (a == "--compare-packing") compare_modes = true;
        else if (a == "--tiles") order = canopy::bench::pixel_order::tiles;
        else if (a == "--count" && i + 1 < argc) count = std::size_t(std::atoll(argv[++i]));
        else if (a == "--from" && i + 1 < argc) from = std::size_t(std::atoll(argv[++i]));
        else if (a == "--passes" && i + 1 < argc) passes = std::max(1, std::atoi(argv[++i]));
        else if (a == "--quality" && i + 1 < argc) {
            if (!parse_quality(argv[++i], options.quality)) return usage(argv[0]);
        } else if (a == "--bins" && i + 1 < argc) {
            options.bins = std::atoi(argv[++i]);
        } else if (a == "--max-leaf" && i + 1 < argc) {
            options.max_leaf_size = std::atoi(argv[++i]);
        } else if (a == "--split-budget" && i + 1 < argc) {
            options.split_budget = float(std::atof(argv[++i]));
        } else if (a == "--split-min-references" && i + 1 < argc) {
            options.split_min_references = std::uint32_t(std::atol(argv[++i]));
        }
        else return usage(argv[0]);
    }
    if (query != "closest" && query != "any") return usage(argv[0]);
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
    std::printf("sliver box share %.3f (build_quality::automatic builds high from 0.05)\n",
                canopy::sliver_box_share(std::span<canopy::triangle const>(scene.mesh)));
    auto const build_start = std::chrono::steady_clock::now();
    auto const s = build_canopy(scene, options);
    double const build_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - build_start).count();
    canopy::bvh<canopy::triangle> const& mesh = s->scene.meshes[0].accel;
    auto const st = canopy::compute_stats(mesh);
    std::size_t const references = st.reference_count;
    std::printf("mesh BVH (%s): %zu triangles, %zu references, %zu leaves (%.2f references each), %zu wide nodes, "
                "%zu blocks, depth %d, SAH %.2f, %.1f bytes/triangle, compiled in %.0f ms\n",
                mesh.quality == canopy::build_quality::high ? "high" : "fast", st.primitive_count, references,
                st.leaf_count, double(references) / double(st.leaf_count), st.wide_node_count,
                mesh.blocks.size(), st.depth, st.sah_cost, st.bytes_per_primitive, build_ms);
    auto sets = make_rays(*s, scene, order);
    for (auto& set : sets) {
        if (set.name != set_name) continue;
        // --from I: the set from its I-th ray (e.g. the middle rows of the camera, where primary rays
        // hit: the first rows often miss the scene), then --count N of them.
        set.rays.erase(set.rays.begin(), set.rays.begin() + std::ptrdiff_t(std::min(from, set.rays.size())));
        if (count != 0 && count < set.rays.size()) set.rays.resize(count);
        bool const closest = query == "closest";
        if (alpha) return run<canopy::bench_alpha_intersector>(*s, set.rays, closest, passes, batch, packing, compare_modes);
        if (alpha_hook) return run<canopy::bench_alpha_hook_intersector>(*s, set.rays, closest, passes, batch, packing, compare_modes);
        return run<canopy::default_intersector>(*s, set.rays, closest, passes, batch, packing, compare_modes);
    }
    return usage(argv[0]);
}
