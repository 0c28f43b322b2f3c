// canopy.bvh:wide — collapses a binary BVH into the 8-wide layout that traversal walks.
//
// Each wide node takes a cut of a binary node's subtree, at most bvh_width slots, chosen so that the
// wide tree's node cost (Σ area of its wide nodes) is least (optimal_collapse). Leaves are kept
// as they are: every primitive stays in exactly one leaf. The wide tree is never deeper than the
// binary one. Triangle BVHs then get their leaves packed into triangle blocks
// (pack_triangle_blocks).
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
#include <vector>
export module canopy.bvh:wide;
import canopy.geometry;
import :storage;
import :parallel;
import :build_buffer;

// The builder's own steps: nothing here is exported.
namespace canopy {

namespace detail {

// The collapse that minimises the wide tree's node cost, Σ over wide nodes of their surface area
// (Ylitie, Karras and Laine 2017, "Efficient incoherent ray traversal on GPUs through compressed
// wide BVHs", section 3.1, with the binary tree's leaves kept as they are). Bottom-up over the
// binary nodes (post-order, the subtrees of the top levels in parallel: solve):
//   F(n, k)  the least cost of covering n's subtree with at most k slots: 0 for a leaf; for an
//            inner node the smaller of W(n) (n one slot, a wide node of its own) and, opening n,
//            min over i of F(left, i) + F(right, k − i);
//   W(n)     area(n) + min over i of F(left, i) + F(right, bvh_width − i).
// Then top-down, each wide node takes the slots its W chose. Against the greedy collapse (open the
// largest child until the node is full) this gives fewer wide nodes and fewer node visits per ray,
// which is where a ray's time goes (docs/performance.md). Ties go to the first choice met, so the
// tree depends only on the binary tree.
template <typename S>
struct optimal_collapse {
    using costs = std::array<double, bvh_width + 1>; // F(n, k) for k = 1 … bvh_width ([0] unused)
    std::span<bvh_node<S> const> nodes;
    // Written for every node before they are read (solve), so left unzeroed (build_buffer). The
    // costs F are not kept: each node's are returned to its parent, the only reader.
    // Per inner node and per k = 2 … bvh_width, at [2 (k − 2)] and [2 (k − 2) + 1]: the slots (i, j)
    // its F(n, k) gives its two children; (0, 0): n as one slot (as always for k = 1, not stored).
    // Not written for leaves (gather never reads a leaf's).
    build_buffer<std::array<std::uint8_t, 2 * (bvh_width - 1)>> pick;
    build_buffer<std::uint8_t> open_left; // W(n): the slots its left child gets

    explicit optimal_collapse(std::span<bvh_node<S> const> n) : nodes(n) {
        pick.resize(n.size());
        open_left.resize(n.size());
        if (!n.empty()) solve(0, 0);
    }

    // The subtrees of the top levels are solved in parallel (the binary tree's node indices follow
    // no order that would split the work into ranges: parallel builds allocate them as they go).
    static constexpr int parallel_levels = 6;

    // F and W of x's subtree, children before their parent (post-order); returns F(x, ·). Each
    // node's values depend only on its children's: the result does not depend on the threads.
    costs solve(std::uint32_t x, int level) {
        auto const& node = nodes[x];
        if (node.is_leaf()) {
            open_left[x] = 0;
            return costs{}; // F(leaf, k) = 0: a leaf is one slot, and no wide node
        }
        std::uint32_t const l = node.index, r = l + 1;
        costs left, right;
        if (level < parallel_levels)
            parallel_invoke([&] { left = solve(l, level + 1); }, [&] { right = solve(r, level + 1); });
        else
            left = solve(l, level + 1), right = solve(r, level + 1);
        costs f;
        // Opening x with k slots: the least F(l, i) + F(r, k − i), the first i that reaches it
        // (1 when no cost is finite: NaN or infinite boxes, a valid choice all the same).
        std::array<double, bvh_width + 1> opened;
        std::array<std::uint8_t, bvh_width + 1> opened_left;
        for (int k = 2; k <= bvh_width; ++k) {
            auto const kk = std::size_t(k);
            opened[kk] = std::numeric_limits<double>::infinity();
            opened_left[kk] = 1;
            for (int i = 1; i < k; ++i) {
                double const c = left[std::size_t(i)] + right[std::size_t(k - i)];
                if (c < opened[kk]) opened[kk] = c, opened_left[kk] = std::uint8_t(i);
            }
        }
        open_left[x] = opened_left[bvh_width];
        // A NaN area (a box of NaN coordinates) counts as infinite, so that every comparison
        // is defined; the choices then keep their valid defaults.
        double const area = double(surface_area(node.bounds));
        f[0] = std::numeric_limits<double>::infinity(); // never asked: every cover has a slot
        f[1] = (area == area ? area : std::numeric_limits<double>::infinity()) + opened[bvh_width];
        // F(x, k) = min(F(x, k − 1), opened[k]): the picks of k − 1 unless opening x with k is cheaper.
        auto& p = pick[x];
        std::uint8_t i = 0, j = 0;
        for (int k = 2; k <= bvh_width; ++k) {
            auto const kk = std::size_t(k);
            f[kk] = f[kk - 1];
            if (opened[kk] < f[kk]) f[kk] = opened[kk], i = opened_left[kk], j = std::uint8_t(k - opened_left[kk]);
            p[2 * (kk - 2)] = i, p[2 * (kk - 2) + 1] = j;
        }
        return f;
    }
    // The slots that cover x's subtree with at most k of them, appended to slots[count…].
    void gather(std::uint32_t x, int k, std::uint32_t* slots, int& count) const {
        int i = 0, j = 0; // a leaf, and k = 1: x as one slot
        if (!nodes[x].is_leaf() && k > 1) i = pick[x][2 * std::size_t(k - 2)], j = pick[x][2 * std::size_t(k - 2) + 1];
        if (i == 0 && j == 0) {
            slots[count++] = x;
            return;
        }
        gather(nodes[x].index, i, slots, count);
        gather(nodes[x].index + 1, j, slots, count);
    }
    // Appends the wide node of binary node x, then its wide children depth first; returns its index.
    std::uint32_t emit(std::uint32_t x, wide_node_array<S>& wide) const {
        std::uint32_t slots[bvh_width];
        int n = 0;
        if (nodes[x].is_leaf()) {
            slots[n++] = x;
        } else {
            gather(nodes[x].index, open_left[x], slots, n);
            gather(nodes[x].index + 1, bvh_width - open_left[x], slots, n);
        }
        auto const index = std::uint32_t(wide.size());
        wide.emplace_back();
        {
            auto& w = wide.back();
            S const inf = std::numeric_limits<S>::infinity();
            for (std::size_t a = 0; a < 3; ++a) w.planes[w.min_row(a)].fill(inf), w.planes[w.max_row(a)].fill(-inf);
            w.child.fill(invalid_id);
            w.count.fill(0);
        }
        for (int i = 0; i < n; ++i) {
            auto const& c = nodes[slots[i]];
            auto const k = std::size_t(i);
            std::uint32_t child = c.index;
            if (!c.is_leaf()) child = emit(slots[i], wide);
            auto& w = wide[index]; // emit may have reallocated
            w.set_child_bounds(k, c.bounds);
            w.child[k] = child;
            w.count[k] = c.count;
        }
        return index;
    }
};

} // namespace detail

// The wide layout of a binary tree (empty for an empty tree). Children come after their parents.
template <typename S>
wide_node_array<S> collapse_to_wide(std::span<bvh_node<S> const> nodes) {
    wide_node_array<S> wide;
    if (nodes.empty()) return wide;
    wide.reserve(nodes.size() / 4 + 1);
    detail::optimal_collapse<S>(nodes).emit(0, wide);
    return wide;
}

// Fills the triangle blocks of a triangle BVH straight from the input: leaf by leaf in leaf
// order, the triangles prims[order[i]] with prim_id = order[i] (`order`: the input index of the
// primitive at each leaf position), and points the wide nodes' leaves at their first block
// (count unchanged). `primitives` stays empty. Leaves are filled in parallel, each into blocks
// placed beforehand (a prefix sum of the leaves' block counts), so the result does not depend on
// the threads.
template <typename Prim>
    requires stores_triangle_blocks_v<Prim>
void pack_triangle_blocks(bvh<Prim>& b, std::span<Prim const> prims, std::vector<std::uint32_t> const& order) {
    std::vector<std::uint32_t> leaf_starts;
    for_each_leaf(b, [&](std::uint32_t child, std::uint32_t, auto const&) { leaf_starts.push_back(child); });
    std::sort(leaf_starts.begin(), leaf_starts.end());
    std::size_t const leaves = leaf_starts.size();
    auto const leaf_end = [&](std::size_t k) { return k + 1 < leaves ? std::size_t(leaf_starts[k + 1]) : order.size(); };
    // first_block[k]: the first block of the k-th leaf in leaf order; first_block[leaves]: the total.
    std::vector<std::uint32_t> first_block(leaves + 1, 0);
    for (std::size_t k = 0; k < leaves; ++k)
        first_block[k + 1] = first_block[k] +
                             std::uint32_t((leaf_end(k) - leaf_starts[k] + triangle_block_width - 1) / triangle_block_width);
    b.blocks.clear();
    // Not value-initialised here on one thread: each block is made whole below, by the thread
    // that fills it.
    detail::unwritten_resize(b.blocks, first_block[leaves]);
    parallel_for_chunks(leaves, 256, [&](std::size_t first, std::size_t last) {
        for (std::size_t k = first; k < last; ++k) {
            std::size_t const begin = leaf_starts[k], end = leaf_end(k);
            for (std::size_t block_begin = begin; block_begin < end; block_begin += triangle_block_width) {
                triangle_block block{}; // lanes past the leaf's end: no triangle
                for (std::size_t i = block_begin, stop = std::min(end, block_begin + triangle_block_width); i < stop; ++i) {
                    Prim t = prims[order[i]];
                    t.prim_id = order[i];
                    block.set(int(i - block_begin), t);
                }
                b.blocks[first_block[k] + (block_begin - begin) / triangle_block_width] = block;
            }
        }
    });
    // A leaf's first position s → its first block, block_at[s]: written for every leaf start (the
    // other entries are never read, and stay unwritten).
    detail::build_buffer<std::uint32_t> block_at;
    block_at.resize(order.size());
    parallel_for_chunks(leaves, 4096, [&](std::size_t first, std::size_t last) {
        for (std::size_t k = first; k < last; ++k) block_at[leaf_starts[k]] = first_block[k];
    });
    parallel_for_chunks(b.wide_nodes.size(), 1024, [&](std::size_t first, std::size_t last) {
        for (std::size_t i = first; i < last; ++i) {
            auto& node = b.wide_nodes[i];
            for (std::size_t k = 0; k < std::size_t(bvh_width); ++k)
                if (node.count[k] != 0) node.child[k] = block_at[node.child[k]];
        }
    });
    b.primitives = {};
}

namespace detail {

// The last steps of a build, once `nodes` holds the binary tree (nodes[0] its root; leaves
// indexing `order`, which gives the input index of the primitive at each leaf position; an index
// may appear more than once, see canopy.bvh:spatial): the wide nodes, the root's box, size = the
// input count, and the primitives in leaf order with prim_id = their input index (triangle BVHs:
// in blocks, pack_triangle_blocks). The binary tree is not kept.
template <typename Prim>
void finish_build(bvh<Prim>& result, std::span<bvh_node<bounds_value_t<Prim>> const> nodes, std::span<Prim const> prims,
                  std::vector<std::uint32_t> const& order) {
    auto clock = std::chrono::steady_clock::now();
    result.wide_nodes = collapse_to_wide(nodes);
    result.root_bounds.assign(1, wide_bvh_node<bounds_value_t<Prim>>::stored_box(nodes[0].bounds));
    result.build_phases.wide_nodes = lap(clock);
    result.size = prims.size();
    if constexpr (stores_triangle_blocks_v<Prim>) {
        pack_triangle_blocks(result, prims, order);
    } else {
        result.primitives.resize(order.size());
        parallel_for_chunks(order.size(), 1024, [&](std::size_t first, std::size_t last) {
            for (std::size_t i = first; i < last; ++i) {
                result.primitives[i] = prims[order[i]];
                if constexpr (requires(Prim& p) { p.prim_id = std::uint32_t(0); })
                    result.primitives[i].prim_id = order[i];
            }
        });
    }
    result.build_phases.leaves = lap(clock);
}

} // namespace detail

} // namespace canopy
