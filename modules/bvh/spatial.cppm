// canopy.bvh:spatial — the `high` quality builder of triangle BVHs (build_quality::high): a split
// BVH (Stich, Friedrich, Dietrich 2009, "Spatial Splits in Bounding Volume Hierarchies").
//
// Each node weighs the best binned object split (the bins of canopy.bvh:object) against the best
// binned spatial split: planes at equal intervals across the node's box, each triangle reference
// clipped to the bins it crosses (its box cut to them when it is narrow across the axis:
// chop_reference). A reference that straddles the chosen plane goes to both sides, each copy with
// the box of its triangle's part on that side, unless keeping it whole on one side is cheaper by
// the SAH (Stich et al.'s reference unsplitting). Spatial splits are tried only
// where the two sides of the best object split overlap by more than split_overlap of the root's
// surface area and more than split_node_overlap of the node's (Embree's second test), and where
// cutting those sides apart along the split's axis could shrink one of them by more than
// split_min_gain of its area (trimming_gain: a mesh of small triangles, whose sides overlap only
// by the width of the triangles on the plane, then skips the spatial binning), in nodes of at
// least split_min_references references, and add at
// most split_budget × n references in all: each node's share of the budget goes to its children
// in proportion to their references, so the tree does not depend on how threads are scheduled.
// The references live in one array with room for each subtree's budget (Embree's extended ranges,
// spatial_context); a subtree whose budget is spent is built by canopy.bvh:object's build_node in
// place. Nodes of 4 × parallel_threshold references and more
// bin their spatial splits in parallel (find_spatial_split), with the same bins.
//
// Guarantees:
// - every input triangle is referenced by one leaf or more, never twice by one leaf;
// - leaves store the whole triangle as given, prim_id = its input index, never a clipped piece;
// - a reference's box contains the exact part of its triangle inside the region left by the
//   split planes above it (the clipping is computed in double and rounded outward), so the boxes
//   of a triangle's references cover it. Traversal stays conservative for the watertight test: the
//   box margin of canopy.geometry:box grows every box by the same absolute amount, and a point
//   within that margin of the triangle is within it of the box of the part holding the nearest
//   point of the triangle;
// - triangles with a NaN or infinite coordinate are never split (nodes holding one make object
//   splits only).
// A ray may therefore meet one triangle in several leaves: the queries report it once (the same
// triangle gives the same hit, bit for bit), but a triangle hook or a filter may see it once per
// leaf (see canopy.intersector).
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <bit>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <type_traits>
#include <utility>
#include <vector>
export module canopy.bvh:spatial;
import canopy.geometry;
import :storage;
import :parallel;
import :build_buffer;
import :wide;
import :binning;
import :object;

namespace canopy::detail {

// The primitive types spatial splits apply to.
template <typename Prim>
inline constexpr bool splittable_triangle = std::is_same_v<Prim, basic_triangle<float>> ||
                                            std::is_same_v<Prim, basic_triangle<double>>;

// x rounded to S towards -inf (round_down) or +inf (round_up). The neighbouring float is a step
// of the bit pattern (std::nextafter is a library call, and this runs once per clipped box).
template <typename S>
S next_float(S f, bool up) {
    using bits_type = std::conditional_t<sizeof(S) == 4, std::uint32_t, std::uint64_t>;
    if (std::isnan(f) || f == (up ? std::numeric_limits<S>::infinity() : -std::numeric_limits<S>::infinity())) return f;
    if (f == S(0)) return up ? std::numeric_limits<S>::denorm_min() : -std::numeric_limits<S>::denorm_min();
    auto const b = std::bit_cast<bits_type>(f);
    return std::bit_cast<S>((f > S(0)) == up ? bits_type(b + 1) : bits_type(b - 1));
}
template <typename S>
S round_down(double x) {
    S const f = S(x);
    return double(f) > x ? next_float(f, false) : f;
}
template <typename S>
S round_up(double x) {
    S const f = S(x);
    return double(f) < x ? next_float(f, true) : f;
}

// The boxes of the parts of `tri` on either side of the plane p[axis] = position (closed half
// spaces: a point on the plane belongs to both), each rounded outward and intersected with
// `within` (taken by value: it may be left or right); a side without any part of the triangle gets an empty box. Each part is a polygon
// whose corners are the triangle's vertices on that side and the points where its edges cross the
// plane. A crossing is computed in double with an error below 12 · 2^-53 of the edge's largest
// coordinate; it is widened by 2^-48 of that, clamped to the edge's extent (where the exact
// crossing lies; a NaN from an overflow falls back to it), then rounded outward with the rest.
template <typename S>
void split_box(basic_triangle<S> const& tri, int axis, S position, basic_aabb<S> const within, basic_aabb<S>& left,
               basic_aabb<S>& right) {
    constexpr double inf = std::numeric_limits<double>::infinity();
    vec3<S> const v[3] = {tri.v0, tri.v1, tri.v2};
    // low / high per side (0 left, 1 right) and coordinate, in double.
    double low[2][3] = {{inf, inf, inf}, {inf, inf, inf}}, high[2][3] = {{-inf, -inf, -inf}, {-inf, -inf, -inf}};
    auto const take = [&](int side, int c, double a, double b) {
        auto const s = std::size_t(side), k = std::size_t(c);
        low[s][k] = std::min(low[s][k], a);
        high[s][k] = std::max(high[s][k], b);
    };
    for (int i = 0; i < 3; ++i) {
        vec3<S> const& p = v[i];
        vec3<S> const& q = v[(i + 1) % 3];
        for (int side = 0; side < 2; ++side)
            if (side == 0 ? p[axis] <= position : p[axis] >= position)
                for (int c = 0; c < 3; ++c) take(side, c, double(p[c]), double(p[c]));
        if (!((p[axis] < position && position < q[axis]) || (q[axis] < position && position < p[axis]))) continue;
        double const f = (double(position) - double(p[axis])) / (double(q[axis]) - double(p[axis]));
        for (int c = 0; c < 3; ++c) {
            double a = double(position), b = a;
            if (c != axis) {
                double const pc = double(p[c]), qc = double(q[c]);
                double const x = pc + (qc - pc) * f;
                double const margin = std::max(std::fabs(pc), std::fabs(qc)) * 0x1p-48;
                a = x - margin > std::min(pc, qc) ? x - margin : std::min(pc, qc);
                b = x + margin < std::max(pc, qc) ? x + margin : std::max(pc, qc);
            }
            take(0, c, a, b);
            take(1, c, a, b);
        }
    }
    for (int side = 0; side < 2; ++side) {
        auto const s = std::size_t(side);
        basic_aabb<S>& box = side == 0 ? left : right;
        box = {};
        for (int c = 0; c < 3; ++c) {
            auto const k = std::size_t(c);
            S const lo = std::max(round_down<S>(low[s][k]), within.min[c]);
            S const hi = std::min(round_up<S>(high[s][k]), within.max[c]);
            if (!(lo <= hi)) {
                box = {};
                break;
            }
            box.min[c] = lo;
            box.max[c] = hi;
        }
    }
}

// The references live in one array, ctx.object.refs (prim_ref: a box, the whole triangle's or a
// part's, and the input index), with slack for the duplicates (Embree's extended ranges): a node
// whose subtree may add `budget` references owns `count + budget` entries from its first, its
// references at the start. Its children split that range: each gets its references and its share
// of the rest of the budget.
template <typename Prim>
struct spatial_context {
    using S = typename Prim::value_type;
    std::span<Prim const> prims;
    build_context<S> object; // the references, nodes, node and depth counters, options
    double min_overlap = 0.0;      // split_overlap × the root's surface area
    double node_overlap = 0.0;     // split_node_overlap
    double min_gain = 0.0;         // split_min_gain
};

// bin_spatial's vector scratch for `bins` spatial bins per axis: the three axes' bins of the
// references' first parts, then those of their last parts.
constexpr std::size_t spatial_vector_bin_count(int bins) { return 6 * std::size_t(bins); }

// Per-task working memory: the object bins, the spatial bins of the three axes (boxes, references
// entering and leaving each bin, axis a at a · bins), their planes (axis a at a · (bins + 1)) and the sweep's right sides, and the two sides of a spatial
// partition.
template <typename S>
struct spatial_scratch {
    explicit spatial_scratch(int bins)
        : object(bins), boxes(3 * std::size_t(bins)), enter(3 * std::size_t(bins)), exit(3 * std::size_t(bins)),
          planes(3 * (std::size_t(bins) + 1)), right_boxes(std::size_t(bins)), right_counts(std::size_t(bins)),
          parts(std::size_t(bins)), vector_boxes(spatial_vector_bin_count(bins)) {}
    bin_scratch<S> object;
    std::vector<basic_aabb<S>> boxes;
    std::vector<std::size_t> enter, exit;
    std::vector<S> planes;
    std::vector<basic_aabb<S>> right_boxes;
    std::vector<std::size_t> right_counts;
    std::vector<basic_aabb<S>> parts; // one reference's parts, bin by bin (bin_reference_parts)
    std::vector<vector_bin> vector_boxes; // the three axes' bins' boxes with vector_binning, twice (bin_spatial)
    // The two sides of a partition (build_buffer: large ones in huge pages, kept by
    // canopy.bvh:block_cache from one build to the next; why: at the reserve in build_spatial_node).
    build_buffer<prim_ref<S>> left, right;
};

// The best spatial split: references left of `position` go left, right of it right, those that
// straddle it both ways. left_count / right_count / left_box / right_box are the binned estimates.
template <typename S>
struct spatial_choice {
    double cost = std::numeric_limits<double>::infinity();
    int axis = -1;
    S position = S(0);
    std::size_t left_count = 0, right_count = 0;
    basic_aabb<S> left_box, right_box;
};

} // namespace canopy::detail

// The spatial binning of one reference, exported for the tests that compare its two forms.
export namespace canopy::detail {

// A float's rank in the order of the floats, as an unsigned integer, and the float of a rank: the
// steps of place_spatial_planes' search (-0 and +0 are neighbours).
template <typename S>
auto float_rank(S x) {
    using U = std::conditional_t<sizeof(S) == 4, std::uint32_t, std::uint64_t>;
    U const u = std::bit_cast<U>(x), sign = U(1) << (8 * sizeof(S) - 1);
    return (u & sign) ? U(~u) : U(u | sign);
}
template <typename S, typename U>
S float_of_rank(U rank) {
    U const sign = U(1) << (8 * sizeof(S) - 1);
    return std::bit_cast<S>((rank & sign) ? U(rank & ~sign) : U(~rank));
}

// The bins + 1 planes of spatial bins that split [lo, hi] (lo < hi) into equal parts, and the
// scale that maps a coordinate to its bin: bin_index(x, lo, scale, bins), exactly. Each inner
// plane k is the least float whose bin_index is k or more (bin_index is monotonic), searched from
// the equal interval's value by steps doubling in rank, then bisection: one or two evaluations
// mostly, at most twice the float's bits. A coordinate's bin among the planes (plane_bin) is then
// one subtraction, one multiply and a clamp, in vectors too (bin_spatial). Returns 0 (no planes:
// the axis makes no spatial split) where the scale is not finite and positive: a width that
// overflows, or one too small for its reciprocal.
template <typename S>
S place_spatial_planes(S lo, S hi, int bins, S* planes) {
    auto const b = std::size_t(bins);
    S const scale = S(bins) / (hi - lo);
    if (!(scale > S(0) && scale < std::numeric_limits<S>::infinity())) return S(0);
    planes[0] = lo;
    planes[b] = hi;
    auto const below = [&](auto rank, int k) { return bin_index(float_of_rank<S>(rank), lo, scale, bins) < k; };
    auto const lowest = float_rank(lo), highest = float_rank(hi);
    for (std::size_t k = 1; k < b; ++k) {
        // Ranks a < c with bin_index(a) < k ≤ bin_index(c) (lo's bin is 0, hi's is bins - 1).
        S const even = std::clamp(S(double(lo) + (double(hi) - double(lo)) * double(k) / double(bins)), lo, hi);
        auto a = float_rank(even), c = a;
        decltype(a) step = 1;
        if (below(a, int(k))) {
            do {
                a = c;
                c = highest - a > step ? a + step : highest;
                step *= 2;
            } while (below(c, int(k)));
        } else {
            do {
                c = a;
                a = a - lowest > step ? c - step : lowest;
                step *= 2;
            } while (!below(a, int(k)));
        }
        while (c - a > 1) {
            auto const m = a + (c - a) / 2;
            (below(m, int(k)) ? a : c) = m;
        }
        planes[k] = float_of_rank<S>(c);
    }
    return scale;
}

// The bin k of x among the planes of place_spatial_planes (planes[k] ≤ x < planes[k + 1];
// clamped to [0, bins)): bin_index, which those planes follow exactly.
template <typename S>
int plane_bin(S x, S const* planes, int bins, S scale) {
    return bin_index(x, planes[0], scale, bins);
}

// Adds to boxes[first..last] the parts of one reference that spans those bins along `axis`: bin k
// gets the bounds of the triangle's part between planes k and k + 1 (its vertices there and the
// points where its edges cross those planes), clipped to the reference's box. Each crossing point
// is computed once, for the two bins it bounds, in S: an estimate for the sweep (the references a
// chosen split duplicates are clipped exactly, split_box), and a tighter one than clipping
// the reference bin after bin, which bounds each part by two half-planes' boxes.
template <typename S>
void bin_reference_parts(basic_triangle<S> const& tri, basic_aabb<S> const& box, int axis, S const* planes, int bins,
                         S scale, int first, int last, basic_aabb<S>* boxes, basic_aabb<S>* parts) {
    for (int k = first; k <= last; ++k) parts[k] = {};
    vec3<S> const v[3] = {tri.v0, tri.v1, tri.v2};
    int vertex_bin[3]; // each vertex's bin, found once for the vertex and the edges from it
    for (int i = 0; i < 3; ++i) {
        vertex_bin[i] = plane_bin(v[i][axis], planes, bins, scale);
        int const k = std::clamp(vertex_bin[i], first, last);
        parts[k] = extend(parts[k], v[i]);
    }
    for (int i = 0; i < 3; ++i) {
        int lower = i, upper = (i + 1) % 3;
        if (v[upper][axis] < v[lower][axis]) std::swap(lower, upper);
        vec3<S> const& p = v[lower];
        vec3<S> const& q = v[upper];
        if (!(p[axis] < q[axis])) continue; // in one plane across the axis: its vertices bound it
        S const run = q[axis] - p[axis];
        vec3<S> const d = q - p;
        for (int k = std::max(first, vertex_bin[lower]); k < last; ++k) {
            S const plane = planes[k + 1];
            if (!(plane < q[axis])) break;
            if (!(plane > p[axis])) continue;
            vec3<S> x = p + d * ((plane - p[axis]) / run);
            x[axis] = plane;
            parts[k] = extend(parts[k], x);
            parts[k + 1] = extend(parts[k + 1], x);
        }
    }
    for (int k = first; k <= last; ++k) {
        basic_aabb<S> const part = intersection(parts[k], box);
        if (!is_empty(part)) boxes[k] = extend(boxes[k], part);
    }
}

// bin_reference_parts with vector_binning, the same boxes bit for bit, in one sweep along the
// axis: a point or box in the lanes of one vector (lane 3 ignored), extend and intersection as
// canopy.math's lane by lane, the crossing p + d · t of an edge from its lower end. With the
// vertices sorted along the axis (lo, mid, hi), the edges a plane crosses strictly are the long
// edge lo–hi and one of lo–mid and mid–hi; bin k gets the crossings on its two planes (they are
// shared with its neighbours: computed once) and the vertices whose bin, clamped to
// [first, last], is k.
inline void bin_reference_parts_vector(basic_triangle<float> const& tri, vector_bin const& box, int axis,
                                       float const* planes, int bins, float scale, int first, int last,
                                       vector_bin* boxes) {
    using simd::float4;
    float const inf = std::numeric_limits<float>::infinity();
    float4 const lanes[3] = {to_lanes(tri.v0), to_lanes(tri.v1), to_lanes(tri.v2)};
    float const coord[3] = {tri.v0[axis], tri.v1[axis], tri.v2[axis]};
    int lo = 0, mid = 1, hi = 2;
    if (coord[mid] < coord[lo]) std::swap(lo, mid);
    if (coord[hi] < coord[mid]) std::swap(mid, hi);
    if (coord[mid] < coord[lo]) std::swap(lo, mid);
    float const lo_a = coord[lo], mid_a = coord[mid], hi_a = coord[hi];
    float4 const p_lo = lanes[lo], p_mid = lanes[mid], p_hi = lanes[hi];
    float4 const d_long = p_hi - p_lo, d_low = p_mid - p_lo, d_high = p_hi - p_mid;
    auto const on_axis = float4::iota() == float4(float(axis));
    auto const extend_by = [](vector_bin& b, float4 const& x) {
        b.lo = simd::min(x, b.lo);
        b.hi = simd::max(x, b.hi);
    };
    // Where the edge from p (coordinate p_a along the axis) by d (to q_a) meets the plane.
    auto const crossing = [&](float plane, float4 const& p, float4 const& d, float p_a, float q_a) {
        return simd::select(on_axis, float4(plane), p + d * float4((plane - p_a) / (q_a - p_a)));
    };
    // The points where the triangle's edges cross `plane` strictly: the long edge, and one of the
    // two short ones.
    auto const crossings_on = [&](float plane) {
        vector_bin c{float4(inf), float4(-inf)};
        if (plane > lo_a && plane < hi_a) extend_by(c, crossing(plane, p_lo, d_long, lo_a, hi_a));
        if (plane > lo_a && plane < mid_a) extend_by(c, crossing(plane, p_lo, d_low, lo_a, mid_a));
        else if (plane > mid_a && plane < hi_a) extend_by(c, crossing(plane, p_mid, d_high, mid_a, hi_a));
        return c;
    };
    // Bin k's part clipped to the reference's box, into bin k.
    auto const add_part = [&](int k, vector_bin const& part) {
        float4 const clipped_lo = simd::max(part.lo, box.lo), clipped_hi = simd::min(part.hi, box.hi);
        if ((simd::movemask(clipped_lo > clipped_hi) & 7u) == 0) {
            boxes[k].lo = simd::min(clipped_lo, boxes[k].lo);
            boxes[k].hi = simd::max(clipped_hi, boxes[k].hi);
        }
    };
    if (last == first + 1) {
        // Two bins (most references that straddle a plane): the loop below with its one plane,
        // the same operations in the same order. There a vertex falls in bin last exactly when
        // its coordinate is at least planes[last]: plane_bin is monotonic, and ref_lo <
        // planes[last] ≤ ref_hi.
        float const plane = planes[last];
        bool const lo_last = !(lo_a < plane), mid_last = !(mid_a < plane), hi_last = !(hi_a < plane);
        vector_bin part{float4(inf), float4(-inf)};
        if (!lo_last) extend_by(part, p_lo);
        if (!mid_last) extend_by(part, p_mid);
        if (!hi_last) extend_by(part, p_hi);
        vector_bin next = crossings_on(plane);
        part.lo = simd::min(next.lo, part.lo);
        part.hi = simd::max(next.hi, part.hi);
        add_part(first, part);
        if (lo_last) extend_by(next, p_lo);
        if (mid_last) extend_by(next, p_mid);
        if (hi_last) extend_by(next, p_hi);
        add_part(last, next);
        return;
    }
    // A vertex at or below the reference's lowest coordinate (first = its bin) falls in bin first
    // or below, one at or above its highest in bin last or above (plane_bin is monotonic): the
    // search only for the others.
    float const ref_lo = box.lo[axis], ref_hi = box.hi[axis];
    auto const vertex_bin = [&](float x) {
        if (x <= ref_lo) return first;
        if (x >= ref_hi) return last;
        return std::clamp(plane_bin(x, planes, bins, scale), first, last);
    };
    int const lo_bin = vertex_bin(lo_a), mid_bin = vertex_bin(mid_a), hi_bin = vertex_bin(hi_a);
    vector_bin part{float4(inf), float4(-inf)}; // bin k's points so far: the crossings on plane k
    for (int k = first; k <= last; ++k) {
        if (k == lo_bin) extend_by(part, p_lo);
        if (k == mid_bin) extend_by(part, p_mid);
        if (k == hi_bin) extend_by(part, p_hi);
        vector_bin next{float4(inf), float4(-inf)}; // the crossings on plane k + 1
        if (k < last) {
            next = crossings_on(planes[k + 1]);
            part.lo = simd::min(next.lo, part.lo);
            part.hi = simd::max(next.hi, part.hi);
        }
        add_part(k, part);
        part = next;
    }
}

// The last bin of a reference whose first bin is `first` and whose highest coordinate is hi. A
// reference's box has lo ≤ hi and plane_bin is monotonic, so the max changes nothing for one; it
// is one instruction that keeps a box that broke that rule from walking its bins backwards.
// bin_spatial's vector path takes the same max in lanes.
template <typename S>
int last_plane_bin(S hi, int first, S const* planes, int bins, S scale) {
    return std::max(first, plane_bin(hi, planes, bins, scale));
}

} // namespace canopy::detail

namespace canopy::detail {

// Chopped binning (Fuetterling, Lojewski, Pfreundt, Ebert 2016, "Parallel Spatial Splits in
// Bounding Volume Hierarchies"): a reference whose box is at most chopped_extent_in_bins of the
// node's spatial bins wide along each of the two other axes adds to each spatial bin it crosses its
// box cut to the bin's slab; any other adds its triangle's part clipped to the slab
// (bin_reference_parts). A cut box holds the clipped part and differs from it only across the
// axis, by less than the reference's width there: for a reference narrow against the node the
// sweep's estimate barely moves, and the cut costs a fraction of the clipping. A long diagonal
// sliver is wide across the axis too, and its cut boxes are much larger than its parts: clipping
// them is what lets the SAH separate slivers. The chosen plane always clips exactly
// (partition_spatial), so no guarantee depends on this. Measured (docs/performance.md, Run 30):
// 4 leaves the sliver scene's tree bit for bit (8 raises its SAH by 1 %, chopping every reference
// by 15 %, and its rays then run 10–25 % slower) and lowers the engine's and the forest tree's
// SAH, with their builds a quarter faster.
inline constexpr double chopped_extent_in_bins = 4.0;

// The axes along which a reference is narrow enough to be chopped across (bit a: its box's width
// along a is at most chop_extent[a], the widest reference box chopped, chopped_extent_in_bins of
// the node's bins). bin_spatial's vector path computes the same bits in lanes.
template <typename S>
unsigned narrow_axes(prim_ref<S> const& r, vec3<S> const& chop_extent) {
    unsigned bits = 0;
    for (int a = 0; a < 3; ++a) bits |= unsigned(r.hi[a] - r.lo[a] <= chop_extent[a]) << a;
    return bits;
}

// Whether a reference narrow along the axes `narrow` (narrow_axes) is binned by its chopped box
// along `axis`: it is narrow along both other axes.
constexpr bool chop_reference(unsigned narrow, int axis) {
    unsigned const others = 7u & ~(1u << axis);
    return (narrow & others) == others;
}

// A node's spatial planes on its three axes: axis a's bins + 1 planes at planes + a · (bins + 1)
// and their scale (place_spatial_planes), whether the node's box has a width along it to split
// (usable), and the widest reference box chopped across it (chop_reference).
template <typename S>
struct spatial_axes {
    S const* planes = nullptr;
    int bins = 0;
    bool usable[3] = {};
    S scale[3] = {};
    vec3<S> chop_extent;
};

// Adds the spatial bins of refs along the usable axes to boxes, enter and exit (axis a's at
// a · bins): each bin's box grows by the parts of the references in it, enter / exit count the
// references whose first / last bin it is (chop_reference: by its box cut to each bin's slab, or
// by its triangle's clipped parts). One pass over the references bins all three axes: each is
// loaded once, and the axes' independent work overlaps. vector_boxes: spatial_vector_bin_count
// entries of scratch, parts: bins.
template <typename Prim, typename S>
void bin_spatial(spatial_context<Prim> const& ctx, std::span<prim_ref<S> const> refs, spatial_axes<S> const& axes,
                 basic_aabb<S>* boxes, std::size_t* enter, std::size_t* exit, vector_bin* vector_boxes,
                 basic_aabb<S>* parts) {
    int const bins = axes.bins;
    auto const b = std::size_t(bins);
    if constexpr (vector_binning<S>) {
        using simd::float4;
        float const inf = std::numeric_limits<float>::infinity();
        // A reference's first bin on each axis takes its part there (and any middle bins theirs)
        // in vector_boxes[0, 3 · bins), its last bin its part there in vector_boxes[3 · bins,
        // 6 · bins): both without a branch on whether they are the same bin (then both take the
        // whole box), merged after the pass. Only the references clipped to their triangle
        // (chop_reference) take a branch.
        for (std::size_t k = 0; k < spatial_vector_bin_count(bins); ++k) vector_boxes[k] = {float4(inf), float4(-inf)};
        // plane_bin of the three axes in lanes: the same subtraction, multiply and clamp.
        vector_bin_index const bins_of(
            to_lanes(vec3<float>(axes.planes[0], axes.planes[b + 1], axes.planes[2 * (b + 1)])),
            to_lanes(vec3<float>(axes.scale[0], axes.scale[1], axes.scale[2])), bins);
        // narrow_axes in lanes: lane a of the box's width within chop_extent.
        float4 const chop_extent(to_lanes(axes.chop_extent));
        auto const bin_axis = [&]<int axis>(prim_ref<S> const& r, vector_bin const& box, int first, int last,
                                            unsigned narrow) {
            S const* const planes = axes.planes + std::size_t(axis) * (b + 1);
            std::size_t const at = std::size_t(axis) * b;
            ++enter[at + std::size_t(first)];
            ++exit[at + std::size_t(last)];
            vector_bin* const axis_boxes = vector_boxes + at;
            auto const on_axis = float4::iota() == float4(float(axis));
            if (first == last || chop_reference(narrow, axis)) {
                // The parts in the first and the last bin: the box cut at the planes between.
                bool const spans = last > first;
                float const first_hi = spans ? planes[first + 1] : r.hi[axis];
                float const last_lo = spans ? planes[last] : r.lo[axis];
                grow_bin(axis_boxes[first], box.lo, simd::select(on_axis, float4(first_hi), box.hi));
                grow_bin(axis_boxes[3 * b + std::size_t(last)], simd::select(on_axis, float4(last_lo), box.lo), box.hi);
                for (int k = first + 1; k < last; ++k)
                    grow_bin(axis_boxes[k], simd::select(on_axis, float4(planes[k]), box.lo),
                             simd::select(on_axis, float4(planes[k + 1]), box.hi));
            } else {
                bin_reference_parts_vector(ctx.prims[r.index], box, axis, planes, bins, axes.scale[axis], first, last,
                                           axis_boxes);
            }
        };
        bool const all_usable = axes.usable[0] && axes.usable[1] && axes.usable[2];
        constexpr std::size_t prefetch_distance = 8;
        alignas(16) std::int32_t firsts[4], lasts[4];
        std::size_t const n = refs.size();
        for (std::size_t i = 0; i < n; ++i) {
            prim_ref<S> const& r = refs[i];
            // The triangle of a reference ahead, in case it is clipped: references reach their
            // triangles in no particular order, and a mesh's triangles outgrow the caches
            // nearest the core.
            if (i + prefetch_distance < n) __builtin_prefetch(&ctx.prims[refs[i + prefetch_distance].index]);
            // Lane 3 holds the index or the padding: taken only by min, max and select, or zeroed.
            vector_bin const box{float4::load(&r.lo.x), float4::load(&r.hi.x)};
            float4 const lo = vector_bin_index::xyz_only(box.lo), hi = vector_bin_index::xyz_only(box.hi);
            simd::int4 const first_bins = bins_of(lo);
            first_bins.store_aligned(firsts);
            simd::max(first_bins, bins_of(hi)).store_aligned(lasts); // last_plane_bin
            unsigned const narrow = simd::movemask(hi - lo <= chop_extent) & 7u; // narrow_axes
            auto const bin_axes = [&]<int axis>() {
                if (all_usable || axes.usable[axis])
                    bin_axis.template operator()<axis>(r, box, firsts[axis], lasts[axis], narrow);
            };
            bin_axes.template operator()<0>();
            bin_axes.template operator()<1>();
            bin_axes.template operator()<2>();
        }
        for (std::size_t k = 0; k < 3 * b; ++k) {
            vector_bin const& first_parts = vector_boxes[k];
            vector_bin const& last_parts = vector_boxes[3 * b + k];
            boxes[k] = extend(boxes[k], basic_aabb<S>{from_lanes(simd::min(first_parts.lo, last_parts.lo)),
                                                      from_lanes(simd::max(first_parts.hi, last_parts.hi))});
        }
    } else {
        (void)vector_boxes;
        for (auto const& r : refs) {
            unsigned const narrow = narrow_axes(r, axes.chop_extent);
            for (int axis = 0; axis < 3; ++axis) {
                if (!axes.usable[axis]) continue;
                S const* const planes = axes.planes + std::size_t(axis) * (b + 1);
                std::size_t const at = std::size_t(axis) * b;
                basic_aabb<S>* const axis_boxes = boxes + at;
                int const first = plane_bin(r.lo[axis], planes, bins, axes.scale[axis]);
                int const last = last_plane_bin(r.hi[axis], first, planes, bins, axes.scale[axis]);
                ++enter[at + std::size_t(first)];
                ++exit[at + std::size_t(last)];
                if (first == last) {
                    axis_boxes[first] = extend(axis_boxes[first], r.box());
                } else if (chop_reference(narrow, axis)) {
                    for (int k = first; k <= last; ++k) {
                        basic_aabb<S> part = r.box();
                        if (k > first) part.min[axis] = planes[k];
                        if (k < last) part.max[axis] = planes[k + 1];
                        axis_boxes[k] = extend(axis_boxes[k], part);
                    }
                } else {
                    bin_reference_parts(ctx.prims[r.index], r.box(), axis, planes, bins, axes.scale[axis], first, last,
                                        axis_boxes, parts);
                }
            }
        }
    }
}

// The cheapest spatial split of refs (bounded by `bounds`) over `bins` bins per axis, chopping
// the references at most chopped_extent_in_bins of `chop_bins` bins of the node wide (the width
// chop_reference allows does not grow where a node bins coarsely, spatial_bins). Nodes of
// canopy.bvh:binning's bins_in_parallel bin in parallel: the three axes of each fixed chunk
// (bin_chunk), merged in chunk order. Boxes merge by min and max and counts
// by sums, so the bins, and the tree, are the same however the chunks are scheduled.
template <typename Prim, typename S>
spatial_choice<S> find_spatial_split(spatial_context<Prim> const& ctx, spatial_scratch<S>& scratch,
                                     std::span<prim_ref<S> const> refs, basic_aabb<S> const& bounds, int bins,
                                     int chop_bins) {
    auto const b = std::size_t(bins);
    spatial_axes<S> axes;
    axes.planes = scratch.planes.data();
    axes.bins = bins;
    bool const* const usable = axes.usable;
    for (int axis = 0; axis < 3; ++axis) {
        S const lo = bounds.min[axis], hi = bounds.max[axis];
        axes.chop_extent[axis] = S(double(hi - lo) / double(chop_bins) * chopped_extent_in_bins);
        scratch.planes[std::size_t(axis) * (b + 1)] = lo; // the vector bins' origin, of unused axes too
        if (!(hi > lo)) continue;
        axes.scale[axis] = place_spatial_planes(lo, hi, bins, scratch.planes.data() + std::size_t(axis) * (b + 1));
        axes.usable[axis] = axes.scale[axis] > S(0);
    }
    std::fill(scratch.boxes.begin(), scratch.boxes.end(), basic_aabb<S>{});
    std::fill(scratch.enter.begin(), scratch.enter.end(), std::size_t(0));
    std::fill(scratch.exit.begin(), scratch.exit.end(), std::size_t(0));
    std::size_t const threshold = ctx.object.options.parallel_threshold;
    std::size_t const chunk = bin_chunk(threshold, refs.size());
    if (!bins_in_parallel(threshold, refs.size())) {
        bin_spatial(ctx, refs, axes, scratch.boxes.data(), scratch.enter.data(), scratch.exit.data(),
                    scratch.vector_boxes.data(), scratch.parts.data());
    } else {
        std::size_t const chunks = (refs.size() + chunk - 1) / chunk;
        std::vector<basic_aabb<S>> boxes(chunks * 3 * b);
        std::vector<std::size_t> enter(chunks * 3 * b), exit(chunks * 3 * b);
        parallel_for_chunks(chunks, 1, [&](std::size_t first, std::size_t last) {
            std::vector<vector_bin> vector_boxes(spatial_vector_bin_count(bins));
            std::vector<basic_aabb<S>> parts(b);
            for (std::size_t c = first; c < last; ++c) {
                std::size_t const begin = c * chunk, at = c * 3 * b;
                bin_spatial(ctx, refs.subspan(begin, std::min(chunk, refs.size() - begin)), axes, boxes.data() + at,
                            enter.data() + at, exit.data() + at, vector_boxes.data(), parts.data());
            }
        });
        for (std::size_t c = 0; c < chunks; ++c)
            for (std::size_t k = 0; k < 3 * b; ++k) {
                std::size_t const from = c * 3 * b + k;
                scratch.boxes[k] = extend(scratch.boxes[k], boxes[from]);
                scratch.enter[k] += enter[from];
                scratch.exit[k] += exit[from];
            }
    }

    spatial_choice<S> best;
    for (int axis = 0; axis < 3; ++axis) {
        if (!usable[axis]) continue;
        S const lo = bounds.min[axis], hi = bounds.max[axis];
        S const* const planes = scratch.planes.data() + std::size_t(axis) * (b + 1);
        basic_aabb<S> const* const boxes = scratch.boxes.data() + std::size_t(axis) * b;
        std::size_t const* const enter = scratch.enter.data() + std::size_t(axis) * b;
        std::size_t const* const exit = scratch.exit.data() + std::size_t(axis) * b;
        // From the right: the references leaving bins ≥ k; then from the left: those entering
        // bins < k. Plane k splits there.
        basic_aabb<S> acc;
        std::size_t n = 0;
        for (std::size_t k = b - 1; k > 0; --k) {
            acc = extend(acc, boxes[k]);
            n += exit[k];
            scratch.right_boxes[k] = acc;
            scratch.right_counts[k] = n;
        }
        acc = basic_aabb<S>{};
        n = 0;
        for (std::size_t k = 1; k < b; ++k) {
            acc = extend(acc, boxes[k - 1]);
            n += enter[k - 1];
            std::size_t const right = scratch.right_counts[k];
            if (n == 0 || right == 0 || !(planes[k] > lo && planes[k] < hi)) continue;
            double const cost = double(surface_area(acc)) * leaf_tests(n, ctx.object.block_size) +
                                double(surface_area(scratch.right_boxes[k])) * leaf_tests(right, ctx.object.block_size);
            if (cost < best.cost)
                best = {cost, axis, planes[k], n, right, acc, scratch.right_boxes[k]};
        }
    }
    return best;
}

// Copies refs to the two sides of plane `split.position`, clipping the references that straddle
// it (at most `budget` of them are duplicated). Returns the number of duplicates.
template <typename Prim, typename S>
std::size_t partition_spatial(spatial_context<Prim> const& ctx, std::span<prim_ref<S> const> refs,
                              spatial_choice<S> const& split, std::size_t budget, build_buffer<prim_ref<S>>& left,
                              build_buffer<prim_ref<S>>& right) {
    int const axis = split.axis;
    S const position = split.position;
    // The unsplitting test counts references one by one, as Stich et al. do.
    double const left_area = double(surface_area(split.left_box)), right_area = double(surface_area(split.right_box));
    double left_count = double(split.left_count), right_count = double(split.right_count);
    std::size_t duplicates = 0;
    for (auto const& r : refs) {
        if (r.hi[axis] <= position) {
            left.push_back(r);
            continue;
        }
        if (r.lo[axis] >= position) {
            right.push_back(r);
            continue;
        }
        basic_aabb<S> left_part, right_part;
        split_box(ctx.prims[r.index], axis, position, r.box(), left_part, right_part);
        if (is_empty(left_part)) {
            right.push_back({right_part.min, r.index, right_part.max});
            continue;
        }
        if (is_empty(right_part)) {
            left.push_back({left_part.min, r.index, left_part.max});
            continue;
        }
        double const both = left_area * left_count + right_area * right_count;
        double const all_left = double(surface_area(extend(split.left_box, r.box()))) * left_count +
                                right_area * (right_count - 1.0);
        double const all_right = left_area * (left_count - 1.0) +
                                 double(surface_area(extend(split.right_box, r.box()))) * right_count;
        if (duplicates < budget && both <= all_left && both <= all_right) {
            left.push_back({left_part.min, r.index, left_part.max});
            right.push_back({right_part.min, r.index, right_part.max});
            ++duplicates;
        } else if (all_left <= all_right) {
            left.push_back(r);
            right_count -= 1.0;
        } else {
            right.push_back(r);
            left_count -= 1.0;
        }
    }
    return duplicates;
}

// How much cutting the object split's two sides apart along its axis could shrink them: the
// larger of the two sides' relative loss of surface area when each is clipped where the other
// begins. A spatial split along that axis lowers the SAH of the object split by at most that
// fraction (it clips the same sides and never lowers their counts).
template <typename S>
double trimming_gain(basic_aabb<S> const& left, basic_aabb<S> const& right, int axis) {
    auto const gain = [&](basic_aabb<S> box, bool is_left) {
        double const area = double(surface_area(box));
        if (!(area > 0.0)) return 0.0;
        if (is_left)
            box.max[axis] = std::max(right.min[axis], box.min[axis]);
        else
            box.min[axis] = std::min(left.max[axis], box.max[axis]);
        return 1.0 - double(surface_area(box)) / area;
    };
    return std::max(gain(left, true), gain(right, false));
}

// Adds to range the bounds of refs and of their doubled centres; whether every coordinate of
// refs is finite (a node holding any other makes object splits only). With vector_binning, in
// vectors, the same bounds as canopy.math's extend lane by lane: lane 3 of a reference's first row
// (its index, whose bits are a denormal) is taken only by minima, maxima and comparisons, and
// zeroed before the centre's sum.
template <typename S>
bool spatial_range(std::span<prim_ref<S> const> refs, range_bounds<S>& range) {
    if constexpr (vector_binning<S>) {
        using simd::float4;
        float const inf = std::numeric_limits<float>::infinity();
        vector_bin bounds{to_lanes(range.bounds.min), to_lanes(range.bounds.max)};
        vector_bin centroids{to_lanes(range.centroids.min), to_lanes(range.centroids.max)};
        auto const xyz = float4::iota() < float4(3.0f);
        auto finite = xyz;
        for (auto const& r : refs) {
            float4 const lo = float4::load(&r.lo.x), hi = float4::load(&r.hi.x);
            bounds.lo = simd::min(lo, bounds.lo);
            bounds.hi = simd::max(hi, bounds.hi);
            float4 const center = vector_bin_index::doubled_center(lo, hi);
            centroids.lo = simd::min(center, centroids.lo);
            centroids.hi = simd::max(center, centroids.hi);
            finite = finite & (simd::abs(lo) < float4(inf)) & (simd::abs(hi) < float4(inf));
        }
        range.bounds = {from_lanes(bounds.lo), from_lanes(bounds.hi)};
        range.centroids = {from_lanes(centroids.lo), from_lanes(centroids.hi)};
        return (simd::movemask(finite) & 7u) == 7u;
    } else {
        bool finite = true;
        for (auto const& r : refs) {
            range.bounds = extend(range.bounds, r.box());
            range.centroids = extend(range.centroids, r.doubled_center());
            for (int c = 0; c < 3; ++c) finite = finite && std::isfinite(r.lo[c]) && std::isfinite(r.hi[c]);
        }
        return finite;
    }
}

// The spatial bins per axis of a node of `count` references: the object bins, halved (at least 2)
// in nodes of fewer than coarse_spatial_references. A reference spans a larger share of a small
// node, so it crosses more of its bins and most of the spatial search's time is spent there
// (clipping it into each), while a finer plane placement gains a small node little SAH. The
// chopping width stays that of the object bins (find_spatial_split): chopping by the coarse bins'
// width left bvh_test's soup of 1,500 random needles 54 split references, under its bound of 75
// (the needles were chopped instead of clipped, and their splits not found). Measured (docs/performance.md, Run 31):
// the engine's and the forest tree's builds about 10 % faster, SAH within 0.1 % (the sliver
// scene's within 1e-7), the box and triangle tests per ray within 1.3 %.
inline constexpr std::size_t coarse_spatial_references = 1024;
inline int spatial_bins(int bins, std::size_t count) {
    return count < coarse_spatial_references ? std::max(bins / 2, 2) : bins;
}

// Builds the subtree of the `count` references at refs[begin] into nodes[node_index], adding at
// most `budget` references (the slack after them). Where the budget is spent, the rest of the
// subtree is canopy.bvh:object's (build_node, the same object splits, in place).
template <typename Prim, typename S>
void build_spatial_node(spatial_context<Prim>& ctx, spatial_scratch<S>& scratch, std::uint32_t node_index,
                        std::size_t begin, std::size_t count, int depth, std::size_t budget) {
    auto& object = ctx.object;
    auto& nodes = *object.nodes;
    auto const& opt = object.options;
    std::span<prim_ref<S> const> const refs(object.refs.data() + begin, count);
    range_bounds<S> range;
    bool const finite = spatial_range(refs, range);
    if (budget == 0) return build_node(object, scratch.object, node_index, begin, begin + count, depth, range);
    nodes[node_index].bounds = range.bounds;

    int prev = object.depth.load(std::memory_order_relaxed);
    while (prev < depth + 1 && !object.depth.compare_exchange_weak(prev, depth + 1)) {}

    auto make_leaf = [&] {
        nodes[node_index].index = std::uint32_t(begin);
        nodes[node_index].count = std::uint32_t(count);
    };
    if (count == 1 || depth + 1 >= opt.max_depth) return make_leaf();

    centroid_bins<S> const binning(range.centroids, bins_for(opt.bins, count));
    split_choice const object_best = object_split(object, scratch.object, binning, begin, begin + count);
    split_choice best = object_best;

    spatial_choice<S> spatial;
    if (finite && best.axis >= 0 && count >= opt.split_min_references) {
        basic_aabb<S> left, right;
        object_side_bounds(scratch.object, binning, best, left, right);
        double const overlap = double(surface_area(intersection(left, right)));
        if (overlap > ctx.min_overlap && overlap > ctx.node_overlap * double(surface_area(range.bounds)) &&
            (ctx.min_gain <= 0.0 || trimming_gain(left, right, best.axis) > ctx.min_gain))
            spatial = find_spatial_split(ctx, scratch, refs, range.bounds, spatial_bins(opt.bins, count), opt.bins);
    }
    // A split that would duplicate more references than the budget allows keeps the rest whole
    // on their cheaper side (partition_spatial).
    bool use_spatial = spatial.axis >= 0 && spatial.cost < best.cost;
    if (use_spatial) best = {spatial.cost, spatial.axis, 0};
    if (leaf_is_cheaper(opt, count, object.block_size, double(surface_area(range.bounds)), best)) return make_leaf();

    // The two sides go through scratch.left and scratch.right, in the references' order (the
    // unsplitting test of partition_spatial counts them in that order: the in-place partition's
    // order cost 0.3 % of SAH on the benchmark meshes), then back into the node's range.
    build_buffer<prim_ref<S>>& left = scratch.left;
    build_buffer<prim_ref<S>>& right = scratch.right;
    left.clear();
    right.clear();
    // Each side gets at most every reference once (a straddling one goes to both sides, as one
    // piece each). Pushed one by one into growing arrays, the root's sides had been reallocated
    // some 14 times each, and each task's again, in fresh pages where the C library had returned
    // the freed ones: on a virtual machine whose page faults cost ~13 µs, 2,350 faults and about
    // 30 ms of the engine's build (docs/performance.md, Run 32).
    left.reserve(count);
    right.reserve(count);
    std::size_t duplicates = 0;
    if (use_spatial) {
        duplicates = partition_spatial(ctx, refs, spatial, budget, left, right);
        if (left.empty() || right.empty()) {
            // Every straddling reference had its triangle on one side: split by objects instead.
            left.clear();
            right.clear();
            duplicates = 0;
            use_spatial = false;
        }
    }
    if (!use_spatial) {
        if (object_best.axis >= 0) {
            for (auto const& r : refs)
                (binning.index(object_best.axis, r.doubled_center()[object_best.axis]) < object_best.split ? left : right)
                    .push_back(r);
        } else {
            left.assign(refs.begin(), refs.begin() + std::ptrdiff_t(count / 2));
            right.assign(refs.begin() + std::ptrdiff_t(count / 2), refs.end());
        }
    }

    // The rest of the budget, shared by the children's reference counts; each child's range
    // starts with its references, followed by its budget.
    std::size_t const left_count = left.size(), right_count = right.size();
    std::size_t const rest = budget - duplicates;
    std::size_t const left_budget = std::size_t(double(rest) * double(left_count) / double(left_count + right_count));
    std::size_t const right_budget = rest - left_budget;
    std::size_t const right_begin = begin + left_count + left_budget;
    std::copy(left.begin(), left.end(), object.refs.begin() + std::ptrdiff_t(begin));
    std::copy(right.begin(), right.end(), object.refs.begin() + std::ptrdiff_t(right_begin));

    std::uint32_t const children = object.node_count.fetch_add(2, std::memory_order_relaxed);
    nodes[node_index].index = children;
    nodes[node_index].count = 0;
    if (count >= opt.parallel_threshold) {
        parallel_invoke(
            [&] {
                spatial_scratch<S> own(opt.bins);
                build_spatial_node(ctx, own, children, begin, left_count, depth + 1, left_budget);
            },
            [&] { build_spatial_node(ctx, scratch, children + 1, right_begin, right_count, depth + 1, right_budget); });
    } else {
        build_spatial_node(ctx, scratch, children, begin, left_count, depth + 1, left_budget);
        build_spatial_node(ctx, scratch, children + 1, right_begin, right_count, depth + 1, right_budget);
    }
}

// A fraction among the `high` options (split_budget, split_overlap, split_node_overlap,
// split_min_gain): a negative, NaN or infinite value counts as 0.
inline double fraction_option(float f) { return std::isfinite(f) ? std::max(0.0, double(f)) : 0.0; }

// The split BVH of prims (options already checked by build_binned_sah; prims not empty).
template <typename Prim>
    requires splittable_triangle<Prim>
bvh<Prim> build_spatial_splits(std::span<Prim const> prims, bvh_build_options const& options) {
    using S = typename Prim::value_type;
    bvh<Prim> result;
    std::size_t const n = prims.size();
    double const fraction = fraction_option(options.split_budget);
    // References are numbered in 32 bits, as primitives are.
    auto const budget = std::size_t(std::min(double(n) * fraction, double(std::numeric_limits<std::uint32_t>::max() / 2) - double(n)));

    auto clock = std::chrono::steady_clock::now();
    spatial_context<Prim> ctx;
    ctx.prims = prims;
    ctx.object.options = options;
    if constexpr (stores_triangle_blocks_v<Prim>) ctx.object.block_size = triangle_block_width;
    auto& refs = ctx.object.refs;
    refs.resize(n + budget); // not zeroed (build_buffer): filled here, the slack for the clipped pieces too
    parallel_for_chunks(n + budget, 1024, [&](std::size_t first, std::size_t last) {
        for (std::size_t i = first; i < last; ++i) {
            if (i >= n) {
                refs[i] = prim_ref<S>{};
                continue;
            }
            auto const box = get_bounds(prims[i]);
            refs[i] = {box.min, std::uint32_t(i), box.max};
        }
    });
    basic_aabb<S> root;
    for (std::size_t i = 0; i < n; ++i) root = extend(root, refs[i].box());
    result.build_phases.references = lap(clock);
    ctx.min_overlap = fraction_option(options.split_overlap) * double(surface_area(root));
    ctx.node_overlap = fraction_option(options.split_node_overlap);
    ctx.min_gain = fraction_option(options.split_min_gain);
    build_buffer<bvh_node<S>> nodes;
    nodes.resize(2 * (n + budget) - 1); // not zeroed: only the nodes made are written, and copied
    ctx.object.nodes = &nodes;
    spatial_scratch<S> scratch(options.bins);
    build_spatial_node(ctx, scratch, 0, 0, n, 0, budget);
    std::span<bvh_node<S>> const tree(nodes.data(), ctx.object.node_count.load());
    result.depth = ctx.object.depth.load();
    // The leaves' references, in node order, without the slack left between them.
    std::vector<std::uint32_t> order;
    order.reserve(n + budget);
    for (auto& node : tree) {
        if (!node.is_leaf()) continue;
        auto const first = std::uint32_t(order.size());
        for (std::uint32_t i = node.index; i < node.index + node.count; ++i) order.push_back(refs[i].index);
        node.index = first;
    }
    refs = {};
    result.build_phases.tree = lap(clock);
    finish_build(result, std::span<bvh_node<S> const>(tree), prims, order);
    return result;
}

} // namespace canopy::detail
