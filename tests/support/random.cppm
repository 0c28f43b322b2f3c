// canopy.testing:random — random test geometry shared by the core tests (geometry, intersector,
// bvh, query, stress): a seeded random source, random affine transforms, triangle soups, rays into
// a box, meshes moved for refits; also eight rays packed into one packet and the checkerboard alpha
// mask the intersector tests use. Fixed seeds: every run tests the same cases.
module;
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>
export module canopy.testing:random;
import canopy.query;

export namespace test_support {

struct random_source {
    std::mt19937 engine;
    explicit random_source(std::uint32_t seed) : engine(seed) {}
    float uniform(float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(engine); }
    double uniform_double(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(engine); }
    int integer(int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(engine); }
    canopy::vec3<float> point(float lo, float hi) { return {uniform(lo, hi), uniform(lo, hi), uniform(lo, hi)}; }
    canopy::vec3<float> point_in(canopy::aabb const& b) {
        return {uniform(b.min.x, b.max.x), uniform(b.min.y, b.max.y), uniform(b.min.z, b.max.z)};
    }
    // A multiple of 2^-k in [lo, hi]: exactly representable, differences of such values too.
    float dyadic(float lo, float hi, int k) {
        float const scale = std::ldexp(1.0f, k);
        return static_cast<float>(integer(static_cast<int>(lo * scale), static_cast<int>(hi * scale))) / scale;
    }
    canopy::vec3<float> dyadic_point(float lo, float hi, int k) { return {dyadic(lo, hi, k), dyadic(lo, hi, k), dyadic(lo, hi, k)}; }
    canopy::vec3<float> dyadic_point(canopy::vec3<float> lo, canopy::vec3<float> hi, int k) {
        return {dyadic(lo.x, hi.x, k), dyadic(lo.y, hi.y, k), dyadic(lo.z, hi.z, k)};
    }
    // A point of the unit ball.
    canopy::vec3<float> in_ball() {
        for (;;) {
            canopy::vec3<float> const p = point(-1.0f, 1.0f);
            if (canopy::dot(p, p) <= 1.0f) return p;
        }
    }
    // A direction, uniform over the sphere, of length in [0.1, 1] (not normalised).
    canopy::vec3<float> direction() {
        for (;;) {
            canopy::vec3<float> const p = point(-1.0f, 1.0f);
            float const l2 = canopy::dot(p, p);
            if (l2 >= 0.01f && l2 <= 1.0f) return p;
        }
    }
};

inline canopy::ray make_ray(canopy::vec3<float> origin, canopy::vec3<float> direction, float tmin = 0.0f,
                            float tmax = std::numeric_limits<float>::infinity()) {
    return {origin, tmin, direction, tmax};
}

// `count` triangles of corners within `size` of centres within `extent` of the origin;
// prim_id = index (what the builder assigns), geom_id = index mod 3.
inline std::vector<canopy::triangle> triangle_soup(random_source& rng, int count, float extent, float size) {
    std::vector<canopy::triangle> soup;
    for (int i = 0; i < count; ++i) {
        canopy::vec3<float> const c = rng.point(-extent, extent);
        soup.push_back({c + rng.point(-size, size), c + rng.point(-size, size), c + rng.point(-size, size),
                        static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(i % 3)});
    }
    return soup;
}

// `count` long thin triangles: two corners within `width` of each other, the third anywhere,
// all within `extent` of the origin; prim_id = index, geom_id = index mod 3.
inline std::vector<canopy::triangle> needle_soup(random_source& rng, int count, float extent, float width) {
    std::vector<canopy::triangle> out;
    for (int i = 0; i < count; ++i) {
        canopy::vec3<float> const a = rng.point(-extent, extent), far = rng.point(-extent, extent);
        out.push_back({a, a + rng.point(-width, width), far, static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(i % 3)});
    }
    return out;
}

// Long thin triangles in one mesh (prim_id = index, geom_id 0), where spatial splits
// (build_quality::high) reference one triangle from several leaves: 400 triangles of a disk fan
// of aspect 1e3, a fan of 128 needles of aspect 1e5, a closed bicone of 512 slivers (half length
// 1, radius 0.05) and a closed cylinder of radius 0.01 and length 3 (24 segments × 8 rings).
inline std::vector<canopy::triangle> sliver_mesh() {
    using v3 = canopy::vec3<float>;
    constexpr double two_pi = 6.283185307179586;
    std::vector<canopy::triangle> out;
    auto const add = [&](v3 a, v3 b, v3 c) { out.push_back({a, b, c, static_cast<std::uint32_t>(out.size()), 0}); };
    auto const circle = [&](v3 centre, v3 u, v3 w, double radius, int i, int segments) {
        double const a = two_pi * double(i % segments) / double(segments);
        return centre + (u * float(std::cos(a)) + w * float(std::sin(a))) * float(radius);
    };
    v3 const ex(1, 0, 0), ey(0, 1, 0), ez(0, 0, 1);
    for (int i = 0; i < 400; ++i) add({0, 0, 0}, circle({0, 0, 0}, ex, ey, 1.0, i, 6283), circle({0, 0, 0}, ex, ey, 1.0, i + 1, 6283));
    for (int i = 0; i < 128; ++i) {
        float const w = 2.0f / 1e5f;
        add({3.5f, 0, 0.25f}, {1.5f, w * float(i - 64), 0.25f}, {1.5f, w * float(i - 63), 0.25f});
    }
    v3 const centre(0, 1.5f, 0), left = centre - ex, right = centre + ex;
    for (int i = 0; i < 256; ++i) {
        add(left, circle(centre, ey, ez, 0.05, i + 1, 256), circle(centre, ey, ez, 0.05, i, 256));
        add(right, circle(centre, ey, ez, 0.05, i, 256), circle(centre, ey, ez, 0.05, i + 1, 256));
    }
    auto const ring = [&](int k, int i) { return circle(v3(-1.5f + 3.0f * float(k) / 8.0f, -1.5f, 0), ey, ez, 0.01, i, 24); };
    for (int k = 0; k < 8; ++k)
        for (int i = 0; i < 24; ++i) {
            add(ring(k, i), ring(k, i + 1), ring(k + 1, i + 1));
            add(ring(k, i), ring(k + 1, i + 1), ring(k + 1, i));
        }
    for (int i = 0; i < 24; ++i) {
        add({-1.5f, -1.5f, 0}, ring(0, i + 1), ring(0, i));
        add({1.5f, -1.5f, 0}, ring(8, i), ring(8, i + 1));
    }
    return out;
}

// Rays from around the box towards random points inside it.
inline std::vector<canopy::ray> random_rays(random_source& rng, canopy::aabb const& bounds, int count) {
    canopy::vec3<float> const c = (bounds.min + bounds.max) * 0.5f;
    float const r = canopy::length(bounds.max - bounds.min);
    std::vector<canopy::ray> rays;
    for (int i = 0; i < count; ++i) {
        canopy::vec3<float> const origin = c + rng.point(-r, r);
        rays.push_back(make_ray(origin, rng.point_in(bounds) - origin));
    }
    return rays;
}

// Ways to move a mesh's vertices (same triangles, same order, same ids), for refit tests.
//   displace  every vertex moved by up to `amount` on each axis, at random;
//   twist     each vertex turned about the y axis by `amount` radians per unit of height;
//   collapse  every vertex put on the plane y = 0 (a flat mesh: boxes of zero height).
enum class deformation { displace, twist, collapse };

inline std::vector<canopy::triangle> deformed(std::vector<canopy::triangle> mesh, deformation how, float amount,
                                              random_source& rng) {
    auto const move = [&](canopy::vec3<float> p) -> canopy::vec3<float> {
        switch (how) {
        case deformation::displace: return p + rng.point(-amount, amount);
        case deformation::twist: {
            double const a = double(amount) * double(p.y), c = std::cos(a), s = std::sin(a);
            return {float(c * double(p.x) - s * double(p.z)), p.y, float(s * double(p.x) + c * double(p.z))};
        }
        case deformation::collapse: return {p.x, 0.0f, p.z};
        }
        return p;
    };
    for (auto& t : mesh) {
        t.v0 = move(t.v0);
        t.v1 = move(t.v1);
        t.v2 = move(t.v2);
    }
    return mesh;
}

// Rotation (random unit quaternion) × non-uniform scale in [0.5, 2], plus a translation in
// [-translation, translation]^3.
inline canopy::affine_transform<float> random_transform(random_source& rng, float translation) {
    std::normal_distribution<double> normal;
    double q[4];
    double norm = 0;
    for (double& c : q) {
        c = normal(rng.engine);
        norm += c * c;
    }
    for (double& c : q) c /= std::sqrt(norm);
    double const w = q[0], x = q[1], y = q[2], z = q[3];
    double const rot[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                              {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                              {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
    double const s[3] = {rng.uniform(0.5f, 2.0f), rng.uniform(0.5f, 2.0f), rng.uniform(0.5f, 2.0f)};
    std::array<float, 12> rows{};
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) rows[std::size_t(4 * i + j)] = static_cast<float>(rot[i][j] * s[j]);
        rows[std::size_t(4 * i + 3)] = rng.uniform(-translation, translation);
    }
    return canopy::affine_transform<float>::from_rows(rows);
}

// Eight scalar rays as one packet: lane i is rays[i].
inline canopy::basic_ray<canopy::simd::float8> pack(std::array<canopy::ray, 8> const& rays) {
    canopy::basic_ray<canopy::simd::float8> p;
    for (int i = 0; i < 8; ++i) {
        auto const& r = rays[std::size_t(i)];
        canopy::set_lane(p.origin, i, r.origin);
        canopy::set_lane(p.direction, i, r.direction);
        p.tmin.set(i, r.tmin);
        p.tmax.set(i, r.tmax);
    }
    return p;
}

// Procedural checkerboard alpha: transparent where floor(8u) + floor(8v) is odd (u, v clamped
// to [0, 1]).
inline bool checkerboard_opaque(float u, float v) {
    auto const cell = [](float x) { return static_cast<int>(std::floor(8.0f * std::fmin(std::fmax(x, 0.0f), 1.0f))); };
    return (cell(u) + cell(v)) % 2 == 0;
}

} // namespace test_support
