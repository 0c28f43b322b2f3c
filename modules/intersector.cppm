// canopy.intersector — custom intersectors (Zellmann, "Adding Custom Intersectors to the C++ Ray
// Tracing Template Library Visionaray").
//
// An intersector is user code handed to a query at compile time. Every ray/primitive and every
// ray/box test of the traversal goes through it, at every level of nested BVHs:
//
//   struct my_isect : canopy::basic_intersector<my_isect> {
//       using canopy::basic_intersector<my_isect>::operator();
//       template <typename Ray> auto operator()(Ray const& ray, canopy::triangle const& tri);
//       template <typename Ray, typename... Args>
//       auto operator()(Ray const& ray, canopy::aabb const& box, Args&&... args);  // optional
//   };
//
// Guarantees:
// - Anything the intersector does not handle falls back to the library's own test, also when the
//   `using` line is forgotten (the derived operator() then hides the base's) and for lambdas or
//   overload sets, which are intersectors too.
// - Nested structures (BVHs, instances) are never handed to hooks: the intersector is passed down
//   into them (call_hooks_or_descend below is the one place that decides).
// - With default_intersector, or with hooks that only forward, the calls inline to exactly the
//   default tests: no cost.
// - Hooks receive the ray as traversal prepared it. A box hook that forwards to
//   intersect(ray, box, args...) with that ray keeps traversal's box test, widened for the
//   watertight triangle test (canopy.geometry:box). One that declares its ray as a plain
//   canopy::ray forwards to the exact-box test, which can cull a triangle that rounding in the
//   triangle test would hit (rays grazing long thin triangles): declare the Ray as a template.
// - A filter (beyond the paper): a member `filter(ray, hr)` returning bool (a mask for packets)
//   is called for the candidates the library's own test found, with t in [tmin, current tmax],
//   u, v, prim_id, geom_id and the instance path (inst_id, inner_inst_id) filled in; a candidate
//   it rejects is dropped. Unlike a triangle hook it leaves the library its SIMD leaf test:
//
//   struct alpha : canopy::basic_intersector<alpha> {
//       template <typename Ray> bool filter(Ray const& ray, canopy::basic_hit_record<float> const& hr);
//   };
//
//   A filter must be a function of the candidate it is given: which candidates it sees, and in
//   which order, depends on the leaf layout (a closer accepted hit makes farther ones no longer
//   candidates).
module;
// No a·b + c → FMA contraction in this file, whatever -ffp-contract says: every build and
// every path (scalar, SIMD, packet) rounds the same way.
#pragma STDC FP_CONTRACT OFF
#include <bit>
#include <concepts>
#include <cstdint>
#include <type_traits>
#include <utility>
export module canopy.intersector;
export import canopy.geometry;

export namespace canopy {

// Types that only hooks written by the user accept (as `aabb const&` / `triangle const&` or
// generically): the base class's forwarding operator() excludes them. Used in unevaluated checks
// only, to tell a user's hook from the inherited default, so that traversal can use its own fast
// paths (wide SIMD box tests, prepared rays) when no hook is there.
template <typename Base>
struct hook_probe : Base {};

template <typename P>
inline constexpr bool is_hook_probe_v = false;
template <typename Base>
inline constexpr bool is_hook_probe_v<hook_probe<Base>> = true;

// CRTP base: forwards every test to the library's intersect(), found by ADL. It does not take
// the prepared rays of traversal (which derive from basic_ray): a user's hook declared for
// `canopy::ray const&` then takes them by derived-to-base conversion, unopposed, and template
// hooks receive them as they are, with their cached per-ray constants.
template <typename Derived>
struct basic_intersector {
    template <typename Ray, typename Prim, typename... Args>
        requires(!is_hook_probe_v<Prim>) && (!is_prepared_ray_v<Ray>) && requires(Ray const& ray, Prim const& prim, Args&&... args) {
            intersect(ray, prim, std::forward<Args>(args)...);
        }
    auto operator()(Ray const& ray, Prim const& prim, Args&&... args) {
        return intersect(ray, prim, std::forward<Args>(args)...);
    }
};

struct default_intersector : basic_intersector<default_intersector> {};

// Opt-in Möller–Trumbore for triangles (not watertight; see canopy.geometry:triangle).
struct moller_trumbore_intersector : basic_intersector<moller_trumbore_intersector> {
    using basic_intersector<moller_trumbore_intersector>::operator();
    template <typename Ray, typename S>
    auto operator()(Ray const& ray, basic_triangle<S> const& tri) {
        return intersect_moller_trumbore(ray, tri);
    }
};

// A structure that contains primitives and is traversed with the caller's intersector and query
// (bvh<P>, instance<B>): it declares `using acceleration_structure_tag = void;`.
template <typename P>
concept acceleration_structure = requires { typename P::acceleration_structure_tag; };

// I has a ray/primitive hook of its own for Prim (a member, a lambda, an overload set); the
// forwarding operator inherited from basic_intersector does not count.
template <typename I, typename Ray, typename Prim>
concept primitive_hook_for = requires(I& isect, Ray const& ray, hook_probe<Prim> const& prim) {
    { isect(ray, prim) };
};

// I has a ray/box hook of its own (called with the precomputed inverse direction).
template <typename I, typename Ray, typename Box, typename InvDir>
concept box_hook_for = requires(I& isect, Ray const& ray, hook_probe<Box> const& box, InvDir const& inv_dir) {
    { isect(ray, box, inv_dir) };
};

// I has a filter of its own for hit records of Ray (see the top of this file).
template <typename I, typename Ray>
concept filter_hook_for = requires(I& isect, Ray const& ray, basic_hit_record<ray_value_t<Ray>> const& hr) {
    { isect.filter(ray, hr) };
};

// The ray/box test of the traversal: the intersector's hook if it has one, else the default.
template <typename I, typename Ray, typename Box, typename InvDir>
[[gnu::always_inline]] inline auto test_box(I& isect, Ray const& ray, Box const& box, InvDir const& inv_dir) {
    if constexpr (box_hook_for<I, Ray, Box, InvDir>)
        return isect(ray, box, inv_dir);
    else
        return intersect(ray, box, inv_dir);
}

// The ray/primitive test of the traversal: the intersector's hook if it has one, else the default.
template <typename I, typename Ray, typename Prim>
[[gnu::always_inline]] inline auto test_primitive(I& isect, Ray const& ray, Prim const& prim) {
    if constexpr (primitive_hook_for<I, Ray, Prim>)
        return isect(ray, prim);
    else
        return intersect(ray, prim);
}

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

// The one place that tells leaf primitives from nested structures. Query is a hit accumulator
// (canopy.query): report(hit_record, ray) accepts or rejects a candidate, tightens ray.tmax as
// the query allows, and returns true when the whole traversal must stop; stamp(hit_record) fills
// in the current instance path; enter_instance(id) / leave_instance() track it; wants_near_first
// says whether traversal should order children near to far (closest and multi hit) or need not
// (any hit). Nested structures are traversed by their own `traverse(ray, structure, isect,
// query)` (found by ADL), which comes back here for their primitives. Returns true when the query
// is finished.
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
// at a time, exactly as given (triangle_at), as the paper's API promises. Otherwise, for scalar
// rays, the block's triangles are tested at once (intersect_block: bit-identical lane by lane;
// degenerate triangles are known from the block and never tested) and the hit lanes go to the
// filter and the query: in lane order for queries that stop at any hit (the first hit in leaf
// order, as one at a time would find), by increasing (t, prim_id) otherwise, each while its t is
// still within the ray's tightening tmax.
template <typename Ray, typename I, typename Query>
[[gnu::always_inline]] inline bool call_hooks_or_descend(Ray& ray, triangle_block const& block, int count, I& isect,
                                                         Query& query) {
    if constexpr (primitive_hook_for<I, Ray, triangle> || !is_prepared_ray_v<Ray> ||
                  simd::simd_width_v<ray_value_t<Ray>> != 1) {
        for (int lane = 0; lane < count; ++lane)
            if (call_hooks_or_descend(ray, block.triangle_at(lane), isect, query)) return true;
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
            if (query.report(hr, ray)) return true;
        }
        return false;
    }
}

} // namespace canopy
