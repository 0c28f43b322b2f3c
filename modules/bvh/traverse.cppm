// canopy.bvh:traverse — depth-first BVH traversal with the caller's intersector and query.
//
// Every ray/box test (root and both children of each visited inner node) goes through
// test_box, every primitive through call_hooks_or_descend (canopy.intersector): hooks see every
// test, nested BVHs/instances receive the same intersector and query. The nearer child is
// visited first; stacked nodes whose entry distance lies beyond the query's current tmax are
// skipped (closest-hit culling). Works for scalar and SIMD packet rays (a node is visited when
// any active lane hits it).
module;
#include <array>
#include <cstdint>
#include <limits>
export module canopy.bvh:traverse;
import canopy.intersector;
import :storage;

export namespace canopy {

// Traverses b with a prepared ray; returns true when the query asked to stop (any-hit found,
// packet finished).
template <typename T, typename Prim, typename I, typename Query>
bool traverse(prepared_ray<T>& ray, bvh<Prim> const& b, I& isect, Query& query) {
    if (b.nodes.empty()) return false;

    vec3<T> const& inv_dir = ray.inv_dir;
    auto const root = test_box(isect, ray, b.nodes[0].bounds, inv_dir);
    if (simd::none(root.hit)) return false;

    struct entry {
        std::uint32_t node;
        T tnear;
    };
    std::array<entry, bvh_max_depth> stack;
    int size = 0;
    std::uint32_t current = 0;
    for (;;) {
        auto const& node = b.nodes[current];
        if (!node.is_leaf()) {
            auto const left = test_box(isect, ray, b.nodes[node.index].bounds, inv_dir);
            auto const right = test_box(isect, ray, b.nodes[node.index + 1].bounds, inv_dir);
            bool const hit_left = simd::any(left.hit);
            bool const hit_right = simd::any(right.hit);
            if (hit_left && hit_right) {
                // Nearer child first (packets: where more lanes see it nearer).
                bool right_first;
                if constexpr (simd::simd_width_v<T> == 1)
                    right_first = right.tnear < left.tnear;
                else
                    right_first = simd::popcount(right.hit & (!left.hit | (right.tnear < left.tnear))) >
                                  simd::popcount(left.hit & (!right.hit | (left.tnear <= right.tnear)));
                std::uint32_t const near = node.index + (right_first ? 1u : 0u);
                std::uint32_t const far = node.index + (right_first ? 0u : 1u);
                T const far_tnear = simd::select(right_first ? left.hit : right.hit,
                                                 right_first ? left.tnear : right.tnear,
                                                 T(std::numeric_limits<simd::scalar_type_t<T>>::infinity()));
                stack[std::size_t(size++)] = {far, far_tnear};
                current = near;
                continue;
            }
            if (hit_left || hit_right) {
                current = node.index + (hit_left ? 0u : 1u);
                continue;
            }
        } else {
            for (std::uint32_t i = node.index, end = node.index + node.count; i < end; ++i)
                if (call_hooks_or_descend(ray, b.primitives[i], isect, query)) return true;
        }
        // Pop the next node still in front of the ray's (possibly tightened) tmax.
        for (;;) {
            if (size == 0) return false;
            entry const& e = stack[std::size_t(--size)];
            if (simd::any(e.tnear <= ray.tmax)) {
                current = e.node;
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
