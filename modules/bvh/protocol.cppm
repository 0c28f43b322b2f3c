// canopy.bvh:protocol — the traversal protocol: what a BVH's leaves and a query's range may hold
// (primitive, acceleration_structure), what collects a query's hits (hit_collector), and the one
// place where every ray/box and ray/primitive test goes through the caller's intersector
// (test_box, test_primitive, call_hooks_or_descend).
//
// A primitive provides, in its own namespace (found by ADL; canopy.geometry's triangles and
// spheres do):
//   basic_aabb<S> get_bounds(P const&);                              (for BVH builds)
//   basic_hit_record<S> intersect(basic_ray<S> const&, P const&);    (for queries)
// and members prim_id / geom_id if the builder should number it (canopy.bvh:build).
// An acceleration structure (bvh<P>, instance<B>, or one of the user's) declares
// `using acceleration_structure_tag = void;`, has bounds (get_bounds) and is traversed by
//   bool traverse(Ray& ray, Structure const& s, I& isect, Collector& collector);
// found by ADL, which hands its boxes to test_box and its contents to call_hooks_or_descend, and
// returns true when the query is finished.
// The builder, the queries and traverse are constrained with these concepts: a type that lacks a
// piece is refused at the call, and the compiler's notes name the missing expression.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <bit>
#include <concepts>
#include <cstddef>
#include <cstdint>
#include <type_traits>
export module canopy.bvh:protocol;
import canopy.intersector;
import :storage;

namespace canopy::detail {

// The box of a primitive or structure: basic_aabb<S> for some S.
template <typename B>
inline constexpr bool is_basic_aabb_v = false;
template <typename S>
inline constexpr bool is_basic_aabb_v<basic_aabb<S>> = true;
template <typename B>
concept bounding_box = is_basic_aabb_v<std::remove_cvref_t<B>>;

} // namespace canopy::detail

export namespace canopy {

// The state of a query (canopy.query) that traversal reports to, for rays of value type T:
// report(hit_record, ray) accepts or rejects a candidate, tightens ray.tmax as the query allows,
// and returns true when the whole traversal must stop; stamp(hit_record) fills in the current
// instance path; enter_instance(id) / leave_instance() track it (instance_path provides all
// three); wants_near_first, a constant, says whether traversal should order children near to far
// (closest and multi hit) or need not (any hit).
template <typename C, typename T>
concept hit_collector = requires(C& collector, basic_hit_record<T>& hr, prepared_ray<T>& ray, std::uint32_t id) {
    { collector.report(hr, ray) } -> std::convertible_to<bool>;
    collector.stamp(hr);
    collector.enter_instance(id);
    collector.leave_instance();
    typename std::bool_constant<C::wants_near_first>;
};

} // namespace canopy

namespace canopy::detail {

// The least hit collector, to ask whether a structure can be traversed at all.
template <typename T>
struct collector_archetype : instance_path {
    static constexpr bool wants_near_first = true;
    template <typename Ray>
    bool report(basic_hit_record<T> const&, Ray&) {
        return false;
    }
};

} // namespace canopy::detail

export namespace canopy {

// A structure that contains primitives (or other structures) and is traversed with the caller's
// intersector and hit collector (see the top of this file).
template <typename S>
concept acceleration_structure = requires { typename S::acceleration_structure_tag; } &&
                                 requires(S const& s) {
                                     { get_bounds(s) } -> detail::bounding_box;
                                 } &&
                                 requires(S const& s, prepared_ray<bounds_value_t<S>>& ray, default_intersector& isect,
                                          detail::collector_archetype<bounds_value_t<S>>& collector) {
                                     { traverse(ray, s, isect, collector) } -> std::same_as<bool>;
                                 };

// A leaf primitive: not an acceleration structure, with bounds for the builder and a ray test for
// the queries, both found by ADL (see the top of this file). Intersectors may replace the test
// (canopy.intersector); the library's own is what they fall back to.
template <typename P>
concept primitive = !acceleration_structure<P> && requires(P const& p) {
    { get_bounds(p) } -> detail::bounding_box;
} && requires(P const& p, basic_ray<bounds_value_t<P>> const& ray) {
    { intersect(ray, p) } -> std::convertible_to<basic_hit_record<bounds_value_t<P>>>;
};

// What a BVH's leaves and a query's range may hold.
template <typename P>
concept traceable = acceleration_structure<P> || primitive<P>;

// The ray/box test of the traversal: the intersector's hook if it has one, else the default.
// A hook's result is converted to the default's (intersector_mistake_v checks it converts).
template <typename I, typename Ray, typename Box, typename InvDir>
[[gnu::always_inline]] inline auto test_box(I& isect, Ray const& ray, Box const& box, InvDir const& inv_dir)
    -> decltype(intersect(ray, box, inv_dir)) {
    if constexpr (box_hook_for<I, Ray, Box, InvDir>)
        return isect(ray, box, inv_dir);
    else
        return intersect(ray, box, inv_dir);
}

// The ray/primitive test of the traversal: the intersector's hook if it has one, else the default.
template <typename I, typename Ray, typename Prim>
[[gnu::always_inline]] inline basic_hit_record<ray_value_t<Ray>> test_primitive(I& isect, Ray const& ray,
                                                                                Prim const& prim) {
    if constexpr (primitive_hook_for<I, Ray, Prim>)
        return isect(ray, prim);
    else
        return intersect(ray, prim);
}

} // namespace canopy

namespace canopy::detail {

// The leaf primitive type of acceleration structures that say which (bvh<P>: primitive_type;
// instance<B>: bvh_type); others are their own leaf.
template <typename P>
struct leaf_primitive {
    using type = P;
};
template <typename P>
    requires requires { typename P::primitive_type; }
struct leaf_primitive<P> : leaf_primitive<typename P::primitive_type> {};
template <typename P>
    requires requires { typename P::bvh_type; }
struct leaf_primitive<P> : leaf_primitive<typename P::bvh_type> {};

} // namespace canopy::detail

export namespace canopy {

// The leaf primitive type of a query over a range of P: P itself, or the primitives at the
// bottom of nested BVHs and instances.
template <typename P>
using leaf_primitive_t = typename detail::leaf_primitive<P>::type;

} // namespace canopy

namespace canopy::detail {

// The mistake I makes in a query over a range of Elem with rays of type Ray (canopy.intersector,
// hook_mistake_v, for the rays its hooks receive and the leaf primitives); none for acceleration
// structures whose leaves the library cannot name.
template <typename I, typename Ray, typename Elem>
constexpr intersector_mistake find_intersector_mistake_in() {
    using Leaf = leaf_primitive_t<Elem>;
    using HookRay = std::conditional_t<acceleration_structure<Elem>, prepared_ray<ray_value_t<Ray>>, Ray>;
    if constexpr (acceleration_structure<Leaf>)
        return intersector_mistake::none;
    else
        return hook_mistake_v<I, HookRay, Leaf>;
}

} // namespace canopy::detail

export namespace canopy {

// The mistake I makes in a query over a range of Elem with rays of type Ray; the queries refuse
// to compile unless it is intersector_mistake::none (canopy.query, report_intersector_mistake).
template <typename I, typename Ray, typename Elem>
inline constexpr intersector_mistake intersector_mistake_v = detail::find_intersector_mistake_in<I, Ray, Elem>();

// A candidate hit through the intersector's filter, if it has one: hr.hit keeps the lanes it
// accepts. The query stamps the instance path first, so that the filter sees it.
template <typename Ray, typename I, typename Query>
[[gnu::always_inline]] inline void apply_filter(Ray const& ray, basic_hit_record<ray_value_t<Ray>>& hr, I& isect,
                                                Query& query) {
    if constexpr (filter_hook_for<I, Ray>) {
        if (simd::none(hr.hit)) return;
        query.stamp(hr);
        hr.hit = hr.hit & isect.filter(ray, hr);
    }
}

// Whether a hit collector keeps one hit, the first in the order of (t, instance path, prim_id),
// accepting a candidate only when it precedes that hit (canopy.query's closest hit says so with
// `static constexpr bool keeps_nearest_only = true;`; collectors that do not say are not assumed to).
template <typename Query>
inline constexpr bool keeps_nearest_only = [] {
    if constexpr (requires { Query::keeps_nearest_only; })
        return bool(Query::keeps_nearest_only);
    else
        return false;
}();

// The one place that tells leaf primitives from nested structures. Query is a hit_collector
// (above). Nested structures are traversed by their own `traverse(ray, structure, isect, query)`
// (found by ADL), which comes back here for their primitives. Returns true when the query is
// finished.
template <typename Ray, typename Prim, typename I, typename Query>
[[gnu::always_inline]] inline bool call_hooks_or_descend(Ray& ray, Prim const& prim, I& isect, Query& query) {
    if constexpr (acceleration_structure<Prim>) {
        return traverse(ray, prim, isect, query);
    } else {
        auto hr = test_primitive(isect, ray, prim);
        apply_filter(ray, hr, isect, query);
        return query.report(hr, ray);
    }
}

// The first `count` triangles of a leaf block. A triangle hook of the intersector sees them one
// at a time, exactly as given (triangle_at), as the paper's API promises. Otherwise packets test
// them one at a time, read from the block (intersect_lane), or, with no filter, the block lane by
// lane of the packet (intersect_block_by_lanes) when fewer lanes take part than the block has
// triangles: one pass of either costs about the same (docs/performance.md, Run 28; lanes <
// triangles / 2 gives up some of the models' gain, lanes < 2 × triangles costs the slivers'
// leaves, where most lanes miss, 10 %). For scalar rays the block's triangles are tested at once
// (intersect_block: bit-identical lane by lane; degenerate triangles are known from the block and
// never tested) and the hit lanes go to the filter and the query: in lane order for queries that
// stop at any hit (the first hit in leaf order, as one at a time would find), by increasing
// (t, prim_id) otherwise, each while its t is still within the ray's tightening tmax, and for a
// collector that keeps only the nearest hit up to the first that the filter keeps.
template <typename Ray, typename I, typename Query>
[[gnu::always_inline]] inline bool call_hooks_or_descend(Ray& ray, triangle_block const& block, int count, I& isect,
                                                         Query& query) {
    if constexpr (primitive_hook_for<I, Ray, triangle> || !is_prepared_ray_v<Ray>) {
        for (int lane = 0; lane < count; ++lane)
            if (call_hooks_or_descend(ray, block.triangle_at(lane), isect, query)) return true;
        return false;
    } else if constexpr (simd::simd_width_v<ray_value_t<Ray>> != 1) {
        // Packets with no filter, whose lanes share one shear permutation: lane by lane of the
        // packet when fewer lanes take part than the block has triangles, with
        // intersect_block_by_lanes: the same tests, and for each lane the hit the loop below would
        // leave it with, reported at once.
        if constexpr (!filter_hook_for<I, Ray>) {
            if (ray.shear.uniform) {
                std::uint32_t const live = simd::movemask(ray.tmin <= ray.tmax);
                if (std::popcount(live) < count)
                    return query.report(intersect_block_by_lanes<Query::wants_near_first>(
                                            ray, block, (1u << count) - 1u, live),
                                        ray);
            }
        }
        // Packets: one triangle at a time against all lanes (intersect_lane), as the loop above.
        for (int lane = 0; lane < count; ++lane) {
            auto hr = intersect_lane(ray, block, lane);
            apply_filter(ray, hr, isect, query);
            bool const some_hit = simd::any(hr.hit);
            if (query.report(hr, ray)) return true;
            // Any hit: once every lane that reached the leaf has its hit (tmax −inf, as for the
            // lanes that did not reach it), the block's other triangles would be tested for no lane.
            if constexpr (!Query::wants_near_first)
                if (some_hit && simd::none(ray.tmin <= ray.tmax)) return false;
        }
        return false;
    } else {
        auto const hits = intersect_block(ray, block);
        for (std::uint32_t mask = hits.mask; mask != 0;) {
            int lane = std::countr_zero(mask);
            if constexpr (Query::wants_near_first) {
                for (std::uint32_t rest = mask & (mask - 1); rest != 0; rest &= rest - 1) {
                    int const other = std::countr_zero(rest);
                    auto const o = std::size_t(other), l = std::size_t(lane);
                    if (hits.t[o] < hits.t[l] || (hits.t[o] == hits.t[l] && block.prim_id[o] < block.prim_id[l]))
                        lane = other;
                }
                if (!(hits.t[std::size_t(lane)] <= ray.tmax)) return false;
            }
            mask &= ~(1u << lane);
            auto hr = hits.record(block, lane);
            apply_filter(ray, hr, isect, query);
            // A collector that keeps only the nearest hit cannot accept a later lane once one has
            // passed the filter: the later ones follow it in (t, prim_id) order, under the same
            // instance path. Where many triangles meet at a vertex the ray passes through, every
            // lane of a block may be a candidate at nearly the same t.
            if constexpr (keeps_nearest_only<Query>)
                if (hr.hit) return query.report(hr, ray);
            if (query.report(hr, ray)) return true;
        }
        return false;
    }
}

} // namespace canopy
