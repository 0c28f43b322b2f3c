// canopy.bvh:traverse — depth-first traversal of the 8-wide BVH with the caller's intersector
// and query.
//
// Each visited node tests its children's boxes, nearest hit child first, the others pushed far to
// near (queries that stop at any hit, Query::wants_near_first == false, skip the ordering). Which box test runs is decided at compile time:
// - the intersector has its own box hook → the hook, once per child box (it sees every test);
// - otherwise, scalar float rays → all eight boxes in one SIMD slab test (no per-box calls);
// - otherwise (double rays, packets) → the library's box test, once per child box.
// All three compute the same conservative test (canopy.geometry:box): same hits, same order.
// Every primitive goes through call_hooks_or_descend (canopy.intersector): nested BVHs and
// instances receive the same intersector and query. Stacked entries whose entry distance lies
// beyond the ray's current tmax are skipped (closest-hit culling). Packet rays visit a child
// when any active lane hits it. The memory of every hit child is prefetched as soon as the node
// test is done, so that cache misses overlap (incoherent rays in large BVHs are memory-bound).
module;
// No a·b + c → FMA contraction in this file, whatever -ffp-contract says: every build and
// every path (scalar, SIMD, packet) rounds the same way.
#pragma STDC FP_CONTRACT OFF
#include <array>
#include <bit>
#include <cstdint>
#include <limits>
#include <type_traits>
export module canopy.bvh:traverse;
import canopy.intersector;
import :storage;

export namespace canopy {

namespace detail {

// Hit children of a wide node: bit i of mask set when child i is hit, entry distance in tnear[i]
// (for packets: the smallest over the lanes that hit it).
template <typename S>
struct child_hits {
    std::uint32_t mask = 0;
    std::array<S, bvh_width> tnear;
};

// All eight child boxes against one scalar float ray at once; the same arithmetic as
// canopy.geometry:box, lane by lane.
[[gnu::always_inline]] inline child_hits<float> test_children_wide(prepared_ray<float> const& ray,
                                                                   wide_bvh_node<float> const& node) {
    using simd::float8;
    constexpr float far_scale = 1.0f + 2.0f * gamma<float>(3);
    float8 tnear(ray.tmin), tfar(box_test_tmax(ray.tmax));
    auto slab = [&](std::array<float, bvh_width> const& lo, std::array<float, bvh_width> const& hi, float origin,
                    float inv) {
        float8 const t0 = (float8::load(lo.data()) - float8(origin)) * float8(inv);
        float8 const t1 = (float8::load(hi.data()) - float8(origin)) * float8(inv);
        bool const negative = inv < 0.0f;
        float8 const slab_near = negative ? t1 : t0;
        float8 const slab_far = (negative ? t0 : t1) * float8(far_scale);
        tnear = simd::max(slab_near, tnear);
        tfar = simd::min(slab_far, tfar);
    };
    slab(node.min_x, node.max_x, ray.origin.x, ray.inv_dir.x);
    slab(node.min_y, node.max_y, ray.origin.y, ray.inv_dir.y);
    slab(node.min_z, node.max_z, ray.origin.z, ray.inv_dir.z);
    // Unused slots hold empty boxes, but a NaN or infinite ray can make any box look hit: they
    // are masked out by their child index.
    auto const used = simd::int8::load(reinterpret_cast<std::int32_t const*>(node.child.data())) !=
                      simd::int8(std::int32_t(-1));
    child_hits<float> h;
    h.mask = simd::movemask((tnear <= tfar) & used);
    tnear.store(h.tnear.data());
    return h;
}

// Child boxes one at a time through test_box (hook or default).
template <typename T, typename S, typename I>
[[gnu::always_inline]] inline child_hits<S> test_children_each(prepared_ray<T> const& ray,
                                                              wide_bvh_node<S> const& node, I& isect) {
    child_hits<S> h;
    for (int i = 0; i < bvh_width && node.used(i); ++i) {
        auto const box = test_box(isect, ray, node.child_bounds(i), ray.inv_dir);
        if (simd::none(box.hit)) continue;
        h.mask |= 1u << i;
        if constexpr (simd::simd_width_v<T> == 1)
            h.tnear[std::size_t(i)] = box.tnear;
        else
            h.tnear[std::size_t(i)] =
                simd::reduce_min(simd::select(box.hit, box.tnear, T(std::numeric_limits<S>::infinity())));
    }
    return h;
}

template <typename T, typename S, typename I>
[[gnu::always_inline]] inline child_hits<S> test_children(prepared_ray<T> const& ray, wide_bvh_node<S> const& node,
                                                          I& isect) {
    if constexpr (std::is_same_v<T, float> && std::is_same_v<S, float> &&
                  !box_hook_for<I, prepared_ray<T>, basic_aabb<S>, vec3<T>>)
        return test_children_wide(ray, node);
    else
        return test_children_each(ray, node, isect);
}

// Starts loading the memory of the hit children (wide nodes, or a leaf's primitives) into the
// cache, so that the loads of all of them overlap with each other and with the work on the
// current node, instead of each waiting for memory when its turn comes.
template <typename Prim, typename S>
[[gnu::always_inline]] inline void prefetch_children(bvh<Prim> const& b, wide_bvh_node<S> const& node,
                                                     std::uint32_t mask) {
    constexpr std::uintptr_t line = 64;
    for (; mask != 0; mask &= mask - 1) {
        auto const i = std::size_t(std::countr_zero(mask));
        if (node.count[i] == 0) {
            // A wide node: aligned to a cache line, sizeof(wide_bvh_node<S>) / 64 lines.
            auto const* p = reinterpret_cast<char const*>(&b.wide_nodes[node.child[i]]);
            for (std::size_t k = 0; k < sizeof(wide_bvh_node<S>); k += line) __builtin_prefetch(p + k);
        } else {
            auto const begin = reinterpret_cast<std::uintptr_t>(&b.primitives[node.child[i]]);
            auto const end = begin + node.count[i] * sizeof(Prim);
            for (std::uintptr_t a = begin & ~(line - 1); a < end; a += line)
                __builtin_prefetch(reinterpret_cast<void const*>(a));
        }
    }
}

// Largest tmax over the lanes (inactive lanes hold -inf).
template <typename T>
auto widest_tmax(T const& tmax) {
    if constexpr (simd::simd_width_v<T> == 1)
        return tmax;
    else
        return simd::reduce_max(tmax);
}

} // namespace detail

// Traverses b with a prepared ray; returns true when the query asked to stop (any-hit found,
// packet finished). ray.tmax is tightened as the query allows.
template <typename T, typename Prim, typename I, typename Query>
bool traverse(prepared_ray<T>& ray, bvh<Prim> const& b, I& isect, Query& query) {
    using S = typename bvh<Prim>::value_type;
    if (b.wide_nodes.empty()) return false;

    struct entry {
        std::uint32_t child;
        std::uint32_t count; // 0: wide node; ≥ 1: leaf
        S tnear;
    };
    std::array<entry, (bvh_width - 1) * bvh_max_depth + 1> stack;
    int size = 0;
    entry current{0, 0, S(0)};
    for (;;) {
        if (current.count == 0) {
            auto const& node = b.wide_nodes[current.child];
            auto const hits = detail::test_children(ray, node, isect);
            if (hits.mask != 0) {
                detail::prefetch_children(b, node, hits.mask);
                if constexpr (!Query::wants_near_first) {
                    // Any accepted hit ends the query: visit children in slot order.
                    std::uint32_t m = hits.mask;
                    auto const first = std::size_t(std::countr_zero(m));
                    for (m &= m - 1; m != 0; m &= m - 1) {
                        auto const i = std::size_t(std::countr_zero(m));
                        stack[std::size_t(size++)] = {node.child[i], node.count[i], hits.tnear[i]};
                    }
                    current = {node.child[first], node.count[first], hits.tnear[first]};
                    continue;
                }
                std::uint32_t const first = std::uint32_t(std::countr_zero(hits.mask));
                std::uint32_t const rest = hits.mask & (hits.mask - 1);
                entry const one{node.child[first], node.count[first], hits.tnear[first]};
                if (rest == 0) { // one child hit: no ordering
                    current = one;
                    continue;
                }
                if ((rest & (rest - 1)) == 0) { // two: the nearer first
                    auto const second = std::size_t(std::countr_zero(rest));
                    entry const two{node.child[second], node.count[second], hits.tnear[second]};
                    bool const two_first = two.tnear < one.tnear;
                    stack[std::size_t(size++)] = two_first ? one : two;
                    current = two_first ? two : one;
                    continue;
                }
                // Order the hit children near to far (insertion sort of at most eight).
                std::array<entry, bvh_width> order;
                int n = 0;
                for (std::uint32_t m = hits.mask; m != 0; m &= m - 1) {
                    auto const i = std::size_t(std::countr_zero(m));
                    entry const e{node.child[i], node.count[i], hits.tnear[i]};
                    int j = n++;
                    for (; j > 0 && e.tnear < order[std::size_t(j - 1)].tnear; --j)
                        order[std::size_t(j)] = order[std::size_t(j - 1)];
                    order[std::size_t(j)] = e;
                }
                for (int j = n - 1; j > 0; --j) stack[std::size_t(size++)] = order[std::size_t(j)];
                current = order[0];
                continue;
            }
        } else {
            for (std::uint32_t i = current.child, end = current.child + current.count; i < end; ++i)
                if (call_hooks_or_descend(ray, b.primitives[i], isect, query)) return true;
        }
        // Pop the next entry still in front of the ray's (possibly tightened) tmax.
        for (;;) {
            if (size == 0) return false;
            entry const& e = stack[std::size_t(--size)];
            if (e.tnear <= box_test_tmax(detail::widest_tmax(ray.tmax))) {
                current = e;
                break;
            }
        }
    }
}

// Traverses b with a plain ray (prepared here, once); ray.tmax is tightened as the query allows.
template <typename T, typename Prim, typename I, typename Query>
bool traverse(basic_ray<T>& ray, bvh<Prim> const& b, I& isect, Query& query) {
    prepared_ray<T> prepared(ray);
    bool const stop = traverse(prepared, b, isect, query);
    ray.tmax = prepared.tmax;
    return stop;
}

} // namespace canopy
