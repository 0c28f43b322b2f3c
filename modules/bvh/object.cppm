// canopy.bvh:object — the object-split builder (build_quality::fast): binned SAH (Wald 2007, "On
// fast Construction of SAH-based Bounding Volume Hierarchies") over the primitives' centroids on
// all three axes, subtrees built in parallel (oneTBB task groups). The primitives' boxes are
// partitioned in place as 32-byte references (prim_ref, Embree's PrimRef); float boxes are binned
// and swept with 4-lane vectors, the three axes at once (vector_binning), large nodes in parallel
// chunks (bin_refs: the same bins, so the same tree, on any number of threads). canopy.bvh:build runs it
// on all the primitives; canopy.bvh:spatial on the subtrees where its budget of references is
// spent, and bins and partitions its own nodes' references with the same steps (object_split,
// partition_object).
//
// Contract of build_node: every reference of the range ends in exactly one leaf, a leaf's index is
// the position of its first reference in build_context::refs. Leaves hold at most max_leaf_size
// primitives, except where max_depth stops the recursion or all centroids coincide (then leaves
// split by index). NaN bounds never crash the builder (they sort into bin 0).
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>
export module canopy.bvh:object;
import canopy.geometry;
import :storage;
import :parallel;
import :build_buffer;
import :binning;

namespace canopy::detail {

// A primitive's box and its input index: what the builder partitions in place (Embree's PrimRef),
// so that every pass over a node's primitives reads consecutive memory instead of gathering boxes
// through an index array. 32 bytes for float: one box in two 4-lane loads (the index and the
// padding ride in lane 3, which the binning ignores). The index's bits read as a float are a
// denormal: vector code takes lane 3 through minima, maxima, comparisons and blends only, or zeroes
// it before arithmetic (vector_bin_index::doubled_center).
template <typename S>
struct prim_ref {
    vec3<S> lo;
    std::uint32_t index = 0;
    vec3<S> hi;
    std::uint32_t unused = 0;

    // Twice the box's centre: the builder bins lo + hi, which splits exactly where the centre
    // would (halving is exact), one operation fewer per primitive and per pass.
    vec3<S> doubled_center() const { return lo + hi; }
    basic_aabb<S> box() const { return {lo, hi}; }
};

// The counters that every node updates sit on cache lines of their own: written by one thread,
// they would otherwise evict the line holding the fields every node reads (refs, nodes, options)
// from the other threads' caches (false sharing).
template <typename S>
struct build_context {
    build_buffer<prim_ref<S>> refs;     // sized without being zeroed: filled in parallel
    build_buffer<bvh_node<S>>* nodes = nullptr; // each node written whole by the step creating it
    bvh_build_options options;
    std::size_t block_size = 1; // primitives tested together in a leaf (see leaf_tests)
    alignas(64) std::atomic<std::uint32_t> node_count{1};
    alignas(64) std::atomic<int> depth{0};
};

// Bounds of refs[begin, end) and of their doubled centres.
template <typename S>
range_bounds<S> bounds_of(build_context<S> const& ctx, std::size_t begin, std::size_t end) {
    range_bounds<S> r;
    for (std::size_t i = begin; i < end; ++i) {
        r.bounds = extend(r.bounds, ctx.refs[i].box());
        r.centroids = extend(r.centroids, ctx.refs[i].doubled_center());
    }
    return r;
}

// Grows bin b by the box [lo, hi]: min(new, b) and max(new, b), so that a NaN coordinate of the
// new box leaves b's as it was (x86 min and max return their second operand then).
[[gnu::always_inline]] inline void grow_bin(vector_bin& b, simd::float4 lo, simd::float4 hi) {
    b.lo = simd::min(lo, b.lo);
    b.hi = simd::max(hi, b.hi);
}

// centroid_bins::index on the three axes at once (lane a: axis a; lane 3 unused), for a doubled
// centre in 4 lanes: the same arithmetic as bin_index, lane by lane (NaN and values below the
// range in bin 0, values above it in the last bin). The one mapping from centre to bin of the
// vector binning (bin_refs_vector) and the vector partition (partition_blocks), so that a
// reference is partitioned by the bin it was counted in. Its members are declared inline: a
// member of a non-template class in a named module is not implicitly inline, and always_inline
// alone left them called out of line, every vector register spilled around each call
// (docs/performance.md, Run 29).
struct vector_bin_index {
    template <typename S>
    explicit vector_bin_index(centroid_bins<S> const& binning)
        : vector_bin_index(to_lanes(vec3<float>(binning.lo[0], binning.lo[1], binning.lo[2])),
                           to_lanes(vec3<float>(binning.scale[0], binning.scale[1], binning.scale[2])),
                           binning.bins) {}

    // Bins of width 1 / scale from origin, per lane (canopy.bvh:spatial's planes, plane_bin).
    vector_bin_index(simd::float4 origin, simd::float4 scale_, int bins)
        : lo(origin), scale(scale_), last(float(bins - 1)) {}

    // v with lane 3 zero: that lane of a reference loaded as two 4-lane vectors holds its index
    // (prim_ref::index) as float bits, a denormal, and arithmetic on denormals takes a microcode
    // assist on some processors (on an AMD Zen 5 the bin mapping had a third of the bunny's build
    // time, 82 % of it on the instruction after its multiply).
    [[gnu::always_inline]] static inline simd::float4 xyz_only(simd::float4 v) {
        return simd::select(simd::int4::iota() < simd::int4(3), v, simd::float4(0.0f));
    }

    // lo + hi of a reference loaded as two 4-lane vectors, lane 3 zero (xyz_only).
    [[gnu::always_inline]] static inline simd::float4 doubled_center(simd::float4 lo_, simd::float4 hi_) {
        return xyz_only(lo_) + xyz_only(hi_);
    }

    [[gnu::always_inline]] inline simd::int4 operator()(simd::float4 doubled_center) const {
        // max(f, 0) takes 0 for NaN (the second operand), as bin_index does.
        return simd::convert_to_int(simd::min(simd::max((doubled_center - lo) * scale, simd::float4(0.0f)), last));
    }

    simd::float4 lo, scale, last;
};

// The vector form of bin_refs below, into the 3 · binning.bins bins and counts given.
template <typename S>
    requires vector_binning<S>
void bin_refs_vector(centroid_bins<S> const& binning, prim_ref<S> const* refs, std::size_t begin, std::size_t end,
                     vector_bin* boxes, std::uint32_t* counts) {
    using simd::float4;
    using simd::int4;
    std::size_t const n = 3 * std::size_t(binning.bins);
    float const inf = std::numeric_limits<float>::infinity();
    for (std::size_t k = 0; k < n; ++k) {
        boxes[k] = {float4(inf), float4(-inf)};
        counts[k] = 0;
    }
    vector_bin_index const bin_of(binning);
    int4 const first_of_axis = int4::iota() * int4(binning.bins);
    for (std::size_t i = begin; i < end; ++i) {
        float4 const box_lo = float4::load(&refs[i].lo.x), box_hi = float4::load(&refs[i].hi.x);
        alignas(16) std::int32_t slot[4];
        (bin_of(bin_of.doubled_center(box_lo, box_hi)) + first_of_axis).store_aligned(slot);
        for (int a = 0; a < 3; ++a) {
            grow_bin(boxes[std::size_t(slot[a])], box_lo, box_hi);
            ++counts[std::size_t(slot[a])];
        }
    }
}

// bin_refs_vector over fixed chunks of `chunk` references in parallel (bins_in_parallel: the
// first levels of a build, which would otherwise bin on one thread while the other waits), each
// chunk into bins of its own, merged in chunk order. Boxes merge by min and max and counts by
// sums, so the bins, and the tree, are those of one pass, however the chunks are scheduled.
template <typename S>
    requires vector_binning<S>
void bin_refs_in_parallel(centroid_bins<S> const& binning, prim_ref<S> const* refs, std::size_t begin,
                          std::size_t end, std::size_t chunk, bin_scratch<S>& scratch) {
    std::size_t const chunks = (end - begin + chunk - 1) / chunk;
    std::size_t const n = 3 * std::size_t(binning.bins);
    std::vector<vector_bin> boxes(chunks * n);
    std::vector<std::uint32_t> counts(chunks * n);
    parallel_for_chunks(chunks, 1, [&](std::size_t first, std::size_t last) {
        for (std::size_t c = first; c < last; ++c) {
            std::size_t const from = begin + c * chunk;
            bin_refs_vector(binning, refs, from, std::min(end, from + chunk), boxes.data() + c * n, counts.data() + c * n);
        }
    });
    for (std::size_t k = 0; k < n; ++k) {
        vector_bin merged = boxes[k];
        std::uint32_t count = counts[k];
        for (std::size_t c = 1; c < chunks; ++c) {
            grow_bin(merged, boxes[c * n + k].lo, boxes[c * n + k].hi);
            count += counts[c * n + k];
        }
        scratch.vector_bins[k] = merged;
        scratch.vector_counts[k] = count;
    }
}

// Bins refs[begin, end) on the three axes, as centroid_bins::add does one primitive at a time.
// With vector_binning, the three axes' bin indices come from one vector computation and each
// bin's box grows by one 4-lane min and max, with the same rules lane by lane (bin_index: NaN and
// values below the range in bin 0, values above it in the last bin; extend: NaN coordinates
// ignored), so the bins of every usable axis hold the same boxes and counts (the others, which
// the sweep skips, are filled too instead of tested for); large nodes in parallel chunks
// (bins_in_parallel with the options' parallel_threshold).
template <typename S>
void bin_refs(centroid_bins<S> const& binning, prim_ref<S> const* refs, std::size_t begin, std::size_t end,
              std::size_t parallel_threshold, bin_scratch<S>& scratch) {
    if constexpr (vector_binning<S>) {
        std::size_t const count = end - begin;
        if (bins_in_parallel(parallel_threshold, count))
            bin_refs_in_parallel(binning, refs, begin, end, bin_chunk(parallel_threshold, count), scratch);
        else
            bin_refs_vector(binning, refs, begin, end, scratch.vector_bins.data(), scratch.vector_counts.data());
    } else {
        bin<S>* const bin_data = scratch.bins.data();
        binning.clear(bin_data);
        for (std::size_t i = begin; i < end; ++i) binning.add(bin_data, refs[i].box(), refs[i].doubled_center());
    }
}

// centroid_bins::best_split over the vector bins: the sweeps of the three axes run together, one
// axis per lane, on the bins transposed (lane a of plane row c, bin k: coordinate c of the box
// of bin k on axis a). Each lane computes the float areas of canopy.math's surface_area with the
// same operations; the costs are formed in float (sweep_object_bins forms them in double), and
// the first cheapest boundary of the lowest axis wins, as in sweep_object_bins' scan.
template <typename S>
    requires vector_binning<S>
split_choice best_split_vector(centroid_bins<S> const& binning, bin_scratch<S>& scratch, std::size_t count,
                               std::size_t block_size) {
    using simd::float4;
    using simd::int4;
    std::size_t const bins = std::size_t(binning.bins);
    float4* const plane = scratch.sweep_boxes.data(); // row c (min x, y, z, max x, y, z) at c * bins
    int4* const bin_count = scratch.sweep_counts.data();
    for (std::size_t k = 0; k < bins; ++k) {
        // Rows c of the axes' boxes (lane a: axis a's bin k; lane 3 zero), by transposing the
        // three axes' box corners.
        std::array<float4, 4> lo{scratch.vector_bins[k].lo, scratch.vector_bins[bins + k].lo,
                                 scratch.vector_bins[2 * bins + k].lo, float4(0.0f)};
        std::array<float4, 4> hi{scratch.vector_bins[k].hi, scratch.vector_bins[bins + k].hi,
                                 scratch.vector_bins[2 * bins + k].hi, float4(0.0f)};
        simd::transpose(lo);
        simd::transpose(hi);
        for (std::size_t c = 0; c < 3; ++c) {
            plane[c * bins + k] = lo[c];
            plane[(3 + c) * bins + k] = hi[c];
        }
        alignas(16) std::int32_t const n[4] = {std::int32_t(scratch.vector_counts[k]),
                                               std::int32_t(scratch.vector_counts[bins + k]),
                                               std::int32_t(scratch.vector_counts[2 * bins + k]), 0};
        bin_count[k] = int4::load_aligned(n);
    }
    // surface_area of each lane's box (canopy.math): 2 · (dx·dy + dy·dz + dz·dx), 0 when empty.
    auto const area = [](std::array<float4, 6> const& box) {
        float4 const dx = box[3] - box[0], dy = box[4] - box[1], dz = box[5] - box[2];
        auto const empty = ((box[0] > box[3]) | (box[1] > box[4])) | (box[2] > box[5]);
        return simd::select(empty, float4(0.0f), float4(2.0f) * (dx * dy + dy * dz + dz * dx));
    };
    auto const empty_box = [] {
        float const inf = std::numeric_limits<float>::infinity();
        return std::array<float4, 6>{float4(inf), float4(inf), float4(inf), float4(-inf), float4(-inf), float4(-inf)};
    };
    // extend(acc, bin k): min(bin, acc) and max(bin, acc), as canopy.math's extend.
    auto const take = [&](std::array<float4, 6>& acc, std::size_t k) {
        for (std::size_t c = 0; c < 3; ++c) {
            acc[c] = simd::min(plane[c * bins + k], acc[c]);
            acc[3 + c] = simd::max(plane[(3 + c) * bins + k], acc[3 + c]);
        }
    };
    // The costs of all boundaries, lane by lane: area × blocks on each side (blocks: leaf_tests,
    // by shift; block sizes are powers of two), formed in float as Embree's binner forms them.
    int const shift = std::countr_zero(block_size);
    int4 const round_up(std::int32_t(block_size) - 1);
    auto const blocks = [&](int4 n) { return simd::convert_to_float((n + round_up) >> shift); };
    float4* const right_cost = scratch.sweep_right.data();
    auto acc = empty_box();
    int4 n(0);
    for (std::size_t k = bins - 1; k > 0; --k) {
        take(acc, k);
        n = n + bin_count[k];
        right_cost[k] = area(acc) * blocks(n);
    }
    // From the left: the cheapest boundary of each axis (lane), the first one on ties, among
    // those that leave both sides non-empty.
    float const inf = std::numeric_limits<float>::infinity();
    acc = empty_box();
    n = int4(0);
    int4 const all = int4(std::int32_t(count));
    float4 best_cost(inf);
    int4 best_k(0);
    for (std::size_t k = 1; k < bins; ++k) {
        take(acc, k - 1);
        n = n + bin_count[k - 1];
        float4 const cost = area(acc) * blocks(n) + right_cost[k];
        auto const better = (cost < best_cost) & (n != int4(0)) & (n != all);
        best_cost = simd::select(better, cost, best_cost);
        best_k = simd::select(better, int4(std::int32_t(k)), best_k);
    }
    alignas(16) float costs[4];
    alignas(16) std::int32_t ks[4];
    best_cost.store_aligned(costs);
    best_k.store_aligned(ks);
    split_choice best;
    for (std::size_t a = 0; a < 3; ++a)
        if (binning.usable[a] && double(costs[a]) < best.cost) best = {double(costs[a]), int(a), int(ks[a])};
    return best;
}

// centroid_bins::side_bounds over the vector bins.
template <typename S>
    requires vector_binning<S>
void side_bounds_vector(centroid_bins<S> const& binning, bin_scratch<S> const& scratch, split_choice const& split,
                        basic_aabb<S>& left, basic_aabb<S>& right) {
    vector_bin const* const b = scratch.vector_bins.data() + std::size_t(split.axis * binning.bins);
    float const inf = std::numeric_limits<float>::infinity();
    vector_bin sides[2] = {{simd::float4(inf), simd::float4(-inf)}, {simd::float4(inf), simd::float4(-inf)}};
    for (int k = 0; k < binning.bins; ++k) {
        grow_bin(sides[k < split.split ? 0 : 1], b[k].lo, b[k].hi);
    }
    left = {from_lanes(sides[0].lo), from_lanes(sides[0].hi)};
    right = {from_lanes(sides[1].lo), from_lanes(sides[1].hi)};
}

// The cheapest object split of refs[begin, end) (count of them) by the SAH, binned over `binning`
// in one pass over the references. Small nodes use one bin per primitive at most (bins_for): the
// sweep costs O(bins) whatever the count.
inline int bins_for(int bins, std::size_t count) {
    return int(std::min<std::size_t>(std::size_t(bins), std::max<std::size_t>(count, 2)));
}

template <typename S>
split_choice object_split(build_context<S> const& ctx, bin_scratch<S>& scratch, centroid_bins<S> const& binning,
                          std::size_t begin, std::size_t end) {
    bin_refs(binning, ctx.refs.data(), begin, end, ctx.options.parallel_threshold, scratch);
    if constexpr (vector_binning<S>)
        return best_split_vector(binning, scratch, end - begin, ctx.block_size);
    else
        return binning.best_split(scratch.bins.data(), end - begin, ctx.block_size, scratch.right_cost);
}

// The boxes of the references on each side of `best` (the unions of their bins).
template <typename S>
void object_side_bounds(bin_scratch<S> const& scratch, centroid_bins<S> const& binning, split_choice const& best,
                        basic_aabb<S>& left, basic_aabb<S>& right) {
    if constexpr (vector_binning<S>)
        side_bounds_vector(binning, scratch, best, left, right);
    else
        binning.side_bounds(scratch.bins.data(), best, left, right);
}

// Partitions refs[begin, end) by Hoare's scheme, each reference read once and only misplaced
// pairs swapped, gathering the two sides' centroid bounds (goes_left: the side of a doubled
// centre); returns where the right side starts.
template <typename S, typename GoesLeft>
std::size_t partition_hoare(prim_ref<S>* refs, std::size_t begin, std::size_t end, GoesLeft const& goes_left,
                            range_bounds<S>& left, range_bounds<S>& right) {
    std::size_t i = begin, j = end;
    for (;;) {
        vec3<S> ci, cj;
        while (i < j && goes_left(ci = refs[i].doubled_center())) {
            left.centroids = extend(left.centroids, ci);
            ++i;
        }
        while (i < j && !goes_left(cj = refs[j - 1].doubled_center())) {
            right.centroids = extend(right.centroids, cj);
            --j;
        }
        if (i >= j) break;
        // refs[i] goes right and refs[j - 1] left (so i + 1 < j): swap them.
        std::swap(refs[i], refs[j - 1]);
        left.centroids = extend(left.centroids, cj);
        right.centroids = extend(right.centroids, ci);
        ++i;
        --j;
    }
    return i;
}

// The same partition without a branch per reference (block partitioning: Edelkamp and Weiß 2016,
// "BlockQuicksort: How branch mispredictions don't affect quicksort"). Near the root a
// reference's side is a coin toss for the branch predictor; here blocks of partition_block
// references at each end are classified first, the side of each computed in 4-lane vectors (the
// bin index of bin_refs_vector, so the same side as centroid_bins::index) and its centroid added
// to its side's bounds by selects, and the misplaced references of the two blocks are swapped
// pairwise. A block stays until all its misplaced references are swapped, so that [begin, l) holds
// only left references and [r, end) only right ones; partition_hoare finishes [l, r), fewer than
// 2 · partition_block references (some seen twice: their centroids are added to the same side's
// bounds again, which changes nothing). The two sides are the same sets as partition_hoare's, in
// another order.
inline constexpr std::size_t partition_block = 32;

template <typename S, typename GoesLeft>
    requires vector_binning<S>
std::size_t partition_blocks(prim_ref<S>* refs, centroid_bins<S> const& binning, split_choice const& best,
                             std::size_t begin, std::size_t end, GoesLeft const& goes_left, range_bounds<S>& left,
                             range_bounds<S>& right) {
    using simd::float4;
    using simd::int4;
    constexpr std::size_t B = partition_block;
    vector_bin_index const bin_of(binning);
    int4 const split(std::int32_t(best.split));
    int const axis = best.axis;
    float const inf = std::numeric_limits<float>::infinity();
    float4 left_lo(inf), left_hi(-inf), right_lo(inf), right_hi(-inf);
    // The offsets k (block[k * step]) of the block's references that belong on the other side
    // (belongs_left: 1 for the left block, 0 for the right one), in misplaced[0, count); returns
    // count. Each reference's doubled centre joins its side's centroid bounds (min and max with
    // the bounds second: a NaN coordinate is ignored, as extend does), gathered in the block's own
    // vectors and merged once per block: the byte stores into misplaced may alias any object
    // whose address is known, so bounds kept in the enclosing function's variables went through
    // memory for every reference.
    auto const classify = [&](prim_ref<S> const* block, std::ptrdiff_t step, std::uint32_t belongs_left,
                              std::uint8_t* misplaced) {
        float4 block_left_lo(inf), block_left_hi(-inf), block_right_lo(inf), block_right_hi(-inf);
        std::size_t count = 0;
        for (std::size_t k = 0; k < B; ++k) {
            prim_ref<S> const& ref = block[std::ptrdiff_t(k) * step];
            float4 const c = bin_of.doubled_center(float4::load(&ref.lo.x), float4::load(&ref.hi.x));
            std::uint32_t const goes = (simd::movemask(bin_of(c) < split) >> axis) & 1u;
            auto const is_left = int4(std::int32_t(goes)) != int4(0);
            block_left_lo = simd::min(simd::select(is_left, c, float4(inf)), block_left_lo);
            block_left_hi = simd::max(simd::select(is_left, c, float4(-inf)), block_left_hi);
            block_right_lo = simd::min(simd::select(is_left, float4(inf), c), block_right_lo);
            block_right_hi = simd::max(simd::select(is_left, float4(-inf), c), block_right_hi);
            misplaced[count] = std::uint8_t(k);
            count += goes ^ belongs_left;
        }
        left_lo = simd::min(block_left_lo, left_lo);
        left_hi = simd::max(block_left_hi, left_hi);
        right_lo = simd::min(block_right_lo, right_lo);
        right_hi = simd::max(block_right_hi, right_hi);
        return count;
    };
    std::uint8_t misplaced_left[B], misplaced_right[B]; // offsets in the left and right blocks
    std::size_t l = begin, r = end, count_l = 0, count_r = 0, first_l = 0, first_r = 0;
    while (r - l >= 2 * B) {
        if (count_l == 0) first_l = 0, count_l = classify(refs + l, 1, 1u, misplaced_left);
        if (count_r == 0) first_r = 0, count_r = classify(refs + (r - 1), -1, 0u, misplaced_right);
        std::size_t const swaps = std::min(count_l, count_r);
        for (std::size_t k = 0; k < swaps; ++k)
            std::swap(refs[l + misplaced_left[first_l + k]], refs[r - 1 - misplaced_right[first_r + k]]);
        count_l -= swaps, first_l += swaps;
        count_r -= swaps, first_r += swaps;
        if (count_l == 0) l += B;
        if (count_r == 0) r -= B;
    }
    left.centroids = extend(left.centroids, basic_aabb<S>{from_lanes(left_lo), from_lanes(left_hi)});
    right.centroids = extend(right.centroids, basic_aabb<S>{from_lanes(right_lo), from_lanes(right_hi)});
    return partition_hoare(refs, l, r, goes_left, left, right);
}

// Partitions refs[begin, end) in place by the bin boundary `best` found by object_split (or by
// index when best.axis < 0: the centroids coincide), gathering the two sides' bounds and centroid
// bounds on the way; returns where the right side starts.
template <typename S>
std::size_t partition_object(build_context<S>& ctx, bin_scratch<S> const& scratch, centroid_bins<S> const& binning,
                             split_choice const& best, std::size_t begin, std::size_t end, range_bounds<S>& left,
                             range_bounds<S>& right) {
    if (best.axis < 0) {
        std::size_t const mid = begin + (end - begin) / 2;
        left = bounds_of(ctx, begin, mid);
        right = bounds_of(ctx, mid, end);
        return mid;
    }
    int const axis = best.axis;
    auto const goes_left = [&](vec3<S> const& c) { return binning.index(axis, c[axis]) < best.split; };
    std::size_t mid;
    if constexpr (vector_binning<S>)
        mid = partition_blocks(ctx.refs.data(), binning, best, begin, end, goes_left, left, right);
    else
        mid = partition_hoare(ctx.refs.data(), begin, end, goes_left, left, right);
    object_side_bounds(scratch, binning, best, left.bounds, right.bounds);
    return mid;
}

// Builds the subtree of refs[begin, end) into nodes[node_index]; `range` holds the bounds of
// those primitives and of their doubled centres (the parent computes them while partitioning, so
// no node walks its primitives just for that).
template <typename S>
void build_node(build_context<S>& ctx, bin_scratch<S>& scratch, std::uint32_t node_index, std::size_t begin,
                std::size_t end, int depth, range_bounds<S> const& range) {
    auto& nodes = *ctx.nodes;
    auto const& opt = ctx.options;
    std::size_t const count = end - begin;
    basic_aabb<S> const& bounds = range.bounds;
    nodes[node_index].bounds = bounds;

    int prev = ctx.depth.load(std::memory_order_relaxed);
    while (prev < depth + 1 && !ctx.depth.compare_exchange_weak(prev, depth + 1)) {}

    auto make_leaf = [&] {
        nodes[node_index].index = std::uint32_t(begin);
        nodes[node_index].count = std::uint32_t(count);
    };
    if (count == 1 || depth + 1 >= opt.max_depth) return make_leaf();

    centroid_bins<S> const binning(range.centroids, bins_for(opt.bins, count));
    split_choice const best = object_split(ctx, scratch, binning, begin, end);
    if (leaf_is_cheaper(opt, count, ctx.block_size, double(surface_area(bounds)), best)) return make_leaf();

    range_bounds<S> left, right;
    std::size_t const mid = partition_object(ctx, scratch, binning, best, begin, end, left, right);

    std::uint32_t const children = ctx.node_count.fetch_add(2, std::memory_order_relaxed);
    nodes[node_index].index = children;
    nodes[node_index].count = 0;
    if (count >= opt.parallel_threshold) {
        parallel_invoke(
            [&] {
                bin_scratch<S> own(opt.bins);
                build_node(ctx, own, children, begin, mid, depth + 1, left);
            },
            [&] { build_node(ctx, scratch, children + 1, mid, end, depth + 1, right); });
    } else {
        build_node(ctx, scratch, children, begin, mid, depth + 1, left);
        build_node(ctx, scratch, children + 1, mid, end, depth + 1, right);
    }
}

} // namespace canopy::detail
