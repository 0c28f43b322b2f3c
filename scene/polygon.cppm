// canopy.scene:polygon — triangles of a loader's polygon face (OBJ, PLY, OFF, OM faces of more
// than three corners).
//
// The face is looked at in the plane of its Newell normal (Newell 1972; projected by dropping the
// normal's largest component, so the 2-D coordinates are the 3-D ones, exactly). Then:
// - a convex face (no turn against the face's orientation, winding round once) becomes the fan
//   (c0, ck, ck+1), k = 1 … n−2, which is what loaders have always produced for convex faces;
// - a simple non-convex face is ear-clipped (Meisters 1975, "Polygons have ears"; O(n²)): every
//   triangle lies inside the face, and together they cover it exactly;
// - a face that is neither (self-intersecting, winding round more than once, all corners
//   collinear, no ear left) is fanned from the corners not yet cut off, and reported as such;
//   so is a non-convex face of more than
//   max_ear_clipped_corners corners, and one whose clipping takes more than 8 n² corner-in-ear
//   tests (ear clipping is quadratic in the corners for ordinary faces, cubic at worst, and no
//   face may make a loader hang).
//   Loaders count such faces in mesh_data::fanned_faces (and where the first is in first_fanned);
//   compile() names them in its decisions, which `canopy info` prints.
// Every face of n corners gives n − 2 triangles with the face's winding (corner order). Every
// turn (orientation) test has an exact sign: its six products of float coordinates are exact in
// double, and their sum is kept as a nonoverlapping expansion (Shewchuk 1997, "Adaptive
// Precision Floating-Point Arithmetic and Fast Robust Geometric Predicates"), whose largest
// nonzero component has the sign of the exact sum. Convexity and ears are thus decided exactly,
// in every build.
module;
// No a·b + c → FMA contraction: the two-sum steps below need every sum rounded on its own.
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>
export module canopy.scene:polygon;
import canopy.math;

export namespace canopy {

// Non-convex faces with more corners than this are fanned, not ear-clipped.
inline constexpr std::size_t max_ear_clipped_corners = 256;

struct polygon_triangles {
    std::vector<std::array<std::uint32_t, 3>> triangles; // indices into the face's corners
    bool ear_clipped = false; // a non-convex face, cut into ears
    bool fanned_fallback = false; // fanned although not convex (may cover more than the face): report it
};

} // namespace canopy

namespace canopy::detail {

struct point2 {
    double x, y;
};

// a + b = s + error exactly (Knuth's two-sum).
inline void two_sum(double a, double b, double& s, double& error) {
    s = a + b;
    double const bb = s - a;
    error = (a - (s - bb)) + (b - bb);
}

// Twice the signed area of (a, b, c) for float coordinates, with the exact sign (> 0 when
// a → b → c turns counter-clockwise); the magnitude is the sum's largest expansion component.
inline double turn(point2 a, point2 b, point2 c) {
    // a.x·b.y − a.y·b.x + b.x·c.y − b.y·c.x + c.x·a.y − c.y·a.x: products of floats, exact.
    double const terms[6] = {a.x * b.y, -(a.y * b.x), b.x * c.y, -(b.y * c.x), c.x * a.y, -(c.y * a.x)};
    double e[6];
    int m = 0;
    for (double t : terms) { // grow the expansion e[0..m) by t
        double q = t;
        for (int i = 0; i < m; ++i) two_sum(q, e[i], q, e[i]);
        e[m++] = q;
    }
    for (int i = m - 1; i >= 0; --i)
        if (e[i] != 0.0) return e[i];
    return 0.0;
}

// p in the closed triangle (a, b, c) of orientation `sign` (+1 or −1).
inline bool in_triangle(point2 p, point2 a, point2 b, point2 c, double sign) {
    return sign * turn(a, b, p) >= 0.0 && sign * turn(b, c, p) >= 0.0 && sign * turn(c, a, p) >= 0.0;
}

inline void fan(std::span<std::uint32_t const> corners, polygon_triangles& out) {
    for (std::size_t k = 1; k + 1 < corners.size(); ++k) out.triangles.push_back({corners[0], corners[k], corners[k + 1]});
}

} // namespace canopy::detail

export namespace canopy {

inline polygon_triangles triangulate_polygon(std::span<vec3<float> const> corners) {
    using detail::point2;
    polygon_triangles out;
    std::size_t const n = corners.size();
    if (n < 3) return out;
    if (n == 3) {
        out.triangles.push_back({0, 1, 2});
        return out;
    }
    out.triangles.reserve(n - 2);
    std::vector<std::uint32_t> order(n);
    for (std::size_t k = 0; k < n; ++k) order[k] = std::uint32_t(k);

    // Newell normal, and the plane it is most nearly perpendicular to.
    double nx = 0.0, ny = 0.0, nz = 0.0;
    for (std::size_t k = 0; k < n; ++k) {
        vec3<double> const p(corners[k]), q(corners[(k + 1) % n]);
        nx += (p.y - q.y) * (p.z + q.z);
        ny += (p.z - q.z) * (p.x + q.x);
        nz += (p.x - q.x) * (p.y + q.y);
    }
    int const drop = std::abs(nx) >= std::abs(ny) && std::abs(nx) >= std::abs(nz) ? 0 : (std::abs(ny) >= std::abs(nz) ? 1 : 2);
    std::vector<point2> p(n);
    for (std::size_t k = 0; k < n; ++k) {
        vec3<double> const c(corners[k]);
        p[k] = drop == 0 ? point2{c.y, c.z} : drop == 1 ? point2{c.z, c.x} : point2{c.x, c.y};
    }
    // The face's orientation: the turn at its lowest-leftmost corner, which is convex in a simple
    // face (the signed area when that turn is flat, e.g. at a repeated corner).
    std::size_t const low = std::size_t(std::min_element(p.begin(), p.end(), [](point2 a, point2 b) {
                                            return a.x < b.x || (a.x == b.x && a.y < b.y);
                                        }) - p.begin());
    double orientation = detail::turn(p[(low + n - 1) % n], p[low], p[(low + 1) % n]);
    if (orientation == 0.0)
        for (std::size_t k = 0; k < n; ++k) orientation += p[k].x * p[(k + 1) % n].y - p[(k + 1) % n].x * p[k].y;
    if (orientation == 0.0) { // collinear corners: nothing to cut
        out.fanned_fallback = true;
        detail::fan(order, out);
        return out;
    }
    double const sign = orientation > 0.0 ? 1.0 : -1.0;

    bool convex = true;
    for (std::size_t k = 0; k < n && convex; ++k)
        convex = sign * detail::turn(p[(k + n - 1) % n], p[k], p[(k + 1) % n]) >= 0.0;
    // Every turn the same way is not enough: a face that winds round more than once (a
    // pentagram, a triangle's corners listed twice) turns one way at each corner too. Winding
    // once, the edge directions sweep one full turn, so the signs of their x and of their y
    // components change at most twice each round the face (exact: the sign of a difference of
    // doubles is exact; edges of no length in a coordinate are skipped).
    auto const sign_changes = [&](auto coordinate) {
        int changes = 0, last = 0, first = 0;
        for (std::size_t k = 0; k < n; ++k) {
            double const d = coordinate(p[(k + 1) % n]) - coordinate(p[k]);
            int const s = d > 0.0 ? 1 : d < 0.0 ? -1 : 0;
            if (s == 0) continue;
            if (first == 0) first = s;
            if (last != 0 && s != last) ++changes;
            last = s;
        }
        return changes + (last != 0 && last != first ? 1 : 0);
    };
    if (convex && (sign_changes([](point2 q) { return q.x; }) > 2 || sign_changes([](point2 q) { return q.y; }) > 2))
        convex = false;
    if (convex) {
        detail::fan(order, out);
        return out;
    }

    if (n > max_ear_clipped_corners) {
        out.fanned_fallback = true;
        detail::fan(order, out);
        return out;
    }

    // Two edges that cross (each one's ends strictly on both sides of the other: exact turns)
    // make the face self-intersecting; ear clipping would cut it without noticing.
    for (std::size_t a = 0; a < n; ++a)
        for (std::size_t c = a + 2; c < n; ++c) {
            if (a == 0 && c == n - 1) continue; // adjacent round the end
            point2 const p0 = p[a], p1 = p[(a + 1) % n], q0 = p[c], q1 = p[(c + 1) % n];
            double const t0 = detail::turn(p0, p1, q0), t1 = detail::turn(p0, p1, q1);
            double const t2 = detail::turn(q0, q1, p0), t3 = detail::turn(q0, q1, p1);
            if (((t0 > 0.0 && t1 < 0.0) || (t0 < 0.0 && t1 > 0.0)) && ((t2 > 0.0 && t3 < 0.0) || (t2 < 0.0 && t3 > 0.0))) {
                out.fanned_fallback = true;
                detail::fan(order, out);
                return out;
            }
        }

    // Ear clipping: walk round the face and cut off a corner whose triangle turns the face's way
    // and holds no other remaining corner, until three are left. A full round without a cut
    // means the face is not simple.
    out.ear_clipped = true;
    std::size_t budget = 8 * n * n; // corner-in-ear tests allowed
    auto const is_ear = [&](std::uint32_t a, std::uint32_t b, std::uint32_t c) {
        if (!(sign * detail::turn(p[a], p[b], p[c]) > 0.0)) return false;
        for (std::uint32_t q : order) {
            if (budget > 0) --budget;
            if (q == a || q == b || q == c) continue;
            bool const shared = (p[q].x == p[a].x && p[q].y == p[a].y) || (p[q].x == p[b].x && p[q].y == p[b].y) ||
                                (p[q].x == p[c].x && p[q].y == p[c].y);
            if (!shared && detail::in_triangle(p[q], p[a], p[b], p[c], sign)) return false;
        }
        return true;
    };
    std::size_t i = 0, misses = 0;
    while (order.size() > 3) {
        std::size_t const m = order.size();
        i %= m;
        std::uint32_t const a = order[(i + m - 1) % m], b = order[i], c = order[(i + 1) % m];
        if (is_ear(a, b, c)) {
            out.triangles.push_back({a, b, c});
            order.erase(order.begin() + std::ptrdiff_t(i));
            i = (i + m - 2) % (m - 1); // the corner before may have become an ear
            misses = 0;
        } else if (++misses == m || budget == 0) { // not simple, or too slow: fan what is left
            out.fanned_fallback = true;
            detail::fan(order, out);
            return out;
        } else {
            ++i;
        }
    }
    out.triangles.push_back({order[0], order[1], order[2]});
    return out;
}

} // namespace canopy
