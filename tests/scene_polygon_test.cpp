// Tests of canopy.scene:polygon, the triangulation of loaders' faces. Convex faces must give the
// fan exactly; every other simple face must be cut into triangles that partition it, which is
// checked against the face itself: n − 2 triangles with the face's orientation, no triangle edge
// crossing the boundary, no corner strictly inside a triangle, every centroid inside the face
// (crossing number), and the areas adding up to the face's area (shoelace formula). Corners are
// multiples of 2^-10, so the test's own predicates are exact whatever the build's contraction.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <random>
#include <vector>

import canopy.scene;

namespace {

using canopy::vec3;

struct p2 {
    double x, y;
};

double cross(p2 a, p2 b, p2 c) { return (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x); }

double shoelace(std::vector<p2> const& p) {
    double s = 0.0;
    for (std::size_t k = 0; k < p.size(); ++k) s += p[k].x * p[(k + 1) % p.size()].y - p[(k + 1) % p.size()].x * p[k].y;
    return 0.5 * s;
}

// Point strictly inside the polygon by the crossing number (points on the boundary are not
// asked about: centroids of non-degenerate triangles of a partition are interior).
bool inside(std::vector<p2> const& poly, p2 q) {
    bool in = false;
    for (std::size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
        p2 const a = poly[i], b = poly[j];
        if ((a.y > q.y) != (b.y > q.y) && q.x < (b.x - a.x) * (q.y - a.y) / (b.y - a.y) + a.x) in = !in;
    }
    return in;
}

// Segments ab and cd cross at a point inside both (touching at an end does not count).
bool proper_crossing(p2 a, p2 b, p2 c, p2 d) {
    double const d1 = cross(a, b, c), d2 = cross(a, b, d), d3 = cross(c, d, a), d4 = cross(c, d, b);
    return ((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0));
}

// The face's corners in the plane z = 0 (float coordinates, as a loader has them).
std::vector<vec3<float>> in_plane(std::vector<p2> const& p) {
    std::vector<vec3<float>> out;
    for (auto const& q : p) out.push_back({float(q.x), float(q.y), 0.0f});
    return out;
}

// The triangles partition the simple polygon `poly`.
void check_partition(std::vector<p2> const& poly, canopy::polygon_triangles const& cut) {
    std::size_t const n = poly.size();
    REQUIRE(cut.triangles.size() == n - 2);
    CHECK_FALSE(cut.fanned_fallback);
    double const area = shoelace(poly);
    double sum = 0.0;
    for (auto const& t : cut.triangles) {
        for (auto k : t) REQUIRE(k < n);
        p2 const a = poly[t[0]], b = poly[t[1]], c = poly[t[2]];
        double const twice = cross(a, b, c);
        CHECK(twice * area > 0.0); // the face's orientation, and not degenerate
        sum += 0.5 * std::abs(twice);
        p2 const centroid{(a.x + b.x + c.x) / 3.0, (a.y + b.y + c.y) / 3.0};
        CHECK(inside(poly, centroid));
        for (std::size_t e = 0; e < n; ++e) {
            p2 const u = poly[e], v = poly[(e + 1) % n];
            CHECK_FALSE(proper_crossing(a, b, u, v));
            CHECK_FALSE(proper_crossing(b, c, u, v));
            CHECK_FALSE(proper_crossing(c, a, u, v));
            // No corner strictly inside the triangle.
            p2 const q = poly[e];
            double const s = twice > 0 ? 1.0 : -1.0;
            CHECK_FALSE((s * cross(a, b, q) > 0 && s * cross(b, c, q) > 0 && s * cross(c, a, q) > 0));
        }
    }
    CHECK(sum == Approx(std::abs(area)).epsilon(1e-12));
}

// A star-shaped polygon: n corners at increasing angles, random radii in [0.2, 1], coordinates
// multiples of 2^-10 (so that every cross product above is exact in double, in any build), and
// no three consecutive corners on a line (drawn again until so).
std::vector<p2> random_star(std::mt19937& rng, std::size_t n) {
    std::uniform_real_distribution<double> radius(0.2, 1.0);
    for (;;) {
        std::vector<p2> p;
        for (std::size_t k = 0; k < n; ++k) {
            double const angle = 2.0 * 3.141592653589793 * double(k) / double(n);
            double const r = radius(rng);
            p.push_back({std::round(r * std::cos(angle) * 1024.0) / 1024.0, std::round(r * std::sin(angle) * 1024.0) / 1024.0});
        }
        bool flat = false;
        for (std::size_t k = 0; k < n; ++k) flat = flat || cross(p[k], p[(k + 1) % n], p[(k + 2) % n]) == 0.0;
        if (!flat) return p;
    }
}

} // namespace

TEST_CASE("polygon: triangles and convex faces are fanned (c0, ck, ck+1), as loaders always did") {
    std::vector<vec3<float>> const tri{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    auto const t = canopy::triangulate_polygon(tri);
    REQUIRE(t.triangles.size() == 1);
    CHECK(t.triangles[0] == std::array<std::uint32_t, 3>{0, 1, 2});

    // A convex pentagon, clockwise, tilted out of every axis plane.
    std::vector<vec3<float>> const pentagon{{0, 0, 0}, {0, 2, 1}, {1, 3, 2}, {2, 2, 2}, {2, 0, 1}};
    auto const p = canopy::triangulate_polygon(pentagon);
    REQUIRE(p.triangles.size() == 3);
    CHECK(p.triangles[0] == std::array<std::uint32_t, 3>{0, 1, 2});
    CHECK(p.triangles[1] == std::array<std::uint32_t, 3>{0, 2, 3});
    CHECK(p.triangles[2] == std::array<std::uint32_t, 3>{0, 3, 4});
    CHECK_FALSE(p.ear_clipped);
    CHECK_FALSE(p.fanned_fallback);
}

TEST_CASE("polygon: non-convex faces are cut into triangles that partition them, either winding") {
    // An L, an arrowhead whose fan from corner 0 would cover the notch, and a comb.
    std::vector<std::vector<p2>> const faces{
        {{0, 0}, {2, 0}, {2, 1}, {1, 1}, {1, 2}, {0, 2}},
        {{2, 2}, {1, 1}, {0, 2}, {1, 0.25}},
        {{0, 0}, {5, 0}, {5, 3}, {4, 3}, {4, 1}, {3, 1}, {3, 3}, {2, 3}, {2, 1}, {1, 1}, {1, 3}, {0, 3}},
    };
    for (auto const& face : faces) {
        for (bool reversed : {false, true}) {
            std::vector<p2> poly = face;
            if (reversed) std::reverse(poly.begin(), poly.end());
            CAPTURE(poly.size(), reversed);
            auto const cut = canopy::triangulate_polygon(in_plane(poly));
            CHECK(cut.ear_clipped);
            check_partition(poly, cut);
        }
    }
}

TEST_CASE("polygon: the arrowhead's fan would leave the face, its triangles do not") {
    // Corner 0 sees corner 2 only across the notch: the fan's (0 1 2) is the notch itself.
    std::vector<p2> const arrow{{2, 2}, {1, 1}, {0, 2}, {1, 0.25}};
    CHECK_FALSE(inside(arrow, {1.0, 1.5})); // the notch
    auto const cut = canopy::triangulate_polygon(in_plane(arrow));
    for (auto const& t : cut.triangles) {
        p2 const a = arrow[t[0]], b = arrow[t[1]], c = arrow[t[2]];
        double const s = cross(a, b, c) > 0 ? 1.0 : -1.0;
        p2 const notch{1.0, 1.5};
        CHECK_FALSE((s * cross(a, b, notch) >= 0 && s * cross(b, c, notch) >= 0 && s * cross(c, a, notch) >= 0));
    }
}

TEST_CASE("polygon: 200 random star-shaped faces of 4 to 60 corners, in tilted planes") {
    std::mt19937 rng(2026);
    std::uniform_int_distribution<std::size_t> corners(4, 60);
    for (int round = 0; round < 200; ++round) {
        auto const poly = random_star(rng, corners(rng));
        CAPTURE(round, poly.size());
        // Lifted into the plane z = 0.5 x − 0.25 y + 3, then with y and z swapped: the 2-D
        // coordinates above are still the face's own (the test checks against them).
        std::vector<vec3<float>> lifted;
        for (auto const& q : poly) lifted.push_back({float(q.x), float(0.5 * q.x - 0.25 * q.y + 3.0), float(q.y)});
        auto const cut = canopy::triangulate_polygon(lifted);
        check_partition(poly, cut);
    }
}

TEST_CASE("polygon: a comb of max_ear_clipped_corners corners is ear-clipped within the work bound") {
    // A base and 127 teeth: half of the corners are reflex.
    std::vector<p2> comb{{0, 0}, {127, 0}};
    for (int i = 127; i > 0; --i) {
        comb.push_back({double(i), 3.0});
        comb.push_back({double(i) - 0.5, 1.0});
    }
    REQUIRE(comb.size() == canopy::max_ear_clipped_corners);
    auto const cut = canopy::triangulate_polygon(in_plane(comb));
    CHECK(cut.ear_clipped);
    check_partition(comb, cut);
}

TEST_CASE("polygon: faces that cannot be cut are fanned and reported, and large ones stay fast") {
    // A bow tie (self-intersecting): signed area 0.
    std::vector<vec3<float>> const bow{{0, 0, 0}, {1, 1, 0}, {1, 0, 0}, {0, 1, 0}};
    auto const b = canopy::triangulate_polygon(bow);
    CHECK(b.triangles.size() == 2);
    CHECK(b.fanned_fallback);

    // All corners on a line.
    std::vector<vec3<float>> const line{{0, 0, 0}, {1, 1, 1}, {2, 2, 2}, {3, 3, 3}, {4, 4, 4}};
    auto const l = canopy::triangulate_polygon(line);
    CHECK(l.triangles.size() == 3);
    CHECK(l.fanned_fallback);

    // A self-overlapping star (a pentagram's five points in drawing order).
    std::vector<vec3<float>> pentagram;
    for (int k = 0; k < 5; ++k) {
        double const angle = 2.0 * 3.141592653589793 * (2.0 * k) / 5.0;
        pentagram.push_back({float(std::cos(angle)), float(std::sin(angle)), 0.0f});
    }
    auto const s = canopy::triangulate_polygon(pentagram);
    CHECK(s.triangles.size() == 3);
    CHECK(s.fanned_fallback); // every turn is the same way, but it winds round twice: not convex

    // Faces that wind round more than once, turning the same way at every corner: a square's
    // corners listed twice, a triangle's listed 100 times (over max_ear_clipped_corners).
    std::vector<vec3<float>> square_twice;
    for (int round = 0; round < 2; ++round)
        for (vec3<float> c : {vec3<float>{0, 0, 0}, vec3<float>{1, 0, 0}, vec3<float>{1, 1, 0}, vec3<float>{0, 1, 0}})
            square_twice.push_back(c);
    auto const sq = canopy::triangulate_polygon(square_twice);
    CHECK(sq.triangles.size() == 6);
    CHECK((sq.ear_clipped || sq.fanned_fallback));
    std::vector<vec3<float>> triangle_100;
    for (int round = 0; round < 100; ++round)
        for (vec3<float> c : {vec3<float>{0, 0, 0}, vec3<float>{1, 0, 0}, vec3<float>{0, 1, 0}}) triangle_100.push_back(c);
    auto const t100 = canopy::triangulate_polygon(triangle_100);
    CHECK(t100.triangles.size() == 298);
    CHECK(t100.fanned_fallback);
    // A convex face of 1000 corners winds round once: still its plain fan.
    std::vector<vec3<float>> round_face;
    for (int k = 0; k < 1000; ++k) {
        double const angle = 2.0 * 3.141592653589793 * k / 1000.0;
        round_face.push_back({float(std::cos(angle)), float(std::sin(angle)), 0.0f});
    }
    auto const r = canopy::triangulate_polygon(round_face);
    CHECK(r.triangles.size() == 998);
    CHECK_FALSE(r.ear_clipped);
    CHECK_FALSE(r.fanned_fallback);

    // Non-convex and larger than max_ear_clipped_corners: fanned at once.
    std::vector<vec3<float>> zigzag;
    std::size_t const n = 4 * canopy::max_ear_clipped_corners;
    for (std::size_t k = 0; k < n; ++k) zigzag.push_back({float(k), float(k % 2), 0.0f});
    zigzag.push_back({float(n), -5.0f, 0.0f});
    zigzag.push_back({0.0f, -5.0f, 0.0f});
    auto const z = canopy::triangulate_polygon(zigzag);
    CHECK(z.triangles.size() == zigzag.size() - 2);
    CHECK(z.fanned_fallback);
    CHECK(z.triangles[0] == std::array<std::uint32_t, 3>{0, 1, 2});
}
