// canopy.geometry:sphere — spheres and their ray test.
//
// Roots of |o + t·d − c|² = r² with the cancellation-free discriminant and the stable quadratic
// of Haines et al., "Precision Improvements for Ray/Sphere Intersection", Ray Tracing Gems
// (2019), ch. 7. Reports the nearest root in [tmin, tmax]; u, v are 0.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <cstdint>
#include <type_traits>
export module canopy.geometry:sphere;
import canopy.math;
import :hit_record;

export namespace canopy {

template <typename T>
struct basic_sphere {
    using value_type = T;
    vec3<T> center;
    T radius{};
    std::uint32_t prim_id = 0;
    std::uint32_t geom_id = 0;
};
using sphere = basic_sphere<float>;

template <typename T>
basic_aabb<T> get_bounds(basic_sphere<T> const& s) {
    return {s.center - vec3<T>(s.radius), s.center + vec3<T>(s.radius)};
}

template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
basic_hit_record<T> intersect(basic_ray<T> const& ray, basic_sphere<S> const& sph) {
    basic_hit_record<T> hr;
    vec3<T> const f = ray.origin - vec3<T>(sph.center);
    T const r = T(sph.radius);
    T const a = dot(ray.direction, ray.direction);
    T const b = dot(f, ray.direction);
    T const c = dot(f, f) - r * r;
    // b² − a·c evaluated as a·(r² − |f − (b/a)·d|²).
    vec3<T> const l = f - (b / a) * ray.direction;
    T const discriminant = a * (r * r - dot(l, l));
    auto const real_roots = discriminant >= T(0);
    if (simd::none(real_roots)) return hr;

    T const q = -(b + simd::copysign(simd::sqrt(discriminant), b));
    T const t0 = c / q;
    T const t1 = q / a;
    T const t_lo = simd::min(t0, t1);
    T const t_hi = simd::max(t0, t1);
    auto const lo_in = (t_lo >= ray.tmin) & (t_lo <= ray.tmax);
    auto const hi_in = (t_hi >= ray.tmin) & (t_hi <= ray.tmax);
    auto const hit = real_roots & (sph.radius > S(0)) & (lo_in | hi_in);
    if (simd::none(hit)) return hr;
    record_hit(hr, hit, simd::select(lo_in, t_lo, t_hi), T(0), T(0), sph.prim_id, sph.geom_id);
    return hr;
}

} // namespace canopy
