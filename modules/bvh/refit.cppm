// canopy.bvh:refit — updating a BVH's boxes after its geometry moved, keeping its tree.
//
//   refit(mesh, moved_triangles);   // a mesh whose vertices moved (same count, order, topology)
//   refit(top);                     // a top level over instances whose BVHs were refitted
//
// refit(b, moved) rewrites the stored primitives from moved[prim_id] (prim_id is the input index;
// the stored prim_id and geom_id are kept, only the geometry changes; triangle blocks get their
// `testable` bits recomputed), then recomputes every box bottom-up: each leaf's box is the union
// of its primitives' boxes, each inner slot's the union of its wide node's slots (the builder
// stores wide nodes after their parents, so one reverse sweep sees children first), the root's
// the union of the root node's slots.
// refit(b) does the same from the primitives b already stores: for a BVH of instances, the boxes
// come from the instances' BVHs as they are now, so refit the levels from the bottom up.
//
// After a refit the queries give exactly the results of a fresh build over the moved geometry
// (same primitive, same t, u and v: the primitive tests do not depend on the boxes); only their
// cost changes. A leaf's box is always the union of its primitives' whole boxes: in a
// build_quality::high tree, where a triangle referenced from several leaves had a clipped piece
// of its box in each, each of those leaves now bounds the whole triangle (conservative, and
// looser than the build's boxes even for unmoved geometry).
//
// The tree is the one built for the old geometry: as the geometry moves away from it, its SAH
// cost grows. sah_drift(b, built_cost) is the SAH cost now over the cost right after the build
// (compute_stats(b).sah_cost, kept by the caller); needs_rebuild says when that ratio passes a
// threshold (default_rebuild_drift, 1.5: the expected traversal cost of a random ray is then half
// as high again as after the build, while a rebuild costs about ten refits).
//
// Leaves are refitted in parallel (bvh:parallel), wide node by wide node; the inner-node sweep
// runs on one thread (a wide node per 4 leaves or so, 8 boxes merged each).
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <cstddef>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>
export module canopy.bvh:refit;
import canopy.geometry;
import :storage;
import :parallel;
import :instance;

namespace canopy::detail {

// The box of a wide node: the union of its used slots.
template <typename S>
basic_aabb<S> node_bounds(wide_bvh_node<S> const& w) {
    basic_aabb<S> box;
    for (int j = 0; j < bvh_width; ++j)
        if (w.used(j)) box = extend(box, w.child_bounds(j));
    return box;
}

// The leaves' boxes from what they store, then every inner box bottom-up, then the root's.
template <typename Prim>
void refit_boxes(bvh<Prim>& b) {
    using S = typename bvh<Prim>::value_type;
    if (b.empty()) return;
    parallel_for_chunks(b.wide_nodes.size(), 256, [&](std::size_t first, std::size_t last) {
        for (std::size_t i = first; i < last; ++i) {
            auto& w = b.wide_nodes[i];
            for (int k = 0; k < bvh_width; ++k) {
                auto const slot = std::size_t(k);
                if (w.count[slot] == 0) continue;
                basic_aabb<S> box;
                for_each_leaf_primitive(b, w.child[slot], w.count[slot], [&](Prim const& p) { box = extend(box, get_bounds(p)); });
                w.set_child_bounds(slot, box);
            }
        }
    });
    for (std::size_t i = b.wide_nodes.size(); i-- > 0;) {
        auto& w = b.wide_nodes[i];
        for (int k = 0; k < bvh_width; ++k) {
            auto const slot = std::size_t(k);
            if (w.used(k) && w.count[slot] == 0) w.set_child_bounds(slot, node_bounds(b.wide_nodes[w.child[slot]]));
        }
    }
    // In place: instances point at this box (bvh_storage).
    if (b.root_bounds.empty()) b.root_bounds.resize(1);
    b.root_bounds[0] = node_bounds(b.wide_nodes[0]);
}

} // namespace canopy::detail

export namespace canopy {

// Recomputes b's boxes from the primitives it stores (see the top of this file).
template <typename Prim>
void refit(bvh<Prim>& b) {
    detail::refit_boxes(b);
}

// Replaces b's primitives by moved[prim_id] (vertices only: the stored prim_id and geom_id are
// kept) and recomputes its boxes. Throws std::invalid_argument unless moved has as many
// primitives as b was built from.
template <typename Prim>
    requires requires(Prim const& p) { std::uint32_t(p.prim_id) + std::uint32_t(p.geom_id); }
void refit(bvh<Prim>& b, std::span<Prim const> moved) {
    if (moved.size() != b.primitive_count())
        throw std::invalid_argument("canopy::refit: " + std::to_string(moved.size()) + " primitives given for a BVH of " +
                                    std::to_string(b.primitive_count()));
    auto const replace = [&](Prim& p) {
        Prim const& m = moved[p.prim_id];
        std::uint32_t const prim_id = p.prim_id, geom_id = p.geom_id;
        p = m;
        p.prim_id = prim_id;
        p.geom_id = geom_id;
    };
    if constexpr (stores_triangle_blocks_v<Prim>) {
        parallel_for_chunks(b.blocks.size(), 256, [&](std::size_t first, std::size_t last) {
            for (std::size_t i = first; i < last; ++i) {
                triangle_block& block = b.blocks[i];
                for (int lane = 0; lane < triangle_block_width; ++lane) {
                    if (block.prim_id[std::size_t(lane)] == invalid_id) continue; // an unused lane
                    Prim p = block.triangle_at(lane);
                    replace(p);
                    block.set(lane, p);
                }
            }
        });
    } else {
        parallel_for_chunks(b.primitives.size(), 1024, [&](std::size_t first, std::size_t last) {
            for (std::size_t i = first; i < last; ++i) replace(b.primitives[i]);
        });
    }
    detail::refit_boxes(b);
}

template <typename Prim>
    requires requires(Prim const& p) { std::uint32_t(p.prim_id) + std::uint32_t(p.geom_id); }
void refit(bvh<Prim>& b, std::vector<Prim> const& moved) {
    refit(b, std::span<Prim const>(moved));
}

// SAH drift and the rebuild threshold (see the top of this file).
inline constexpr double default_rebuild_drift = 1.5;

// b's SAH cost now over built_sah_cost, its cost right after the build (1 for an empty BVH or a
// cost that is not positive).
template <typename Prim>
double sah_drift(bvh<Prim> const& b, double built_sah_cost, sah_costs costs = {}) {
    double const now = compute_stats(b, costs).sah_cost;
    return built_sah_cost > 0.0 && !b.empty() ? now / built_sah_cost : 1.0;
}

// Whether a refitted b has drifted past max_drift (a rebuild then pays, see the top of this file).
template <typename Prim>
bool needs_rebuild(bvh<Prim> const& b, double built_sah_cost, double max_drift = default_rebuild_drift,
                   sah_costs costs = {}) {
    return sah_drift(b, built_sah_cost, costs) > max_drift;
}

} // namespace canopy
