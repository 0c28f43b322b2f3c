// canopy.query:single — the visibility queries of the paper for one ray (or one packet):
// closest_hit, any_hit, multi_hit<N>, over an iterator range of primitives, of BVHs (multiple
// roots) or of instances, with or without a custom intersector (taken by reference: counters in it
// are visible to the caller). Spans of rays go to canopy.query:batch.
//
// Guarantees, at every level of nesting:
// - hooks receive a ray whose tmax is the closest accepted hit so far (closest_hit), or the N-th
//   accepted hit once N are found (multi_hit): intersect() inside a hook already culls.
// - any_hit stays any-hit in nested BVHs and stops the whole traversal at the first accepted hit.
// - multi_hit<N> returns up to N accepted hits sorted by t, each (instance path, primitive) once,
//   also when spatial splits (build_quality::high) put a triangle in several leaves.
// - Equal t: the hit with the smaller (inst_id, inner_inst_id…, prim_id) wins, so results do not
//   depend on traversal order (BVH, brute force, packets and threads agree).
// Rays with a NaN or infinite origin or direction component, a NaN tmin/tmax, or tmin > tmax
// miss without being traced. Packet rays (basic_ray<float8>, …) are supported by closest_hit and
// any_hit; such lanes are inactive and report misses.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <array>
#include <cstddef>
#include <cstdint>
#include <iterator>
#include <limits>
#include <type_traits>
#include <utility>
export module canopy.query:single;
export import canopy.bvh;

namespace canopy::detail {

// Unsigned a < b, lane-wise, for ids held in signed SIMD int lanes.
template <typename I>
auto id_less(I const& a, I const& b) {
    I const bias(std::numeric_limits<std::int32_t>::min());
    return (a ^ bias) < (b ^ bias);
}

// a precedes b: smaller t, ties broken by (inst_id, inner_inst_id…, prim_id).
template <typename T>
auto precedes(basic_hit_record<T> const& a, basic_hit_record<T> const& b) {
    if constexpr (simd::simd_width_v<T> == 1) {
        if (a.t != b.t) return a.t < b.t;
        if (a.inst_id != b.inst_id) return a.inst_id < b.inst_id;
        if (a.inner_inst_id != b.inner_inst_id) return a.inner_inst_id < b.inner_inst_id;
        return a.prim_id < b.prim_id;
    } else {
        auto less = id_less(a.prim_id, b.prim_id);
        for (int k = max_instance_depth - 2; k >= 0; --k) {
            auto const& ak = a.inner_inst_id[std::size_t(k)];
            auto const& bk = b.inner_inst_id[std::size_t(k)];
            less = id_less(ak, bk) | ((ak == bk) & less);
        }
        less = id_less(a.inst_id, b.inst_id) | ((a.inst_id == b.inst_id) & less);
        return (a.t < b.t) | ((a.t == b.t) & less);
    }
}

template <typename T>
struct closest_query : instance_path {
    static constexpr bool wants_near_first = true;
    static constexpr bool keeps_nearest_only = true; // report accepts only what precedes `best`
    basic_hit_record<T> best;

    template <typename Ray>
    bool report(basic_hit_record<T> hr, Ray& ray) {
        if (simd::none(hr.hit)) return false;
        stamp(hr);
        auto const accept = hr.hit & precedes(hr, best);
        if (simd::none(accept)) return false;
        best = select(accept, hr, best);
        ray.tmax = simd::select(accept, hr.t, ray.tmax);
        return false;
    }

    // Packets: lane k on its own (canopy.bvh:instance, lanes traced alone), as a scalar query
    // with the lane's best hit and this query's instance path; absorb takes its result back.
    closest_query<simd::scalar_type_t<T>> lane(int k) const
        requires(simd::simd_width_v<T> > 1)
    {
        closest_query<simd::scalar_type_t<T>> q;
        static_cast<instance_path&>(q) = *this;
        q.best = record_lane(best, k);
        return q;
    }
    template <typename Ray>
    bool absorb(int k, closest_query<simd::scalar_type_t<T>> const& q, simd::scalar_type_t<T> lane_tmax, Ray& ray)
        requires(simd::simd_width_v<T> > 1)
    {
        set_record_lane(best, k, q.best);
        ray.tmax.set(k, lane_tmax);
        return false;
    }
};

template <typename T>
struct any_query : instance_path {
    static constexpr bool wants_near_first = false;
    basic_hit_record<T> found;
    simd::mask_type_t<T> done{};

    template <typename Ray>
    bool report(basic_hit_record<T> hr, Ray& ray) {
        if (simd::none(hr.hit)) return false;
        stamp(hr);
        if constexpr (simd::simd_width_v<T> == 1) {
            found = hr;
            return true;
        } else {
            auto const first = hr.hit & !done;
            found = select(first, hr, found);
            done = done | hr.hit;
            // Finished lanes can hit nothing more.
            ray.tmax = simd::select(done, T(-std::numeric_limits<simd::scalar_type_t<T>>::infinity()), ray.tmax);
            return simd::all(done);
        }
    }

    // Packets: lane k on its own (see closest_query::lane). A lane traced alone is not done.
    any_query<simd::scalar_type_t<T>> lane(int) const
        requires(simd::simd_width_v<T> > 1)
    {
        any_query<simd::scalar_type_t<T>> q;
        static_cast<instance_path&>(q) = *this;
        return q;
    }
    template <typename Ray>
    bool absorb(int k, any_query<simd::scalar_type_t<T>> const& q, simd::scalar_type_t<T>, Ray& ray)
        requires(simd::simd_width_v<T> > 1)
    {
        if (!q.found.hit) return false;
        set_record_lane(found, k, q.found);
        done.set(k, true);
        ray.tmax.set(k, -std::numeric_limits<simd::scalar_type_t<T>>::infinity());
        return simd::all(done);
    }
};

template <typename T, std::size_t N>
struct multi_query : instance_path {
    static_assert(simd::simd_width_v<T> == 1, "multi_hit takes scalar rays");
    static constexpr bool wants_near_first = true;
    std::array<basic_hit_record<T>, N> hits{};
    std::size_t count = 0;

    template <typename Ray>
    bool report(basic_hit_record<T> hr, Ray& ray) {
        if (!hr.hit) return false;
        stamp(hr);
        if (count == N && !precedes(hr, hits[N - 1])) return false;
        // Where it goes in the sorted list. A triangle that spatial splits put in several leaves
        // comes back with the same record: the hits it would follow include that record, if it
        // was kept (equal t and ids sort together), and then it is dropped.
        std::size_t at = count;
        while (at > 0 && precedes(hr, hits[at - 1])) --at;
        for (std::size_t k = at; k > 0 && !precedes(hits[k - 1], hr); --k)
            if (hits[k - 1].prim_id == hr.prim_id && hits[k - 1].geom_id == hr.geom_id) return false;
        // Insertion, dropping the last one when full.
        std::size_t i = count < N ? count++ : N - 1;
        for (; i > at; --i) hits[i] = hits[i - 1];
        hits[i] = hr;
        if (count == N) ray.tmax = hits[N - 1].t;
        return false;
    }
};

// Lanes of a (packet) ray that take part: finite origin and direction, tmin ≤ tmax (fails for
// NaN). Other rays miss without being traced.
template <typename Ray>
auto active_lanes(Ray const& ray) {
    auto const& o = ray.origin;
    auto const& d = ray.direction;
    if constexpr (simd::simd_width_v<ray_value_t<Ray>> == 1)
        return ray.tmin <= ray.tmax && simd::isfinite(o.x) && simd::isfinite(o.y) && simd::isfinite(o.z) &&
               simd::isfinite(d.x) && simd::isfinite(d.y) && simd::isfinite(d.z);
    else
        return (ray.tmin <= ray.tmax) & simd::isfinite(o.x) & simd::isfinite(o.y) & simd::isfinite(o.z) &
               simd::isfinite(d.x) & simd::isfinite(d.y) & simd::isfinite(d.z);
}

// The intersector's mistakes (canopy.intersector, intersector_mistake) as compile errors, here at
// the query: one message, naming what to write, and no errors from deeper inside the library.
template <intersector_mistake M>
constexpr bool report_intersector_mistake() {
    using enum intersector_mistake;
    static_assert(M != const_hooks_not_const,
                  "canopy: this intersector is passed as const, but its hooks (operator() or filter) are not const "
                  "member functions, so they would never be called. Pass the intersector non-const, or declare the "
                  "hooks const: `auto operator()(Ray const& ray, Prim const& prim) const`.");
    static_assert(M != primitive_result,
                  "canopy: a ray/primitive hook must return canopy::basic_hit_record<T> (T: the ray's value type), "
                  "e.g. `auto hr = intersect(ray, prim); hr.hit &= keep; return hr;`. To accept or reject candidates "
                  "with a bool, write a filter instead: "
                  "`template <typename Ray> bool filter(Ray const& ray, canopy::basic_hit_record<float> const& hr)`.");
    static_assert(M != box_result,
                  "canopy: a ray/box hook must return what the library's box test returns: "
                  "`return intersect(ray, box, std::forward<Args>(args)...);` (canopy::box_hit<T>).");
    static_assert(M != filter_result,
                  "canopy: filter(ray, hr) must return bool (for packet rays: the mask of the ray's value type), "
                  "true to keep the candidate.");
    static_assert(M != swapped_parameters,
                  "canopy: this intersector's hook takes its parameters in the order (primitive, ray): the ray comes "
                  "first. Expected: `template <typename Ray> auto operator()(Ray const& ray, Prim const& prim)` and, "
                  "for boxes, `template <typename Ray, typename... Args> auto operator()(Ray const& ray, "
                  "canopy::aabb const& box, Args&&... args)`.");
    static_assert(M != non_const_parameters,
                  "canopy: this intersector's hook takes its primitive, box or ray by non-const reference, so it can "
                  "never be called: the library passes them const. Expected: "
                  "`template <typename Ray> auto operator()(Ray const& ray, Prim const& prim)`.");
    static_assert(M != box_hook_without_args,
                  "canopy: this intersector's box hook takes (ray, box) only: box tests also pass the inverse "
                  "direction. Expected: `template <typename Ray, typename... Args> auto operator()(Ray const& ray, "
                  "canopy::aabb const& box, Args&&... args)`, returning `intersect(ray, box, "
                  "std::forward<Args>(args)...)`.");
    static_assert(M != other_precision,
                  "canopy: this intersector's hooks are for the other precision (e.g. basic_triangle<double> or "
                  "basic_aabb<double> in a query of float rays over float triangles, or float hooks in a double "
                  "query), so they would never be called. Declare them for the query's types, or generically: "
                  "`template <typename Ray, typename S> auto operator()(Ray const& ray, "
                  "canopy::basic_triangle<S> const& tri)`.");
    static_assert(M != scalar_hooks_for_packets,
                  "canopy: this intersector's hooks take scalar rays (canopy::ray), but this query traces packets "
                  "(basic_ray<simd::float8>, ...), so they would never be called. Take the ray as a template "
                  "parameter: `template <typename Ray> auto operator()(Ray const& ray, Prim const& prim)`.");
    static_assert(M != no_usable_hook,
                  "canopy: this intersector declares operator(), but none of its overloads can serve as a hook for "
                  "this query's ray and primitive types, so it would never be called. Expected (Prim: the primitive "
                  "type at the bottom of the query, e.g. canopy::triangle): "
                  "`template <typename Ray> auto operator()(Ray const& ray, Prim const& prim)` returning "
                  "canopy::basic_hit_record<T>, and/or `template <typename Ray, typename... Args> auto "
                  "operator()(Ray const& ray, canopy::aabb const& box, Args&&... args)`.");
    return M == none;
}

// Inlined into the query functions, and with them into the caller's loop over rays: a call per ray
// would save and restore registers and rebuild the traversal's constants for every ray.
template <typename Ray, typename It, typename I, typename Query>
[[gnu::always_inline]] inline void run_query(Ray& ray, It first, It last, I& isect, Query& query) {
    using Elem = std::remove_cvref_t<decltype(*first)>;
    static_assert(instance_nesting_v<Elem> <= max_instance_depth,
                  "instances nest deeper than hit records can report (max_instance_depth)");
    if constexpr (report_intersector_mistake<intersector_mistake_v<I, Ray, Elem>>()) {
        for (; first != last; ++first)
            if (call_hooks_or_descend(ray, *first, isect, query)) return;
    }
}

} // namespace canopy::detail

export namespace canopy {

// A ray or a packet of rays (basic_ray<T>, prepared_ray<T>): what the single-ray queries take, so
// that spans of rays go to the batch queries.
template <typename Ray>
concept ray_like = requires(Ray const& r) {
    r.origin;
    r.direction;
    r.tmin;
    r.tmax;
};

// An iterator over what a query can trace: primitives, or structures holding them
// (canopy.bvh:protocol, traceable).
template <typename It>
concept traceable_iterator = traceable<std::remove_cvref_t<std::iter_reference_t<It>>>;

// The queries are inlined into the caller, as run_query is: the compiler otherwise keeps some
// instances out of line (measured: +53 instructions per ray for closest_hit with no intersector,
// the record returned through memory and the ray copied, against an intersector with a filter).
template <ray_like Ray, traceable_iterator It, typename I = default_intersector>
[[gnu::always_inline]] inline basic_hit_record<ray_value_t<Ray>> closest_hit(Ray const& ray, It first, It last,
                                                                             I&& isect = I{}) {
    using T = ray_value_t<Ray>;
    detail::closest_query<T> query;
    Ray r = ray;
    auto const active = detail::active_lanes(r);
    if (simd::none(active)) return query.best;
    if constexpr (simd::simd_width_v<T> > 1)
        r.tmax = simd::select(active, r.tmax, T(-std::numeric_limits<simd::scalar_type_t<T>>::infinity()));
    detail::run_query(r, first, last, isect, query);
    return query.best;
}

template <ray_like Ray, traceable_iterator It, typename I = default_intersector>
[[gnu::always_inline]] inline basic_hit_record<ray_value_t<Ray>> any_hit(Ray const& ray, It first, It last,
                                                                         I&& isect = I{}) {
    using T = ray_value_t<Ray>;
    detail::any_query<T> query;
    Ray r = ray;
    auto const active = detail::active_lanes(r);
    if (simd::none(active)) return query.found;
    if constexpr (simd::simd_width_v<T> > 1) {
        query.done = !active;
        r.tmax = simd::select(active, r.tmax, T(-std::numeric_limits<simd::scalar_type_t<T>>::infinity()));
    }
    detail::run_query(r, first, last, isect, query);
    return query.found;
}

// Up to N accepted hits sorted by t (ties as above); entries past the last hit have hit == false.
template <std::size_t N, ray_like Ray, traceable_iterator It, typename I = default_intersector>
[[gnu::always_inline]] inline std::array<basic_hit_record<ray_value_t<Ray>>, N> multi_hit(Ray const& ray, It first,
                                                                                          It last, I&& isect = I{}) {
    static_assert(N > 0);
    detail::multi_query<ray_value_t<Ray>, N> query;
    Ray r = ray;
    if (detail::active_lanes(r)) detail::run_query(r, first, last, isect, query);
    return query.hits;
}

// The paper's ray/BVH test: closest hit in one BVH (or instance), with an optional intersector.
template <typename T, typename Structure, typename I = default_intersector>
    requires acceleration_structure<Structure>
basic_hit_record<T> intersect(basic_ray<T> const& ray, Structure const& structure, I&& isect = I{}) {
    return closest_hit(ray, &structure, &structure + 1, isect);
}

} // namespace canopy
