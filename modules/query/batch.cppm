// canopy.query:batch — the queries over a span of scalar float rays: closest_hit and any_hit
// trace groups of 8 coherent rays as one packet (basic_ray<simd::float8>), or of 16
// (basic_ray<simd::float16>) where 16-lane vectors are native and the rays come in rows, the
// others one at a time; multi_hit<N> traces every ray on its own.
//
//   std::vector<canopy::ray> rays = ...;
//   std::vector<canopy::hit_record<canopy::ray, canopy::triangle>> hits(rays.size());
//   canopy::closest_hit(rays, &mesh, &mesh + 1, hits);          // optional intersector last
//
// The groups. Rays laid out as an image row by row (a camera's rays, in the order most renderers
// and ray files give them) are grouped in squares of 4 × 2 pixels: two runs of 4 rays, one row's
// length apart. Squares make fewer box and triangle tests per packet than runs of 8 pixels of one
// row (docs/performance.md, Runs 33 and 34). The batch finds the rows' length itself
// (find_row_length): a row ends where the step from one ray to the next (directions scaled to
// length 1, origins to the scene's size) exceeds 4 typical steps; a length is taken when 16
// sampled squares are tighter than the runs of 8 that start where they start (batch_square_gain).
// It looks once per batch, at up to batch_row_candidates row ends, and costs about one step
// computation (in vector form, 8 at a time) per ray of a row. Where 16-lane vectors are native
// (AVX-512) and the intersector takes packets of 16, squares of 4 × 4 go band by band (4 rows) as
// packets of 16 (pack_wide_group), and a square that is not coherent, or while packets of 16 do
// not pay (their own adaptive policy, below), as two squares of 4 × 2; then squares of 4 × 2 go
// band by band (2 rows) as packets of 8. The columns past the last multiple of 4 in each row, and
// the rays past the last whole band, go on as below. Rays not in rows (random rays, rays already
// in tiles, a single row) are grouped in runs of 8 consecutive rays ([8k, 8k + 8)); where 16-lane
// vectors are native, runs of 16 first ([16k, 16k + 16), the same adaptive policy of their own as
// squares of 4 × 4), a run that is not coherent or while they do not pay as two runs of 8 (rays
// already in tiles of 4 × 4 pixels then go as squares; shadow rays from neighbouring pixels gain
// a few per cent, docs/performance.md, Run 36). A shorter tail goes one at a time.
// batch_stats::row_length says which.
//
// The decision is made per group of 8 (or 16). A group is a packet when
// - at least two of its rays take part (finite origin and direction, tmin ≤ tmax; the others are
//   inactive lanes and miss, as they do on their own),
// - their directions share one octant (the sign bits of x, y and z agree; −0 counts as negative,
//   as in the box test), and
// - their origins lie within a box whose sides are at most batch_origin_spread (1/32) of the
//   largest side of the bounds of [first, last) (camera rays: one origin; shadow rays from
//   neighbouring pixels: close origins).
// The test runs on the group packed as a packet (one load per ray and one 8 × 8 transposition;
// two, joined, for 16), in a few dozen vector instructions: far less than tracing the rays.
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
// coarse, and batch_packing::always keeps every coherent group a packet. Packets of 16 have a
// policy of their own, with the same thresholds as fractions of their lanes (10.25 lanes per node
// visit, 9 alone per packet); a group of 16 they skip goes on as two groups of 8 under theirs.
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

// What a batch query traced: packets of 8 rays, packets of 16 (wide_packets), and rays one at a
// time (among them, unpacked_rays: the rays of coherent groups traced one at a time because
// packets did not pay there).
struct batch_stats {
    std::size_t packets = 0; // packets of 8 rays
    std::size_t single_rays = 0;
    std::size_t unpacked_rays = 0;
    // The rows' length the batch found (rays laid out as an image row by row; its packets then
    // cover batch_group_rows rows of 4 rays each), or 0 (packets of 8 consecutive rays).
    std::size_t row_length = 0;
    // Packets of 16 rays: squares of 4 × 4 in rows, where 16-lane vectors are native.
    std::size_t wide_packets = 0;

    // The rays traced in packets (of 8 or 16).
    [[nodiscard]] constexpr std::size_t packed_rays() const { return 8 * packets + 16 * wide_packets; }
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

// A packet's rays as the batch takes them: batch_group_rows runs of batch_group_columns rays.
// In rays laid out as an image row by row (see batch_row_length) the runs are the same columns of
// consecutive rows, so a packet covers a square of 4 × 2 pixels; otherwise they follow each
// other, and a packet is 8 consecutive rays.
inline constexpr std::size_t batch_group_columns = 4;
inline constexpr std::size_t batch_group_rows = 2;

// The widest image rows the batch looks for (rays).
inline constexpr std::size_t batch_max_row_length = std::size_t(1) << 16;

// How many candidate row lengths (row ends found) the batch tries before it takes runs of 8.
inline constexpr std::size_t batch_row_candidates = 4;

// How much tighter than runs of 8 consecutive rays the sampled squares must be, in the measure of
// batch_row_length, for the batch to take squares (a camera's rays: about 4/7 for 4 × 2 against
// 8 × 1).
inline constexpr float batch_square_gain = 0.75f;

} // namespace canopy

namespace canopy::detail {

inline constexpr std::size_t batch_width = 8;
using batch_packet = basic_ray<simd::float8>;
static_assert(batch_group_columns * batch_group_rows == batch_width);

// Squares of 4 × 4 rays as packets of 16, where 16-lane vectors are native (AVX-512).
inline constexpr bool batch_wide_packets = simd::native_width<16>;
inline constexpr std::size_t batch_wide_width = 16;
inline constexpr std::size_t batch_wide_rows = batch_wide_width / batch_group_columns;
using batch_wide_packet = basic_ray<simd::float16>;

// Where a group's rays are: lane k is ray first + (k / 4) * stride + k % 4. Stride 4: 8
// consecutive rays; stride W (the rows' length): 4 × 2 rays of an image.
struct ray_group {
    std::size_t first = 0;
    std::size_t stride = batch_group_columns;
    [[nodiscard]] inline std::size_t operator[](std::size_t k) const {
        return first + k / batch_group_columns * stride + k % batch_group_columns;
    }
};

// Whether `packets` packets of `width` lanes, whose counts (packet_occupancy_tally's, summed over
// them) are `window`, paid: true when they counted no node visit and no lane alone (a structure
// without wide nodes, or an intersector whose packets do not count: they stay packets). The
// thresholds, set for 8 lanes, scale with the width.
inline bool packets_paid(packet_occupancy const& window, std::uint64_t packets, std::uint64_t width) {
    return 64 * window.node_lanes >= batch_paying_occupancy_eighths * width * window.node_visits &&
           16 * window.lanes_alone <= batch_lanes_alone_halves * width * packets;
}

// The adaptive policy's state over one batch (see the top of this file): a window of
// batch_first_probe_packets packets, then windows of batch_probe_packets, each measured from its
// packets' counts in packet_occupancy_tally; after a window that did not pay, batch_skip_groups
// coherent groups traced one ray at a time. With batch_packing::always every coherent group is a
// packet.
// (Member functions are declared inline: in a named module they are not implicitly, and importers
// would call them once per group instead of inlining them.)
class packing_policy {
public:
    inline packing_policy(batch_packing packing, std::size_t width)
        : adaptive_(packing == batch_packing::adaptive), width_(width) {
        open_window(batch_first_probe_packets);
    }

    // Whether the next coherent group is traced as a packet (false while groups are skipped; the
    // last skipped group opens a new window).
    inline bool packs_next() {
        if (skip_left_ == 0) return true;
        if (--skip_left_ == 0) open_window(batch_probe_packets);
        return false;
    }
    // Traces one packet by calling trace(). Under the adaptive policy the packet's own counts (the
    // tally after it less the tally before it) join the window, so that packets of 8 and of 16
    // traced in turn count each in its own policy; a full window either opens the next or starts
    // the skip.
    template <typename Trace>
    inline void trace_packet(Trace&& trace) {
        if (!adaptive_) {
            trace();
            return;
        }
        packet_occupancy const before = packet_occupancy_tally;
        trace();
        packet_occupancy const& after = packet_occupancy_tally;
        window_.node_visits += after.node_visits - before.node_visits;
        window_.node_lanes += after.node_lanes - before.node_lanes;
        window_.lanes_alone += after.lanes_alone - before.lanes_alone;
        if (--probe_left_ != 0) return;
        if (packets_paid(window_, window_packets_, width_))
            open_window(batch_probe_packets);
        else
            skip_left_ = batch_skip_groups;
    }

private:
    inline void open_window(std::size_t packets) {
        probe_left_ = window_packets_ = packets;
        window_ = {};
    }

    bool adaptive_;
    std::size_t width_;
    std::size_t probe_left_ = 0, skip_left_ = 0, window_packets_ = 0;
    packet_occupancy window_;
};

// Whether packets (of T lanes) of I over a range of Elem make the same calls as single rays would:
// the packet query compiles without mistakes, every hook and filter the single rays would call has
// a packet overload, and the structure's boxes are float.
template <typename I, typename Elem, typename T = simd::float8>
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
        using RN = std::conditional_t<nested, prepared_ray<T>, basic_ray<T>>;
        return intersector_mistake_v<I, basic_ray<T>, Elem> == intersector_mistake::none &&
               (!primitive_hook_for<I, R1, Leaf> || primitive_hook_for<I, RN, Leaf>) &&
               (!box_hook_for<I, R1, aabb, vec3<float>> || box_hook_for<I, RN, aabb, vec3<T>>) &&
               (!filter_hook_for<I, R1> || filter_hook_for<I, RN>);
    }
}

// The largest side of the bounds of [first, last); 0 when they are empty or not finite.
template <typename It>
float batch_scene_side(It first, It last) {
    aabb box;
    for (; first != last; ++first) box = extend(box, get_bounds(*first));
    auto const d = diagonal(box);
    float const side = std::max({d.x, d.y, d.z});
    return std::isfinite(side) && side > 0.0f ? side : 0.0f;
}

// The 8 rays of a group as one packet: each ray is 8 floats (origin, tmin, direction, tmax), loaded
// as one vector; the 8 × 8 block transposed gives one vector per member.
inline batch_packet pack_group(std::span<ray const> rays, ray_group g) {
    static_assert(sizeof(ray) == batch_width * sizeof(float) && offsetof(ray, origin) == 0 &&
                      offsetof(ray, tmin) == 3 * sizeof(float) && offsetof(ray, direction) == 4 * sizeof(float) &&
                      offsetof(ray, tmax) == 7 * sizeof(float),
                  "pack_group reads a ray as 8 consecutive floats");
    std::array<simd::float8, batch_width> rows;
    for (std::size_t k = 0; k < batch_width; ++k)
        rows[k] = simd::float8::load(reinterpret_cast<float const*>(&rays[g[k]]));
    simd::transpose(rows);
    batch_packet p;
    p.origin = {rows[0], rows[1], rows[2]};
    p.tmin = rows[3];
    p.direction = {rows[4], rows[5], rows[6]};
    p.tmax = rows[7];
    return p;
}

// The 16 rays of a square of 4 × 4 (lane k: ray g[k]) as one packet: its two halves packed as
// pack_group does, then joined member by member.
inline batch_wide_packet pack_wide_group(std::span<ray const> rays, ray_group g) {
    auto const low = pack_group(rays, g);
    auto const high = pack_group(rays, {g.first + batch_group_rows * g.stride, g.stride});
    auto const join = [](simd::float8 a, simd::float8 b) {
        alignas(64) std::array<float, batch_wide_width> lanes;
        a.store(lanes.data());
        b.store(lanes.data() + batch_width);
        return simd::float16::load(lanes.data());
    };
    batch_wide_packet p;
    for (int a = 0; a < 3; ++a) {
        p.origin[a] = join(low.origin[a], high.origin[a]);
        p.direction[a] = join(low.direction[a], high.direction[a]);
    }
    p.tmin = join(low.tmin, high.tmin);
    p.tmax = join(low.tmax, high.tmax);
    return p;
}

// The places of a group's 8 rays, one vector per coordinate: direction x, y, z, then origin x, y,
// z. A ray's place is its direction scaled to 1-norm 1, and its origin times inv_side (1 / the
// scene's largest side, or 0: origins then do not count); not finite for a ray that takes part in
// nothing (a zero, NaN or infinite direction or origin).
inline std::array<simd::float8, 6> group_places(std::span<ray const> rays, ray_group g, float inv_side) {
    auto const p = pack_group(rays, g);
    simd::float8 const inv =
        simd::float8(1.0f) / (simd::abs(p.direction.x) + simd::abs(p.direction.y) + simd::abs(p.direction.z));
    simd::float8 const scale(inv_side);
    return {p.direction.x * inv, p.direction.y * inv, p.direction.z * inv,
            p.origin.x * scale,  p.origin.y * scale,  p.origin.z * scale};
}

// The spread of a group's places: summed over the six coordinates, the largest minus the smallest,
// over the rays whose place is finite (0 when none is).
inline float place_spread(std::array<simd::float8, 6> const& c) {
    simd::float8 const inf(std::numeric_limits<float>::infinity());
    auto finite = simd::abs(c[0]) < inf;
    for (std::size_t a = 1; a < c.size(); ++a) finite = finite & (simd::abs(c[a]) < inf);
    if (simd::none(finite)) return 0.0f;
    float s = 0.0f;
    for (auto const& v : c) s += simd::reduce_max(simd::select(finite, v, -inf)) - simd::reduce_min(simd::select(finite, v, inf));
    return s;
}

// Whether rays laid out in rows of w make tighter groups as squares (batch_group_rows runs of 4,
// w apart) than as runs of 8 consecutive rays: the summed place_spread of 16 sampled squares is at
// most batch_square_gain times that of the runs of 8 that start where they start. A length whose
// first two squares are already looser than their runs is dropped there (most candidates that are
// not rows: a look at 4 groups instead of 32).
inline bool squares_pay(std::span<ray const> rays, std::size_t w, float inv_side) {
    std::size_t const band = batch_group_rows * w, bands = rays.size() / band, columns = w / batch_group_columns;
    if (w < batch_group_columns || bands == 0) return false;
    float squares = 0.0f, runs = 0.0f;
    constexpr std::size_t samples = 16;
    for (std::size_t k = 0; k < samples; ++k) {
        // Spread over the bands and the columns (7919 is prime: the columns differ between samples).
        ray_group const g{k % bands * band + (k * 7919 % columns) * batch_group_columns, w};
        squares += place_spread(group_places(rays, g, inv_side));
        runs += place_spread(group_places(rays, ray_group{g.first}, inv_side));
        if (k == 1 && !(squares < runs)) return false;
    }
    return squares <= batch_square_gain * runs && runs > 0.0f;
}

// The steps from ray i - 1 to ray i for the 8 rays i in [first, first + 8) (first ≥ 1): the 1-norm
// of the difference of their places (group_places; not finite when either place is not).
inline simd::float8 place_steps(std::span<ray const> rays, std::size_t first, float inv_side) {
    auto const here = group_places(rays, ray_group{first}, inv_side);
    auto const before = group_places(rays, ray_group{first - 1}, inv_side);
    simd::float8 d = simd::abs(here[0] - before[0]);
    for (std::size_t c = 1; c < here.size(); ++c) d = d + simd::abs(here[c] - before[c]);
    return d;
}

// The rows' length of rays laid out as an image row by row, or 0 (see the top of this file).
inline std::size_t find_row_length(std::span<ray const> rays, float scene_side) {
    std::size_t const n = rays.size();
    if (n < 2 * batch_width + 1) return 0;
    float const inv_side = scene_side > 0.0f ? 1.0f / scene_side : 0.0f;
    // A typical step from one ray to the next: the median of the first 16 steps.
    std::array<float, 2 * batch_width> first_steps;
    place_steps(rays, 1, inv_side).store(first_steps.data());
    place_steps(rays, 1 + batch_width, inv_side).store(first_steps.data() + batch_width);
    auto const middle = first_steps.begin() + std::ptrdiff_t(batch_width);
    std::nth_element(first_steps.begin(), middle, first_steps.end(),
                     [](float x, float y) { return std::isless(x, y) || (!std::isnan(x) && std::isnan(y)); });
    float const typical = *middle;
    if (!(typical > 0.0f) || !std::isfinite(typical)) return 0;
    // A row ends where a step is over 4 typical steps (a row of w rays ends with a step of about
    // w - 1 of them; steps to or from a ray whose place is not finite do not count). The first end
    // gives the length when the span starts at a row's start; the distance between two ends
    // otherwise. The first batch_row_candidates lengths are tried.
    // Ends are looked for in the first half of the span: a length is of use when a band of 2 rows
    // fits (the first end of rows that start with the span), and the scan is all the cost of a
    // span that holds no rows (shadow rays with holes, random rays: about 12 instructions a ray).
    std::size_t const last = std::min({n - 1, n / 2, 2 * batch_max_row_length});
    std::size_t previous_end = 0, tried = 0, found = 0;
    auto const row_end = [&](std::size_t i) { // true: stop looking
        std::size_t const w = i - previous_end;
        if (w <= batch_max_row_length && squares_pay(rays, w, inv_side)) {
            found = w;
            return true;
        }
        previous_end = i;
        return ++tried == batch_row_candidates;
    };
    simd::float8 const big(4.0f * typical), inf(std::numeric_limits<float>::infinity());
    // The steps to rays [i, i + 8); at the end (last ≥ 8, as n ≥ 17) the steps to rays
    // (last - 7, last] not yet looked at.
    for (std::size_t i = 1; i <= last; i += batch_width) {
        std::size_t const first = std::min(i, last + 1 - batch_width);
        simd::float8 const step = place_steps(rays, first, inv_side);
        std::uint32_t const ends = simd::movemask((step > big) & (step < inf)) >> (i - first) << (i - first);
        for (std::uint32_t bits = ends; bits != 0; bits &= bits - 1)
            if (row_end(first + std::size_t(std::countr_zero(bits)))) return found;
    }
    return 0;
}

// How many groups ahead of the one being traced the batch loop starts loading rays into the
// cache: a group's rays (256 bytes) are read once, and a packet's traversal is long enough that
// the loads of the next ones finish meanwhile.
inline constexpr std::size_t batch_prefetch_groups = 2;

// Starts loading the rays of group g, of `rows` rows of 4, into the cache (nothing past the end
// of the span).
[[gnu::always_inline]] inline void prefetch_group(std::span<ray const> rays, ray_group g, std::size_t rows = batch_group_rows) {
    if (g[rows * batch_group_columns - 1] >= rays.size()) return;
    for (std::size_t r = 0; r < rows; ++r) {
        auto const* p = reinterpret_cast<char const*>(rays.data() + g[r * batch_group_columns]);
        for (std::size_t k = 0; k < batch_group_columns * sizeof(ray); k += 64) __builtin_prefetch(p + k);
        __builtin_prefetch(p + batch_group_columns * sizeof(ray) - 1);
    }
}

// The coherence test of one group of 8 (or 16) rays, packed (see the top of this file), over the
// lanes that take part: at least two, one octant (sign bits: -0 counts as negative), origins
// within spread_limit on each axis.
template <typename T>
bool coherent_group(basic_ray<T> const& p, float spread_limit) {
    std::uint32_t const active = simd::movemask(active_lanes(p));
    if (std::popcount(active) < 2) return false;
    auto const taking_part = simd::mask_type_t<T>::from_bits(active);
    T const inf(std::numeric_limits<float>::infinity());
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

// The batch loop: groups of 8 coherent rays go to packet(group, packet ray) while packets pay
// (always with batch_packing::always), every other ray to single(index). The groups are squares of
// 4 × 2 rays in rays laid out in rows (find_row_length), runs of 8 otherwise (of 16 and 4 × 4 as
// above, where 16-lane vectors are native); whatever is left
// (the columns past the last multiple of 4 in each row, the tail) goes on alone. packet is
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
    std::size_t const n = rays.size();
    std::size_t i = 0;
    if constexpr (batch_takes_packets<I, Elem>()) {
        if (n >= batch_width) {
            float const side = batch_scene_side(first, last);
            float const limit = side * batch_origin_spread;
            packing_policy policy(packing, batch_width);
            auto const group = [&](ray_group g, ray_group ahead) {
                prefetch_group(rays, ahead);
                auto const p = pack_group(rays, g);
                bool const coherent = coherent_group(p, limit);
                if (coherent && policy.packs_next()) {
                    policy.trace_packet([&] { packet(g, p); });
                    ++stats.packets;
                } else {
                    for (std::size_t k = 0; k < batch_width; ++k) one(g[k]);
                    if (coherent) stats.unpacked_rays += batch_width;
                }
            };
            std::size_t const w = find_row_length(rays, side);
            stats.row_length = w;
            std::size_t const columns = w / batch_group_columns * batch_group_columns;
            if constexpr (batch_wide_packets && batch_takes_packets<I, Elem, simd::float16>()) {
                // Squares of 4 × 4 (in rows) or runs of 16 (not in rows) as packets of 16 while
                // they are coherent and pay; the others as two groups of 8, g's lanes 0–7 and
                // 8–15 (the group batch_group_rows strides on: the next 4 × 2 rows, or the next 8
                // rays of a run).
                packing_policy wide_policy(packing, batch_wide_width);
                auto const wide_group = [&](ray_group g) {
                    auto const p = pack_wide_group(rays, g);
                    if (coherent_group(p, limit) && wide_policy.packs_next()) {
                        wide_policy.trace_packet([&] { packet(g, p); });
                        ++stats.wide_packets;
                    } else {
                        group(g, g);
                        group({g.first + batch_group_rows * g.stride, g.stride}, g);
                    }
                };
                std::size_t const band = batch_wide_rows * w;
                for (; w != 0 && i + band <= n; i += band) {
                    for (std::size_t c = 0; c < columns; c += batch_group_columns) {
                        prefetch_group(rays, {i + c + batch_prefetch_groups * batch_group_columns, w}, batch_wide_rows);
                        wide_group({i + c, w});
                    }
                    for (std::size_t r = 0; r < batch_wide_rows; ++r)
                        for (std::size_t c = columns; c < w; ++c) one(i + r * w + c);
                }
                for (; w == 0 && i + batch_wide_width <= n; i += batch_wide_width) {
                    prefetch_group(rays, {i + batch_prefetch_groups * batch_wide_width}, batch_wide_rows);
                    wide_group({i});
                }
            }
            if (w != 0) {
                std::size_t const band = batch_group_rows * w;
                for (; i + band <= n; i += band) {
                    for (std::size_t c = 0; c < columns; c += batch_group_columns)
                        group({i + c, w}, {i + c + batch_prefetch_groups * batch_group_columns, w});
                    for (std::size_t r = 0; r < batch_group_rows; ++r)
                        for (std::size_t c = columns; c < w; ++c) one(i + r * w + c);
                }
            }
            for (; i + batch_width <= n; i += batch_width) group({i}, {i + batch_prefetch_groups * batch_width});
        }
    }
    for (; i < n; ++i) one(i);
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
        [&](detail::ray_group g, auto const& p) {
            auto const hr = closest_hit(p, first, last, isect);
            write_lane_records(hr, out.data() + g.first, g.stride);
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
        [&](detail::ray_group g, auto const& p) {
            auto const hr = any_hit(p, first, last, isect);
            write_lane_records(hr, out.data() + g.first, g.stride);
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
        [&](detail::ray_group g, auto const& p) {
            auto const hr = any_hit(p, first, last, isect);
            for (int k = 0; k < simd::simd_width_v<decltype(hr.t)>; ++k) out[g[std::size_t(k)]] = hr.hit[k];
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
    return {.packets = 0, .single_rays = rays.size()};
}

} // namespace canopy
