// Tests of canopy.geometry: the ray/triangle tests (watertight default, Möller–Trumbore), the
// ray/sphere test and the conservative ray/box slab test, each against an independent reference:
// hand-computed values, exact arithmetic on exactly representable inputs, or Cramer's rule and
// the quadratic formula in long double.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <utility>
#include <vector>

import canopy.geometry;
import canopy.testing;

namespace {

using canopy::ray;
using canopy::triangle;
using canopy::vec3;
using float8 = canopy::simd::float8;
using test_support::make_ray;
using test_support::pack;
using test_support::random_source;

constexpr float inf = std::numeric_limits<float>::infinity();
constexpr float quiet_nan = std::numeric_limits<float>::quiet_NaN();

std::uint32_t bits(float x) { return std::bit_cast<std::uint32_t>(x); }

bool same_point(vec3<float> a, vec3<float> b) { return a.x == b.x && a.y == b.y && a.z == b.z; }

// Long double vectors for the references.
struct vec3l {
    long double x, y, z;
};
vec3l widen(vec3<float> v) { return {v.x, v.y, v.z}; }
vec3l widen(vec3<double> v) { return {v.x, v.y, v.z}; }
vec3l operator-(vec3l a, vec3l b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
long double dot(vec3l a, vec3l b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
vec3l cross(vec3l a, vec3l b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }

// origin + t·direction = (1 − u − v)·v0 + u·v1 + v·v2 by Cramer's rule.
struct reference_hit {
    bool valid = false;   // the ray is not parallel to the plane
    long double t = 0, u = 0, v = 0;
    long double margin() const { return std::min({u, v, 1 - u - v}); }
};

template <typename T>
reference_hit reference_intersect(canopy::basic_ray<T> const& r, canopy::basic_triangle<T> const& tri) {
    vec3l const e1 = widen(tri.v1) - widen(tri.v0), e2 = widen(tri.v2) - widen(tri.v0);
    vec3l const s = widen(r.origin) - widen(tri.v0), d = widen(r.direction);
    vec3l const n = cross(e1, e2);
    long double const det = -dot(d, n);
    reference_hit h;
    if (det == 0) return h;
    h.valid = true;
    h.t = dot(s, n) / det;
    h.u = -dot(d, cross(s, e2)) / det;
    h.v = -dot(d, cross(e1, s)) / det;
    return h;
}

// |cos| of the angle between the ray and the triangle's normal: rounding errors of t, u, v grow
// like 1 / |cos| (grazing rays are ill-conditioned).
template <typename T>
long double incidence_cosine(canopy::basic_ray<T> const& r, canopy::basic_triangle<T> const& tri) {
    vec3l const n = cross(widen(tri.v1) - widen(tri.v0), widen(tri.v2) - widen(tri.v0));
    vec3l const d = widen(r.direction);
    return std::fabs(dot(n, d)) / std::sqrt(dot(n, n) * dot(d, d));
}

// Condition numbers of the ray/triangle problem, for forward error bounds in units of the unit
// roundoff: κ_uv = D L / (|n| |cos|) for u, v and κ_t = D / (|o − hit| |cos|) for t (relative),
// D = farthest vertex from the origin, L = longest edge, |n| = twice the area.
struct conditioning {
    long double uv = 0, t = 0;
};

template <typename T>
conditioning condition_numbers(canopy::basic_ray<T> const& r, canopy::basic_triangle<T> const& tri, long double t) {
    vec3l const o = widen(r.origin), d = widen(r.direction);
    vec3l const a = widen(tri.v0), b = widen(tri.v1), c = widen(tri.v2);
    auto const norm = [](vec3l v) { return std::sqrt(dot(v, v)); };
    long double const cosine = incidence_cosine(r, tri);
    long double const far = std::max({norm(a - o), norm(b - o), norm(c - o)});
    long double const longest = std::max({norm(b - a), norm(c - b), norm(a - c)});
    return {far * longest / (norm(cross(b - a, c - a)) * cosine), far / (std::fabs(t) * norm(d) * cosine)};
}

triangle random_triangle(random_source& rng, float extent, float size) {
    vec3<float> const c = rng.point(-extent, extent);
    return {c + rng.point(-size, size), c + rng.point(-size, size), c + rng.point(-size, size)};
}

// A ray from a random point towards a random point of the triangle (or of its surroundings).
ray random_ray_towards(random_source& rng, triangle const& tri) {
    float a = rng.uniform(-0.2f, 1.2f), b = rng.uniform(-0.2f, 1.2f);
    vec3<float> const target = tri.v0 + (tri.v1 - tri.v0) * a + (tri.v2 - tri.v0) * b * 0.5f;
    vec3<float> const origin = rng.point(-20.0f, 20.0f);
    return make_ray(origin, (target - origin) * rng.uniform(0.1f, 3.0f));
}

} // namespace

TEST_CASE("watertight triangle test returns the hand-computed t, u, v") {
    triangle const tri{{0, 0, 0}, {4, 0, 0}, {0, 4, 0}, 7, 3};
    auto const hr = intersect(make_ray({1, 2, 5}, {0, 0, -1}), tri);
    REQUIRE(hr.hit);
    CHECK(hr.t == 5.0f);
    CHECK(hr.u == 0.25f);   // weight of v1: x / 4
    CHECK(hr.v == 0.5f);    // weight of v2: y / 4
    CHECK(hr.prim_id == 7u);
    CHECK(hr.geom_id == 3u);
    CHECK(hr.inst_id == canopy::invalid_id);

    // Same point from below and along a slanted direction; the direction is not normalised.
    auto const below = intersect(make_ray({1, 2, -2}, {0, 0, 0.5f}), tri);
    REQUIRE(below.hit);
    CHECK(below.t == 4.0f);
    auto const slanted = intersect(make_ray({-1, 1, 4}, {0.5f, 0.25f, -1}), tri);
    REQUIRE(slanted.hit);
    CHECK(slanted.t == Approx(4.0f).epsilon(1e-6));
    CHECK(slanted.u == Approx(0.25f).epsilon(1e-6));
    CHECK(slanted.v == Approx(0.5f).epsilon(1e-6));

    // A miss leaves the record in its documented default state.
    auto const miss = intersect(make_ray({3, 3, 5}, {0, 0, -1}), tri);
    CHECK_FALSE(miss.hit);
    CHECK(miss.t == inf);
    CHECK(miss.prim_id == canopy::invalid_id);
}

namespace {

// The largest errors of hits against their long-double references, in units of κ u_f.
struct reference_errors {
    long double worst_uv = 0, worst_t = 0;

    // Checks hit `hr` against `ref`: t within tolerance_t relative, u and v within tolerance_uv;
    // keeps the largest errors in units of the condition numbers κ_uv and κ_t times u_f.
    template <typename Hit, typename Ref>
    void check(Hit const& hr, Ref const& ref, long double kappa_uv, long double kappa_t, long double tolerance_uv,
               long double tolerance_t) {
        constexpr long double unit_roundoff = std::numeric_limits<float>::epsilon() / 2;
        worst_uv = std::max({worst_uv, std::fabs(hr.u - ref.u) / (kappa_uv * unit_roundoff),
                             std::fabs(hr.v - ref.v) / (kappa_uv * unit_roundoff)});
        worst_t = std::max(worst_t, std::fabs(hr.t - ref.t) / (ref.t * kappa_t * unit_roundoff));
        CHECK(std::fabs(hr.t - ref.t) <= tolerance_t * ref.t);
        CHECK(std::fabs(hr.u - ref.u) <= tolerance_uv);
        CHECK(std::fabs(hr.v - ref.v) <= tolerance_uv);
    }
};

} // namespace

TEST_CASE("watertight triangle test agrees with Cramer's rule in long double") {
    // Forward error bounds: u, v within 32 κ_uv u_f, t within 32 κ_t u_f relative (the largest
    // errors seen are about 1 κ_uv u_f and 4 κ_t u_f).
    constexpr long double unit_roundoff = std::numeric_limits<float>::epsilon() / 2;
    random_source rng(11);
    int compared = 0;
    reference_errors errors;
    for (int i = 0; i < 20000; ++i) {
        triangle const tri = random_triangle(rng, 5.0f, 2.0f);
        ray const r = random_ray_towards(rng, tri);
        auto const ref = reference_intersect(r, tri);
        long double const cosine = incidence_cosine(r, tri);
        if (!ref.valid || cosine == 0 || ref.t <= 0) continue;
        auto const [kappa_uv, kappa_t] = condition_numbers(r, tri, ref.t);
        long double const tolerance_uv = 32 * kappa_uv * unit_roundoff;
        long double const tolerance_t = 32 * kappa_t * unit_roundoff;
        if (std::fabs(ref.margin()) < tolerance_uv || tolerance_uv > 0.01L || tolerance_t > 0.01L) continue;
        auto const hr = intersect(r, tri);
        INFO("case " << i << ", cos " << double(cosine) << ", t " << double(ref.t) << ", kappa_uv " << double(kappa_uv));
        REQUIRE(hr.hit == (ref.margin() > 0));
        if (!hr.hit) continue;
        ++compared;
        errors.check(hr, ref, kappa_uv, kappa_t, tolerance_uv, tolerance_t);
    }
    INFO("largest errors in units of kappa u_f: u, v " << double(errors.worst_uv) << ", t " << double(errors.worst_t));
    CHECK(compared > 5000);
}

TEST_CASE("a triangle hit is reported iff tmin <= t <= tmax") {
    triangle const tri{{0, 0, 0}, {4, 0, 0}, {0, 4, 0}};
    vec3<float> const origin{1, 2, 5}, direction{0, 0, -1};   // t = 5 exactly
    CHECK(intersect(make_ray(origin, direction, 0.0f, 5.0f), tri).hit);
    CHECK(intersect(make_ray(origin, direction, 5.0f, 5.0f), tri).hit);
    CHECK(intersect(make_ray(origin, direction, 5.0f, inf), tri).hit);
    CHECK_FALSE(intersect(make_ray(origin, direction, 0.0f, canopy::next_float_down(5.0f)), tri).hit);
    CHECK_FALSE(intersect(make_ray(origin, direction, canopy::next_float_up(5.0f), inf), tri).hit);
    // Behind the origin: t = -5, found only when tmin allows it.
    vec3<float> const up{0, 0, 1};
    CHECK_FALSE(intersect(make_ray(origin, up), tri).hit);
    auto const behind = intersect(make_ray(origin, up, -inf, inf), tri);
    REQUIRE(behind.hit);
    CHECK(behind.t == -5.0f);
    CHECK(intersect(make_ray(origin, up, -5.0f, -5.0f), tri).hit);
    CHECK_FALSE(intersect(make_ray(origin, up, canopy::next_float_up(-5.0f), inf), tri).hit);

    // The same boundaries for Möller–Trumbore, and for double precision.
    CHECK(intersect_moller_trumbore(make_ray(origin, direction, 0.0f, 5.0f), tri).hit);
    CHECK_FALSE(intersect_moller_trumbore(make_ray(origin, direction, 0.0f, canopy::next_float_down(5.0f)), tri).hit);
    canopy::basic_triangle<double> const tri_d{{0, 0, 0}, {4, 0, 0}, {0, 4, 0}};
    canopy::basic_ray<double> r_d{{1, 2, 5}, 0.0, {0, 0, -1}, 5.0};
    CHECK(intersect(r_d, tri_d).hit);
    r_d.tmax = canopy::next_float_down(5.0);
    CHECK_FALSE(intersect(r_d, tri_d).hit);
}

TEST_CASE("edges and vertices of a triangle count as hits") {
    // Axis-aligned rays: every quantity of the test is exact, so boundary points are hits.
    std::array<std::array<float, 2>, 9> const boundary{{{0, 0}, {4, 0}, {0, 4}, {2, 0}, {0, 2}, {2, 2}, {1, 3}, {3, 1},
                                                        {0.5f, 0}}};
    std::array<std::array<float, 2>, 5> const outside{{{-0.001f, 1}, {1, -0.001f}, {2.001f, 2}, {4.001f, 0}, {-0.001f, -0.001f}}};
    std::array<triangle, 2> const windings{triangle{{0, 0, 0}, {4, 0, 0}, {0, 4, 0}},
                                           triangle{{0, 4, 0}, {4, 0, 0}, {0, 0, 0}}};
    for (auto const& tri : windings) {
        for (float dz : {-1.0f, 1.0f}) {
            for (auto const& p : boundary) {
                INFO("point " << p[0] << ", " << p[1] << ", dz " << dz);
                auto const hr = intersect(make_ray({p[0], p[1], -3 * dz}, {0, 0, dz}), tri);
                CHECK(hr.hit);
                CHECK(hr.t == 3.0f);
            }
            for (auto const& p : outside) {
                INFO("point " << p[0] << ", " << p[1] << ", dz " << dz);
                CHECK_FALSE(intersect(make_ray({p[0], p[1], -3 * dz}, {0, 0, dz}), tri).hit);
            }
        }
    }
    // The same along the x axis (a different dominant axis) for a triangle in the plane x = 1.
    triangle const side{{1, 0, 0}, {1, 4, 0}, {1, 0, 4}};
    for (auto const& p : boundary) {
        CHECK(intersect(make_ray({-2, p[0], p[1]}, {1, 0, 0}), side).hit);
        CHECK(intersect(make_ray({5, p[0], p[1]}, {-2, 0, 0}), side).hit);
    }
}

TEST_CASE("rays through the shared edge of a split quad hit at least one triangle (watertight)") {
    // A non-planar quad split along p0–p2. Edge points p0 + k/64 (p2 − p0) and ray origins on a
    // 1/16 grid are exact, and so are the directions: each ray contains its edge point exactly.
    vec3<float> const p0{-1.5f, -1.25f, 0.25f}, p1{2.0f, -1.0f, -0.5f}, p2{1.75f, 2.25f, 0.5f}, p3{-1.25f, 1.5f, -0.25f};
    std::array<triangle, 2> const halves{triangle{p0, p1, p2, 0}, triangle{p0, p2, p3, 1}};
    vec3l const n0 = cross(widen(p1) - widen(p0), widen(p2) - widen(p0));
    vec3l const n1 = cross(widen(p2) - widen(p0), widen(p3) - widen(p0));
    random_source rng(5);
    int tested = 0, misses = 0;
    for (int k = 1; k < 64; ++k) {
        vec3<float> const edge_point = p0 + (p2 - p0) * (static_cast<float>(k) / 64.0f);
        for (int j = 0; j < 60; ++j) {
            float const side = (j % 2 == 0) ? 1.0f : -1.0f;
            vec3<float> const origin = rng.dyadic_point({-4, -4, 3}, {4, 4, 7}, 4) * vec3<float>(1, 1, side);
            vec3<float> const direction = edge_point - origin;
            REQUIRE(same_point(origin + direction, edge_point));
            // The ray must cross the surface, not pass along a fold (both faces seen from one side).
            vec3l const d = widen(direction);
            if ((dot(d, n0) > 0) != (dot(d, n1) > 0)) continue;
            ++tested;
            bool const hit = intersect(make_ray(origin, direction), halves[0]).hit ||
                             intersect(make_ray(origin, direction), halves[1]).hit;
            misses += !hit;
        }
    }
    CHECK(tested > 3000);
    CHECK(misses == 0);
}

TEST_CASE("rays through the centre and the spokes of a triangle fan hit at least one triangle (watertight)") {
    // A fan (a low pyramid) around an apex; rim vertices and spoke points are dyadic, windings mixed.
    vec3<float> const apex{0.25f, -0.5f, 1.0f};
    constexpr int sectors = 7;
    std::array<vec3<float>, sectors> rim;
    for (int k = 0; k < sectors; ++k) {
        double const angle = 2.0 * 3.14159265358979 * k / sectors;
        rim[std::size_t(k)] = {static_cast<float>(std::round(128.0 * std::cos(angle)) / 64.0),
                               static_cast<float>(std::round(128.0 * std::sin(angle)) / 64.0),
                               (k % 2 == 0) ? 0.125f : -0.125f};
    }
    std::vector<triangle> fan;
    for (int k = 0; k < sectors; ++k) {
        vec3<float> const a = rim[std::size_t(k)], b = rim[std::size_t((k + 1) % sectors)];
        fan.push_back(k % 2 == 0 ? triangle{apex, a, b} : triangle{b, apex, a});
    }
    std::vector<vec3l> normals;   // consistently oriented (apex, a, b)
    for (int k = 0; k < sectors; ++k)
        normals.push_back(cross(widen(rim[std::size_t(k)]) - widen(apex),
                                widen(rim[std::size_t((k + 1) % sectors)]) - widen(apex)));
    random_source rng(6);
    int tested = 0, misses = 0;
    for (int k = 0; k < sectors; ++k) {
        for (int j = 0; j < 32; ++j) {
            // j = 0 aims at the apex itself.
            vec3<float> const target = apex + (rim[std::size_t(k)] - apex) * (static_cast<float>(j) / 32.0f);
            for (int n = 0; n < 12; ++n) {
                vec3<float> const origin = rng.dyadic_point({-3, -3, 4}, {3, 3, 8}, 4);
                vec3<float> const direction = target - origin;
                REQUIRE(same_point(origin + direction, target));
                // Every face seen from the same side: the ray crosses the fan instead of grazing it.
                vec3l const d = widen(direction);
                if (!std::all_of(normals.begin(), normals.end(), [&](vec3l const& nk) { return dot(d, nk) < 0; }))
                    continue;
                ++tested;
                bool hit = false;
                for (auto const& tri : fan) hit = hit || intersect(make_ray(origin, direction), tri).hit;
                misses += !hit;
            }
        }
    }
    CHECK(tested > 2000);
    CHECK(misses == 0);
}

TEST_CASE("rays from inside a closed mesh always hit it (watertight)") {
    // Octahedron with exact vertices; rays aimed at its vertices, edge points and random points.
    std::array<vec3<float>, 6> const v{vec3<float>{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    std::vector<triangle> mesh;
    for (int sx : {0, 1})
        for (int sy : {2, 3})
            for (int sz : {4, 5}) mesh.push_back({v[std::size_t(sx)], v[std::size_t(sy)], v[std::size_t(sz)]});
    random_source rng(8);
    int misses = 0, rays = 0;
    auto shoot = [&](vec3<float> origin, vec3<float> direction) {
        ++rays;
        bool hit = false;
        for (auto const& tri : mesh) hit = hit || intersect(make_ray(origin, direction), tri).hit;
        misses += !hit;
    };
    for (int i = 0; i < 3000; ++i) {
        vec3<float> const origin = rng.dyadic_point({-0.25f, -0.25f, -0.25f}, {0.25f, 0.25f, 0.25f}, 6);
        vec3<float> const a = v[std::size_t(rng.integer(0, 5))], b = v[std::size_t(rng.integer(0, 5))];
        float const s = rng.dyadic(0, 1, 6);
        vec3<float> const edge_point = a + (b - a) * s;
        shoot(origin, a - origin);                                  // a vertex
        if (!same_point(edge_point, origin)) shoot(origin, edge_point - origin);   // an edge point (or a vertex)
        shoot(origin, rng.point(-1, 1) * rng.uniform(1e-3f, 1e3f)); // anywhere
    }
    CHECK(rays > 8900);
    CHECK(misses == 0);
}

TEST_CASE("degenerate triangles never hit") {
    std::array<triangle, 6> const degenerate{
        triangle{{0, 0, 0}, {1, 1, 1}, {2, 2, 2}},      // collinear
        triangle{{0, 0, 0}, {1, 0, 0}, {3, 0, 0}},      // collinear along an axis
        triangle{{1, 2, 3}, {1, 2, 3}, {4, 0, 1}},      // repeated vertex
        triangle{{1, 2, 3}, {4, 0, 1}, {4, 0, 1}},      // repeated vertex
        triangle{{1, 2, 3}, {1, 2, 3}, {1, 2, 3}},      // a point
        triangle{{-1, 0.5f, 2}, {1, 0.5f, 2}, {0, 0.5f, 2}}};
    random_source rng(9);
    for (auto const& tri : degenerate) {
        CHECK(canopy::is_degenerate(tri));
        for (int i = 0; i < 500; ++i) {
            // Towards points of the degenerate triangle, from anywhere, including along its line.
            float const s = rng.dyadic(0, 1, 5), w = rng.dyadic(0, 1, 5);
            vec3<float> const target = tri.v0 + (tri.v1 - tri.v0) * s + (tri.v2 - tri.v0) * (w * (1 - s));
            vec3<float> const origin = (i % 10 == 0) ? tri.v0 + (tri.v0 - tri.v2) * 2.0f : rng.dyadic_point({-5, -5, -5}, {5, 5, 5}, 4);
            ray const r = make_ray(origin, target - origin, -inf, inf);
            CHECK_FALSE(intersect(r, tri).hit);
            CHECK_FALSE(intersect_moller_trumbore(r, tri).hit);
        }
        for (vec3<float> const d : {vec3<float>{0, 0, 1}, vec3<float>{0, 1, 0}, vec3<float>{1, 0, 0}, vec3<float>{1, -1, 0}}) {
            CHECK_FALSE(intersect(make_ray(tri.v0 - d, d), tri).hit);
            CHECK_FALSE(intersect(make_ray(tri.v1 - d, d), tri).hit);
        }
    }
    CHECK_FALSE(canopy::is_degenerate(triangle{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}));
}

TEST_CASE("rays with NaN or Inf components, or a zero direction, miss") {
    triangle const tri{{0, 0, 0}, {4, 0, 0}, {0, 4, 0}};
    canopy::sphere const sph{{1, 1, 0}, 1.5f};
    for (ray const base : {make_ray({1, 2, 5}, {0, 0, -1}), make_ray({1, 1, 5}, {0.125f, 0.25f, -1})}) {
        REQUIRE(intersect(base, tri).hit);
        REQUIRE(intersect_moller_trumbore(base, tri).hit);
        REQUIRE(intersect(base, sph).hit);
        std::vector<ray> bad;
        for (int axis = 0; axis < 3; ++axis) {
            for (float x : {quiet_nan, inf, -inf}) {
                ray r = base;
                r.origin[axis] = x;
                bad.push_back(r);
                r = base;
                r.direction[axis] = x;
                bad.push_back(r);
            }
        }
        for (float x : {quiet_nan, inf}) {
            ray r = base;
            r.tmin = x;
            bad.push_back(r);
        }
        for (float x : {quiet_nan, -inf}) {
            ray r = base;
            r.tmax = x;
            bad.push_back(r);
        }
        bad.push_back(make_ray(base.origin, {0, 0, 0}));
        bad.push_back(make_ray(base.origin, {-0.0f, 0, -0.0f}));
        bad.push_back(make_ray(base.origin, base.direction, 6, 4));   // tmin > tmax
        for (std::size_t i = 0; i < bad.size(); ++i) {
            ray const& r = bad[i];
            INFO("ray " << i << ": origin (" << r.origin.x << ", " << r.origin.y << ", " << r.origin.z << "), direction ("
                        << r.direction.x << ", " << r.direction.y << ", " << r.direction.z << "), tmin " << r.tmin
                        << ", tmax " << r.tmax);
            auto const watertight = intersect(r, tri);
            auto const moller_trumbore = intersect_moller_trumbore(r, tri);
            auto const sphere_hit = intersect(r, sph);
            INFO("reported t: watertight " << watertight.t << ", Möller–Trumbore " << moller_trumbore.t << ", sphere "
                                           << sphere_hit.t);
            CHECK_FALSE(watertight.hit);
            CHECK_FALSE(moller_trumbore.hit);
            CHECK_FALSE(sphere_hit.hit);
        }
    }
}

TEST_CASE("Möller–Trumbore agrees with the watertight test away from edges") {
    // Away from edges (farther than both tests' error bounds) both report the same hits, with t,
    // u, v within Möller–Trumbore's looser bound of 256 κ u_f (largest seen: about 2 κ_uv u_f
    // and 50 κ_t u_f).
    constexpr long double unit_roundoff = std::numeric_limits<float>::epsilon() / 2;
    random_source rng(12);
    int hits = 0, misses = 0;
    reference_errors errors;
    for (int i = 0; i < 20000; ++i) {
        triangle tri = random_triangle(rng, 5.0f, 2.0f);
        tri.prim_id = std::uint32_t(i);
        ray const r = random_ray_towards(rng, tri);
        auto const ref = reference_intersect(r, tri);
        if (!ref.valid || incidence_cosine(r, tri) == 0 || ref.t == 0) continue;
        auto const [kappa_uv, kappa_t] = condition_numbers(r, tri, ref.t);
        long double const tolerance_uv = 256 * kappa_uv * unit_roundoff;
        long double const tolerance_t = 256 * kappa_t * unit_roundoff;
        if (std::fabs(ref.margin()) < tolerance_uv || tolerance_uv > 0.01L || tolerance_t > 0.01L) continue;
        auto const wt = intersect(r, tri);
        auto const mt = intersect_moller_trumbore(r, tri);
        INFO("case " << i);
        REQUIRE(wt.hit == mt.hit);
        if (!wt.hit) {
            ++misses;
            continue;
        }
        ++hits;
        errors.check(mt, ref, kappa_uv, kappa_t, tolerance_uv, tolerance_t);
        CHECK(std::fabs(mt.t - wt.t) <= 2 * tolerance_t * ref.t);
        CHECK(mt.prim_id == wt.prim_id);
    }
    INFO("largest errors in units of kappa u_f: u, v " << double(errors.worst_uv) << ", t " << double(errors.worst_t));
    CHECK(hits > 2000);
    CHECK(misses > 2000);
}

TEST_CASE("double-precision triangles and rays") {
    canopy::basic_triangle<double> const tri{{0, 0, 0}, {3, 0, 0}, {0, 3, 0}, 4};
    canopy::basic_ray<double> const r{{1, 1, 7}, 0.0, {0, 0, -1}, std::numeric_limits<double>::infinity()};
    auto const hr = intersect(r, tri);
    REQUIRE(hr.hit);
    CHECK(hr.t == 7.0);
    CHECK(hr.u == Approx(1.0 / 3.0).epsilon(1e-15));
    CHECK(hr.v == Approx(1.0 / 3.0).epsilon(1e-15));
    CHECK(hr.prim_id == 4u);

    // Random cases against long double Cramer: double precision is far tighter than float.
    random_source rng(13);
    int compared = 0;
    for (int i = 0; i < 5000; ++i) {
        triangle const f = random_triangle(rng, 5.0f, 2.0f);
        canopy::basic_triangle<double> const td{vec3<double>(f.v0), vec3<double>(f.v1), vec3<double>(f.v2)};
        ray const rf = random_ray_towards(rng, f);
        canopy::basic_ray<double> const rd{vec3<double>(rf.origin), 0.0, vec3<double>(rf.direction),
                                           std::numeric_limits<double>::infinity()};
        auto const ref = reference_intersect(rd, td);
        if (!ref.valid || incidence_cosine(rd, td) == 0 || ref.t <= 0) continue;
        // The float bounds with the double unit roundoff.
        constexpr long double unit_roundoff = std::numeric_limits<double>::epsilon() / 2;
        auto const [kappa_uv, kappa_t] = condition_numbers(rd, td, ref.t);
        long double const tolerance_uv = 32 * kappa_uv * unit_roundoff, tolerance_t = 32 * kappa_t * unit_roundoff;
        if (std::fabs(ref.margin()) < 8 * tolerance_uv) continue;
        auto const h = intersect(rd, td);
        REQUIRE(h.hit == (ref.margin() > 0));
        if (!h.hit) continue;
        ++compared;
        CHECK(std::fabs(h.t - ref.t) <= tolerance_t * ref.t);
        CHECK(std::fabs(h.u - ref.u) <= tolerance_uv);
        CHECK(std::fabs(h.v - ref.v) <= tolerance_uv);
        auto const m = intersect_moller_trumbore(rd, td);
        CHECK(m.hit);
        CHECK(std::fabs(m.t - ref.t) <= 8 * tolerance_t * ref.t);
    }
    CHECK(compared > 500);
}

namespace {

template <typename Packet, typename Scalar>
void check_lane_equals_scalar(Packet const& packet, int lane, Scalar const& scalar) {
    INFO("lane " << lane);
    CHECK(bool(packet.hit[lane]) == scalar.hit);
    CHECK(bits(packet.t[lane]) == bits(scalar.t));
    CHECK(bits(packet.u[lane]) == bits(scalar.u));
    CHECK(bits(packet.v[lane]) == bits(scalar.v));
    CHECK(std::uint32_t(packet.prim_id[lane]) == scalar.prim_id);
    CHECK(std::uint32_t(packet.geom_id[lane]) == scalar.geom_id);
}

// Rays of mixed dominant axes and signs (each lane takes its own permutation), with some misses,
// some inactive lanes and a NaN.
std::array<ray, 8> random_rays_for(random_source& rng, triangle const& tri) {
    std::array<ray, 8> rays;
    for (auto& r : rays) r = random_ray_towards(rng, tri);
    rays[3].direction = {-rays[3].direction.z, rays[3].direction.x, rays[3].direction.y};
    if (rng.integer(0, 3) == 0) rays[5].tmin = quiet_nan;
    if (rng.integer(0, 3) == 0) rays[6].tmax = rays[6].tmin - 1;
    return rays;
}

// A ray of a coherent packet: its direction's largest component along `axis` with `sign`
// (|d[axis]| >= 1 > the others, so every such ray takes the same shear permutation), aimed at a
// point around the target triangle from up to 20 directions away.
ray coherent_ray_towards(random_source& rng, triangle const& target, int axis, float sign) {
    vec3<float> d(rng.uniform(-0.9f, 0.9f), rng.uniform(-0.9f, 0.9f), rng.uniform(-0.9f, 0.9f));
    d[axis] = sign * rng.uniform(1.0f, 2.0f);
    float const b1 = rng.uniform(-0.2f, 1.0f), b2 = rng.uniform(-0.2f, 1.0f - b1);
    vec3<float> const p = target.v0 + (target.v1 - target.v0) * b1 + (target.v2 - target.v0) * b2;
    return make_ray(p - d * rng.uniform(0.5f, 20.0f), d);
}

// The triangles of one block (case i), and the block: a random number of used lanes, some
// triangles degenerate (a repeated vertex, or three collinear vertices), some sharing vertices
// with the previous one.
std::pair<std::vector<triangle>, canopy::triangle_block> random_block(random_source& rng, int i) {
    int const used = rng.integer(1, canopy::triangle_block_width);
    std::vector<triangle> tris;
    for (int lane = 0; lane < used; ++lane) {
        triangle t = random_triangle(rng, 5.0f, 2.0f);
        if (lane > 0 && rng.integer(0, 3) == 0) t.v0 = tris.back().v1, t.v1 = tris.back().v0;
        if (rng.integer(0, 9) == 0) t.v2 = t.v0;
        if (rng.integer(0, 9) == 0) t.v2 = t.v0 + (t.v1 - t.v0) * 2.0f;
        t.prim_id = std::uint32_t(10 * i + lane);
        t.geom_id = std::uint32_t(lane);
        tris.push_back(t);
    }
    std::vector<canopy::triangle_block> blocks;
    canopy::append_triangle_blocks(blocks, tris.begin(), tris.end());
    REQUIRE(blocks.size() == 1);
    return {tris, blocks[0]};
}

} // namespace

TEST_CASE("packet (float8) triangle and sphere tests equal the scalar tests lane by lane, bit for bit") {
    random_source rng(14);
    for (int i = 0; i < 3000; ++i) {
        triangle tri = random_triangle(rng, 5.0f, 2.0f);
        tri.prim_id = std::uint32_t(i);
        tri.geom_id = std::uint32_t(i % 5);
        std::array<ray, 8> const rays = random_rays_for(rng, tri);
        auto const packet = pack(rays);
        auto const wt = intersect(packet, tri);
        auto const mt = intersect_moller_trumbore(packet, tri);
        canopy::sphere const sph{tri.v0, rng.uniform(0.1f, 3.0f), std::uint32_t(i), 2};
        auto const sp = intersect(packet, sph);
        for (int lane = 0; lane < 8; ++lane) {
            INFO("case " << i);
            check_lane_equals_scalar(wt, lane, intersect(rays[std::size_t(lane)], tri));
            check_lane_equals_scalar(mt, lane, intersect_moller_trumbore(rays[std::size_t(lane)], tri));
            check_lane_equals_scalar(sp, lane, intersect(rays[std::size_t(lane)], sph));
        }
    }
}

TEST_CASE("sphere test returns the analytic roots") {
    canopy::sphere const sph{{1, 2, 3}, 2, 9, 1};
    // From outside: roots 8 and 12; the nearer one in [tmin, tmax] is reported.
    auto const outside = intersect(make_ray({1, 2, -7}, {0, 0, 1}), sph);
    REQUIRE(outside.hit);
    CHECK(outside.t == 8.0f);
    CHECK(outside.prim_id == 9u);
    CHECK(outside.geom_id == 1u);
    CHECK(intersect(make_ray({1, 2, -7}, {0, 0, 2}), sph).t == 4.0f);   // direction not normalised
    CHECK(intersect(make_ray({1, 2, -7}, {0, 0, 1}, 9, inf), sph).t == 12.0f);
    CHECK(intersect(make_ray({1, 2, -7}, {0, 0, 1}, 0, 8), sph).hit);
    CHECK_FALSE(intersect(make_ray({1, 2, -7}, {0, 0, 1}, 0, canopy::next_float_down(8.0f)), sph).hit);
    CHECK_FALSE(intersect(make_ray({1, 2, -7}, {0, 0, 1}, canopy::next_float_up(12.0f), inf), sph).hit);
    // From inside: roots −2 and 2; the far root is the hit in front of the origin.
    auto const inside = intersect(make_ray({1, 2, 3}, {0, 0, 1}), sph);
    REQUIRE(inside.hit);
    CHECK(inside.t == 2.0f);
    CHECK(intersect(make_ray({1, 2, 3}, {0, 0, 1}, -inf, inf), sph).t == -2.0f);
    // Beside it, or pointing away: no hit.
    CHECK_FALSE(intersect(make_ray({3.5f, 2, -7}, {0, 0, 1}), sph).hit);
    CHECK_FALSE(intersect(make_ray({1, 2, -7}, {0, 0, -1}), sph).hit);
    // Zero radius never hits.
    CHECK_FALSE(intersect(make_ray({1, 2, -7}, {0, 0, 1}), canopy::sphere{{1, 2, 3}, 0}).hit);

    // Random spheres against the roots of |o + t d − c|² = r² in long double.
    random_source rng(15);
    int compared = 0;
    for (int i = 0; i < 20000; ++i) {
        canopy::sphere const s{rng.point(-5, 5), rng.uniform(0.1f, 3.0f)};
        vec3<float> const origin = rng.point(-20, 20);
        vec3<float> const direction = (s.center + rng.point(-4, 4) - origin) * rng.uniform(0.1f, 3.0f);
        vec3l const f = widen(origin) - widen(s.center), d = widen(direction);
        long double const a = dot(d, d), b = dot(f, d), c = dot(f, f) - (long double)s.radius * s.radius;
        long double const disc = b * b - a * c;
        auto const hr = intersect(make_ray(origin, direction), s);
        if (std::fabs(disc) < 1e-3L * a * s.radius * s.radius) continue;   // near-tangent
        long double const t0 = (-b - std::sqrt(std::fabs(disc))) / a, t1 = (-b + std::sqrt(std::fabs(disc))) / a;
        bool const expected = disc > 0 && t1 >= 0;
        INFO("case " << i);
        if (std::fabs(t0) < 1e-4L || std::fabs(t1) < 1e-4L) continue;     // origin on the surface
        REQUIRE(hr.hit == expected);
        if (!expected) continue;
        ++compared;
        CHECK(hr.t == Approx(double(t0 >= 0 ? t0 : t1)).epsilon(1e-5));
    }
    CHECK(compared > 3000);
}

namespace {

canopy::box_hit<float> slab(ray const& r, canopy::aabb const& box) {
    vec3<float> const inv_dir(1.0f / r.direction.x, 1.0f / r.direction.y, 1.0f / r.direction.z);
    return intersect(r, box, inv_dir);
}

// Exact slab test for the ray with inverse direction inv_dir: all inputs are on a 2^-10 grid of
// small magnitude, so (bound − origin)·inv_dir is exact in long double.
bool exact_slab_hit(ray const& r, vec3<float> inv_dir, canopy::aabb const& box, long double& gap) {
    long double tnear = r.tmin, tfar = r.tmax;
    for (int axis = 0; axis < 3; ++axis) {
        long double const o = r.origin[axis], inv = inv_dir[axis];
        long double const lo = box.min[axis], hi = box.max[axis];
        if (std::isinf(inv)) {
            if (o >= lo && o <= hi) continue;
            gap = -1;
            return false;
        }
        long double const t0 = (lo - o) * inv, t1 = (hi - o) * inv;
        tnear = std::max(tnear, std::min(t0, t1));
        tfar = std::min(tfar, std::max(t0, t1));
    }
    gap = tfar - tnear;
    return tnear <= tfar;
}

// Case i of the grazing-ray batteries: a box on the 2^-10 grid (moved by `shift` on every axis)
// and a ray from a grid point aimed at one of its corners or edge points, slightly jittered.
struct grazing {
    canopy::aabb box;
    ray r;
};

grazing grazing_case(random_source& rng, int i, float shift) {
    vec3<float> const lo = rng.dyadic_point({-4, -4, -4}, {0, 0, 0}, 10) + vec3<float>(shift);
    canopy::aabb const box{lo, lo + rng.dyadic_point({0.25f, 0.25f, 0.25f}, {4, 4, 4}, 10)};
    vec3<float> target((i & 1) ? box.min.x : box.max.x, (i & 2) ? box.min.y : box.max.y, (i & 4) ? box.min.z : box.max.z);
    target[i % 3] = rng.dyadic(box.min[i % 3], box.max[i % 3], 10);
    target = target + rng.dyadic_point({-0.001f, -0.001f, -0.001f}, {0.001f, 0.001f, 0.001f}, 10);
    vec3<float> const origin = rng.dyadic_point({-12, -12, -12}, {12, 12, 12}, 10) + vec3<float>(shift);
    ray r = make_ray(origin, target - origin, 0, inf);
    if (i % 7 == 0) r.tmax = rng.dyadic(0, 2, 10);
    return {box, r};
}

} // namespace

TEST_CASE("ray/box slab test is conservative: it never misses a box the exact slab test hits") {
    random_source rng(16);
    int exact_hits = 0, clear_misses = 0;
    for (int i = 0; i < 50000; ++i) {
        auto const [box, r] = grazing_case(rng, i, 0.0f);
        vec3<float> const inv_dir(1.0f / r.direction.x, 1.0f / r.direction.y, 1.0f / r.direction.z);
        long double gap = 0;
        bool const exact = exact_slab_hit(r, inv_dir, box, gap);
        auto const hr = intersect(r, box, inv_dir);
        INFO("case " << i);
        if (exact) {
            ++exact_hits;
            CHECK(hr.hit);
        } else if (gap < -1e-4L) {
            ++clear_misses;
            CHECK_FALSE(hr.hit);
        }
    }
    CHECK(exact_hits > 5000);
    CHECK(clear_misses > 5000);
}

TEST_CASE("the traversal's box test (widened origins, fused where it applies) never misses a box the exact slab test hits") {
    // As above, through prepared_ray (box_margin_origins, then the fused form of slab_offsets
    // where the build has FMA), with origins near and far from the world origin: the fused form
    // rounds origin · inv_dir once per ray, which the origin margins must absorb; far from the
    // world origin (|o| beyond 4 times the reach) the margin shifts the differences instead and
    // the subtraction form serves the ray.
    random_source rng(61);
    int exact_hits = 0, clear_misses = 0, fused = 0, fusable = 0, nonzero = 0, shifted_rays = 0;
    for (int i = 0; i < 60000; ++i) {
        float const shifts[] = {0.0f, 1000.0f, -65536.0f, 1048576.0f};
        float const shift = shifts[i % 4];
        auto const [box, r] = grazing_case(rng, i, shift);
        canopy::prepared_ray<float> prepared(r, false);
        prepared.widen_box_tests_for(box);
        bool const no_zero = r.direction.x != 0.0f && r.direction.y != 0.0f && r.direction.z != 0.0f;
        nonzero += no_zero ? 1 : 0;
        // Whether an axis's origin floor (2^-21·|o|) exceeds the margin (2^-19 of the reach).
        float reach = 0.0f;
        for (int a = 0; a < 3; ++a)
            reach = std::max({reach, std::fabs(box.min[a] - r.origin[a]), std::fabs(box.max[a] - r.origin[a])});
        bool shifted = false;
        for (int a = 0; a < 3; ++a) shifted = shifted || std::fabs(r.origin[a]) * 0x1p-21f > reach * 0x1p-19f;
        shifted_rays += shifted ? 1 : 0;
        // The fused form serves every ray with finite constants and no shifted axis; rays along a
        // plane and shifted rays keep the other.
        CHECK(canopy::uses_fused_slabs(prepared) == (canopy::simd::native_fma && no_zero && !shifted));
        fused += canopy::uses_fused_slabs(prepared) ? 1 : 0;
        fusable += (no_zero && !shifted) ? 1 : 0;
        long double gap = 0;
        bool const exact = exact_slab_hit(r, prepared.inv_dir, box, gap);
        auto const hr = intersect(prepared, box, prepared.inv_dir);
        // Boxes grow by the origin margins (a few ulps of the coordinates, 2^-20 of the reach), or
        // for shifted rays by the reach's share alone: a clear miss misses the box grown by more
        // than that.
        float const margin = 0x1p-18f * ((shifted ? 0.0f : std::fabs(shift)) + 40.0f);
        canopy::aabb const grown{box.min - vec3<float>(margin), box.max + vec3<float>(margin)};
        long double grown_gap = 0;
        exact_slab_hit(r, prepared.inv_dir, grown, grown_gap);
        INFO("case " << i << ", shift " << shift);
        if (exact) {
            ++exact_hits;
            CHECK(hr.hit);
        } else if (grown_gap < -1e-6L) {
            ++clear_misses;
            CHECK_FALSE(hr.hit);
        }
    }
    CHECK(exact_hits > 5000);
    CHECK(clear_misses > 5000);
    if constexpr (canopy::simd::native_fma) CHECK(fused == fusable);
    CHECK(nonzero > 59000);
    // The boxes here lie within about 40 of their rays' origins: origins 1000 and more away from
    // the world origin are shifted, those near it are not.
    CHECK(shifted_rays > 40000);
    CHECK(fusable > 10000);
}

TEST_CASE("a ray with an infinite direction component keeps the subtraction form of the box test") {
    // Its inverse direction is 0 there: the fused form would turn an empty box's infinite planes
    // into NaN, and the 8-wide node test relies on the fused form never doing so (it drops the
    // mask of unused slots), so such rays take the subtraction form, which masks them.
    canopy::aabb const box{{0, 0, 0}, {1, 1, 1}};
    for (int axis = 0; axis < 3; ++axis) {
        for (float sign : {1.0f, -1.0f}) {
            vec3<float> direction(0.5f, 0.25f, 0.125f);
            direction[axis] = sign * inf;
            canopy::prepared_ray<float> prepared(make_ray({0.5f, 0.5f, 0.5f}, direction), false);
            prepared.widen_box_tests_for(box);
            INFO("axis " << axis << ", sign " << sign);
            CHECK(prepared.inv_dir[axis] == 0.0f);
            CHECK_FALSE(canopy::uses_fused_slabs(prepared));
            // Same ray with a finite direction: the fused form where the build has FMA.
            direction[axis] = sign * 2.0f;
            canopy::prepared_ray<float> finite(make_ray({0.5f, 0.5f, 0.5f}, direction), false);
            finite.widen_box_tests_for(box);
            CHECK(canopy::uses_fused_slabs(finite) == canopy::simd::native_fma);
        }
    }
}

TEST_CASE("ray/box slab test: grazing faces and edges, zero direction components, NaN") {
    canopy::aabb const box{{0, 0, 0}, {1, 1, 1}};
    for (int axis = 0; axis < 3; ++axis) {
        int const along = (axis + 1) % 3;
        for (float plane : {0.0f, 1.0f}) {
            for (float zero : {0.0f, -0.0f}) {
                // In the face plane, travelling along another axis; the axis component is ±0.
                vec3<float> origin(0.5f), direction(zero);
                origin[axis] = plane;
                origin[along] = -1;
                direction[along] = 1;
                INFO("axis " << axis << ", plane " << plane << ", zero " << std::signbit(zero));
                CHECK(slab(make_ray(origin, direction), box).hit);
                // Along an edge: two zero components on boundary planes.
                vec3<float> edge_origin = origin;
                int const third = (axis + 2) % 3;
                edge_origin[third] = plane;
                direction[third] = zero;
                CHECK(slab(make_ray(edge_origin, direction), box).hit);
                // Parallel to the face, just outside it: miss.
                origin[axis] = plane == 0.0f ? -0.001f : 1.001f;
                CHECK_FALSE(slab(make_ray(origin, direction), box).hit);
            }
        }
    }
    // Grazing a corner along the diagonal of a face.
    CHECK(slab(make_ray({-1, 0, 0.5f}, {1, 1, 0}), box).hit);   // touches the edge x = 0, y = 1
    CHECK(slab(make_ray({0, -1, 0.5f}, {1, 1, 0}), box).hit);   // touches the edge x = 1, y = 0
    CHECK_FALSE(slab(make_ray({0, -1.001f, 0.5f}, {1, 1, 0}), box).hit);
    // The ray's interval clips the box. tmax is widened by 2γ3 (relative) for box tests, so that a
    // primitive whose computed t ties tmax is not culled: an entry within that margin still hits,
    // one beyond it does not.
    canopy::aabb const far_box{{1, 1, 1}, {2, 2, 2}};
    float const widened = 1.0f + 2.0f * canopy::gamma<float>(3);
    CHECK(slab(make_ray({0, 1.5f, 1.5f}, {1, 0, 0}, 0, 1), far_box).hit);
    CHECK(slab(make_ray({0, 1.5f, 1.5f}, {1, 0, 0}, 0, canopy::next_float_down(1.0f)), far_box).hit);
    CHECK_FALSE(slab(make_ray({0, 1.5f, 1.5f}, {1, 0, 0}, 0, 0.9999f / widened), far_box).hit);
    CHECK_FALSE(slab(make_ray({0, 1.5f, 1.5f}, {1, 0, 0}, 2.5f, inf), far_box).hit);
    auto const through = slab(make_ray({0, 1.5f, 1.5f}, {1, 0, 0}), far_box);
    REQUIRE(through.hit);
    CHECK(through.tnear == 1.0f);
    CHECK(through.tfar >= 2.0f);
    CHECK(through.tfar <= 2.0f * (1 + 2 * canopy::gamma<float>(3)));
    // NaN in tmin or tmax: miss.
    CHECK_FALSE(slab(make_ray({0.5f, 0.5f, -1}, {0, 0, 1}, quiet_nan, inf), box).hit);
    CHECK_FALSE(slab(make_ray({0.5f, 0.5f, -1}, {0, 0, 1}, 0, quiet_nan), box).hit);
    CHECK_FALSE(slab(make_ray({0.5f, 0.5f, -1}, {0.25f, 0, 1}, quiet_nan, quiet_nan), box).hit);
    // Origin inside: hit with tnear = tmin.
    auto const inside = slab(make_ray({0.5f, 0.5f, 0.5f}, {0.25f, -1, 0.5f}), box);
    CHECK(inside.hit);
    CHECK(inside.tnear == 0.0f);
}

TEST_CASE("primitive bounds hold the primitive") {
    triangle const tri{{1, -2, 3}, {-4, 5, 0.5f}, {2, 2, -6}};
    auto const b = get_bounds(tri);
    CHECK(b.min.x == -4.0f);
    CHECK(b.min.y == -2.0f);
    CHECK(b.min.z == -6.0f);
    CHECK(b.max.x == 2.0f);
    CHECK(b.max.y == 5.0f);
    CHECK(b.max.z == 3.0f);
    auto const s = get_bounds(canopy::sphere{{1, 2, 3}, 0.5f});
    CHECK(s.min.x == 0.5f);
    CHECK(s.max.z == 3.5f);
}

TEST_CASE("a block of triangles gives, lane by lane, the one-triangle watertight result bit for bit") {
    random_source rng(21);
    for (int i = 0; i < 2000; ++i) {
        auto const [tris, block] = random_block(rng, i);
        int const used = int(tris.size());
        for (auto const& r : random_rays_for(rng, tris[std::size_t(rng.integer(0, used - 1))])) {
            canopy::prepared_ray<float> const prepared(r);
            auto const hits = canopy::intersect_block(prepared, block);
            for (int lane = 0; lane < canopy::triangle_block_width; ++lane) {
                INFO("case " << i << ", lane " << lane);
                bool const lane_hit = (hits.mask >> lane) & 1u;
                if (lane >= used) {
                    CHECK_FALSE(lane_hit);
                    continue;
                }
                // The block gives back the very triangle, and the same record.
                triangle const back = block.triangle_at(lane);
                CHECK(std::memcmp(&back, &tris[std::size_t(lane)], sizeof(triangle)) == 0);
                auto const one = intersect(r, tris[std::size_t(lane)]);
                REQUIRE(lane_hit == bool(one.hit));
                if (!lane_hit) continue;
                auto const hr = hits.record(block, lane);
                CHECK(bits(hr.t) == bits(one.t));
                CHECK(bits(hr.u) == bits(one.u));
                CHECK(bits(hr.v) == bits(one.v));
                CHECK(hr.prim_id == one.prim_id);
                CHECK(hr.geom_id == one.geom_id);
            }
        }
    }
}

TEST_CASE("packets whose lanes share one shear permutation test triangles and block lanes as single rays, bit for bit") {
    random_source rng(33);
    int uniform_packets = 0, mixed_packets = 0;
    for (int i = 0; i < 2000; ++i) {
        auto const [tris, block] = random_block(rng, i);
        int const used = int(tris.size());
        auto const& target = tris[std::size_t(rng.integer(0, used - 1))];

        // Every other case: a coherent packet (one dominant axis and sign: |d[axis]| ≥ 1 > the
        // others), aimed at points around the target triangle; else mixed rays.
        std::array<ray, 8> rays;
        bool const coherent = i % 2 == 0;
        if (coherent) {
            int const axis = rng.integer(0, 2);
            float const sign = rng.integer(0, 1) == 0 ? 1.0f : -1.0f;
            for (auto& r : rays) r = coherent_ray_towards(rng, target, axis, sign);
            if (rng.integer(0, 3) == 0) rays[5].tmin = quiet_nan; // an inactive lane
            if (rng.integer(0, 3) == 0) rays[6].tmax = rays[6].tmin - 1;
        } else {
            rays = random_rays_for(rng, target);
        }
        canopy::prepared_ray<float8> const packet(pack(rays));
        if (coherent) REQUIRE(packet.shear.uniform);
        (packet.shear.uniform ? uniform_packets : mixed_packets) += 1;
        for (int t = 0; t < used; ++t) {
            auto const& tri = tris[std::size_t(t)];
            auto const whole = intersect(packet, tri);
            auto const from_block = canopy::intersect_lane(packet, block, t);
            for (int lane = 0; lane < 8; ++lane) {
                INFO("case " << i << ", triangle " << t << (packet.shear.uniform ? ", uniform" : ", mixed"));
                auto const one = intersect(rays[std::size_t(lane)], tri);
                check_lane_equals_scalar(whole, lane, one);
                check_lane_equals_scalar(from_block, lane, one);
            }
        }
    }
    // Both paths were taken.
    CHECK(uniform_packets >= 1000);
    CHECK(mixed_packets >= 100);
}

TEST_CASE("a packet's block test lane by lane gives each lane the first and the nearest hit of the triangles one at a time") {
    // The reference: each lane's scalar ray against the block's triangles one at a time, in block
    // order; the first hit (what any hit keeps) and the hit with the smallest t, then the
    // smallest prim_id (what closest hit keeps). Duplicated triangles with their ids in reverse
    // order make ties of t that only the prim_id decides; lanes outside `live` get no hit.
    random_source rng(35);
    int lanes_hit = 0, ties = 0;
    for (int i = 0; i < 3000; ++i) {
        auto [tris, block] = random_block(rng, i);
        int const used = int(tris.size());
        if (used >= 2 && i % 3 == 0) {
            // The last triangle again, in a lower lane with a higher prim_id.
            auto dup = tris.back();
            dup.prim_id += 1000;
            tris[0] = dup;
            block.set(0, dup);
        }
        auto const& target = tris[std::size_t(rng.integer(0, used - 1))];
        int const axis = rng.integer(0, 2);
        float const sign = rng.integer(0, 1) == 0 ? 1.0f : -1.0f;
        std::array<ray, 8> rays;
        for (auto& r : rays) {
            r = coherent_ray_towards(rng, target, axis, sign);
            if (rng.integer(0, 7) == 0) r.tmax = rng.uniform(0.0f, 10.0f); // some hits beyond tmax
        }
        canopy::prepared_ray<float8> packet(pack(rays));
        REQUIRE(packet.shear.uniform);
        std::uint32_t const live = std::uint32_t(rng.integer(0, 255));
        std::uint32_t const used_mask = (1u << used) - 1u;
        auto const first = canopy::intersect_block_by_lanes<false>(packet, block, used_mask, live);
        auto const nearest = canopy::intersect_block_by_lanes<true>(packet, block, used_mask, live);
        for (int lane = 0; lane < 8; ++lane) {
            INFO("case " << i << ", lane " << lane);
            canopy::basic_hit_record<float> ref_first, ref_nearest;
            int hits = 0;
            if ((live >> lane) & 1u) {
                for (auto const& tri : tris) {
                    auto const one = intersect(rays[std::size_t(lane)], tri);
                    if (!one.hit) continue;
                    ++hits;
                    if (!ref_first.hit) ref_first = one;
                    if (!ref_nearest.hit || one.t < ref_nearest.t ||
                        (one.t == ref_nearest.t && one.prim_id < ref_nearest.prim_id)) {
                        ties += ref_nearest.hit && one.t == ref_nearest.t;
                        ref_nearest = one;
                    }
                }
            }
            lanes_hit += hits > 0;
            check_lane_equals_scalar(first, lane, ref_first);
            check_lane_equals_scalar(nearest, lane, ref_nearest);
        }
    }
    CHECK(lanes_hit > 3000);
    CHECK(ties > 100);
}
