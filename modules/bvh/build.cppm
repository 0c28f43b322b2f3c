// canopy.bvh:build — binned SAH builder (Wald 2007, "On fast Construction of SAH-based Bounding
// Volume Hierarchies"), binning primitive centroids on all three axes, subtrees built in parallel
// (oneTBB task groups).
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

export namespace canopy {

struct bvh_build_options {
    int max_leaf_size = 0;                    // primitives per leaf; 0: triangle_block_width for triangle BVHs, else 4
    int bins = 16;                            // SAH bins per axis (2 … 256)
    int max_depth = bvh_max_depth;            // clamped to [1, bvh_max_depth]
    sah_costs costs = {};
    std::size_t parallel_threshold = 4096;    // subtrees with more primitives become parallel tasks
};

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
    // Primitives tested together in a leaf: the SAH counts a leaf's tests as ceil(n / block_size)
    // (triangle BVHs test blocks of four at once; Embree's builders count blocks the same way).
    std::size_t block_size = 1;

    double tests(std::size_t n) const { return double((n + block_size - 1) / block_size); }
};

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

// Per-task working memory of the binning: 3 · bins bins and one sweep array.
template <typename S>
struct bin_scratch {
    explicit bin_scratch(int bins) : bins(3 * std::size_t(bins)), right_cost(std::size_t(bins)) {}
    std::vector<bin<S>> bins;
    std::vector<double> right_cost;
};

// Bounds of a range of primitives and of their centroids.
template <typename S>
struct range_bounds {
    basic_aabb<S> bounds;
    basic_aabb<S> centroids;
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
    double best_cost = std::numeric_limits<double>::infinity();
    int best_axis = -1, best_split = 0;
    double const parent_area = surface_area(bounds);
    std::array<S, 3> lo{}, scale{};
    std::array<bool, 3> usable{};
    for (int axis = 0; axis < 3; ++axis) {
        lo[std::size_t(axis)] = centroid_bounds.min[axis];
        S const extent = centroid_bounds.max[axis] - lo[std::size_t(axis)];
        usable[std::size_t(axis)] = extent > S(0);
        scale[std::size_t(axis)] = usable[std::size_t(axis)] ? S(bins) / extent : S(0);
    }
    auto& b = scratch.bins;
    // Only the 3 · bins bins in use are cleared. The loop is kept scalar: vectorised, it becomes
    // AVX-512 scatters, which cost more than the whole binning pass on some processors.
#pragma clang loop vectorize(disable)
    for (std::size_t k = 0, used = 3 * std::size_t(bins); k < used; ++k) b[k] = bin<S>{};
    {
        // Plain pointers: the stores into the bins must not make the compiler reload the arrays.
        bin<S>* const bin_data = b.data();
        std::uint32_t const* const order = ctx.order.data();
        vec3<S> const* const centers = ctx.centers.data();
        basic_aabb<S> const* const boxes = ctx.boxes.data();
        for (std::size_t i = begin; i < end; ++i) {
            std::uint32_t const p = order[i];
            basic_aabb<S> const box = boxes[p];
            vec3<S> const c = centers[p];
            for (int axis = 0; axis < 3; ++axis) {
                auto const a = std::size_t(axis);
                if (!usable[a]) continue;
                int const k = bin_index(c[axis], lo[a], scale[a], bins);
                auto& bb = bin_data[std::size_t(axis * bins + k)];
                bb.bounds = extend(bb.bounds, box);
                ++bb.count;
            }
        }
    }
    auto& right_cost = scratch.right_cost;
    for (int axis = 0; axis < 3; ++axis) {
        if (!usable[std::size_t(axis)]) continue;
        auto const* ab = b.data() + axis * bins;
        // Sweep from the right, then from the left; split k puts bins [0, k) left.
        basic_aabb<S> acc;
        std::size_t n = 0;
        for (int k = bins - 1; k > 0; --k) {
            acc = extend(acc, ab[k].bounds);
            n += ab[k].count;
            right_cost[std::size_t(k)] = n ? double(surface_area(acc)) * ctx.tests(n) : 0.0;
        }
        acc = basic_aabb<S>{};
        n = 0;
        for (int k = 1; k < bins; ++k) {
            acc = extend(acc, ab[k - 1].bounds);
            n += ab[k - 1].count;
            if (n == 0 || n == count) continue;
            double const cost = double(surface_area(acc)) * ctx.tests(n) + right_cost[std::size_t(k)];
            if (cost < best_cost) {
                best_cost = cost;
                best_axis = axis;
                best_split = k;
            }
        }
    }

    double const leaf_cost = double(opt.costs.intersection) * ctx.tests(count);
    double const split_cost = parent_area > 0.0
                                  ? opt.costs.traversal + opt.costs.intersection * best_cost / parent_area
                                  : opt.costs.traversal + leaf_cost;
    bool const fits_leaf = count <= std::size_t(opt.max_leaf_size);
    if (fits_leaf && (best_axis < 0 || split_cost >= leaf_cost)) return make_leaf();

    // Partition by the chosen bin boundary, gathering the children's centroid bounds on the way
    // (their primitive bounds are the unions of their bins); or by index when centroids coincide.
    std::size_t mid;
    range_bounds<S> left, right;
    if (best_axis >= 0) {
        S const axis_lo = lo[std::size_t(best_axis)];
        S const axis_scale = scale[std::size_t(best_axis)];
        std::size_t i = begin, j = end;
        while (i < j) {
            std::uint32_t const p = ctx.order[i];
            if (bin_index(ctx.centers[p][best_axis], axis_lo, axis_scale, bins) < best_split) {
                left.centroids = extend(left.centroids, ctx.centers[p]);
                ++i;
            } else {
                right.centroids = extend(right.centroids, ctx.centers[p]);
                std::swap(ctx.order[i], ctx.order[--j]);
            }
        }
        mid = i;
        auto const* ab = b.data() + best_axis * bins;
        for (int k = 0; k < bins; ++k) {
            auto& side = k < best_split ? left : right;
            side.bounds = extend(side.bounds, ab[k].bounds);
        }
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
    result.wide_nodes = collapse_to_wide(result.nodes);

    result.primitives.resize(n);
    parallel_for_chunks(n, 1024, [&](std::size_t first, std::size_t last) {
        for (std::size_t i = first; i < last; ++i) {
            result.primitives[i] = prims[ctx.order[i]];
            if constexpr (requires(Prim& p) { p.prim_id = std::uint32_t(0); })
                result.primitives[i].prim_id = ctx.order[i];
        }
    });
    result.size = n;
    if constexpr (stores_triangle_blocks_v<Prim>) pack_triangle_blocks(result);
    return result;
}

template <typename Prim>
bvh<Prim> build_binned_sah(std::vector<Prim> const& prims, bvh_build_options options = {}) {
    return build_binned_sah(std::span<Prim const>(prims), options);
}

} // namespace canopy
