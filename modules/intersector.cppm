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
// - Mistakes are compile errors at the query, never silently ignored hooks (intersector_mistake
//   below; canopy.query turns each into a static_assert naming the expected signatures):
//   * a const intersector whose hooks or filter are not const;
//   * a hook whose result the traversal cannot use: a primitive hook must return
//     basic_hit_record<T> (T: the ray's value type), a box hook what intersect(ray, box, inv_dir)
//     returns, a filter bool (a mask for packets);
//   * an operator() that is no hook for the query: no overload serves as a primitive hook
//     `(Ray const&, Prim const&)` for the query's leaf primitive type Prim (hooks receive the
//     query's ray, or inside BVHs a prepared ray derived from it) or as a box hook
//     `(Ray const&, basic_aabb<S> const&, Args&&...)`, and the intersector has an operator() of
//     its own, which is decided at compile time:
//       - one of the usual slips accepts a call: (prim, ray) swapped; a primitive, box or ray
//         taken by non-const reference; a box hook (ray, box) without the trailing Args&&...;
//         hooks for the other precision (double in a float query, or float in a double one);
//         hooks for scalar rays in a packet query;
//       - or a class derived from basic_intersector hides the inherited operator() (it declares
//         one without the `using`), a class of another kind (a lambda, an overload set) has an
//         operator(), or the intersector is a function pointer.
//     So an intersector with no operator() of its own (a filter only; default_intersector) is
//     fine, and so is one that says `using` and whose hooks are for another primitive type
//     (moller_trumbore_intersector over spheres): nothing it declares looks meant for the query.
// - Nested structures (BVHs, instances) are never handed to hooks: the intersector is passed down
//   into them (call_hooks_or_descend, canopy.bvh:protocol, is the one place that decides).
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
// - BVHs built with spatial splits (build_quality::high, canopy.bvh:spatial) may hold one triangle
//   in several leaves. The queries still report it once per ray, but a triangle hook and a filter
//   are then called at least once for each triangle a ray meets, possibly once per leaf holding
//   it (each time with the same triangle and the same candidate). The default,
//   build_quality::automatic, builds that way only meshes of long thin triangles (bvh::quality
//   says); with build_quality::fast every triangle is in one leaf.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <concepts>
#include <cstdint>
#include <type_traits>
#include <utility>
export module canopy.intersector;
export import canopy.geometry;

namespace canopy::detail {

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

// The argument of basic_intersector's marker overload: an intersector hides the inherited
// operator() exactly when a call with it fails.
struct inherited_call_probe {};

} // namespace canopy::detail

export namespace canopy {

// CRTP base: forwards every test to the library's intersect(), found by ADL. It does not take
// the prepared rays of traversal (which derive from basic_ray): a user's hook declared for
// `canopy::ray const&` then takes them by derived-to-base conversion, unopposed, and template
// hooks receive them as they are, with their cached per-ray constants.
template <typename Derived>
struct basic_intersector {
    template <typename Ray, typename Prim, typename... Args>
        requires(!detail::is_hook_probe_v<Prim>) && (!detail::is_hook_probe_v<Ray>) && (!is_prepared_ray_v<Ray>) &&
                requires(Ray const& ray, Prim const& prim, Args&&... args) {
                    intersect(ray, prim, std::forward<Args>(args)...);
                }
    auto operator()(Ray const& ray, Prim const& prim, Args&&... args) const {
        return intersect(ray, prim, std::forward<Args>(args)...);
    }

    // Not a hook: tells the library whether Derived's own operator() hides the inherited one.
    void operator()(detail::inherited_call_probe) const {}
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

// I has a ray/primitive hook of its own for Prim (a member, a lambda, an overload set); the
// forwarding operator inherited from basic_intersector does not count.
template <typename I, typename Ray, typename Prim>
concept primitive_hook_for = requires(I& isect, Ray const& ray, detail::hook_probe<Prim> const& prim) {
    { isect(ray, prim) };
};

// I has a ray/box hook of its own (called with the precomputed inverse direction).
template <typename I, typename Ray, typename Box, typename InvDir>
concept box_hook_for = requires(I& isect, Ray const& ray, detail::hook_probe<Box> const& box, InvDir const& inv_dir) {
    { isect(ray, box, inv_dir) };
};

// I has a filter of its own for hit records of Ray (see the top of this file).
template <typename I, typename Ray>
concept filter_hook_for = requires(I& isect, Ray const& ray, basic_hit_record<ray_value_t<Ray>> const& hr) {
    { isect.filter(ray, hr) };
};

// ---- mistakes ------------------------------------------------------------------------------

// What is wrong with intersector I for a query whose hooks receive rays of type Ray (the
// prepared ray of traversal, or the query's own ray over a range of primitives) and whose leaf
// primitives are of type Prim. The queries refuse to compile unless it is `none`, each mistake
// with its own message (canopy.query, report_intersector_mistake).
enum class intersector_mistake {
    none,
    const_hooks_not_const,    // a const intersector whose hooks (or filter) are not const
    primitive_result,         // a primitive hook that does not return basic_hit_record<T>
    box_result,               // a box hook that does not return what intersect(ray, box, inv_dir) does
    filter_result,            // a filter that returns neither bool nor the packet's mask
    swapped_parameters,       // (prim, ray) instead of (ray, prim)
    non_const_parameters,     // Prim& (or a non-const ray) instead of Prim const&
    box_hook_without_args,    // (ray, box) instead of (ray, box, Args&&...)
    other_precision,          // hooks for double in a float query, or for float in a double one
    scalar_hooks_for_packets, // hooks for scalar rays in a packet query
    no_usable_hook,           // an operator() of its own, none of which is a hook here
};

} // namespace canopy

namespace canopy::detail {

template <typename T>
struct is_basic_triangle : std::false_type {};
template <typename S>
struct is_basic_triangle<basic_triangle<S>> : std::true_type {};

// Derived from basic_intersector<X> for some X (directly, or through an intersector it extends).
template <typename X>
std::true_type derives_basic_intersector(basic_intersector<X> const*);
std::false_type derives_basic_intersector(...);
template <typename I>
inline constexpr bool is_basic_intersector_v =
    decltype(derives_basic_intersector(static_cast<std::remove_cvref_t<I> const*>(nullptr)))::value;

// A class with an operator() of its own: lookup of operator() in call_detector<C> is ambiguous
// exactly when C has one too.
struct call_marker {
    void operator()() const {}
};
template <typename C>
struct call_detector : C, call_marker {};

// I declares an operator() that is not basic_intersector's forwarding one (see the top of this
// file; the near misses are tested separately).
template <typename I>
constexpr bool has_own_call_operator() {
    using M = std::remove_cvref_t<I>;
    if constexpr (!std::is_class_v<M>)
        return std::is_pointer_v<M> || std::is_function_v<M>;
    else if constexpr (is_basic_intersector_v<M>)
        return !requires(M const& isect) { isect(inherited_call_probe{}); };
    else if constexpr (std::is_final_v<M>)
        return false;
    else
        return !requires { &call_detector<M>::operator(); };
}

// A box hook for boxes of type Box, called with Ray's inverse direction.
template <typename I, typename Ray, typename Box>
concept box_hook_with = box_hook_for<I, Ray, Box, vec3<ray_value_t<Ray>>>;

// The same ray type for value type U: prepared_ray<T> → prepared_ray<U>, basic_ray<T> → basic_ray<U>.
template <typename Ray, typename U>
using ray_as = std::conditional_t<is_prepared_ray_v<Ray>, prepared_ray<U>, basic_ray<U>>;

// Hooks written for scalar type U (float or double) whose query is of another value type.
template <typename I, typename Ray, typename Prim, typename U>
constexpr bool hooks_for_value_type() {
    using R = ray_as<Ray, U>;
    if constexpr (primitive_hook_for<I, R, Prim> || box_hook_with<I, R, basic_aabb<U>>)
        return true;
    else if constexpr (is_basic_triangle<Prim>::value)
        return primitive_hook_for<I, R, basic_triangle<U>>;
    else
        return false;
}

// Hooks whose results the traversal can use: the default test's result type (or one that
// converts to it).
template <typename I, typename Ray, typename Prim>
concept primitive_result_ok = requires(I& isect, Ray const& ray, Prim const& prim) {
    { isect(ray, prim) } -> std::convertible_to<basic_hit_record<ray_value_t<Ray>>>;
};
template <typename I, typename Ray, typename Box, typename InvDir>
concept box_result_ok = requires(I& isect, Ray const& ray, Box const& box, InvDir const& inv_dir) {
    { isect(ray, box, inv_dir) } -> std::convertible_to<decltype(intersect(ray, box, inv_dir))>;
};
template <typename I, typename Ray>
concept filter_result_ok = requires(I& isect, Ray const& ray, basic_hit_record<ray_value_t<Ray>> const& hr) {
    { isect.filter(ray, hr) } -> std::convertible_to<simd::mask_type_t<ray_value_t<Ray>>>;
};

template <typename I, typename Ray, typename Prim>
constexpr intersector_mistake find_intersector_mistake() {
    using M = std::remove_const_t<I>;
    using T = ray_value_t<Ray>;
    using S = simd::scalar_type_t<T>;
    using Box = basic_aabb<S>;
    using InvDir = vec3<T>;
    constexpr bool prim_hook = primitive_hook_for<I, Ray, Prim>;
    constexpr bool box_hook = box_hook_for<I, Ray, Box, InvDir>;
    if constexpr (std::is_const_v<I> && ((primitive_hook_for<M, Ray, Prim> && !prim_hook) ||
                                         (box_hook_for<M, Ray, Box, InvDir> && !box_hook) ||
                                         (filter_hook_for<M, Ray> && !filter_hook_for<I, Ray>))) {
        return intersector_mistake::const_hooks_not_const;
    } else if constexpr (prim_hook && !primitive_result_ok<I, Ray, Prim>) {
        return intersector_mistake::primitive_result;
    } else if constexpr (box_hook && !box_result_ok<I, Ray, Box, InvDir>) {
        return intersector_mistake::box_result;
    } else if constexpr (filter_hook_for<I, Ray> && !filter_result_ok<I, Ray>) {
        return intersector_mistake::filter_result;
    } else if constexpr (prim_hook || box_hook) {
        return intersector_mistake::none;
    } else if constexpr (requires(I& isect, hook_probe<Prim> const& prim, Ray const& ray) { isect(prim, ray); } ||
                         requires(I& isect, hook_probe<Box> const& box, Ray const& ray, InvDir const& inv_dir) {
                             isect(box, ray, inv_dir);
                         }) {
        return intersector_mistake::swapped_parameters;
    } else if constexpr (requires(I& isect, Ray& ray, hook_probe<Prim>& prim) { isect(ray, prim); } ||
                         requires(I& isect, Ray& ray, hook_probe<Box>& box, InvDir& inv_dir) { isect(ray, box, inv_dir); }) {
        return intersector_mistake::non_const_parameters;
    } else if constexpr (requires(I& isect, Ray const& ray, hook_probe<Box> const& box) { isect(ray, box); }) {
        return intersector_mistake::box_hook_without_args;
    } else if constexpr (simd::simd_width_v<T> == 1 &&
                         hooks_for_value_type<I, Ray, Prim, std::conditional_t<std::is_same_v<S, float>, double, float>>()) {
        return intersector_mistake::other_precision;
    } else if constexpr (simd::simd_width_v<T> != 1 && hooks_for_value_type<I, Ray, Prim, S>()) {
        return intersector_mistake::scalar_hooks_for_packets;
    } else if constexpr (has_own_call_operator<I>()) {
        return intersector_mistake::no_usable_hook;
    } else {
        return intersector_mistake::none;
    }
}

} // namespace canopy::detail

export namespace canopy {

// The mistake intersector I makes (see above) when its hooks receive rays of type Ray and the
// leaf primitives are of type Prim. canopy.bvh:protocol (intersector_mistake_v) finds Ray and
// Prim for a query over a range of primitives or of nested structures.
template <typename I, typename Ray, typename Prim>
inline constexpr intersector_mistake hook_mistake_v = detail::find_intersector_mistake<I, Ray, Prim>();

} // namespace canopy
