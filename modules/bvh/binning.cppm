// canopy.bvh:binning — the SAH bins shared by the builders (canopy.bvh:build, canopy.bvh:spatial):
// bins of boxes along one axis, and the sweep that finds the cheapest boundary between them.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <vector>
export module canopy.bvh:binning;
import canopy.geometry;

namespace canopy::detail {

template <typename S>
struct bin {
    basic_aabb<S> bounds;
    std::size_t count = 0;
};

// Bin of a centroid coordinate; NaN and out-of-range values clamp into [0, bins).
template <typename S>
int bin_index(S x, S lo, S scale, int bins) {
    S const f = (x - lo) * scale;
    if (!(f >= S(0))) return 0;
    if (!(f < S(bins))) return bins - 1;
    return int(f);
}

} // namespace canopy::detail

export namespace canopy::detail {

// A bin as the 4-lane binning of canopy.bvh:build fills it: its box in two vectors (lane 3
// ignored) and its count.
struct alignas(32) vector_bin {
    simd::float4 lo, hi;
};

} // namespace canopy::detail

namespace canopy::detail {

// Whether the builders bin with 4-lane vectors (float boxes, SSE or wider). canopy.bvh:build then
// keeps its bins in bin_scratch::vector_bins, else in bin_scratch::bins (centroid_bins, one
// primitive and one axis at a time); both give the same bins. Its vector sweep forms the SAH
// costs in float, the other in double, so a near tie may split differently (the benchmark
// meshes' SAH moved by at most 0.01 %). canopy.bvh:spatial bins the parts of references in
// vector_bins then, with the same results as its scalar binning.
template <typename S>
inline constexpr bool vector_binning = std::is_same_v<S, float> && simd::native_width<4>;

// Binning a node's references in parallel chunks (canopy.bvh:object, bin_refs_in_parallel;
// canopy.bvh:spatial, find_spatial_split). A chunk is the options' parallel_threshold references,
// but never so small that a node has more than max_bin_chunks chunks (their bins are all held
// until they are merged: a threshold of 1 would otherwise hold a set of bins per reference); and
// a node bins in parallel when it has at least 4 chunks and parallel_binning_min references
// (below that, the merge and the tasks cost what they save). Both depend on the node's size and
// the options only, never on the number of threads, and the bins are the same either way.
inline constexpr std::size_t max_bin_chunks = 64;
inline constexpr std::size_t parallel_binning_min = 1024;
inline std::size_t bin_chunk(std::size_t parallel_threshold, std::size_t count) {
    return std::max({parallel_threshold, std::size_t(1), (count + max_bin_chunks - 1) / max_bin_chunks});
}
inline bool bins_in_parallel(std::size_t parallel_threshold, std::size_t count) {
    return count >= parallel_binning_min && count >= 4 * bin_chunk(parallel_threshold, count);
}

// Per-task working memory of the binning: 3 · bins bins and one sweep array; for the 4-lane
// binning of canopy.bvh:build, its bins with their counts and its sweep's transposed bins, counts
// and right-side costs.
template <typename S>
struct bin_scratch {
    explicit bin_scratch(int bins)
        : bins(3 * std::size_t(bins)), right_cost(std::size_t(bins)), vector_bins(3 * std::size_t(bins)),
          vector_counts(3 * std::size_t(bins)), sweep_boxes(6 * std::size_t(bins)), sweep_counts(std::size_t(bins)),
          sweep_right(std::size_t(bins)) {}
    std::vector<bin<S>> bins;
    std::vector<double> right_cost;
    std::vector<vector_bin> vector_bins;
    std::vector<std::uint32_t> vector_counts;
    std::vector<simd::float4> sweep_boxes;
    std::vector<simd::int4> sweep_counts;
    std::vector<simd::float4> sweep_right; // the right sides' costs, one lane per axis
};

// Bounds of a range of primitives and of their centroids.
template <typename S>
struct range_bounds {
    basic_aabb<S> bounds;
    basic_aabb<S> centroids;
};

// Tests the SAH counts for a leaf of n primitives tested block_size at a time: ceil(n / block_size)
// (triangle BVHs test blocks of triangles at once; Embree's builders count blocks the same way).
// (A shift where block_size is a power of two, as it always is for blocks: no division per bin.)
inline double leaf_tests(std::size_t n, std::size_t block_size) {
    std::size_t const rounded_up = n + block_size - 1;
    return double(std::has_single_bit(block_size) ? rounded_up >> std::countr_zero(block_size)
                                                  : rounded_up / block_size);
}

// The cheapest split found so far: bins [0, split) of `axis` go left. cost is the sum over both
// sides of surface area × leaf_tests (no traversal term, not divided by the parent's area).
struct split_choice {
    double cost = std::numeric_limits<double>::infinity();
    int axis = -1;
    int split = 0;
};

// Sweeps the `bins` bins of one axis (holding `count` primitives in all) from the right, then
// from the left, and keeps in `best` any boundary cheaper than it that leaves both sides
// non-empty. right_cost: scratch of at least `bins` entries.
template <typename S>
void sweep_object_bins(bin<S> const* ab, int bins, std::size_t count, int axis, std::size_t block_size,
                       std::vector<double>& right_cost, split_choice& best) {
    basic_aabb<S> acc;
    std::size_t n = 0;
    for (int k = bins - 1; k > 0; --k) {
        acc = extend(acc, ab[k].bounds);
        n += ab[k].count;
        right_cost[std::size_t(k)] = n ? double(surface_area(acc)) * leaf_tests(n, block_size) : 0.0;
    }
    acc = basic_aabb<S>{};
    n = 0;
    for (int k = 1; k < bins; ++k) {
        acc = extend(acc, ab[k - 1].bounds);
        n += ab[k - 1].count;
        if (n == 0 || n == count) continue;
        double const cost = double(surface_area(acc)) * leaf_tests(n, block_size) + right_cost[std::size_t(k)];
        if (cost < best.cost) best = {cost, axis, k};
    }
}

// The centroid bins of one node on all three axes: `bins` bins per axis across the centroids'
// bounds (an axis along which all centroids coincide is not usable).
template <typename S>
struct centroid_bins {
    inline centroid_bins(basic_aabb<S> const& centroids, int bins_) : bins(bins_) {
        for (int axis = 0; axis < 3; ++axis) {
            auto const a = std::size_t(axis);
            lo[a] = centroids.min[axis];
            S const extent = centroids.max[axis] - lo[a];
            usable[a] = extent > S(0);
            scale[a] = usable[a] ? S(bins) / extent : S(0);
        }
    }

    // Clears the 3 · bins bins in use. Kept scalar: vectorised, the loop becomes AVX-512
    // scatters, which cost more than the whole binning pass on some processors.
    inline void clear(bin<S>* b) const {
#pragma clang loop vectorize(disable)
        for (std::size_t k = 0, used = 3 * std::size_t(bins); k < used; ++k) b[k] = bin<S>{};
    }

    [[gnu::always_inline]] inline int index(int axis, S x) const {
        return bin_index(x, lo[std::size_t(axis)], scale[std::size_t(axis)], bins);
    }

    // Adds a primitive (its box, its centroid) to its bin on each usable axis.
    [[gnu::always_inline]] inline void add(bin<S>* b, basic_aabb<S> const& box, vec3<S> const& c) const {
        for (int axis = 0; axis < 3; ++axis) {
            if (!usable[std::size_t(axis)]) continue;
            auto& bb = b[std::size_t(axis * bins + index(axis, c[axis]))];
            bb.bounds = extend(bb.bounds, box);
            ++bb.count;
        }
    }

    // The cheapest boundary over the usable axes of bins holding `count` primitives.
    inline split_choice best_split(bin<S> const* b, std::size_t count, std::size_t block_size,
                                   std::vector<double>& right_cost) const {
        split_choice best;
        for (int axis = 0; axis < 3; ++axis)
            if (usable[std::size_t(axis)])
                sweep_object_bins(b + axis * bins, bins, count, axis, block_size, right_cost, best);
        return best;
    }

    // The bounds of the primitives on each side of `split` (the unions of their bins).
    inline void side_bounds(bin<S> const* b, split_choice const& split, basic_aabb<S>& left,
                            basic_aabb<S>& right) const {
        auto const* ab = b + split.axis * bins;
        for (int k = 0; k < bins; ++k) {
            auto& side = k < split.split ? left : right;
            side = extend(side, ab[k].bounds);
        }
    }

    int bins;
    std::array<S, 3> lo{}, scale{};
    std::array<bool, 3> usable{};
};

// Whether a node of `count` primitives (parent_area its surface area) is better left a leaf than
// split at `best` (best.axis < 0: no split was found). Nodes over max_leaf_size are always split.
template <typename Options>
bool leaf_is_cheaper(Options const& opt, std::size_t count, std::size_t block_size, double parent_area,
                     split_choice const& best) {
    double const leaf_cost = double(opt.costs.intersection) * leaf_tests(count, block_size);
    double const split_cost = parent_area > 0.0
                                  ? opt.costs.traversal + opt.costs.intersection * best.cost / parent_area
                                  : opt.costs.traversal + leaf_cost;
    bool const fits_leaf = count <= std::size_t(opt.max_leaf_size);
    return fits_leaf && (best.axis < 0 || split_cost >= leaf_cost);
}

} // namespace canopy::detail
