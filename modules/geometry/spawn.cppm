// canopy.geometry:spawn — secondary rays that do not re-hit the surface they leave.
//
// The origin is the barycentric hit point, pushed off the surface along the geometric normal
// (flipped to the side the new ray goes to) by an offset proportional to the point's magnitude in
// integer ulps, with a fixed epsilon near the origin: Wächter & Binder 2019, "A Fast and Robust
// Method for Avoiding Self-Intersection", Ray Tracing Gems ch. 6; and further by a small fraction
// of the triangle's extent around the point, the scale of the watertight test's own rounding
// (offset_ray_origin). The new ray starts at tmin = 0.
//
// Points are in the triangle's own (object) space; for instanced geometry, transform the ray
// afterwards or spawn from the world-space triangle.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <bit>
#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <limits>
export module canopy.geometry:spawn;
import canopy.math;
import :triangle;

export namespace canopy {

// p moved off the plane with normal n (any length, pointing to the side to leave to). `reach`
// is the largest distance (per coordinate) from p to the corners of the triangle p lies on: the
// watertight test rounds the corners relative to the ray origin, so a ray leaving p sees the
// plane only to within a few ulps of `reach` (9u·reach, see canopy.geometry:box), which can be
// far more than p's own ulps near an axis plane. The origin moves a further 2^-19·reach along n.
inline vec3<float> offset_ray_origin(vec3<float> const& p, vec3<float> const& n, float reach = 0.0f) {
    constexpr float origin = 1.0f / 32.0f;
    constexpr float float_scale = 1.0f / 65536.0f;
    constexpr float int_scale = 256.0f;
    vec3<float> const unit = normalize(n);
    vec3<float> out;
    for (int k = 0; k < 3; ++k) {
        float const pk = p[k], nk = unit[k];
        auto const of = std::int32_t(int_scale * nk);
        auto const bits = std::bit_cast<std::int32_t>(pk);
        float const moved = std::bit_cast<float>(bits + (pk < 0.0f ? -of : of));
        out[k] = (std::fabs(pk) < origin ? pk + float_scale * nk : moved) + nk * (reach * 0x1p-19f);
    }
    return out;
}

// The largest coordinate difference between p and a corner of tri (offset_ray_origin's reach).
inline float corner_reach(triangle const& tri, vec3<float> const& p) {
    float r = 0.0f;
    for (vec3<float> const& v : {tri.v0, tri.v1, tri.v2})
        for (int k = 0; k < 3; ++k) r = std::fmax(r, std::fabs(v[k] - p[k]));
    return r;
}

// Geometric normal of a triangle (right-handed winding v0 → v1 → v2), not normalised.
template <typename T>
vec3<T> geometric_normal(basic_triangle<T> const& tri) {
    return cross(tri.v1 - tri.v0, tri.v2 - tri.v0);
}

// The point with barycentric weights (u, v) for v1 and v2.
template <typename T>
vec3<T> surface_point(basic_triangle<T> const& tri, T u, T v) {
    return lerp(tri.v0, tri.v1, tri.v2, u, v);
}

// A ray leaving the triangle at (u, v) in direction dir (not normalised), up to tmax.
inline ray spawn_ray(triangle const& tri, float u, float v, vec3<float> const& dir,
                     float tmax = std::numeric_limits<float>::infinity()) {
    vec3<float> n = geometric_normal(tri);
    if (dot(n, dir) < 0.0f) n = -n;
    vec3<float> const p = surface_point(tri, u, v);
    return {offset_ray_origin(p, n, corner_reach(tri, p)), 0.0f, dir, tmax};
}

// A ray from the triangle at (u, v) towards target, ending just before it (t in [0, 1)).
inline ray spawn_ray_to(triangle const& tri, float u, float v, vec3<float> const& target) {
    vec3<float> n = geometric_normal(tri);
    vec3<float> const p = surface_point(tri, u, v);
    if (dot(n, target - p) < 0.0f) n = -n;
    vec3<float> const origin = offset_ray_origin(p, n, corner_reach(tri, p));
    return {origin, 0.0f, target - origin, next_float_down(1.0f)};
}

} // namespace canopy
