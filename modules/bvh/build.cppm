// canopy.bvh:build — build_binned_sah, the builder's entry point: binned SAH over object splits
// (canopy.bvh:object: Wald 2007, centroids binned on all three axes, 32-byte references
// partitioned in place, subtrees built in parallel), then the wide nodes and the leaves'
// primitives (canopy.bvh:wide).
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
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <chrono>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <numeric>
#include <span>
#include <type_traits>
#include <vector>
export module canopy.bvh:build;
import canopy.geometry;
import :storage;
import :parallel;
import :build_buffer;
import :wide;
import :binning;
import :object;
import :spatial;
import :protocol;

export namespace canopy {

// The measure behind build_quality::automatic: of the triangles' summed box half-areas (what
// the SAH pays for), the share held by triangles whose box half-area exceeds 64 times their own
// area. Measured on the benchmark scenes: 0 for a closed sphere, a height field and the bunny,
// 0.006 for a soup of random triangles (spatial splits there cut work by 5 %), 0.16 for the
// 2CylinderEngine CAD model, 0.32 for a tree with thin leaf quads and 1.0 for slivers (spatial
// splits there cut box tests by 10–28 % and triangle tests by 15–43 %). One pass, in parallel:
// sums over fixed chunks of sliver_chunk triangles, added in chunk order, so the share is the
// same on any number of threads.
inline constexpr std::size_t sliver_chunk = 16384;

template <typename T>
double sliver_box_share(std::span<basic_triangle<T> const> prims) {
    std::size_t const chunks = (prims.size() + sliver_chunk - 1) / sliver_chunk;
    std::vector<std::array<double, 2>> sums(chunks); // per chunk: all, slivers
    parallel_for_chunks(chunks, 1, [&](std::size_t first, std::size_t last) {
        for (std::size_t chunk = first; chunk < last; ++chunk) {
            double total = 0.0, sliver = 0.0;
            for (std::size_t i = chunk * sliver_chunk, end = std::min(prims.size(), i + sliver_chunk); i < end; ++i) {
                auto const& t = prims[i];
                vec3<double> const a(t.v0), b(t.v1), c(t.v2);
                vec3<double> const lo = min(min(a, b), c), hi = max(max(a, b), c);
                vec3<double> const e = hi - lo;
                double const half_area = e.x * e.y + e.y * e.z + e.z * e.x;
                double const area = 0.5 * length(cross(b - a, c - a));
                if (!(half_area < std::numeric_limits<double>::infinity())) continue; // NaN or infinite: not measured
                total += half_area;
                if (half_area > 64.0 * area) sliver += half_area;
            }
            sums[chunk] = {total, sliver};
        }
    });
    double total = 0.0, sliver = 0.0;
    for (auto const& [t, s] : sums) {
        total += t;
        sliver += s;
    }
    return total > 0.0 ? sliver / total : 0.0;
}

// Whether build_quality::automatic builds these triangles with spatial splits: when at least 5 %
// of the box area belongs to long thin triangles (sliver_box_share).
template <typename T>
bool spatial_splits_pay(std::span<basic_triangle<T> const> prims) {
    return sliver_box_share(prims) >= 0.05;
}

template <traceable Prim>
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

    auto clock = std::chrono::steady_clock::now();
    detail::build_context<S> ctx;
    ctx.options = options;
    if constexpr (stores_triangle_blocks_v<Prim>) ctx.block_size = triangle_block_width;
    ctx.refs.resize(n); // not zeroed (build_buffer): filled here in parallel
    parallel_for_chunks(n, 1024, [&](std::size_t first, std::size_t last) {
        for (std::size_t i = first; i < last; ++i) {
            auto const box = get_bounds(prims[i]);
            ctx.refs[i] = {box.min, std::uint32_t(i), box.max};
        }
    });
    result.build_phases.references = detail::lap(clock);

    detail::build_buffer<bvh_node<S>> nodes;
    nodes.resize(2 * n - 1); // not zeroed: only the nodes made are written, and copied
    ctx.nodes = &nodes;
    detail::bin_scratch<S> scratch(options.bins);
    detail::build_node(ctx, scratch, 0, 0, n, 0, detail::bounds_of(ctx, 0, n));
    std::span<bvh_node<S> const> const tree(nodes.data(), ctx.node_count.load());
    result.depth = ctx.depth.load();
    std::vector<std::uint32_t> order(n);
    parallel_for_chunks(n, 4096, [&](std::size_t first, std::size_t last) {
        for (std::size_t i = first; i < last; ++i) order[i] = ctx.refs[i].index;
    });
    ctx.refs = {};
    result.build_phases.tree = detail::lap(clock);
    detail::finish_build(result, tree, prims, order);
    return result;
}

template <traceable Prim>
bvh<Prim> build_binned_sah(std::vector<Prim> const& prims, bvh_build_options options = {}) {
    return build_binned_sah(std::span<Prim const>(prims), options);
}

} // namespace canopy
