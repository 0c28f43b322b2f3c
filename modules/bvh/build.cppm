// canopy.bvh:build — binned SAH builder (Wald 2007, "On fast Construction of SAH-based Bounding
// Volume Hierarchies"), binning primitive centroids on all three axes, subtrees built in parallel
// (oneTBB task groups).
//
// bvh_build_options::quality = build_quality::high hands triangle BVHs to the split-BVH builder
// (canopy.bvh:spatial), where a triangle may be referenced from several leaves; the rest of this
// comment is about build_quality::fast (what build_quality::automatic, the default, runs unless
// spatial_splits_pay says otherwise).
//
// Contract: every input primitive appears exactly once in the result; a primitive type with a
// `prim_id` member gets prim_id = its index in the input sequence. Leaves hold at most
// max_leaf_size primitives, except where max_depth stops the recursion or all centroids coincide
// (then leaves split by index). NaN bounds never crash the builder (they sort into bin 0).
module;
// No a·b + c → FMA contraction in this file, whatever -ffp-contract says: every build and
// every path (scalar, SIMD, packet) rounds the same way.
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <numeric>
#include <span>
#include <vector>
export module canopy.bvh:build;
import canopy.geometry;
import :storage;
import :parallel;
import :wide;
import :binning;
import :spatial;

export namespace canopy {

namespace detail {


template <typename S>
struct build_context {
    std::vector<basic_aabb<S>> boxes;
    std::vector<vec3<S>> centers;
    std::vector<std::uint32_t> order;
    std::vector<bvh_node<S>>* nodes = nullptr;
    std::atomic<std::uint32_t> node_count{1};
    std::atomic<int> depth{0};
    bvh_build_options options;
    std::size_t block_size = 1; // primitives tested together in a leaf (see leaf_tests)
};

template <typename S>
range_bounds<S> bounds_of(build_context<S> const& ctx, std::size_t begin, std::size_t end) {
    range_bounds<S> r;
    for (std::size_t i = begin; i < end; ++i) {
        r.bounds = extend(r.bounds, ctx.boxes[ctx.order[i]]);
        r.centroids = extend(r.centroids, ctx.centers[ctx.order[i]]);
    }
    return r;
}

// Builds the subtree of order[begin, end) into nodes[node_index]; `range` holds the bounds of
// those primitives and of their centroids (the parent computes them while partitioning, so no
// node walks its primitives just for that).
template <typename S>
void build_node(build_context<S>& ctx, bin_scratch<S>& scratch, std::uint32_t node_index, std::size_t begin,
                std::size_t end, int depth, range_bounds<S> const& range) {
    auto& nodes = *ctx.nodes;
    auto const& opt = ctx.options;
    std::size_t const count = end - begin;
    basic_aabb<S> const& bounds = range.bounds;
    basic_aabb<S> const& centroid_bounds = range.centroids;
    nodes[node_index].bounds = bounds;

    int prev = ctx.depth.load(std::memory_order_relaxed);
    while (prev < depth + 1 && !ctx.depth.compare_exchange_weak(prev, depth + 1)) {}

    auto make_leaf = [&] {
        nodes[node_index].index = std::uint32_t(begin);
        nodes[node_index].count = std::uint32_t(count);
    };
    if (count == 1 || depth + 1 >= opt.max_depth) return make_leaf();

    // Best binned SAH split over all three axes, binned in one pass over the primitives. Small
    // nodes use one bin per primitive at most: the sweep costs O(bins) whatever the count.
    int const bins = int(std::min<std::size_t>(std::size_t(opt.bins), std::max<std::size_t>(count, 2)));
    centroid_bins<S> const binning(centroid_bounds, bins);
    bin<S>* const bin_data = scratch.bins.data();
    binning.clear(bin_data);
    {
        // Plain pointers: the stores into the bins must not make the compiler reload the arrays.
        std::uint32_t const* const order = ctx.order.data();
        vec3<S> const* const centers = ctx.centers.data();
        basic_aabb<S> const* const boxes = ctx.boxes.data();
        for (std::size_t i = begin; i < end; ++i) {
            std::uint32_t const p = order[i];
            binning.add(bin_data, boxes[p], centers[p]);
        }
    }
    split_choice const best = binning.best_split(bin_data, count, ctx.block_size, scratch.right_cost);
    if (leaf_is_cheaper(opt, count, ctx.block_size, double(surface_area(bounds)), best)) return make_leaf();

    // Partition by the chosen bin boundary, gathering the children's centroid bounds on the way
    // (their primitive bounds are the unions of their bins); or by index when centroids coincide.
    std::size_t mid;
    range_bounds<S> left, right;
    if (best.axis >= 0) {
        std::size_t i = begin, j = end;
        while (i < j) {
            std::uint32_t const p = ctx.order[i];
            if (binning.index(best.axis, ctx.centers[p][best.axis]) < best.split) {
                left.centroids = extend(left.centroids, ctx.centers[p]);
                ++i;
            } else {
                right.centroids = extend(right.centroids, ctx.centers[p]);
                std::swap(ctx.order[i], ctx.order[--j]);
            }
        }
        mid = i;
        binning.side_bounds(bin_data, best, left.bounds, right.bounds);
    } else {
        mid = begin + count / 2;
        left = bounds_of(ctx, begin, mid);
        right = bounds_of(ctx, mid, end);
    }

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

} // namespace detail

// The measure behind build_quality::automatic: of the triangles' summed box half-areas (what
// the SAH pays for), the share held by triangles whose box half-area exceeds 64 times their own
// area. Measured on the benchmark scenes: 0 for a closed sphere, a height field and the bunny,
// 0.006 for a soup of random triangles (spatial splits there cut work by 5 %), 0.16 for the
// 2CylinderEngine CAD model, 0.32 for a tree with thin leaf quads and 1.0 for slivers (spatial
// splits there cut box tests by 10–28 % and triangle tests by 15–43 %). One pass, no allocation.
template <typename T>
double sliver_box_share(std::span<basic_triangle<T> const> prims) {
    double total = 0.0, sliver = 0.0;
    for (auto const& t : prims) {
        vec3<double> const a(t.v0), b(t.v1), c(t.v2);
        vec3<double> const lo = min(min(a, b), c), hi = max(max(a, b), c);
        vec3<double> const e = hi - lo;
        double const half_area = e.x * e.y + e.y * e.z + e.z * e.x;
        double const area = 0.5 * length(cross(b - a, c - a));
        if (!(half_area < std::numeric_limits<double>::infinity())) continue; // NaN or infinite: not measured
        total += half_area;
        if (half_area > 64.0 * area) sliver += half_area;
    }
    return total > 0.0 ? sliver / total : 0.0;
}

// Whether build_quality::automatic builds these triangles with spatial splits: when at least 5 %
// of the box area belongs to long thin triangles (sliver_box_share).
template <typename T>
bool spatial_splits_pay(std::span<basic_triangle<T> const> prims) {
    return sliver_box_share(prims) >= 0.05;
}

template <typename Prim>
bvh<Prim> build_binned_sah(std::span<Prim const> prims, bvh_build_options options = {}) {
    using S = bounds_value_t<Prim>;
    bvh<Prim> result;
    std::size_t const n = prims.size();
    if (n == 0) return result;

    if (options.max_leaf_size == 0) options.max_leaf_size = stores_triangle_blocks_v<Prim> ? triangle_block_width : 4;
    options.max_leaf_size = std::max(options.max_leaf_size, 1);
    options.bins = std::clamp(options.bins, 2, 256);
    options.max_depth = std::clamp(options.max_depth, 1, bvh_max_depth);

    if constexpr (detail::splittable_triangle<Prim>) {
        if (options.quality == build_quality::automatic)
            options.quality = spatial_splits_pay(prims) ? build_quality::high : build_quality::fast;
        if (options.quality == build_quality::high) {
            auto built = detail::build_spatial_splits(prims, options);
            built.quality = build_quality::high;
            return built;
        }
    }

    detail::build_context<S> ctx;
    ctx.options = options;
    if constexpr (stores_triangle_blocks_v<Prim>) ctx.block_size = triangle_block_width;
    ctx.boxes.resize(n);
    ctx.centers.resize(n);
    ctx.order.resize(n);
    std::iota(ctx.order.begin(), ctx.order.end(), std::uint32_t(0));
    parallel_for_chunks(n, 1024, [&](std::size_t first, std::size_t last) {
        for (std::size_t i = first; i < last; ++i) {
            ctx.boxes[i] = get_bounds(prims[i]);
            ctx.centers[i] = center(ctx.boxes[i]);
        }
    });

    result.nodes.resize(2 * n - 1);
    ctx.nodes = &result.nodes;
    detail::bin_scratch<S> scratch(options.bins);
    detail::build_node(ctx, scratch, 0, 0, n, 0, detail::bounds_of(ctx, 0, n));
    result.nodes.resize(ctx.node_count.load());
    result.depth = ctx.depth.load();
    detail::finish_build(result, prims, ctx.order);
    return result;
}

template <typename Prim>
bvh<Prim> build_binned_sah(std::vector<Prim> const& prims, bvh_build_options options = {}) {
    return build_binned_sah(std::span<Prim const>(prims), options);
}

} // namespace canopy
