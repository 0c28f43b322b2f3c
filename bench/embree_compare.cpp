// embree_compare — Canopy and Embree 3 side by side: the same scenes, the same rays, one run.
//
//   canopy_bench_embree [--scenes sphere,terrain,soup,forest,engine,bunny,slivers]
//                       [--scene FILE.obj|FILE.inst] [--quick] [--rounds N] [--threads-list 1,2]
//                       [--rays primary,random,shadow,vertices,inside] [--quality automatic|fast|high] [--coherent]
//                       [--tiles]
//
// Scenes (canopy.bench_scenes, bench/bench_scenes.cppm): a 1.3M-triangle icosphere, a 2M-triangle
// terrain, a 500k triangle soup, a forest of 10,000 instances of a 51k-triangle tree, two real
// models (the glTF engine of assimp's examples, glmark2's bunny; skipped with a note when the
// file is missing) and a scene of thin triangles. --scenes picks some; --quick shrinks every
// generated scene about 16× for smoke tests; --scene traces one file of the bench formats instead,
// loaded by the bench plugin and compiled as `canopy trace` compiles it.
//
// Rays per scene: primary (a 512 × 512 pinhole camera), random (origins in the scene's box,
// random directions) and shadow (from the primary hits toward a light; any hit only); on request
// (--rays), vertices (16,384 rays through mesh vertices, where fans of slivers meet) and inside
// (from inside the slivers' closed spindle and cylinder). Each set is
// traced closest hit and any hit, with every Canopy intersector of `intersector_variants` below:
// none, and the alpha rule of the bench formats (Embree: an intersection filter function).
//
// Canopy traces each scene as compile() lays it out (canopy.bench_tracing: the bench plugin's
// scene graph, one mesh BVH or a top level over its instances).
//
// Timing: for each scene, thread count, ray set, query and intersector, --rounds interleaved
// rounds (default 5); a round times Canopy then Embree over the whole ray set (the order swapped
// every other round) with tbb::parallel_for under tbb::global_control(threads). Reported: the
// median and the best Mrays/s of each library and the ratios Canopy / Embree of the medians (the
// main figure) and of the bests. Build time is measured the same way (ratio > 1: Canopy slower;
// Canopy: its BVHs rebuilt in the compiled scene, Embree: its scenes from the same triangles);
// memory per stored triangle: canopy::compute_stats(bvh).bytes summed over the BVHs against
// Embree's device memory monitor.
//
// Work counts (untimed, one thread, once per scene, ray set, query and intersector): Canopy's
// ray/box and ray/triangle tests per ray, through a counting intersector. Agreement: the rays
// whose hit/miss differs between the libraries, and for closest hits the rays both hit whose
// (instance, primitive) differs (informational: ties and near-ties may go either way).
//
// --coherent adds, for each ray set and query with no intersector, Canopy's batch queries
// (canopy.query:batch: coherent groups of 8 rays as packets) against Embree's coherent modes:
// packets of 8 (rtcIntersect8 / rtcOccluded8), packets of 16, and streams (rtcIntersect1M /
// rtcOccluded1M over each range, RTC_INTERSECT_CONTEXT_FLAG_COHERENT). Each library sees the
// rays in the same order, in ranges of whole groups of 16. The row's Embree figure is its best
// mode (by median), named in the row with the other two; the row also gives Canopy's batch against
// its own single rays, timed in the same rounds.
//
// --tiles orders the primary rays (and so the shadow rays made from them) in tiles of 4 × 4 pixels
// instead of row by row (canopy.bench_tracing, pixel_order): 8 consecutive rays then cover 4 × 2
// pixels, 16 cover 4 × 4. Both libraries see the same order.
//
// --quality high builds Canopy's meshes with spatial splits (build_quality::high) and Embree's
// scenes and triangle geometries with RTC_BUILD_QUALITY_HIGH (its split BVH); the default,
// automatic (the library's default: spatial splits only where sliver_box_share says they pay),
// and fast run against Embree's default (medium) quality.
//
// Output: Markdown, one table per scene.
#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <functional>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <string_view>
#include <tuple>
#include <utility>
#include <vector>
#include <embree3/rtcore.h>
#include "embree_support.hpp"
#include <fmt/core.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
import canopy.bench_tracing;
import canopy.plugins.bench;

namespace {

using canopy::bench::bench_scene;
using canopy::bench::build_canopy;
using canopy::bench::canopy_scene;
using canopy::bench::canopy_trace;
using canopy::bench::canopy_trace_batch;
using canopy::bench::counting_intersector;
using canopy::bench::make_rays;
using canopy::bench::ray_set;
using clock_type = std::chrono::steady_clock;

double seconds_since(clock_type::time_point t) { return std::chrono::duration<double>(clock_type::now() - t).count(); }

// ---- the intersectors compared --------------------------------------------------------------

// A Canopy intersector measured against Embree: the suffix of its figures' names, and whether it
// applies the alpha rule (Embree then runs with the alpha filter function).
template <typename Isect>
struct intersector_variant {
    using type = Isect;
    char const* suffix;
    bool alpha_rule;
};

// Every variant is measured on every ray set and query. Another Canopy intersector for the alpha
// rule is one more line here.
constexpr auto intersector_variants = std::tuple{
    intersector_variant<canopy::default_intersector>{"", false},
    intersector_variant<canopy::bench_alpha_intersector>{" + alpha", true},
    intersector_variant<canopy::bench_alpha_hook_intersector>{" + alpha (triangle hook)", true},
};

// ---- Embree -------------------------------------------------------------------------------

std::atomic<long long> embree_bytes{0};

bool memory_monitor(void*, ssize_t bytes, bool) {
    embree_bytes += bytes;
    return true;
}

void alpha_filter(RTCFilterFunctionNArguments const* args) {
    for (unsigned i = 0; i < args->N; ++i) {
        if (args->valid[i] == 0) continue;
        float const u = RTCHitN_u(args->hit, args->N, i);
        float const v = RTCHitN_v(args->hit, args->N, i);
        if (canopy::bench_alpha_intersector::rejects(u, v)) args->valid[i] = 0;
    }
}

struct embree_scene {
    RTCScene mesh = nullptr;
    RTCScene top = nullptr;
    bool instanced = false;
    embree_scene() = default;
    embree_scene(embree_scene const&) = delete;
    embree_scene& operator=(embree_scene const&) = delete;
    ~embree_scene() {
        if (top) rtcReleaseScene(top);
        if (mesh) rtcReleaseScene(mesh);
    }
    RTCScene root() const { return instanced ? top : mesh; }
};

// The mesh as an unindexed triangle geometry (canopy_bench::embree_triangles), committed, with the
// alpha rule as its filter when asked.
RTCGeometry embree_triangles(RTCDevice device, std::vector<canopy::triangle> const& mesh, bool alpha) {
    RTCGeometry geom = canopy_bench::embree_triangles(device, mesh);
    if (alpha) {
        rtcSetGeometryIntersectFilterFunction(geom, alpha_filter);
        rtcSetGeometryOccludedFilterFunction(geom, alpha_filter);
    }
    rtcCommitGeometry(geom);
    return geom;
}

RTCGeometry embree_instance(RTCDevice device, RTCScene mesh, canopy::affine_transform<float> const& m) {
    RTCGeometry inst = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(inst, mesh);
    // Embree's FLOAT3X4_ROW_MAJOR: three rows of (linear | translation).
    float const rows[12] = {m.linear.col0.x, m.linear.col1.x, m.linear.col2.x, m.translation.x,
                            m.linear.col0.y, m.linear.col1.y, m.linear.col2.y, m.translation.y,
                            m.linear.col0.z, m.linear.col1.z, m.linear.col2.z, m.translation.z};
    rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, rows);
    rtcCommitGeometry(inst);
    return inst;
}

std::unique_ptr<embree_scene> build_embree(RTCDevice device, bench_scene const& in, bool alpha,
                                           canopy::build_quality quality) {
    auto s = std::make_unique<embree_scene>();
    s->mesh = rtcNewScene(device);
    RTCGeometry geom = embree_triangles(device, in.mesh, alpha);
    if (quality == canopy::build_quality::high) {
        rtcSetSceneBuildQuality(s->mesh, RTC_BUILD_QUALITY_HIGH);
        rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_HIGH);
        rtcCommitGeometry(geom); // a changed geometry counts only once committed again
    }
    rtcAttachGeometry(s->mesh, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(s->mesh);
    if (!in.instances.empty()) {
        s->instanced = true;
        s->top = rtcNewScene(device);
        // Instance k is attached k-th: its geometry id is k, as Canopy's inst_id.
        for (auto const& m : in.instances) {
            RTCGeometry inst = embree_instance(device, s->mesh, m);
            rtcAttachGeometry(s->top, inst);
            rtcReleaseGeometry(inst);
        }
        rtcCommitScene(s->top);
    }
    return s;
}

canopy::bench_hit embree_trace(embree_scene const& s, canopy::ray const& r, bool closest) {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    if (closest) {
        RTCRayHit rh = canopy_bench::embree_ray_hit(r);
        rtcIntersect1(s.root(), &context, &rh);
        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return {};
        return {rh.ray.tfar, rh.hit.primID, s.instanced ? rh.hit.instID[0] : canopy::invalid_id, rh.hit.u, rh.hit.v};
    }
    RTCRay ray = canopy_bench::embree_ray(r);
    rtcOccluded1(s.root(), &context, &ray);
    if (ray.tfar != -std::numeric_limits<float>::infinity()) return {};
    return {0.0f, canopy::occluded_unreported, canopy::invalid_id, 0.0f, 0.0f};
}

// ---- coherent rays: Embree's packets and streams, Canopy's batch queries ------------------------

canopy::bench_hit embree_result(bool closest, bool hit, float t, unsigned prim, unsigned inst, float u, float v,
                                bool instanced) {
    if (!hit) return {};
    if (!closest) return {0.0f, canopy::occluded_unreported, canopy::invalid_id, 0.0f, 0.0f};
    return {t, prim, instanced ? inst : canopy::invalid_id, u, v};
}

// Rays [0, rays.size()) in packets of N (the last one with invalid lanes past the end).
template <int N>
void embree_trace_packets(embree_scene const& s, std::span<canopy::ray const> rays, bool closest,
                          canopy::bench_hit* out) {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    for (std::size_t first = 0; first < rays.size(); first += N) {
        std::size_t const count = std::min<std::size_t>(N, rays.size() - first);
        alignas(64) int valid[N];
        alignas(64) RTCRayHitNt<N> rh{};
        for (std::size_t k = 0; k < std::size_t(N); ++k) {
            valid[k] = k < count ? -1 : 0;
            RTCRay const r = canopy_bench::embree_ray(rays[first + std::min(k, count - 1)]);
            rh.ray.org_x[k] = r.org_x, rh.ray.org_y[k] = r.org_y, rh.ray.org_z[k] = r.org_z;
            rh.ray.dir_x[k] = r.dir_x, rh.ray.dir_y[k] = r.dir_y, rh.ray.dir_z[k] = r.dir_z;
            rh.ray.tnear[k] = r.tnear, rh.ray.tfar[k] = r.tfar, rh.ray.mask[k] = r.mask;
            rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
        }
        if constexpr (N == 8) {
            if (closest) rtcIntersect8(valid, s.root(), &context, reinterpret_cast<RTCRayHit8*>(&rh));
            else rtcOccluded8(valid, s.root(), &context, reinterpret_cast<RTCRay8*>(&rh.ray));
        } else {
            static_assert(N == 16);
            if (closest) rtcIntersect16(valid, s.root(), &context, reinterpret_cast<RTCRayHit16*>(&rh));
            else rtcOccluded16(valid, s.root(), &context, reinterpret_cast<RTCRay16*>(&rh.ray));
        }
        for (std::size_t k = 0; k < count; ++k) {
            bool const hit = closest ? rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID
                                     : rh.ray.tfar[k] == -std::numeric_limits<float>::infinity();
            out[first + k] = embree_result(closest, hit, rh.ray.tfar[k], rh.hit.primID[k], rh.hit.instID[0][k],
                                           rh.hit.u[k], rh.hit.v[k], s.instanced);
        }
    }
}

// Rays [0, rays.size()) as one stream.
void embree_trace_stream(embree_scene const& s, std::span<canopy::ray const> rays, bool closest,
                         canopy::bench_hit* out) {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    auto const m = unsigned(rays.size());
    if (closest) {
        thread_local std::vector<RTCRayHit> rh;
        rh.resize(rays.size());
        for (std::size_t i = 0; i < rays.size(); ++i) rh[i] = canopy_bench::embree_ray_hit(rays[i]);
        rtcIntersect1M(s.root(), &context, rh.data(), m, sizeof(RTCRayHit));
        for (std::size_t i = 0; i < rays.size(); ++i)
            out[i] = embree_result(true, rh[i].hit.geomID != RTC_INVALID_GEOMETRY_ID, rh[i].ray.tfar, rh[i].hit.primID,
                                   rh[i].hit.instID[0], rh[i].hit.u, rh[i].hit.v, s.instanced);
    } else {
        thread_local std::vector<RTCRay> r;
        r.resize(rays.size());
        for (std::size_t i = 0; i < rays.size(); ++i) r[i] = canopy_bench::embree_ray(rays[i]);
        rtcOccluded1M(s.root(), &context, r.data(), m, sizeof(RTCRay));
        for (std::size_t i = 0; i < rays.size(); ++i)
            out[i] = embree_result(false, r[i].tfar == -std::numeric_limits<float>::infinity(), 0.0f, 0, 0, 0.0f,
                                   0.0f, s.instanced);
    }
}

// Canopy's batch query over rays [0, rays.size()), results as the single-ray figures report them.
void canopy_trace_coherent(canopy_scene const& s, std::span<canopy::ray const> rays, bool closest,
                           std::vector<canopy::basic_hit_record<float>>& records, canopy::bench_hit* out) {
    canopy::default_intersector isect;
    records.resize(rays.size());
    canopy_trace_batch(s, rays, closest, isect, std::span(records.data(), rays.size()));
    for (std::size_t i = 0; i < rays.size(); ++i) {
        auto const& hr = records[i];
        out[i] = hr.hit ? canopy::bench_hit{hr.t, hr.prim_id, hr.inst_id, hr.u, hr.v} : canopy::bench_hit{};
    }
}

// ---- measuring ----------------------------------------------------------------------------

// One pass of trace_range(lo, hi) over n rays on the threads allowed; returns Mrays/s.
template <typename F>
double trace_rate(std::size_t n, F const& trace_range) {
    auto const start = clock_type::now();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024),
                      [&](auto const& r) { trace_range(r.begin(), r.end()); });
    return double(n) / seconds_since(start) * 1e-6;
}

// The same over whole groups of 16 rays: trace_group(first, last) gets ranges that start at a
// multiple of 16, so that batch queries and packets see the same groups at any thread count.
template <typename F>
double trace_rate_grouped(std::size_t n, F const& trace_group) {
    constexpr std::size_t group = 16;
    std::size_t const groups = (n + group - 1) / group;
    auto const start = clock_type::now();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, groups, 64), [&](auto const& r) {
        trace_group(r.begin() * group, std::min(r.end() * group, n));
    });
    return double(n) / seconds_since(start) * 1e-6;
}

struct samples {
    std::vector<double> canopy, embree;
};

// `rounds` rounds of one Canopy and one Embree measurement; every other round Embree goes first,
// so that neither always runs on the warmer caches (or the cooler CPU).
template <typename C, typename E>
samples interleaved_rounds(int rounds, C&& canopy_once, E&& embree_once) {
    samples s;
    for (int k = 0; k < rounds; ++k) {
        if (k % 2 == 0) {
            s.canopy.push_back(canopy_once());
            s.embree.push_back(embree_once());
        } else {
            s.embree.push_back(embree_once());
            s.canopy.push_back(canopy_once());
        }
    }
    return s;
}

struct summary {
    double median = 0.0;
    double best = 0.0;
};

// Best: the largest value (rates) or the smallest (times).
summary summarize(std::vector<double> v, bool larger_is_better) {
    std::sort(v.begin(), v.end());
    std::size_t const n = v.size();
    double const median = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
    return {median, larger_is_better ? v.back() : v.front()};
}

struct work_counts {
    double boxes_per_ray = 0.0;
    double triangles_per_ray = 0.0;
};

template <typename Isect>
work_counts count_work(canopy_scene const& s, std::vector<canopy::ray> const& rays, bool closest) {
    counting_intersector<Isect> counter;
    for (auto const& r : rays) canopy_trace(s, r, closest, counter);
    double const n = double(std::max<std::size_t>(rays.size(), 1));
    return {double(counter.boxes) / n, double(counter.triangles) / n};
}

// "hit/miss" differences, and for closest hits also "/ (instance, prim)" differences.
std::string disagreements(std::vector<canopy::bench_hit> const& a, std::vector<canopy::bench_hit> const& b,
                          bool closest) {
    std::size_t hit_miss = 0, which = 0;
    for (std::size_t i = 0; i < a.size(); ++i) {
        bool const ha = a[i].prim != canopy::invalid_id, hb = b[i].prim != canopy::invalid_id;
        hit_miss += ha != hb;
        which += closest && ha && hb && (a[i].prim != b[i].prim || a[i].inst != b[i].inst);
    }
    return closest ? fmt::format("{} / {}", hit_miss, which) : fmt::format("{}", hit_miss);
}

// ---- the table ------------------------------------------------------------------------------

void print_table_header() {
    fmt::print("| threads | figure | Canopy median | Embree median | Canopy/Embree (medians) | Canopy best | "
               "Embree best | Canopy/Embree (bests) | box tests/ray | triangle tests/ray | disagreements |\n");
    fmt::print("|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n");
}

struct row_extras {
    std::string boxes = "–";
    std::string triangles = "–";
    std::string disagreements = "–";
};

void print_row(std::string_view threads, std::string_view figure, summary c, summary e, int precision,
               row_extras const& x = {}) {
    fmt::print("| {} | {} | {:.{}f} | {:.{}f} | **{:.2f}** | {:.{}f} | {:.{}f} | {:.2f} | {} | {} | {} |\n", threads,
               figure, c.median, precision, e.median, precision, c.median / e.median, c.best, precision, e.best,
               precision, c.best / e.best, x.boxes, x.triangles, x.disagreements);
    std::fflush(stdout);
}

// ---- one scene ------------------------------------------------------------------------------

struct settings {
    std::vector<std::string> scenes = canopy::bench::bench_scene_names();
    std::string scene_file;
    std::vector<int> threads{1, 2};
    int rounds = 5;
    bool quick = false;
    bool coherent = false;
    canopy::bench::pixel_order order = canopy::bench::pixel_order::rows;
    std::vector<std::string> ray_sets{"primary", "random", "shadow"};
    canopy::build_quality quality = canopy::build_quality::automatic; // the library's default
};

// What the figures of one thread count trace.
struct traced_scene {
    int threads;
    int rounds;
    canopy_scene const& canopy;
    embree_scene const& embree_plain;
    embree_scene const& embree_alpha;
};

// Work counts per figure: the same at every thread count, so counted once.
using work_cache = std::map<std::string, work_counts>;

// Out of line, so that bench/callgrind_embree.sh can dump its counts figure by figure.
template <typename Variant>
[[gnu::noinline]] void measure_figure(traced_scene const& s, ray_set const& set, bool closest,
                                      Variant const& variant, work_cache& work) {
    using isect_type = typename Variant::type;
    std::string const figure = fmt::format("{} {}{}", set.name, closest ? "closest" : "any", variant.suffix);
    std::size_t const n = set.rays.size();
    std::vector<canopy::bench_hit> a(n), b(n);
    embree_scene const& e = variant.alpha_rule ? s.embree_alpha : s.embree_plain;
    auto const canopy_once = [&] {
        return trace_rate(n, [&](std::size_t lo, std::size_t hi) {
            isect_type isect;
            for (std::size_t i = lo; i < hi; ++i) a[i] = canopy_trace(s.canopy, set.rays[i], closest, isect);
        });
    };
    auto const embree_once = [&] {
        return trace_rate(n, [&](std::size_t lo, std::size_t hi) {
            for (std::size_t i = lo; i < hi; ++i) b[i] = embree_trace(e, set.rays[i], closest);
        });
    };
    samples const rates = interleaved_rounds(s.rounds, canopy_once, embree_once);
    auto [it, fresh] = work.try_emplace(figure);
    if (fresh) it->second = count_work<isect_type>(s.canopy, set.rays, closest);
    row_extras const x{fmt::format("{:.1f}", it->second.boxes_per_ray),
                       fmt::format("{:.2f}", it->second.triangles_per_ray), disagreements(a, b, closest)};
    print_row(fmt::format("{}", s.threads), figure + " (Mrays/s)", summarize(rates.canopy, true),
              summarize(rates.embree, true), 2, x);
}

// Rays whose results differ bit for bit (t, primitive, instance, u, v).
std::size_t differing(std::vector<canopy::bench_hit> const& a, std::vector<canopy::bench_hit> const& b) {
    std::size_t n = 0;
    for (std::size_t i = 0; i < a.size(); ++i)
        n += std::bit_cast<std::uint32_t>(a[i].t) != std::bit_cast<std::uint32_t>(b[i].t) || a[i].prim != b[i].prim ||
             a[i].inst != b[i].inst || std::bit_cast<std::uint32_t>(a[i].u) != std::bit_cast<std::uint32_t>(b[i].u) ||
             std::bit_cast<std::uint32_t>(a[i].v) != std::bit_cast<std::uint32_t>(b[i].v);
    return n;
}

// --coherent: Canopy's batch query against Embree's best coherent mode, no intersector (see the
// top of this file). Five measurements a round, their order reversed every other round.
void measure_coherent(traced_scene const& s, ray_set const& set, bool closest) {
    std::size_t const n = set.rays.size();
    std::span<canopy::ray const> const all(set.rays);
    std::array<std::vector<canopy::bench_hit>, 5> hits;
    for (auto& h : hits) h.resize(n);
    std::array<std::function<void(std::size_t, std::size_t)>, 5> const trace{
        [&](std::size_t lo, std::size_t hi) {
            thread_local std::vector<canopy::basic_hit_record<float>> records;
            canopy_trace_coherent(s.canopy, all.subspan(lo, hi - lo), closest, records, hits[0].data() + lo);
        },
        [&](std::size_t lo, std::size_t hi) {
            canopy::default_intersector isect;
            for (std::size_t i = lo; i < hi; ++i) hits[1][i] = canopy_trace(s.canopy, set.rays[i], closest, isect);
        },
        [&](std::size_t lo, std::size_t hi) {
            embree_trace_packets<8>(s.embree_plain, all.subspan(lo, hi - lo), closest, hits[2].data() + lo);
        },
        [&](std::size_t lo, std::size_t hi) {
            embree_trace_packets<16>(s.embree_plain, all.subspan(lo, hi - lo), closest, hits[3].data() + lo);
        },
        [&](std::size_t lo, std::size_t hi) {
            embree_trace_stream(s.embree_plain, all.subspan(lo, hi - lo), closest, hits[4].data() + lo);
        }};
    std::array<std::vector<double>, 5> rates;
    for (int round = 0; round < s.rounds; ++round)
        for (std::size_t j = 0; j < trace.size(); ++j) {
            std::size_t const k = round % 2 == 0 ? j : trace.size() - 1 - j;
            rates[k].push_back(trace_rate_grouped(n, trace[k]));
        }
    std::array<summary, 5> sums;
    for (std::size_t k = 0; k < sums.size(); ++k) sums[k] = summarize(rates[k], true);
    constexpr std::array<char const*, 3> modes{"packet8", "packet16", "stream"};
    std::size_t best = 2;
    for (std::size_t k = 3; k < 5; ++k)
        if (sums[k].median > sums[best].median) best = k;
    std::size_t const mismatched = differing(hits[0], hits[1]);
    std::string const figure = fmt::format(
        "{} {}, batch vs Embree {} (Mrays/s; Embree packet8 / packet16 / stream {:.2f} / {:.2f} / {:.2f}; Canopy "
        "single {:.2f}, batch / single {:.2f}{})",
        set.name, closest ? "closest" : "any", modes[best - 2], sums[2].median, sums[3].median, sums[4].median,
        sums[1].median, sums[0].median / sums[1].median,
        mismatched == 0 ? "" : fmt::format("; BATCH DIFFERS FROM SINGLE ON {} RAYS", mismatched));
    print_row(fmt::format("{}", s.threads), figure, sums[0], sums[best], 2,
              {"–", "–", disagreements(hits[0], hits[best], closest)});
}

void measure_rays(traced_scene const& s, std::vector<ray_set> const& sets, std::vector<std::string> const& wanted,
                  bool coherent, work_cache& work) {
    for (auto const& set : sets) {
        if (set.rays.empty() || std::find(wanted.begin(), wanted.end(), set.name) == wanted.end()) continue;
        for (bool closest : {true, false}) {
            if (set.shadow && closest) continue;
            std::apply([&](auto const&... variant) { (measure_figure(s, set, closest, variant, work), ...); },
                       intersector_variants);
            if (coherent) measure_coherent(s, set, closest);
        }
    }
}

std::string describe(bench_scene const& in) {
    if (in.instances.empty()) return fmt::format("{}, {} triangles", in.description, in.mesh.size());
    return fmt::format("{}, {} triangles × {} instances = {} placed", in.description, in.mesh.size(),
                       in.instances.size(), in.mesh.size() * in.instances.size());
}

// Below the table: how many rays each set holds (shadow: one per primary hit).
void print_ray_counts(std::vector<ray_set> const& sets) {
    std::string line = "\nRays:";
    for (auto const& set : sets) line += fmt::format(" {} {}{}", set.name, set.rays.size(), &set == &sets.back() ? "." : ",");
    fmt::print("{}\n", line);
}

void run_scene(bench_scene const& in, settings const& opt) {
    fmt::print("\n## {} ({})\n\n", in.name, describe(in));
    print_table_header();
    std::vector<ray_set> sets; // made once, from the first scene built (the same at every thread count)
    work_cache work;
    for (int threads : opt.threads) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        RTCDevice device = rtcNewDevice(fmt::format("threads={}", threads).c_str());
        rtcSetDeviceMemoryMonitorFunction(device, memory_monitor, nullptr);

        // Build: interleaved rounds as for the rays; the scenes of the last round are traced.
        std::unique_ptr<canopy_scene> const cs = build_canopy(in, {.quality = opt.quality});
        std::unique_ptr<embree_scene> es;
        long long embree_memory = 0;
        auto const canopy_build = [&] {
            canopy::bench::release_bvhs(*cs); // untimed, as Embree's es.reset() below
            auto const t = clock_type::now();
            cs->scene.build({.quality = opt.quality}); // the mesh BVH, the instances and the top level
            double const ms = seconds_since(t) * 1e3;
            cs->bytes = canopy::bench::bvh_bytes(cs->scene); // untimed: a walk over the BVHs, not the build
            return ms;
        };
        auto const embree_build = [&] {
            es.reset();
            embree_bytes = 0;
            auto const t = clock_type::now();
            es = build_embree(device, in, false, opt.quality);
            double const ms = seconds_since(t) * 1e3;
            embree_memory = embree_bytes.load();
            return ms;
        };
        // One untimed build each first: the first pays for the allocator's and the threads' start-up.
        canopy_build();
        embree_build();
        samples const builds = interleaved_rounds(opt.rounds, canopy_build, embree_build);
        std::unique_ptr<embree_scene> es_alpha = build_embree(device, in, true, opt.quality);
        if (sets.empty()) {
            double const triangles = double(in.mesh.size());
            print_row("–", "memory (bytes/triangle stored)", {double(cs->bytes) / triangles, double(cs->bytes) / triangles},
                      {double(embree_memory) / triangles, double(embree_memory) / triangles}, 1);
            sets = make_rays(*cs, in, opt.order);
        }
        print_row(fmt::format("{}", threads), "build (ms; ratio > 1: Canopy slower)", summarize(builds.canopy, false),
                  summarize(builds.embree, false), 1);

        measure_rays({threads, opt.rounds, *cs, *es, *es_alpha}, sets, opt.ray_sets, opt.coherent, work);
        es.reset();
        es_alpha.reset();
        rtcReleaseDevice(device);
    }
    print_ray_counts(sets);
}

// ---- command line -------------------------------------------------------------------------

// Comma-separated list → items.
std::vector<std::string> split_list(std::string_view text) {
    std::vector<std::string> items;
    std::size_t start = 0;
    while (start <= text.size()) {
        std::size_t const end = std::min(text.find(',', start), text.size());
        if (end > start) items.emplace_back(text.substr(start, end - start));
        start = end + 1;
    }
    return items;
}

bool is_one_of(std::string const& item, std::vector<std::string> const& allowed) {
    return std::find(allowed.begin(), allowed.end(), item) != allowed.end();
}

std::optional<settings> parse_command_line(int argc, char** argv) {
    settings opt;
    for (int i = 1; i < argc; ++i) {
        std::string const name = argv[i];
        if (name == "--quick" || name == "--coherent") {
            (name == "--quick" ? opt.quick : opt.coherent) = true;
            continue;
        }
        if (name == "--tiles") {
            opt.order = canopy::bench::pixel_order::tiles;
            continue;
        }
        if (i + 1 == argc) return std::nullopt;
        char const* value = argv[++i];
        if (name == "--scene") opt.scene_file = value;
        else if (name == "--scenes") opt.scenes = split_list(value);
        else if (name == "--rounds") opt.rounds = std::max(1, std::atoi(value));
        else if (name == "--rays") opt.ray_sets = split_list(value);
        else if (name == "--quality") {
            if (!canopy::bench::parse_quality(value, opt.quality)) return std::nullopt;
        }
        else if (name == "--threads-list") {
            opt.threads.clear();
            for (auto const& t : split_list(value)) opt.threads.push_back(std::max(1, std::atoi(t.c_str())));
        } else {
            return std::nullopt;
        }
    }
    for (auto const& r : opt.ray_sets)
        if (!is_one_of(r, {"primary", "random", "shadow", "vertices", "inside"})) return std::nullopt;
    for (auto const& s : opt.scenes)
        if (!is_one_of(s, canopy::bench::bench_scene_names())) return std::nullopt;
    if (opt.threads.empty()) return std::nullopt;
    return opt;
}

// A file of the bench formats, loaded by the bench plugin and compiled as `canopy trace` does: the
// mesh and the instances' transforms, as compile() placed them.
bench_scene load_scene_file(std::filesystem::path const& p) {
    canopy::registry bench;
    canopy::register_bench_plugin(bench);
    canopy::scene graph;
    bench.load(graph, p, graph.root(), "bench");
    canopy::compiled_scene const c = canopy::compile(graph, {.name = p.string(), .keep_single_instance = true});
    bench_scene out{p.filename().string(), "file", c.meshes[0].triangles, {}, {}, {}};
    for (canopy::placement const& placed : c.top_meshes) out.instances.push_back(placed.transform);
    return out;
}

std::string cpu_model() {
    std::ifstream in("/proc/cpuinfo");
    for (std::string line; std::getline(in, line);) {
        if (line.rfind("model name", 0) != 0) continue;
        std::size_t const start = line.find_first_not_of(" \t", line.find(':') + 1);
        return start == std::string::npos ? "unknown" : line.substr(start);
    }
    return "unknown";
}

void print_header(settings const& opt) {
    fmt::print("# Canopy vs Embree {}.{}.{}: same scenes, same rays\n\n", RTC_VERSION_MAJOR, RTC_VERSION_MINOR,
               RTC_VERSION_PATCH);
    fmt::print("Median and best of {} interleaved rounds{}{}. CPU: {}. Canopy ISA: {}. Build quality: {}.\n\n",
               opt.rounds, opt.quick ? " (--quick: scenes shrunk about 16×)" : "",
               opt.order == canopy::bench::pixel_order::tiles ? " (--tiles: camera pixels in tiles of 4 × 4)" : "",
               cpu_model(),
               canopy::simd::build_isa(),
               opt.quality == canopy::build_quality::high
                   ? "high (Canopy: spatial splits; Embree: RTC_BUILD_QUALITY_HIGH)"
                   : opt.quality == canopy::build_quality::fast
                         ? "fast (Canopy: object splits only; Embree: its default, medium)"
                         : "automatic (Canopy's default: spatial splits where they pay; Embree: its default, medium)");
    fmt::print("Rays in Mrays/s (ratio > 1: Canopy faster); build in ms (ratio > 1: Canopy slower); memory in bytes "
               "per stored triangle. Ratios Canopy / Embree; the ratio of medians (bold) is the main figure. Work "
               "counts: Canopy's tests per ray. Disagreements: rays whose hit/miss differs (closest: / rays both "
               "hit whose instance or primitive differs).\n");
}

} // namespace

int main(int argc, char** argv) {
    std::optional<settings> const opt = parse_command_line(argc, argv);
    if (!opt) {
        std::fprintf(stderr,
                     "usage: %s [--scenes sphere,terrain,soup,forest,engine,bunny,slivers] "
                     "[--scene FILE.obj|FILE.inst] [--quick] [--rounds N] [--threads-list 1,2] "
                     "[--rays primary,random,shadow,vertices,inside] [--quality automatic|fast|high] [--coherent] [--tiles]\n",
                     argv[0]);
        return 2;
    }
    try {
        print_header(*opt);
        if (!opt->scene_file.empty()) {
            run_scene(load_scene_file(opt->scene_file), *opt);
            return 0;
        }
        for (auto const& name : opt->scenes) {
            bench_scene const scene = canopy::bench::make_bench_scene(name, opt->quick);
            if (!scene.skipped.empty()) {
                fmt::print("\n## {}\n\nSkipped: {}.\n", name, scene.skipped);
                continue;
            }
            run_scene(scene, *opt);
        }
    } catch (std::exception const& e) {
        std::fprintf(stderr, "canopy_bench_embree: %s\n", e.what());
        return 1;
    }
}
