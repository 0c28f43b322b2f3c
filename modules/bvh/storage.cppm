// canopy.bvh:storage — the BVH layout and its statistics.
//
// The builder produces a binary BVH (nodes in one array, the two children of an inner node side
// by side), then collapses it into an 8-wide BVH with the children's boxes stored as
// structure-of-arrays, which is what traversal walks: one node fetch tests eight boxes at once
// (Wald et al. 2008, "Getting Rid of Packets"; Embree's BVH8). Only the wide nodes are kept (the
// binary tree is the builder's scratch): refit, the statistics and the SAH work on them. Primitives are stored once (a
// triangle of a build_quality::high BVH once per leaf holding it), reordered so that each leaf
// owns a contiguous range. Depth never exceeds bvh_max_depth (the
// builder enforces it), which bounds every traversal stack.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <type_traits>
#include <utility>
#include <vector>
export module canopy.bvh:storage;
import canopy.geometry;
import :build_buffer;

export namespace canopy {

// Deepest BVH the builder produces; traversal stacks are sized from it.
inline constexpr int bvh_max_depth = 64;

// Scalar type of a primitive's bounds (float for triangle and for instance<bvh<triangle>>).
template <typename Prim>
using bounds_value_t = typename decltype(get_bounds(std::declval<Prim const&>()))::value_type;

// A node of the builder's binary tree (canopy.bvh:build, canopy.bvh:wide).
template <typename S>
struct bvh_node {
    basic_aabb<S> bounds;
    // Inner node: index of the first child (the second is index + 1), count == 0.
    // Leaf: index of the first primitive, count ≥ 1 primitives.
    std::uint32_t index = 0;
    std::uint32_t count = 0;

    bool is_leaf() const { return count != 0; }
};

// Children per wide node.
inline constexpr int bvh_width = 8;

// A wide node: up to bvh_width children, each an inner wide node or a leaf. Unused slots have
// an empty box (min = +inf, max = -inf), count = 0 and child = invalid_id.
template <typename S>
struct alignas(64) wide_bvh_node {
    // The children's boxes, one row per plane, one column per child: along axis a (x, y, z)
    // the minima in row min_row(a) = 2a and the maxima in row max_row(a) = 2a + 1. A ray's near
    // and far rows on an axis are then one row apart, row ^ 1 (canopy.bvh:traverse).
    std::array<std::array<S, bvh_width>, 6> planes;
    static constexpr std::size_t min_row(std::size_t a) { return 2 * a; }
    static constexpr std::size_t max_row(std::size_t a) { return 2 * a + 1; }
    // count == 0: child is the index of a wide node (or invalid_id for an unused slot);
    // count ≥ 1: child is the first of `count` primitives of a leaf.
    std::array<std::uint32_t, bvh_width> child;
    std::array<std::uint32_t, bvh_width> count;

    // Sets child k's box. Subnormal coordinates are rounded outward, to 0 or to the smallest
    // normal number (outward_from_subnormal): the box grows by less than
    // numeric_limits<S>::min() on such a side, and never shrinks. Every node test multiplies
    // every plane of its node, and on many x86 cores an arithmetic operation with a subnormal
    // operand takes a microcode assist of about a hundred cycles (unless the thread runs with
    // denormals-are-zero, which Canopy never sets: it would change the triangle test's
    // arithmetic). Subnormal planes come from ordinary scenes: an instance's world box is widened
    // by two subnormals for products that underflow (transform_box), so a mesh standing on y = 0
    // gets a lower plane of -3 · denorm_min. Measured on an Intel Xeon (AVX-512), the forest of
    // 10,000 trees standing on y = 0: primary closest 276 → 190 ns per ray
    // (docs/performance.md, Run 20).
    void set_child_bounds(std::size_t k, basic_aabb<S> const& box) {
        auto const stored = stored_box(box);
        for (std::size_t a = 0; a < 3; ++a) {
            planes[min_row(a)][k] = stored.min[int(a)];
            planes[max_row(a)][k] = stored.max[int(a)];
        }
    }
    // The box as a node stores it (set_child_bounds): the BVH's root box is stored so too, and so
    // stays the union of the root's slots (the rounding is monotonic).
    static constexpr basic_aabb<S> stored_box(basic_aabb<S> const& box) {
        basic_aabb<S> r;
        for (int a = 0; a < 3; ++a) {
            r.min[a] = outward_from_subnormal(box.min[a], false);
            r.max[a] = outward_from_subnormal(box.max[a], true);
        }
        return r;
    }
    // x when it is not subnormal; else the nearest of 0 and ±numeric_limits<S>::min() on the
    // side of x that `up` asks for (up: not below x; else not above x). NaN, ±0 and ±inf stay.
    static constexpr S outward_from_subnormal(S x, bool up) {
        S const smallest = std::numeric_limits<S>::min();
        if (!(x > -smallest && x < smallest) || x == S(0)) return x;
        if (up) return x > S(0) ? smallest : S(0);
        return x > S(0) ? S(0) : -smallest;
    }

    basic_aabb<S> child_bounds(int i) const {
        auto const k = std::size_t(i);
        return {vec3<S>(planes[min_row(0)][k], planes[min_row(1)][k], planes[min_row(2)][k]),
                vec3<S>(planes[max_row(0)][k], planes[max_row(1)][k], planes[max_row(2)][k])};
    }
    bool used(int i) const { return child[std::size_t(i)] != invalid_id; }
};

// BVHs of float triangles keep their leaves' triangles in blocks (canopy.geometry:
// triangle_block) instead of `primitives`: traversal tests a block's triangles at once, and hooks
// get each triangle back exactly as given. A leaf (binary node or wide-node slot) then indexes
// blocks: its index is the first block, its count the number of triangles (the last block may be
// partly used). Memory per triangle: a block's share (48 bytes when full) instead of the 44 of a
// triangle plus its copy in a block.
template <typename Prim>
inline constexpr bool stores_triangle_blocks_v = std::is_same_v<Prim, triangle>;

// How hard the builder works on triangle BVHs (other primitives are always built `fast`).
//   fast  binned SAH over object splits.
//   high  spatial splits as well (canopy.bvh:spatial, Stich et al. 2009): a triangle whose box
//         is much larger than itself (long thin triangles, slivers) may be referenced from
//         several leaves, each bounding only its part. Builds take longer and use more memory.
//   automatic  high where spatial splits pay, by a cheap measure of the triangles
//         (spatial_splits_pay in canopy.bvh:build: long thin triangles hold a large share of
//         the boxes' area), else fast: the default. bvh::quality says which one a build used.
enum class build_quality { fast, high, automatic };

// The wide nodes of a BVH (canopy.bvh:build_buffer for the allocator).
template <typename S>
using wide_node_array = std::vector<wide_bvh_node<S>, large_array_allocator<wide_bvh_node<S>>>;

// Where a build's time went, in seconds (canopy info prints it): the input's boxes as the
// builder's references; the binary tree (binning, SAH sweeps, partitions, and at build_quality::high
// the spatial splits); the collapse to wide nodes; the leaves' primitives (triangle blocks) in
// leaf order. A BVH that was not built (default-constructed, or built from nothing) has zeros.
struct build_phase_times {
    double references = 0.0;
    double tree = 0.0;
    double wide_nodes = 0.0;
    double leaves = 0.0;

    double total() const { return references + tree + wide_nodes + leaves; }
};

namespace detail {
// Seconds since `start`, and `start` moved to now: the builder's phase timer.
inline double lap(std::chrono::steady_clock::time_point& start) {
    auto const now = std::chrono::steady_clock::now();
    double const seconds = std::chrono::duration<double>(now - start).count();
    start = now;
    return seconds;
}
} // namespace detail

template <typename Prim>
struct bvh {
    using primitive_type = Prim;
    using value_type = bounds_value_t<Prim>;
    using acceleration_structure_tag = void;

    wide_node_array<value_type> wide_nodes; // the tree, 8-wide; [0] is the root; empty for an empty BVH
    // The root's box, the one element of a heap buffer (empty for an empty BVH): instances point at
    // it (bvh_storage), so that it stays where it is when the bvh object moves and they see refits.
    std::vector<basic_aabb<value_type>> root_bounds;
    std::vector<Prim> primitives;   // in leaf order; empty when stores_triangle_blocks_v<Prim>
    std::vector<triangle_block, large_array_allocator<triangle_block>>
        blocks;                     // stores_triangle_blocks_v<Prim>: the leaves' triangles
    std::size_t size = 0;           // number of input primitives (leaves may hold more references: build_quality::high)
    int depth = 0;                  // levels of the builder's binary tree (a single leaf: 1); the wide tree has no more
    build_quality quality = build_quality::fast; // how it was built (fast or high, automatic resolved)
    build_phase_times build_phases;              // where the build's time went

    bool empty() const { return wide_nodes.empty(); }
    std::size_t primitive_count() const { return size; }
    basic_aabb<value_type> bounds() const { return root_bounds.empty() ? basic_aabb<value_type>{} : root_bounds[0]; }
};

// Calls f(primitive) for each primitive of the leaf that a wide node's slot (child, count) or a
// binary node (index, count) points to, in leaf order: from the triangle blocks of triangle BVHs, else from
// `primitives`.
template <typename Prim, typename F>
void for_each_leaf_primitive(bvh<Prim> const& b, std::uint32_t child, std::uint32_t count, F&& f) {
    if constexpr (stores_triangle_blocks_v<Prim>) {
        for (std::uint32_t i = 0; i < count; ++i)
            f(b.blocks[child + i / triangle_block_width].triangle_at(int(i % triangle_block_width)));
    } else {
        for (std::uint32_t i = child; i < child + count; ++i) f(b.primitives[i]);
    }
}

// Calls f(child, count, box) for each leaf of b (a wide node's slot with count ≥ 1), in the
// order of the wide nodes.
template <typename Prim, typename F>
void for_each_leaf(bvh<Prim> const& b, F&& f) {
    for (auto const& w : b.wide_nodes)
        for (int k = 0; k < bvh_width; ++k)
            if (w.count[std::size_t(k)] != 0) f(w.child[std::size_t(k)], w.count[std::size_t(k)], w.child_bounds(k));
}

// Calls f(primitive) once for each primitive reference of b, leaf by leaf: once per primitive,
// except in triangle BVHs built with spatial splits (build_quality::high), where a triangle is
// visited once per leaf holding it.
template <typename Prim, typename F>
void for_each_primitive(bvh<Prim> const& b, F&& f) {
    for_each_leaf(b, [&](std::uint32_t child, std::uint32_t count, auto const&) { for_each_leaf_primitive(b, child, count, f); });
}

// A BVH's bounds as a primitive of an enclosing structure (a list of BVHs, multiple roots).
template <typename Prim>
basic_aabb<bounds_value_t<Prim>> get_bounds(bvh<Prim> const& b) {
    return b.bounds();
}

// Surface area heuristic costs (MacDonald & Booth 1990): per node visited and per primitive tested.
struct sah_costs {
    float traversal = 1.0f;
    float intersection = 1.0f;
};


// The builder's options, one aggregate with its defaults.
struct bvh_build_options {
    int max_leaf_size = 0;                    // primitives per leaf; 0: triangle_block_width for triangle BVHs, else 4
    int bins = 16;                            // SAH bins per axis (2 … 256)
    int max_depth = bvh_max_depth;            // clamped to [1, bvh_max_depth]
    sah_costs costs = {};
    std::size_t parallel_threshold = 4096;    // subtrees with more primitives become parallel tasks
    build_quality quality = build_quality::automatic;
    // high: extra references spatial splits may add, as a fraction of the triangle count (≥ 0).
    float split_budget = 0.3f;
    // high: spatial splits are tried where the two sides of the best object split overlap by more
    // than this fraction of the root's surface area (Stich et al.'s α).
    float split_overlap = 1e-5f;
    // high: and where that overlap is also more than this fraction of the node's own surface area
    // (Embree's second test and value; 0: the first test alone).
    float split_node_overlap = 0.1f;
    // high: and where clipping those two sides apart along the split's axis could shrink one of
    // them by more than this fraction of its surface area (a bound on what a spatial split along
    // that axis could gain; 0: no such test).
    float split_min_gain = 0.03f;
    // high: spatial splits are tried only in nodes of at least this many references (0 or 1: in
    // every node). Below, a split gains little SAH, and binning the references' clipped parts
    // costs the most per reference (each crosses many bins of a small node).
    std::uint32_t split_min_references = 16;
};

// A BVH's statistics, over the wide tree that traversal walks.
struct bvh_stats {
    std::size_t node_count = 0;      // wide nodes + leaves
    std::size_t leaf_count = 0;
    std::size_t primitive_count = 0; // input primitives
    std::size_t reference_count = 0; // primitives in the leaves (more than primitive_count after spatial splits)
    int depth = 0;                   // bvh::depth
    std::size_t max_leaf_size = 0;
    // Expected cost of a random ray hitting the root box: Σ over wide nodes of area/root area ×
    // traversal, plus Σ over leaves of area/root area × count × intersection.
    double sah_cost = 0.0;
    std::size_t wide_node_count = 0;
    std::size_t bytes = 0;           // wide nodes + root box + primitives + triangle blocks
    double bytes_per_primitive = 0.0;
};

template <typename Prim>
bvh_stats compute_stats(bvh<Prim> const& b, sah_costs costs = {}) {
    using S = typename bvh<Prim>::value_type;
    bvh_stats s;
    s.primitive_count = b.primitive_count();
    s.depth = b.depth;
    s.wide_node_count = b.wide_nodes.size();
    s.bytes = b.wide_nodes.size() * sizeof(wide_bvh_node<S>) + b.root_bounds.size() * sizeof(basic_aabb<S>) +
              b.primitives.size() * sizeof(Prim) + b.blocks.size() * sizeof(triangle_block);
    if (b.empty()) return s;
    double const root_area = surface_area(b.bounds());
    auto const rel = [&](basic_aabb<S> const& box) { return root_area > 0.0 ? double(surface_area(box)) / root_area : 1.0; };
    // The root by its box; every other wide node by its slot in its parent.
    s.sah_cost = rel(b.bounds()) * costs.traversal;
    for (auto const& w : b.wide_nodes) {
        for (int k = 0; k < bvh_width; ++k) {
            auto const slot = std::size_t(k);
            if (!w.used(k)) continue;
            if (w.count[slot] == 0) {
                s.sah_cost += rel(w.child_bounds(k)) * costs.traversal;
                continue;
            }
            ++s.leaf_count;
            s.reference_count += w.count[slot];
            s.max_leaf_size = std::max<std::size_t>(s.max_leaf_size, w.count[slot]);
            s.sah_cost += rel(w.child_bounds(k)) * costs.intersection * w.count[slot];
        }
    }
    s.node_count = s.wide_node_count + s.leaf_count;
    s.bytes_per_primitive = s.primitive_count ? double(s.bytes) / double(s.primitive_count) : 0.0;
    return s;
}

} // namespace canopy
