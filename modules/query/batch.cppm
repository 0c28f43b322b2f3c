// canopy.query:batch — the queries over a span of scalar float rays: closest_hit and any_hit
// trace runs of 8 consecutive coherent rays as one packet (basic_ray<simd::float8>), the others
// one at a time; multi_hit<N> traces every ray on its own.
//
//   std::vector<canopy::ray> rays = ...;
//   std::vector<canopy::hit_record<canopy::ray, canopy::triangle>> hits(rays.size());
//   canopy::closest_hit(rays, &mesh, &mesh + 1, hits);          // optional intersector last
//
// The decision is made per group of 8 (rays [8k, 8k + 8)); a shorter tail goes one at a time. A
// group is a packet when
// - at least two of its rays take part (finite origin and direction, tmin ≤ tmax; the others are
//   inactive lanes and miss, as they do on their own),
// - their directions share one octant (the sign bits of x, y and z agree; −0 counts as negative,
//   as in the box test), and
// - their origins lie within a box whose sides are at most batch_origin_spread (1/32) of the
//   largest side of the bounds of [first, last) (camera rays: one origin; shadow rays from
//   neighbouring pixels: close origins).
// The test runs on the group packed as a packet (one load per ray and one 8 × 8 transposition),
// in a few dozen vector instructions: far less than tracing the rays.
//
// Whether packets pay is then measured, not guessed (batch_packing::adaptive, the default). On
// large meshes seen from afar the lanes of a packet part early, and a packet costs more than its
// rays traced one by one (a packet tests one child box or one triangle at a time against its
// lanes, a single ray eight boxes or eight triangles at once). Packets of an intersector that
// intercepts nothing count, as they go, the lanes that reach each wide node they visit
// (canopy.bvh:traverse, packet_occupancy), and the lanes that went on alone. After the first
// batch_first_probe_packets packets, and then after every batch_probe_packets packets, the batch
// looks at the window's means: fewer than batch_paying_occupancy_eighths / 8 lanes per node visit,
// or more than batch_lanes_alone_halves / 2 lanes gone on alone per packet, and the next
// batch_skip_groups coherent groups are traced one ray at a time, then packets are probed again.
// The counts depend only on the rays and the scene, never on timing: a batch makes the same
// choices on every run.
// Measured on primary rays (canopy_bench_profile --batch --packets-always, docs/performance.md,
// Run 13), packets that pay: CAD model and bunny 6.8–7.0 lanes per node visit and 0.1–0.2 lanes
// alone per packet, slivers 5.9–7.0 and 0.3–0.5, 1.3M-triangle sphere 5.5–5.9 and 0.8–1.1, soup
// 5.25–5.45 and 3.1–3.5; packets that lose: 2M terrain 5.0 and 2.1, the forest's instances
// 6.2–6.3 and 5.9–6.1. Hence 41/8 (5.125) and 9/2 (4.5), between the two sides; the signal is
// coarse, and batch_packing::always keeps every coherent group a packet.
//
// How a packet is traced (canopy.bvh:traverse): its node test takes one child box at a time
// against all lanes; its leaf test one triangle at a time, read straight from the leaf's block,
// with the vertex components picked once for all lanes when they share one shear permutation
// (canopy.geometry:triangle_block, intersect_lane), or, with no filter and fewer lanes taking part
// than the block has triangles, the whole block once per lane (intersect_block_by_lanes); and
// with no hook or filter, lanes that reach a node (or a leaf of instances) fewer than
// packet_lanes_alone_below at a time go on from there as scalar rays.
//
// Guarantees:
// - Results are bit-identical to the single-ray queries (hit, t, u, v, prim_id, geom_id, inst_id,
//   inner_inst_id): a packet tests each lane with the single ray's arithmetic, its box tests are
//   conservative for every lane, and the closest hit does not depend on traversal order
//   (canopy.query:single, equal-t rule). any_hit too: a packet tests a leaf only for the lanes
//   that hit every box on the way to it (canopy.bvh:traverse), and any-hit traversal is depth
//   first with children in slot order; so each lane meets the leaves it would meet alone, in the
//   same order, and the same first accepted hit (also in BVHs built with spatial splits).
// - Intersectors: hooks and filters see packets (prepared_ray<simd::float8>), so every test of
//   every active lane goes through them. For any_hit, a filter or triangle hook sees, lane by
//   lane, the candidates (hit lanes) it would see for the single ray, in the same order: hit
//   counts summed over lanes equal the single-ray counts. Call counts are per packet, not per ray,
//   and for closest_hit the candidates a lane meets depend on the order in which the packet
//   visits leaves (near to far for the packet, not for each lane): only the result is the same.
// - An intersector that cannot take packets (hooks or a filter declared for canopy::ray or
//   basic_hit_record<float> only, or a template hook whose declared return type is
//   basic_hit_record<float>) makes the batch trace every ray on its own, decided at compile time;
//   so do structures whose boxes are not float. A template hook with a deduced return type
//   (`auto`) is taken to serve packets: its body must compile for them (lane by lane: hr.hit[k],
//   hr.hit.set(k, ...)), as for the packet single-ray queries.
// Each query returns batch_stats: how many packets and single rays it traced, and how many of the
// single rays were coherent groups that the adaptive policy traced one by one.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <iterator>
#include <limits>
#include <span>
#include <stdexcept>
#include <type_traits>
#include <utility>
export module canopy.query:batch;
import canopy.bvh;
import :single;

export namespace canopy {

// What a batch query traced: packets of 8 rays, and rays one at a time (among them, unpacked_rays:
// the rays of coherent groups traced one at a time because packets did not pay there).
struct batch_stats {
    std::size_t packets = 0;
    std::size_t single_rays = 0;
    std::size_t unpacked_rays = 0;
};

// Whether coherent groups of rays become packets always, or only while packets pay (see the top
// of this file).
enum class batch_packing { adaptive, always };

// The adaptive policy (see the top of this file): packets in a batch's first measured window (few,
// so that short batches, such as a renderer's tiles of 32 groups, decide too) and in the later ones
// (more: a window's means vary less, measured in docs/performance.md, Run 23); the lanes per node
// visit, in eighths, from which packets pay (41/8 = 5.125 of 8); the lanes gone on alone per
// packet, in halves, beyond which they do not (9/2 = 4.5); the coherent groups traced one ray at
// a time after a window that did not pay (so one group in 16 is a probing packet there).
inline constexpr std::size_t batch_first_probe_packets = 16;
inline constexpr std::size_t batch_probe_packets = 64;
inline constexpr std::uint64_t batch_paying_occupancy_eighths = 41;
inline constexpr std::uint64_t batch_lanes_alone_halves = 9;
inline constexpr std::size_t batch_skip_groups = 15 * batch_probe_packets;

// The largest origin spread of a packet, as a fraction of the largest side of the scene's bounds.
// Measured on shadow rays to a point light from the hits of neighbouring pixels
// (docs/performance.md, Run 22): against 1/64, 1/32 makes packets of most of the models' groups
// (bunny 2,237 → 10,170 packets, 24 % less time per ray; engine 8 %; slivers 23 %) and costs the
// 1.3M-triangle sphere 3–5 % (its packets pass the adaptive test but do not pay); 1/16 and 1/8
// gain no more on the models and lose more on the sphere.
inline constexpr float batch_origin_spread = 1.0f / 32.0f;

} // namespace canopy

namespace canopy::detail {

inline constexpr std::size_t batch_width = 8;
using batch_packet = basic_ray<simd::float8>;

// Whether the `packets` packets traced between two readings of packet_occupancy_tally paid: true
// when they counted no node visit and no lane alone (a structure without wide nodes, or an
// intersector whose packets do not count: they stay packets).
inline bool packets_paid(packet_occupancy const& before, packet_occupancy const& after, std::uint64_t packets) {
    std::uint64_t const visits = after.node_visits - before.node_visits;
    std::uint64_t const lanes = after.node_lanes - before.node_lanes;
    std::uint64_t const alone = after.lanes_alone - before.lanes_alone;
    return 8 * lanes >= batch_paying_occupancy_eighths * visits && 2 * alone <= batch_lanes_alone_halves * packets;
}

// The adaptive policy's state over one batch (see the top of this file): a window of
// batch_first_probe_packets packets, then windows of batch_probe_packets, each measured from
// packet_occupancy_tally; after a window that did not pay, batch_skip_groups coherent groups traced
// one ray at a time. With batch_packing::always every coherent group is a packet.
// (Member functions are declared inline: in a named module they are not implicitly, and importers
// would call them once per group instead of inlining them.)
class packing_policy {
public:
    inline explicit packing_policy(batch_packing packing) : adaptive_(packing == batch_packing::adaptive) {
        open_window(batch_first_probe_packets);
    }

    // Whether the next coherent group is traced as a packet (false while groups are skipped; the
    // last skipped group opens a new window).
    inline bool packs_next() {
        if (skip_left_ == 0) return true;
        if (--skip_left_ == 0) open_window(batch_probe_packets);
        return false;
    }
    // Called after each packet: a full window either opens the next or starts the skip.
    inline void packet_traced() {
        if (!adaptive_ || --probe_left_ != 0) return;
        if (packets_paid(window_start_, packet_occupancy_tally, window_packets_))
            open_window(batch_probe_packets);
        else
            skip_left_ = batch_skip_groups;
    }

private:
    inline void open_window(std::size_t packets) {
        probe_left_ = window_packets_ = packets;
        window_start_ = packet_occupancy_tally;
    }

    bool adaptive_;
    std::size_t probe_left_ = 0, skip_left_ = 0, window_packets_ = 0;
    packet_occupancy window_start_;
};

// Whether packets of I over a range of Elem make the same calls as single rays would: the packet
// query compiles without mistakes, every hook and filter the single rays would call has a packet
// overload, and the structure's boxes are float.
template <typename I, typename Elem>
constexpr bool batch_takes_packets() {
    using Leaf = leaf_primitive_t<Elem>;
    if constexpr (acceleration_structure<Leaf> || !requires(Elem const& e) { get_bounds(e); }) {
        return false;
    } else if constexpr (!std::is_same_v<typename decltype(get_bounds(std::declval<Elem const&>()))::value_type,
                                         float>) {
        return false;
    } else {
        constexpr bool nested = acceleration_structure<Elem>;
        using R1 = std::conditional_t<nested, prepared_ray<float>, ray>;
        using R8 = std::conditional_t<nested, prepared_ray<simd::float8>, batch_packet>;
        return intersector_mistake_v<I, batch_packet, Elem> == intersector_mistake::none &&
               (!primitive_hook_for<I, R1, Leaf> || primitive_hook_for<I, R8, Leaf>) &&
               (!box_hook_for<I, R1, aabb, vec3<float>> || box_hook_for<I, R8, aabb, vec3<simd::float8>>) &&
               (!filter_hook_for<I, R1> || filter_hook_for<I, R8>);
    }
}

// batch_origin_spread times the largest side of the bounds of [first, last); 0 when they are
// empty or not finite (then only rays from one origin form packets).
template <typename It>
float batch_spread_limit(It first, It last) {
    aabb box;
    for (; first != last; ++first) box = extend(box, get_bounds(*first));
    auto const d = diagonal(box);
    float const side = std::max({d.x, d.y, d.z});
    return std::isfinite(side) && side > 0.0f ? side * batch_origin_spread : 0.0f;
}

// The 8 rays of a group as one packet: each ray is 8 floats (origin, tmin, direction, tmax), loaded
// as one vector; the 8 × 8 block transposed gives one vector per member.
inline batch_packet pack_group(std::span<ray const> group) {
    static_assert(sizeof(ray) == batch_width * sizeof(float) && offsetof(ray, origin) == 0 &&
                      offsetof(ray, tmin) == 3 * sizeof(float) && offsetof(ray, direction) == 4 * sizeof(float) &&
                      offsetof(ray, tmax) == 7 * sizeof(float),
                  "pack_group reads a ray as 8 consecutive floats");
    std::array<simd::float8, batch_width> rows;
    for (std::size_t k = 0; k < batch_width; ++k)
        rows[k] = simd::float8::load(reinterpret_cast<float const*>(&group[k]));
    simd::transpose(rows);
    batch_packet p;
    p.origin = {rows[0], rows[1], rows[2]};
    p.tmin = rows[3];
    p.direction = {rows[4], rows[5], rows[6]};
    p.tmax = rows[7];
    return p;
}

// How many groups ahead of the one being traced the batch loop starts loading rays into the
// cache: a group's rays (256 bytes) are read once, and a packet's traversal is long enough that
// the loads of the next ones finish meanwhile.
inline constexpr std::size_t batch_prefetch_groups = 2;

// Starts loading rays [first, first + 8) into the cache (nothing past the end of the span).
[[gnu::always_inline]] inline void prefetch_group(std::span<ray const> rays, std::size_t first) {
    if (first + batch_width > rays.size()) return;
    auto const* p = reinterpret_cast<char const*>(rays.data() + first);
    for (std::size_t k = 0; k < batch_width * sizeof(ray); k += 64) __builtin_prefetch(p + k);
}

// The coherence test of one group of 8 rays, packed (see the top of this file), over the lanes
// that take part: at least two, one octant (sign bits: -0 counts as negative), origins within
// spread_limit on each axis.
inline bool coherent_group(batch_packet const& p, float spread_limit) {
    std::uint32_t const active = simd::movemask(active_lanes(p));
    if (std::popcount(active) < 2) return false;
    auto const taking_part = simd::mask_type_t<simd::float8>::from_bits(active);
    simd::float8 const inf(std::numeric_limits<float>::infinity());
    for (int a = 0; a < 3; ++a) {
        std::uint32_t const negative = simd::sign_bits(p.direction[a]) & active;
        if (negative != 0 && negative != active) return false;
        float const lo = simd::reduce_min(simd::select(taking_part, p.origin[a], inf));
        float const hi = simd::reduce_max(simd::select(taking_part, p.origin[a], -inf));
        if (!(hi - lo <= spread_limit)) return false;
    }
    return true;
}

inline void check_batch_sizes(std::size_t rays, std::size_t results) {
    if (results < rays) throw std::invalid_argument("canopy: a batch query needs one result per ray");
}

// The batch loop: groups of 8 coherent rays go to packet(index, packet ray) while packets pay
// (always with batch_packing::always), every other ray to single(index). packet is generic, so
// that it is only instantiated where packets are traced.
template <typename I, typename It, typename Packet, typename Single>
batch_stats run_batch(std::span<ray const> rays, It first, It last, batch_packing packing, Packet&& packet,
                      Single&& single) {
    using Elem = std::remove_cvref_t<decltype(*first)>;
    batch_stats stats;
    auto const one = [&](std::size_t k) {
        single(k);
        ++stats.single_rays;
    };
    std::size_t i = 0;
    if constexpr (batch_takes_packets<I, Elem>()) {
        if (rays.size() >= batch_width) {
            float const limit = batch_spread_limit(first, last);
            packing_policy policy(packing);
            for (; i + batch_width <= rays.size(); i += batch_width) {
                prefetch_group(rays, i + batch_prefetch_groups * batch_width);
                auto const p = pack_group(rays.subspan(i, batch_width));
                bool const coherent = coherent_group(p, limit);
                if (coherent && policy.packs_next()) {
                    packet(i, p);
                    ++stats.packets;
                    policy.packet_traced();
                } else {
                    for (std::size_t k = i; k < i + batch_width; ++k) one(k);
                    if (coherent) stats.unpacked_rays += batch_width;
                }
            }
        }
    }
    for (; i < rays.size(); ++i) one(i);
    return stats;
}

// The query of one scalar ray over [first, last), out of line. A batch over one root (a scene's
// top BVH: the common case) traces it as closest_hit(r, &root, &root + 1): the traversal is then
// not nested in a loop over roots whose count is only known at run time. Nested in that loop (and
// inlined into the batch loop), the compiler kept 4 of the node test's 6 fma operands on the stack:
// random rays made 35 % more loads and ran 3-13 % slower in a batch than one by one; so did a loop
// over the unpacked rays inside one out-of-line call (0.88 of the single-ray loop, against
// 0.99-1.01 with one call per ray). Packets are
// the other way round: inlined into the batch loop they take 16-19 % fewer instructions than out
// of line (callgrind, primary rays of the bunny, the engine and the sphere), so they stay there.
template <bool Closest, typename Ray, typename It, typename I>
[[gnu::always_inline]] inline auto query_inline(Ray const& r, It first, It last, I& isect) {
    if constexpr (Closest)
        return closest_hit(r, first, last, isect);
    else
        return any_hit(r, first, last, isect);
}

template <bool Closest, typename Ray, typename Root, typename I>
[[gnu::noinline]] auto query_root(Ray const& r, Root const& root, I& isect) {
    return query_inline<Closest>(r, &root, &root + 1, isect);
}

template <bool Closest, typename Ray, typename It, typename I>
[[gnu::noinline]] auto query_roots(Ray const& r, It first, It last, I& isect) {
    return query_inline<Closest>(r, first, last, isect);
}

template <bool Closest, typename Ray, typename It, typename I>
auto query_one_ray(Ray const& r, It first, It last, I& isect) {
    if constexpr (std::random_access_iterator<It> && std::is_lvalue_reference_v<std::iter_reference_t<It>>)
        if (last - first == 1) return query_root<Closest>(r, *first, isect);
    return query_roots<Closest>(r, first, last, isect);
}

} // namespace canopy::detail

export namespace canopy {

// Closest hit of every ray: out[i] is what closest_hit(rays[i], first, last, isect) returns.
// `packing`: packets while they pay (adaptive) or for every coherent group (always); the results
// are the same either way.
template <traceable_iterator It, typename I = default_intersector>
batch_stats closest_hit(std::span<ray const> rays, It first, It last, std::span<basic_hit_record<float>> out,
                        I&& isect = I{}, batch_packing packing = batch_packing::adaptive) {
    detail::check_batch_sizes(rays.size(), out.size());
    return detail::run_batch<std::remove_reference_t<I>>(
        rays, first, last, packing,
        [&](std::size_t i, auto const& p) {
            auto const hr = closest_hit(p, first, last, isect);
            write_lane_records(hr, out.data() + i);
        },
        [&](std::size_t i) { out[i] = detail::query_one_ray<true>(rays[i], first, last, isect); });
}

// Any hit of every ray: out[i] is what any_hit(rays[i], first, last, isect) returns.
template <traceable_iterator It, typename I = default_intersector>
batch_stats any_hit(std::span<ray const> rays, It first, It last, std::span<basic_hit_record<float>> out,
                    I&& isect = I{}, batch_packing packing = batch_packing::adaptive) {
    detail::check_batch_sizes(rays.size(), out.size());
    return detail::run_batch<std::remove_reference_t<I>>(
        rays, first, last, packing,
        [&](std::size_t i, auto const& p) {
            auto const hr = any_hit(p, first, last, isect);
            write_lane_records(hr, out.data() + i);
        },
        [&](std::size_t i) { out[i] = detail::query_one_ray<false>(rays[i], first, last, isect); });
}

// Occlusion of every ray: out[i] is any_hit(rays[i], first, last, isect).hit.
template <traceable_iterator It, typename I = default_intersector>
batch_stats any_hit(std::span<ray const> rays, It first, It last, std::span<bool> out, I&& isect = I{},
                    batch_packing packing = batch_packing::adaptive) {
    detail::check_batch_sizes(rays.size(), out.size());
    return detail::run_batch<std::remove_reference_t<I>>(
        rays, first, last, packing,
        [&](std::size_t i, auto const& p) {
            auto const hr = any_hit(p, first, last, isect);
            for (int k = 0; k < int(detail::batch_width); ++k) out[i + std::size_t(k)] = hr.hit[k];
        },
        [&](std::size_t i) { out[i] = detail::query_one_ray<false>(rays[i], first, last, isect).hit; });
}

// Up to N hits of every ray: out[i] is what multi_hit<N>(rays[i], first, last, isect) returns.
// Traced one ray at a time.
template <std::size_t N, traceable_iterator It, typename I = default_intersector>
batch_stats multi_hit(std::span<ray const> rays, It first, It last, std::span<std::array<basic_hit_record<float>, N>> out,
                      I&& isect = I{}) {
    detail::check_batch_sizes(rays.size(), out.size());
    for (std::size_t i = 0; i < rays.size(); ++i) out[i] = multi_hit<N>(rays[i], first, last, isect);
    return {0, rays.size()};
}

} // namespace canopy
