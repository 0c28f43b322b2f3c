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
// Whether packets pay is then measured, not guessed (batch_packing::adaptive, the default), by
// timing both ways on the rays at hand. On large meshes seen from afar the lanes of a packet part
// early, and a packet costs more than its rays traced one by one (a packet tests one child box or
// one triangle at a time against its lanes, a single ray eight boxes or eight triangles at once);
// on models seen whole it costs a third less. Which side a set of rays falls on depends on the
// scene, the rays and the machine (an earlier policy's thresholds on counts of lanes per node,
// calibrated on one CPU, chose wrongly on another: docs/performance.md, Runs 22 and 23), so the
// batch asks the clock. It times its first coherent groups both ways, alternately one as a packet
// and one ray by ray, and from then on one coherent group in batch_probe_every (the two ways in
// turn), and traces the other groups the way whose recent groups took less time (the mean of each
// way's last batch_probe_window timed groups, the slowest left out, so that one interruption of
// the thread does not decide). The timing decides only which way is taken: the results are the
// same either way, but the batch_stats of two runs may differ. Intersectors that intercept anything (a hook or a filter)
// see packets always (they are told so below), and so do batches with batch_packing::always.
//
// How a packet is traced (canopy.bvh:traverse): its node test takes one child box at a time
// against all lanes; its leaf test one triangle at a time, read straight from the leaf's block,
// with the vertex components picked once for all lanes when they share one shear permutation
// (canopy.geometry:triangle_block, intersect_lane); and with no hook or filter, lanes that reach
// a node (or a leaf of instances) fewer than packet_lanes_alone_below at a time go on from there
// as scalar rays.
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
#include <chrono>
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

// The adaptive policy (see the top of this file): after the first 2 × batch_probe_window coherent
// groups, all timed, one coherent group in batch_probe_every is timed, the probes alternating
// between the two ways; each way is judged on its last batch_probe_window probes. An odd period
// keeps the probes from falling on the same columns of an image row after row. Measured on the
// seven benchmark scenes (docs/performance.md, Run 23).
inline constexpr std::size_t batch_probe_window = 8;
inline constexpr std::size_t batch_probe_every = 15;

// The largest origin spread of a packet, as a fraction of the largest side of the scene's bounds.
// Measured on shadow rays to a point light from the hits of neighbouring pixels
// (docs/performance.md, Run 22): against 1/64, 1/32 makes packets of most of the models' groups
// (bunny 2,237 → 10,170 packets, 24 % less time per ray; engine 8 %; slivers 23 %) and costs the
// 1.3M-triangle sphere 3–5 % (its packets carry few lanes per leaf and do not pay); 1/16 and 1/8
// gain no more on the models and lose more on the sphere.
inline constexpr float batch_origin_spread = 1.0f / 32.0f;

} // namespace canopy

export namespace canopy::detail {

// The adaptive policy's state over one batch (see the top of this file). next() tells how to
// trace the next coherent group, and whether to time it; traced() takes the group's time back
// (in any unit, the same for every group; ignored for groups not timed). With adapts false every
// coherent group is a packet and nothing is timed. (Member functions are declared inline: in a
// named module they are not implicitly.)
class packing_policy {
public:
    struct choice {
        bool packet = true;
        bool timed = false;
    };

    inline explicit packing_policy(bool adapts) : adapts_(adapts) {}

    inline choice next() const {
        if (!adapts_) return {true, false};
        if (until_probe_ > 0) return {packets_, false};
        // Probes in the order packet, single, single, packet, packet, single, ...
        return {((probes_ + 1) >> 1 & 1u) == 0, true};
    }

    inline void traced(choice c, std::uint64_t time) {
        if (!c.timed) {
            if (until_probe_ > 0) --until_probe_;
            return;
        }
        (c.packet ? packet_times_ : single_times_).add(time);
        ++probes_;
        // Every group is a probe until each way has a full window, then one group in
        // batch_probe_every.
        if (probes_ >= 2 * batch_probe_window) until_probe_ = batch_probe_every - 1;
        if (packet_times_.count >= 2 && single_times_.count >= 2)
            packets_ = packet_times_.trimmed_mean() <= single_times_.trimmed_mean();
    }

    // The way the untimed groups take now (packets until both ways have been timed twice).
    inline bool chose_packets() const { return packets_; }

private:
    // The last batch_probe_window times of one way's probes; their mean without the slowest, so
    // that one interruption of the thread does not decide.
    struct window {
        std::array<std::uint64_t, batch_probe_window> times{};
        std::size_t count = 0, next = 0;
        inline void add(std::uint64_t t) {
            times[next] = t;
            next = (next + 1) % batch_probe_window;
            count = std::min(count + 1, batch_probe_window);
        }
        inline double trimmed_mean() const {
            std::uint64_t sum = 0, slowest = 0;
            for (std::size_t k = 0; k < count; ++k) {
                sum += times[k];
                slowest = std::max(slowest, times[k]);
            }
            return double(sum - slowest) / double(count - 1);
        }
    };

    bool adapts_;
    bool packets_ = true;
    std::size_t probes_ = 0, until_probe_ = 0;
    window packet_times_, single_times_;
};

} // namespace canopy::detail

namespace canopy::detail {

inline constexpr std::size_t batch_width = 8;
using batch_packet = basic_ray<simd::float8>;

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

// Whether the adaptive policy may trace coherent groups of I over a range of Elem ray by ray: the
// intersector intercepts nothing (no primitive hook, box hook or filter, for scalar rays or
// packets, plain or prepared), so that no call could tell the two ways apart.
template <typename I, typename Elem>
constexpr bool batch_adapts() {
    using Leaf = leaf_primitive_t<Elem>;
    auto const intercepts = []<typename R>(R*) {
        return primitive_hook_for<I, R, Leaf> || box_hook_for<I, R, aabb, vec3<ray_value_t<R>>> ||
               filter_hook_for<I, R>;
    };
    return !intercepts(static_cast<ray*>(nullptr)) && !intercepts(static_cast<batch_packet*>(nullptr)) &&
           !intercepts(static_cast<prepared_ray<float>*>(nullptr)) &&
           !intercepts(static_cast<prepared_ray<simd::float8>*>(nullptr));
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

// The batch loop: groups of 8 coherent rays go to packet(index, packet ray) or ray by ray to
// single(index), as the packing policy says (always packets with batch_packing::always, or for an
// intersector that intercepts something); every other ray goes to single(index). packet is
// generic, so that it is only instantiated where packets are traced.
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
            using clock = std::chrono::steady_clock;
            float const limit = batch_spread_limit(first, last);
            packing_policy policy(packing == batch_packing::adaptive && batch_adapts<I, Elem>());
            for (; i + batch_width <= rays.size(); i += batch_width) {
                auto const p = pack_group(rays.subspan(i, batch_width));
                if (!coherent_group(p, limit)) {
                    for (std::size_t k = i; k < i + batch_width; ++k) one(k);
                    continue;
                }
                auto const how = policy.next();
                auto const start = how.timed ? clock::now() : clock::time_point{};
                if (how.packet) {
                    packet(i, p);
                    ++stats.packets;
                } else {
                    for (std::size_t k = i; k < i + batch_width; ++k) one(k);
                    stats.unpacked_rays += batch_width;
                }
                auto const time = how.timed ? std::uint64_t((clock::now() - start).count()) : 0u;
                policy.traced(how, time);
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
