// canopy.bvh:traverse — depth-first traversal of the 8-wide BVH with the caller's intersector
// and query.
//
// Each visited node tests its children's boxes, nearest hit child first, the others pushed far to
// near (queries that stop at any hit, Query::wants_near_first == false, visit them in slot order
// instead). Which
// box test runs is decided at compile time (node_tester):
// - the intersector has its own box hook → the hook, once per child box (it sees every test);
// - otherwise, scalar float rays → all eight boxes in one SIMD slab test (no per-box calls), with
//   the ray's constants computed once per BVH (wide_box_ray); one fma per plane where the build
//   has FMA and the ray's constants are finite (canopy.geometry:box, slab_offsets), else a
//   subtraction and a product (the loop is built for each, chosen once per ray and BVH);
// - packets of float rays with no box hook, when every lane takes the fused form and all lanes
//   share each direction sign (coherent packets) → one child box at a time against all lanes,
//   with the packet's constants prepared once per BVH (no per-box choice of form or of planes);
// - otherwise (double rays, other packets) → the library's box test, once per child box.
// All three compute the same conservative test (canopy.geometry:box): same hits, same order. The
// box tests of a ray are widened for its watertight triangle tests once per BVH entered with a
// new ray (prepared_ray::widen_box_tests_for): no triangle the watertight test would hit sits in
// a box the traversal culls.
// Every primitive goes through call_hooks_or_descend (canopy.bvh:protocol): nested BVHs and
// instances receive the same intersector and query; the leaves of triangle BVHs are blocks of four
// triangles. Stacked entries whose entry distance lies beyond the ray's current tmax are skipped
// (closest-hit culling). Packet rays visit a child when a lane that reached the node hits it, and
// test a leaf's primitives only for the lanes that reached it (the others get tmax −inf there): each
// lane meets the leaves it would meet alone, in the same order for any hit. The memory of
// every hit child is prefetched as soon as the node test is done, so that cache misses overlap
// (incoherent rays in large BVHs are memory-bound).
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
export module canopy.bvh:traverse;
import canopy.intersector;
import :storage;
import :protocol;

export namespace canopy {

// Packets whose lanes reaching a node, or a leaf of instances or nested BVHs, are fewer than this
// trace it one lane at a time, as scalar rays (Embree's hybrid traversal): a packet pays a whole
// packet's work per box for the few lanes it carries, where a scalar ray tests 8 boxes at once.
// Leaves of triangle blocks are always tested as a packet, whatever its lanes: a lane going on
// alone pays its own set-up (its scalar ray, its shear, its query) before its one block test,
// which costs more than the packet's test of the block's triangles (measured: docs/performance.md,
// Run 13). Only for intersectors that intercept nothing (see may_trace_lanes_alone); results are
// the same.
inline constexpr int packet_lanes_alone_below = 2;

// The arrays that traversal of a BVH reads: heap buffers, which stay where they are when the bvh
// object moves (std::vector's move constructor keeps its buffer). Instances hold this instead of
// the bvh's address, so that moving a BVH (a growing std::vector<bvh<...>>) leaves them valid.
template <typename Prim>
struct bvh_storage {
    using value_type = typename bvh<Prim>::value_type;
    using leaf_type = std::conditional_t<stores_triangle_blocks_v<Prim>, triangle_block, Prim>;
    // Vector growth moves bvh objects (keeping their buffers) only if the move cannot throw.
    static_assert(std::is_nothrow_move_constructible_v<bvh<Prim>>);

    bvh_storage() = default;
    inline explicit bvh_storage(bvh<Prim> const& b) {
        if (b.wide_nodes.empty() || b.root_bounds.empty()) return;
        root = b.root_bounds.data();
        wide_nodes = b.wide_nodes.data();
        if constexpr (stores_triangle_blocks_v<Prim>)
            leaves = b.blocks.data();
        else
            leaves = b.primitives.data();
    }

    inline bool empty() const { return root == nullptr; }
    inline basic_aabb<value_type> bounds() const { return root == nullptr ? basic_aabb<value_type>{} : *root; }

    basic_aabb<value_type> const* root = nullptr; // the root's box (bvh::root_bounds); nullptr for an empty BVH
    wide_bvh_node<value_type> const* wide_nodes = nullptr;
    leaf_type const* leaves = nullptr; // the leaves' triangle blocks, or their primitives
};

} // namespace canopy

export namespace canopy::detail {

// What the packets traced on one thread met, summed over traversals (canopy.query:batch reads it
// to tell whether packets pay): wide nodes visited and the lanes that reached them, leaves visited
// and the lanes that reached them, lanes that went on alone (packet_lanes_alone_below). Counted
// only by packets of intersectors that intercept nothing (may_trace_lanes_alone); single rays
// count nothing.
struct packet_occupancy {
    std::uint64_t node_visits = 0, node_lanes = 0;
    std::uint64_t leaf_visits = 0, leaf_lanes = 0;
    std::uint64_t lanes_alone = 0;
};
inline thread_local packet_occupancy packet_occupancy_tally;

} // namespace canopy::detail

namespace canopy::detail {

// The lanes of a packet that reached a node (bit k: lane k hit every box on the way); nothing for
// scalar rays.
struct no_lanes {};
template <typename T>
using lanes_t = std::conditional_t<simd::simd_width_v<T> == 1, no_lanes, std::uint32_t>;

// Hit children of a wide node: bit i of mask set when child i is hit, entry distance in tnear[i]
// (for packets: the smallest over the lanes that hit it, and in lanes[i] those lanes; tnear is
// left unset by tests asked for no distances, see culls_by_lanes).
template <typename S, typename L = no_lanes>
struct child_hits {
    std::uint32_t mask = 0;
    std::array<S, bvh_width> tnear;
    [[no_unique_address]] std::conditional_t<std::is_same_v<L, no_lanes>, no_lanes, std::array<L, bvh_width>> lanes;
};

// The rows of wide_bvh_node::planes that hold axis a's near and far planes for a ray that runs
// towards negative a (an inverse direction below 0; 1/-0 = -inf counts as negative, as in
// canopy.geometry:box): the minima's row 2a and the maxima's 2a + 1, swapped for such rays. The
// far row is the near row ^ 1, so a ray keeps only its near rows.
[[gnu::always_inline]] constexpr std::size_t near_plane_row(std::size_t a, bool negative) {
    return wide_bvh_node<float>::min_row(a) + std::size_t(negative);
}
[[gnu::always_inline]] constexpr std::size_t far_plane_row(std::size_t near_row) { return near_row ^ 1u; }

// The constants of the 8-wide box test for one scalar float ray, computed once per BVH: in every
// lane the inverse direction and either the fused test's offsets (Fused: canopy.geometry:box,
// slab_offsets) or the near and far origins, and the near plane row of each axis (by the sign
// of the inverse direction, Ize 2013's ordered slabs: no select per node).
template <bool Fused>
struct wide_box_ray {
    // Member functions of a class in a named module are not implicitly inline: say so, or
    // importers call them instead of inlining them.
    [[gnu::always_inline]] inline explicit wide_box_ray(prepared_ray<float> const& ray) {
        for (int a = 0; a < 3; ++a) {
            auto const k = std::size_t(a);
            if constexpr (Fused) {
                near_term[k] = simd::float8(-ray.slabs.near_offset[a]);
                far_term[k] = simd::float8(-ray.slabs.far_offset[a]);
            } else {
                near_term[k] = simd::float8(ray.near_origin[a]);
                far_term[k] = simd::float8(ray.far_origin[a]);
                shifts.near[k] = simd::float8(ray.near_shift[a]);
                shifts.far[k] = simd::float8(ray.far_shift[a]);
            }
            inv_dir[k] = simd::float8(ray.inv_dir[a]);
            near_rows[k] = near_plane_row(k, ray.inv_dir[a] < 0.0f);
        }
        tmin = simd::float8(ray.tmin);
        set_tmax(ray.tmax);
    }

    [[gnu::always_inline]] inline void set_tmax(float ray_tmax) {
        box_tmax = box_test_tmax(ray_tmax);
        box_tmax8 = simd::float8(box_tmax);
    }

    // The distance to the near (or far) plane of every child on axis a.
    template <bool Near>
    [[gnu::always_inline]] inline simd::float8 distance(wide_bvh_node<float> const& node, std::size_t a) const {
        std::size_t const row = Near ? near_rows[a] : far_plane_row(near_rows[a]);
        auto const planes = simd::float8::load(node.planes[row].data());
        auto const& term = Near ? near_term : far_term;
        if constexpr (Fused)
            return simd::fma(planes, inv_dir[a], term[a]); // plane · r − origin · r, one rounding
        else // canopy.geometry:box, intersect_slabs
            return ((planes - term[a]) + (Near ? shifts.near[a] : shifts.far[a])) * inv_dir[a];
    }

    // Fused: minus the offsets; else the near and far origins (prepared_ray::widen_box_tests_for),
    // and the shifts of the differences (none in the fused form).
    struct shift_rows {
        std::array<simd::float8, 3> near, far;
    };
    std::array<simd::float8, 3> near_term, far_term, inv_dir;
    [[no_unique_address]] std::conditional_t<Fused, no_lanes, shift_rows> shifts;
    // The near plane row of each axis; the far row is far_plane_row of it (the compiler may keep
    // both per ray: loads of spilled row offsets are off the loop's critical path, measured in
    // docs/performance.md, Run 11).
    std::array<std::size_t, 3> near_rows;
    simd::float8 tmin, box_tmax8;
    float box_tmax = 0.0f;
};

// All eight child boxes against one scalar float ray at once; lane by lane the arithmetic of
// canopy.geometry:box (intersect_slabs_fused or intersect_slabs), the same hits. The far distances
// are scaled after their minimum: rounding is monotonic, so min(fl(a·s), fl(b·s)) = fl(min(a, b)·s)
// exactly; NaN distances (a ray in a slab's boundary plane, subtraction form only) drop out of
// max/min on the same side as in the per-box test.
template <bool Fused>
[[gnu::always_inline]] inline child_hits<float> test_children_wide(wide_box_ray<Fused> const& ray,
                                                                   wide_bvh_node<float> const& node) {
    using simd::float8;
    float8 tnear, tfar;
    float8 const scale(box_far_scale<float>);
    if constexpr (Fused) {
        // No NaN in this form (canopy.geometry:box, slab_offsets), so max and min are associative
        // and commutative bit for bit, and the scale distributes over min exactly (rounding is
        // monotonic): the reductions are trees, two steps from the distances to tnear and three
        // to tfar where chains took three and four. A node's test is on the path from one node
        // to the next, so its depth is what a ray waits for at every visit.
        float8 const n0 = ray.template distance<true>(node, 0), n1 = ray.template distance<true>(node, 1),
                     n2 = ray.template distance<true>(node, 2);
        float8 const f0 = ray.template distance<false>(node, 0), f1 = ray.template distance<false>(node, 1),
                     f2 = ray.template distance<false>(node, 2);
        tnear = simd::max(simd::max(n0, n1), simd::max(n2, ray.tmin));
        tfar = simd::min(simd::min(f0, f1) * scale, simd::min(f2 * scale, ray.box_tmax8));
    } else {
        tnear = ray.tmin;
        tfar = float8(std::numeric_limits<float>::infinity());
        for (std::size_t a = 0; a < 3; ++a) {
            tnear = simd::max(ray.template distance<true>(node, a), tnear);
            tfar = simd::min(ray.template distance<false>(node, a), tfar);
        }
        tfar = simd::min(tfar * scale, ray.box_tmax8);
    }
    child_hits<float> h;
    if constexpr (Fused) {
        // Unused slots hold empty boxes, which the fused form misses by construction (finite,
        // non-zero inverse direction: canopy.geometry:box, slab_offsets).
        h.mask = simd::movemask(tnear <= tfar);
    } else {
        // A NaN or infinite ray can make an empty box look hit: unused slots are masked out by
        // their child index.
        auto const used = simd::int8::load(reinterpret_cast<std::int32_t const*>(node.child.data())) !=
                          simd::int8(std::int32_t(-1));
        h.mask = simd::movemask((tnear <= tfar) & used);
    }
    tnear.store(h.tnear.data());
    return h;
}

// Child boxes one at a time through test_box (hook or default). A packet's child is hit by the
// lanes that reached the node (`lanes`) and hit its box: the others, as alone, never enter it.
template <bool Distances, typename T, typename S, typename I>
[[gnu::always_inline]] inline child_hits<S, lanes_t<T>> test_children_each(prepared_ray<T> const& ray,
                                                                          wide_bvh_node<S> const& node, I& isect,
                                                                          lanes_t<T> lanes) {
    child_hits<S, lanes_t<T>> h;
    for (int i = 0; i < bvh_width && node.used(i); ++i) {
        auto const box = test_box(isect, ray, node.child_bounds(i), ray.inv_dir);
        if constexpr (simd::simd_width_v<T> == 1) {
            if (!box.hit) continue;
            h.mask |= 1u << i;
            h.tnear[std::size_t(i)] = box.tnear;
        } else {
            std::uint32_t const hit_lanes = simd::movemask(box.hit) & lanes;
            if (hit_lanes == 0) continue;
            h.mask |= 1u << i;
            h.lanes[std::size_t(i)] = hit_lanes;
            if constexpr (Distances)
                h.tnear[std::size_t(i)] = simd::reduce_min(
                    simd::select(simd::mask_type_t<T>::from_bits(hit_lanes), box.tnear, T(std::numeric_limits<S>::infinity())));
        }
    }
    return h;
}

// Largest tmax over the lanes (inactive lanes hold -inf).
template <typename T>
auto widest_tmax(T const& tmax) {
    if constexpr (simd::simd_width_v<T> == 1)
        return tmax;
    else
        return simd::reduce_max(tmax);
}

// The box test of one traversal, chosen at compile time (see the top of this file). test(node)
// gives the hit children; box_tmax() the distance beyond which a stacked child is culled;
// tmax_changed() is called after leaves, which may have tightened the ray's tmax.
template <typename T, typename S, typename I>
inline constexpr bool uses_wide_box_test = std::is_same_v<T, float> && std::is_same_v<S, float> &&
                                           !box_hook_for<I, prepared_ray<T>, basic_aabb<S>, vec3<T>>;

template <typename T, typename S, typename I, bool Fused = false>
struct node_tester {
    node_tester(prepared_ray<T> const& r, I& i) : ray(r), isect(i) {}

    // Distances: whether the hit children's entry distances are wanted (see culls_by_lanes).
    template <bool Distances = true>
    child_hits<S, lanes_t<T>> test(wide_bvh_node<S> const& node, lanes_t<T> lanes) {
        return test_children_each<Distances>(ray, node, isect, lanes);
    }
    S box_tmax() const { return box_test_tmax(widest_tmax(ray.tmax)); }
    void tmax_changed() {}

    prepared_ray<T> const& ray;
    I& isect;
};

template <typename T, typename S, typename I, bool Fused>
    requires uses_wide_box_test<T, S, I>
struct node_tester<T, S, I, Fused> {
    node_tester(prepared_ray<float> const& r, I&) : ray(r), box_ray(r) {}

    template <bool = true> // scalar rays always take the distances
    [[gnu::always_inline]] child_hits<float> test(wide_bvh_node<float> const& node, no_lanes) const {
        return test_children_wide(box_ray, node);
    }
    float box_tmax() const { return box_ray.box_tmax; }
    void tmax_changed() { box_ray.set_tmax(ray.tmax); }

    prepared_ray<float> const& ray;
    wide_box_ray<Fused> box_ray;
};

// Packets whose box test needs no hook: one child box at a time against all lanes, with the
// packet's constants prepared once per BVH entered (as wide_box_ray for scalar rays). Chosen at
// run time when every lane can take the fused form (canopy.geometry:box, slab_offsets) and all
// lanes share the sign of each direction component (coherent packets: the batch queries form
// them so), so that each axis has one near and one far plane row for the whole packet. Lane by
// lane this is intersect_slabs_fused: the same fma, max and min in the same order, the first far
// distance standing for min(+inf, it) (no NaN in this form), the same far scale and widened tmax.
template <typename T, typename S, typename I>
inline constexpr bool uses_packet_box_test = (simd::simd_width_v<T> > 1) &&
                                             std::is_same_v<simd::scalar_type_t<T>, float> &&
                                             std::is_same_v<S, float> &&
                                             !box_hook_for<I, prepared_ray<T>, basic_aabb<S>, vec3<T>>;

// Whether every lane's inverse direction has the same sign on each axis.
template <typename T>
[[gnu::always_inline]] inline bool signs_agree(vec3<T> const& inv_dir) {
    constexpr std::uint32_t all = (std::uint32_t(1) << simd::simd_width_v<T>) - 1u;
    for (int a = 0; a < 3; ++a) {
        std::uint32_t const negative = simd::movemask(inv_dir[a] < T(0.0f));
        if (negative != 0 && negative != all) return false;
    }
    return true;
}

template <typename T, typename S, typename I>
    requires uses_packet_box_test<T, S, I>
struct node_tester<T, S, I, true> {
    [[gnu::always_inline]] inline node_tester(prepared_ray<T> const& r, I&) : ray(r) {
        for (int a = 0; a < 3; ++a) {
            auto const k = std::size_t(a);
            bool const negative = simd::movemask(r.inv_dir[a] < T(0.0f)) != 0;
            near_row[k] = near_plane_row(k, negative);
            near_term[k] = -r.slabs.near_offset[a];
            far_term[k] = -r.slabs.far_offset[a];
            // The packet's bounds for the frustum test (all lanes: every one is finite here).
            inv_dir_lo[k] = simd::float8(simd::reduce_min(r.inv_dir[a]));
            inv_dir_hi[k] = simd::float8(simd::reduce_max(r.inv_dir[a]));
            near_term_lo[k] = simd::float8(simd::reduce_min(near_term[k]));
            far_term_hi[k] = simd::float8(simd::reduce_max(far_term[k]));
        }
        tmax_changed();
    }

    // The children that some lane of the packet may hit, all eight at once: a superset of those
    // the lanes hit (Reshetov et al. 2005's frustum, in interval form). Per axis, for every lane
    // i, p·r_i lies between p·r_lo and p·r_hi (all lanes share the sign of r), and the lane's
    // term between the packet's extremes; rounding is monotonic, so the smaller of the two fused
    // products bounds every lane's near distance from below and the larger every far distance from
    // above, bit for bit as the lanes compute them. The far bound scaled and clipped by the widest
    // box tmax bounds each lane's tfar from above (box_test_tmax is monotonic): a child whose
    // lower bound exceeds it is missed by every lane. Empty slots give +inf against -inf.
    [[gnu::always_inline]] inline std::uint32_t frustum_candidates(wide_bvh_node<float> const& node) const {
        using simd::float8;
        float8 lo, hi;
        for (std::size_t a = 0; a < 3; ++a) {
            auto const pn = float8::load(node.planes[near_row[a]].data());
            auto const pf = float8::load(node.planes[far_plane_row(near_row[a])].data());
            float8 const n = simd::min(simd::fma(pn, inv_dir_lo[a], near_term_lo[a]), simd::fma(pn, inv_dir_hi[a], near_term_lo[a]));
            float8 const f = simd::max(simd::fma(pf, inv_dir_lo[a], far_term_hi[a]), simd::fma(pf, inv_dir_hi[a], far_term_hi[a]));
            lo = a == 0 ? n : simd::max(n, lo);
            hi = a == 0 ? f : simd::min(f, hi);
        }
        hi = simd::min(hi * float8(box_far_scale<float>), box_tmax_widest);
        return simd::movemask(lo <= hi);
    }

    // The frustum test first picks, all eight slots at once, the children that some lane may hit
    // (frustum_candidates, a superset of the children hit); each of those is then tested against
    // every lane. Slots the frustum drops, unused ones included (empty boxes, which the fused form
    // misses by construction: every lane's inverse direction is finite and non-zero here,
    // canopy.geometry:box, slab_offsets), are missed by every lane, so the hits are those of
    // testing every slot. A hit child's entry distance, the smallest over the lanes that hit it,
    // is reduced only for the children hit, and only when Distances (see culls_by_lanes).
    template <bool Distances = true>
    [[gnu::always_inline]] inline child_hits<float, std::uint32_t> test(wide_bvh_node<float> const& node,
                                                                        std::uint32_t lanes) const {
        [[maybe_unused]] T const missed(std::numeric_limits<float>::infinity());
        auto const reached = simd::mask_type_t<T>::from_bits(lanes); // once per node, not per child
        child_hits<float, std::uint32_t> h;
        [[maybe_unused]] std::array<T, bvh_width> entry; // per child: tnear in the lanes that hit it, +inf elsewhere
        for (std::uint32_t candidates = frustum_candidates(node); candidates != 0; candidates &= candidates - 1) {
            int const i = std::countr_zero(candidates);
            auto const c = std::size_t(i);
            T tnear = ray.tmin;
            T tfar;
            for (std::size_t a = 0; a < 3; ++a) {
                tnear = simd::max(simd::fma(T(node.planes[near_row[a]][c]), ray.inv_dir[int(a)], near_term[a]), tnear);
                T const far = simd::fma(T(node.planes[far_plane_row(near_row[a])][c]), ray.inv_dir[int(a)], far_term[a]);
                tfar = a == 0 ? far : simd::min(far, tfar);
            }
            tfar = simd::min(tfar * T(box_far_scale<float>), box_tmax_lanes);
            auto const hit = (tnear <= tfar) & reached;
            std::uint32_t const hit_lanes = simd::movemask(hit);
            h.mask |= std::uint32_t(hit_lanes != 0) << i;
            h.lanes[c] = hit_lanes;
            if constexpr (Distances) entry[c] = simd::select(hit, tnear, missed);
        }
        if constexpr (Distances) {
            for (std::uint32_t m = h.mask; m != 0; m &= m - 1) {
                auto const c = std::size_t(std::countr_zero(m));
                h.tnear[c] = simd::reduce_min(entry[c]);
            }
        }
        return h;
    }
    // The widest box tmax, reduced once per change of the lanes' tmax (for the stack's culling and
    // the frustum).
    float box_tmax() const { return box_tmax_scalar; }
    [[gnu::always_inline]] inline void tmax_changed() {
        box_tmax_lanes = box_test_tmax(ray.tmax);
        box_tmax_scalar = box_test_tmax(widest_tmax(ray.tmax));
        box_tmax_widest = simd::float8(box_tmax_scalar);
    }

    prepared_ray<T> const& ray;
    std::array<T, 3> near_term, far_term; // minus the fused offsets
    std::array<std::size_t, 3> near_row; // the far row is far_plane_row(near_row[a])
    T box_tmax_lanes;
    // The frustum (frustum_candidates): per axis the extremes of the lanes' inverse directions,
    // the smallest near term and the largest far term; the widest box tmax.
    std::array<simd::float8, 3> inv_dir_lo, inv_dir_hi, near_term_lo, far_term_hi;
    simd::float8 box_tmax_widest;
    float box_tmax_scalar;
};

// Starts loading the memory of one pending child (a wide node, or a leaf's primitives) into the
// cache, so that the loads of all hit children overlap with each other and with the work on the
// current node, instead of each waiting for memory when its turn comes.
template <typename Prim>
[[gnu::always_inline]] inline void prefetch_child(bvh_storage<Prim> const& b, std::uint32_t child,
                                                  std::uint32_t count) {
    constexpr std::uintptr_t line = 64;
    using S = typename bvh<Prim>::value_type;
    if (count == 0) {
        // A wide node: aligned to a cache line, sizeof(wide_bvh_node<S>) / 64 lines.
        auto const* p = reinterpret_cast<char const*>(&b.wide_nodes[child]);
        for (std::size_t k = 0; k < sizeof(wide_bvh_node<S>); k += line) __builtin_prefetch(p + k);
    } else if constexpr (stores_triangle_blocks_v<Prim>) {
        // The leaf's first block (most leaves have one): aligned to a cache line.
        auto const* p = reinterpret_cast<char const*>(&b.leaves[child]);
        for (std::size_t k = 0; k < sizeof(triangle_block); k += line) __builtin_prefetch(p + k);
    } else {
        auto const begin = reinterpret_cast<std::uintptr_t>(&b.leaves[child]);
        auto const end = begin + count * sizeof(Prim);
        for (std::uintptr_t a = begin & ~(line - 1); a < end; a += line)
            __builtin_prefetch(reinterpret_cast<void const*>(a));
    }
}

// One pending child: a wide node (count 0) or a leaf, with the distance at which the ray enters it
// (and, for packets, the lanes that enter it). No default member initialisers: the stack's array
// of entries is left uninitialised (a packet's would otherwise be zeroed, ~450 stores, at every
// traversal); entries are written whole before they are read.
template <typename S, typename L = no_lanes>
struct traversal_entry {
    std::uint32_t child;
    std::uint32_t count; // 0: wide node; ≥ 1: leaf
    S tnear;
    [[no_unique_address]] L lanes;
};

// The pending children of one traversal. Depth never exceeds bvh_max_depth, and each level
// pushes at most bvh_width - 1 entries.
template <typename S, typename L = no_lanes>
using traversal_entries = std::array<traversal_entry<S, L>, (bvh_width - 1) * bvh_max_depth + 1>;

// The traversal's view of its entries (traversal_entries, a separate local): the bottom and the
// top, two pointers that stay in registers. The top is a pointer, not an int count: the
// entries' 32-bit fields may alias an int, so a count would be reloaded after every entry stored.
// And the pointers are not members of the array's object: a pointer into an object stored in
// that same object makes its address escape, and the compiler then keeps the top in memory,
// reloading and storing it at every push and pop.
template <typename S, typename L = no_lanes>
struct traversal_stack {
    [[gnu::always_inline]] inline explicit traversal_stack(traversal_entries<S, L>& storage)
        : bottom(storage.data()), top(storage.data()) {}
    traversal_stack(traversal_stack const&) = delete;
    traversal_stack& operator=(traversal_stack const&) = delete;

    [[gnu::always_inline]] inline void push(traversal_entry<S, L> const& e) { *top++ = e; }

    // Pops into `next` the most recent entry that the ray still enters before box_tmax; false
    // when none is left.
    [[gnu::always_inline]] inline bool pop_nearer_than(S box_tmax, traversal_entry<S, L>& next) {
        while (top != bottom) {
            --top;
            if (top->tnear <= box_tmax) {
                next = *top;
                return true;
            }
        }
        return false;
    }

    // Pops into `next` the most recent entry that some lane of `live` enters, with its lanes
    // narrowed to those (culls_by_lanes); false when none is left.
    [[gnu::always_inline]] inline bool pop_entered_by(L live, traversal_entry<S, L>& next) {
        while (top != bottom) {
            --top;
            if (L const lanes = top->lanes & live) {
                next = *top;
                next.lanes = lanes;
                return true;
            }
        }
        return false;
    }

    traversal_entry<S, L>* bottom;
    traversal_entry<S, L>* top; // one past the most recent entry
};

// The hit children of `node` in visiting order: returns the first to visit and pushes the
// others so that they pop in order, each prefetched as it is read (prefetch_child). Near to far
// when the query wants it (closest, multi hit; as Embree's traverseClosestHit: one and two
// children without sorting, more sorted by insertion straight into the stack, farthest deepest);
// else in increasing slot order (any hit: every hit child is visited until one primitive is hit).
// Slot order makes any-hit traversal a depth-first walk in one fixed order, whichever children a
// ray hits: a packet visits the leaves each of its lanes would visit alone in the same relative
// order, so each lane finds the same first hit (canopy.query:batch).
template <bool near_first, typename Prim, typename S, typename L>
[[gnu::always_inline]] inline traversal_entry<S, L> order_children(bvh_storage<Prim> const& b,
                                                                   wide_bvh_node<S> const& node,
                                                                   child_hits<S, L> const& hits,
                                                                   traversal_stack<S, L>& stack) {
    // Any-hit packets' tests give no distances (culls_by_lanes in traverse_with).
    constexpr bool distances = near_first || std::is_same_v<L, no_lanes>;
    auto const entry = [&](std::uint32_t i) {
        traversal_entry<S, L> e{node.child[i], node.count[i], distances ? hits.tnear[i] : S(0), {}};
        if constexpr (!std::is_same_v<L, no_lanes>) e.lanes = hits.lanes[i];
        prefetch_child(b, e.child, e.count);
        return e;
    };
    // hits.mask is not zero: its lowest set bit is defined.
    std::uint32_t const first = std::uint32_t(__builtin_ctz(hits.mask));
    std::uint32_t rest = hits.mask & (hits.mask - 1);
    if constexpr (!near_first) {
        // Pushed from the highest slot down: they pop in increasing slot order.
        for (; rest != 0;) {
            auto const i = std::uint32_t(31 - __builtin_clz(rest));
            stack.push(entry(i));
            rest &= ~(1u << i);
        }
        return entry(first);
    } else {
        auto const one = entry(first);
        if (rest == 0) return one;
        if ((rest & (rest - 1)) == 0) {
            auto const two = entry(std::uint32_t(__builtin_ctz(rest)));
            bool const two_first = two.tnear < one.tnear;
            stack.push(two_first ? one : two);
            return two_first ? two : one;
        }
        auto* const base = stack.top;
        *stack.top++ = one;
        for (; rest != 0; rest &= rest - 1) {
            auto const next = entry(std::uint32_t(__builtin_ctz(rest)));
            auto* j = stack.top++;
            for (; j > base && j[-1].tnear < next.tnear; --j) *j = j[-1];
            *j = next;
        }
        return *--stack.top;
    }
}

// The primitives of one leaf through call_hooks_or_descend: blocks of four triangles for triangle
// BVHs, else one primitive at a time. True when the query is finished.
// The ray's triangle shear is prepared at its first leaf: rays that reach none (misses, and every
// ray of BVHs of instances or of BVHs) never compute it.
template <typename T, typename Prim, typename I, typename Query>
[[gnu::always_inline]] inline bool visit_leaf(prepared_ray<T>& ray, bvh_storage<Prim> const& b, std::uint32_t first,
                                              std::uint32_t count, I& isect, Query& query) {
    if constexpr (!acceleration_structure<Prim>)
        if (!ray.has_shear) ray.prepare_shear();
    if constexpr (stores_triangle_blocks_v<Prim>) {
        int remaining = int(count);
        for (std::uint32_t k = first; remaining > 0; ++k, remaining -= triangle_block_width)
            if (call_hooks_or_descend(ray, b.leaves[k], std::min(remaining, triangle_block_width), isect, query))
                return true;
    } else {
        for (std::uint32_t i = first, end = first + count; i < end; ++i)
            if (call_hooks_or_descend(ray, b.leaves[i], isect, query)) return true;
    }
    return false;
}

// Whether packets may trace lanes alone (packet_lanes_alone_below): packets of float rays, a
// query that can hand out a lane and take its result back (canopy.query: lane, absorb), and an
// intersector that intercepts nothing, so that no hook or filter could tell a lane traced alone
// from a lane of the packet. Results are unchanged: the lane's prepared ray is the one a single
// ray would have (prepared_lane), closest hits do not depend on order, and any-hit traversal
// visits the subtree's leaves in the same order alone.
template <typename T, typename I, typename Prim, typename Query>
inline constexpr bool may_trace_lanes_alone = [] {
    if constexpr (simd::simd_width_v<T> == 1 || !std::is_same_v<simd::scalar_type_t<T>, float> ||
                  !requires(Query const& q) { q.lane(0); }) {
        return false;
    } else {
        using Leaf = leaf_primitive_t<Prim>;
        auto const intercepts = []<typename R>(R*) {
            return primitive_hook_for<I, R, Leaf> || box_hook_for<I, R, aabb, vec3<ray_value_t<R>>> ||
                   filter_hook_for<I, R>;
        };
        return !intercepts(static_cast<prepared_ray<float>*>(nullptr)) &&
               !intercepts(static_cast<prepared_ray<T>*>(nullptr));
    }
}();

} // namespace canopy::detail

namespace canopy::detail {

template <typename T, typename Prim, typename I, typename Query, typename S>
bool traverse_lanes_alone(prepared_ray<T>& ray, bvh_storage<Prim> const& b, I& isect, Query& query,
                          traversal_entry<S, std::uint32_t> const& from);

// The traversal loop with one node tester (see the top of this file), from the root or from one
// node or leaf (`from`, with a scalar ray: lanes of a packet traced alone).
template <typename Tester, typename T, typename Prim, typename I, typename Query>
[[gnu::always_inline]] inline bool traverse_with(prepared_ray<T>& ray, bvh_storage<Prim> const& b, I& isect,
                                                 Query& query,
                                                 traversal_entry<typename bvh<Prim>::value_type> from = {0, 0, 0, {}}) {
    using S = typename bvh<Prim>::value_type;
    using L = lanes_t<T>;
    Tester nodes(ray, isect);
    traversal_entries<S, L> pending;
    traversal_stack<S, L> stack(pending);
    traversal_entry<S, L> current{from.child, from.count, from.tnear, {}};
    if constexpr (!std::is_same_v<L, no_lanes>) current.lanes = (1u << simd::simd_width_v<T>) - 1u;
    // Packets that may trace lanes alone tally their occupancy here, and once per traversal into
    // packet_occupancy_tally.
    constexpr bool tally = may_trace_lanes_alone<T, I, Prim, Query>;
    struct occupancy {
        std::uint32_t node_visits = 0, node_lanes = 0, leaf_visits = 0, leaf_lanes = 0, lanes_alone = 0;
        ~occupancy() {
            if constexpr (tally) {
                auto& t = packet_occupancy_tally;
                t.node_visits += node_visits;
                t.node_lanes += node_lanes;
                t.leaf_visits += leaf_visits;
                t.leaf_lanes += leaf_lanes;
                t.lanes_alone += lanes_alone;
            }
        }
    };
    [[maybe_unused]] std::conditional_t<tally, occupancy, no_lanes> counts;
    // Any-hit packets cull stacked children by their lanes, not by distance. A lane's tmax does not
    // change in an any-hit query until the lane is finished (tmax −inf), so a child that a live lane
    // entered is never beyond the widest tmax; children whose lanes have all finished are dropped
    // (they would hit nothing), and the others are visited with their live lanes only. The entry
    // distances are then not needed, and not computed. Every live lane meets the same leaves in
    // the same order as before, so the results are unchanged. (A query that is not near-first but
    // lowers tmax would only lose the culling of far children: a lane is dropped only once
    // tmin > tmax, when it can hit nothing.)
    constexpr bool culls_by_lanes = !std::is_same_v<L, no_lanes> && !Query::wants_near_first;
    auto const pop = [&] {
        if constexpr (culls_by_lanes)
            return stack.pop_entered_by(simd::movemask(ray.tmin <= ray.tmax), current);
        else
            return stack.pop_nearer_than(nodes.box_tmax(), current);
    };
    for (;;) {
        if constexpr (may_trace_lanes_alone<T, I, Prim, Query>) {
            if ((current.count == 0 || !stores_triangle_blocks_v<Prim>) &&
                std::popcount(current.lanes) < packet_lanes_alone_below) {
                counts.lanes_alone += std::uint32_t(std::popcount(current.lanes));
                if (traverse_lanes_alone(ray, b, isect, query, current)) return true;
                nodes.tmax_changed();
                if (!pop()) return false;
                continue;
            }
        }
        if (current.count == 0) {
            auto const& node = b.wide_nodes[current.child];
            if constexpr (tally) {
                ++counts.node_visits;
                counts.node_lanes += std::uint32_t(std::popcount(current.lanes));
            }
            auto const hits = nodes.template test<!culls_by_lanes>(node, current.lanes);
            if (hits.mask != 0) {
                current = order_children<Query::wants_near_first>(b, node, hits, stack);
                continue;
            }
        } else if constexpr (std::is_same_v<L, no_lanes>) {
            if (visit_leaf(ray, b, current.child, current.count, isect, query)) return true;
            nodes.tmax_changed();
        } else {
            // Lanes that did not reach the leaf take no part in it (tmax −inf: every test misses),
            // as they would not alone.
            if constexpr (tally) {
                ++counts.leaf_visits;
                counts.leaf_lanes += std::uint32_t(std::popcount(current.lanes));
            }
            auto const outside = !simd::mask_type_t<T>::from_bits(current.lanes);
            T const saved = ray.tmax;
            ray.tmax = simd::select(outside, T(-std::numeric_limits<simd::scalar_type_t<T>>::infinity()), ray.tmax);
            bool const stop = visit_leaf(ray, b, current.child, current.count, isect, query);
            ray.tmax = simd::select(outside, saved, ray.tmax);
            if (stop) return true;
            nodes.tmax_changed();
        }
        if (!pop()) return false;
    }
}

} // namespace canopy::detail

namespace canopy::detail {

// The traversal of b from `from` (the root by default) with the node tester the ray allows.
// Scalar float rays whose box test can take the fused form (canopy.geometry:box, slab_offsets)
// run the loop built for it.
template <typename T, typename Prim, typename I, typename Query>
[[gnu::always_inline]] inline bool traverse_from(prepared_ray<T>& ray, bvh_storage<Prim> const& b, I& isect,
                                                 Query& query,
                                                 traversal_entry<typename bvh<Prim>::value_type> from = {0, 0, 0, {}}) {
    using S = typename bvh<Prim>::value_type;
    if constexpr (std::is_base_of_v<instance_path, Query>) ray.instances = &query;
    if constexpr (uses_wide_box_test<T, S, I> && simd::native_fma) {
        if (uses_fused_slabs(ray)) return traverse_with<node_tester<T, S, I, true>>(ray, b, isect, query, from);
    } else if constexpr (uses_packet_box_test<T, S, I> && simd::native_fma) {
        if (uses_fused_slabs(ray) && signs_agree(ray.inv_dir))
            return traverse_with<node_tester<T, S, I, true>>(ray, b, isect, query, from);
    }
    return traverse_with<node_tester<T, S, I>>(ray, b, isect, query, from);
}

// The lanes of a packet that reach `from` (a node or a leaf), each traced from there on its own as
// a scalar ray with a scalar query for that lane (may_trace_lanes_alone). True when the packet's
// query is finished. Out of line: it runs for few packets, and inlined it would crowd the
// packet loop's registers.
template <typename T, typename Prim, typename I, typename Query, typename S>
[[gnu::noinline]] bool traverse_lanes_alone(prepared_ray<T>& ray, bvh_storage<Prim> const& b, I& isect,
                                            Query& query, traversal_entry<S, std::uint32_t> const& from) {
    // Lanes that finished (any hit found) or left have tmax −inf: nothing to trace for them.
    std::uint32_t const taking_part = simd::movemask(ray.tmin <= ray.tmax);
    for (std::uint32_t lanes = from.lanes & taking_part; lanes != 0; lanes &= lanes - 1) {
        int const k = std::countr_zero(lanes);
        auto lane = prepared_lane(ray, k);
        auto lane_query = query.lane(k);
        traverse_from(lane, b, isect, lane_query, {from.child, from.count, from.tnear, {}});
        if (query.absorb(k, lane_query, lane.tmax, ray)) return true;
    }
    return false;
}

} // namespace canopy::detail

export namespace canopy {

// Traverses b with a prepared ray; returns true when the query asked to stop (any-hit found,
// packet finished). ray.tmax is tightened as the query allows.
template <typename T, typename Prim, typename I, hit_collector<T> Query>
[[gnu::always_inline]] inline bool traverse(prepared_ray<T>& ray, bvh_storage<Prim> const& b, I& isect, Query& query) {
    if (b.empty()) return false;
    return detail::traverse_from(ray, b, isect, query);
}

// Traverses b with a plain ray (prepared here, once; the triangle shear waits for the first leaf);
// ray.tmax is tightened as the query allows.
template <typename T, typename Prim, typename I, hit_collector<T> Query>
[[gnu::always_inline]] inline bool traverse(basic_ray<T>& ray, bvh_storage<Prim> const& b, I& isect, Query& query) {
    prepared_ray<T> prepared(ray, false);
    prepared.widen_box_tests_for(b.bounds());
    bool const stop = traverse(prepared, b, isect, query);
    ray.tmax = prepared.tmax;
    return stop;
}

// The same for a bvh object, with a prepared or a plain ray.
template <typename Ray, typename Prim, typename I, hit_collector<ray_value_t<Ray>> Query>
[[gnu::always_inline]] inline bool traverse(Ray& ray, bvh<Prim> const& b, I& isect, Query& query) {
    return traverse(ray, bvh_storage<Prim>(b), isect, query);
}

} // namespace canopy
