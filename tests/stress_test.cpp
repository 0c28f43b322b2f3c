// The numerical stress battery (SPEC §4 and §7): closed meshes hit from inside, rays aimed exactly
// at shared vertices and edges, meshes far from the origin, axis-aligned and NaN/Inf rays,
// degenerate triangles and slivers, tmin/tmax at an exact hit distance, multi_hit, a custom
// intersector, spawned secondary rays, real closed meshes, power-of-two scalings of rays and
// scenes, rotated vertex order, and scalar / packet / threaded agreement. Every check compares
// against an independent reference: a brute-force loop, exact dyadic arithmetic, a double
// precision world-space test, or ray parity. Instancing is stressed in stress_instancing_test.cpp.
//
// The default sizes run in a few seconds. The full battery (a 327,680-triangle icosphere, more
// rays, larger real meshes) runs with
//     CANOPY_STRESS_FULL=1 ctest -R stress --output-on-failure
// The real meshes come from the Debian packages glmark2-data and libcgal-demo; without them the
// test that reads them fails and names the package to install.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <string_view>
#include <thread>
#include <tuple>
#include <utility>
#include <vector>

import canopy.query;
import canopy.procedural;
import canopy.testing;

namespace {

using namespace stress_support;

// prim_id = position, as the BVH builder numbers primitives.
void renumber(std::vector<triangle>& tris) {
    for (std::size_t i = 0; i < tris.size(); ++i) tris[i].prim_id = static_cast<std::uint32_t>(i);
}

std::vector<triangle> concatenate(std::vector<triangle> a, std::vector<triangle> const& b) {
    a.insert(a.end(), b.begin(), b.end());
    renumber(a);
    return a;
}

// The closest hit a plain loop over every triangle accepts; equal t goes to the smaller prim_id.
template <typename I = canopy::default_intersector>
record brute_force_closest(ray const& r, std::vector<triangle> const& tris, I&& isect = I{}) {
    record best;
    for (triangle const& tri : tris) {
        record const h = isect(r, tri);
        if (h.hit && (!best.hit || h.t < best.t || (h.t == best.t && h.prim_id < best.prim_id))) best = h;
    }
    return best;
}

template <typename Structure>
record closest(ray const& r, Structure const& s) {
    return canopy::closest_hit(r, &s, &s + 1);
}

bool has_vertex(triangle const& t, vec3<float> const& p) {
    auto const same = [&](vec3<float> const& q) { return q.x == p.x && q.y == p.y && q.z == p.z; };
    return same(t.v0) || same(t.v1) || same(t.v2);
}

// The cross product of the edges in double: exact for float vertices of similar magnitude, so it
// is zero exactly for collinear or repeated vertices.
bool exactly_degenerate(triangle const& t) {
    dvec3 const a(t.v0), b(t.v1), c(t.v2);
    dvec3 const n = canopy::cross(b - a, c - a);
    return n.x == 0.0 && n.y == 0.0 && n.z == 0.0;
}

using point_key = std::array<std::uint32_t, 3>;
point_key key_of(vec3<float> const& p) { return {bits(p.x), bits(p.y), bits(p.z)}; }

// The distinct vertices and edges of a triangle list (vertices identified by their bits).
struct mesh_features {
    std::vector<vec3<float>> vertices;
    std::vector<std::array<vec3<float>, 2>> edges;
    std::size_t open_edges = 0; // edges not shared by exactly two triangles
};

mesh_features features_of(std::vector<triangle> const& tris) {
    std::map<point_key, vec3<float>> vertices;
    std::map<std::pair<point_key, point_key>, std::pair<std::array<vec3<float>, 2>, int>> edges;
    for (triangle const& t : tris) {
        std::array<vec3<float>, 3> const v{t.v0, t.v1, t.v2};
        for (std::size_t k = 0; k < 3; ++k) {
            vertices.emplace(key_of(v[k]), v[k]);
            vec3<float> a = v[k], b = v[(k + 1) % 3];
            if (key_of(b) < key_of(a)) std::swap(a, b);
            auto& e = edges[{key_of(a), key_of(b)}];
            e.first = {a, b};
            ++e.second;
        }
    }
    mesh_features f;
    for (auto const& [k, p] : vertices) f.vertices.push_back(p);
    for (auto const& [k, e] : edges) {
        f.edges.push_back(e.first);
        f.open_edges += e.second != 2;
    }
    return f;
}

// An octahedron subdivided `levels` times, its vertices pushed onto the unit sphere and rounded to
// multiples of 2^-fraction_bits: closed, neighbours share bit-identical vertices, and vertices,
// edge midpoints and their differences with small dyadic points are exactly representable.
std::vector<triangle> make_dyadic_sphere(int levels, int fraction_bits) {
    std::vector<dvec3> unit{{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    std::vector<std::array<std::uint32_t, 3>> faces;
    for (std::uint32_t sx = 0; sx < 2; ++sx)
        for (std::uint32_t sy = 0; sy < 2; ++sy)
            for (std::uint32_t sz = 0; sz < 2; ++sz) {
                std::uint32_t const x = sx, y = 2 + sy, z = 4 + sz;
                // Outward winding: (x, y, z) when an even number of the axes are negative.
                if ((sx + sy + sz) % 2 == 0)
                    faces.push_back({x, y, z});
                else
                    faces.push_back({x, z, y});
            }
    for (int s = 0; s < levels; ++s) {
        std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> midpoints;
        auto midpoint = [&](std::uint32_t a, std::uint32_t b) {
            auto const [lo, hi] = std::minmax(a, b);
            auto const [it, inserted] = midpoints.try_emplace({lo, hi}, static_cast<std::uint32_t>(unit.size()));
            if (inserted) unit.push_back(canopy::normalize((unit[a] + unit[b]) * 0.5));
            return it->second;
        };
        std::vector<std::array<std::uint32_t, 3>> next;
        for (auto const& f : faces) {
            std::uint32_t const ab = midpoint(f[0], f[1]), bc = midpoint(f[1], f[2]), ca = midpoint(f[2], f[0]);
            next.push_back({f[0], ab, ca});
            next.push_back({f[1], bc, ab});
            next.push_back({f[2], ca, bc});
            next.push_back({ab, bc, ca});
        }
        faces = std::move(next);
    }
    double const scale = std::ldexp(1.0, fraction_bits);
    auto const round = [&](double x) { return static_cast<float>(std::round(x * scale) / scale); };
    std::vector<vec3<float>> vertices;
    for (dvec3 const& u : unit) vertices.emplace_back(round(u.x), round(u.y), round(u.z));
    return canopy::expand_indexed(vertices, faces);
}

// 64 triangles around a centre vertex; the rim is the 64 integer points of the boundary of the
// square [-8, 8]^2 (counter-clockwise), lifted to z = height(x, y). Every vertex, and every
// midpoint of an edge, is exactly representable.
std::vector<triangle> make_fan(vec3<float> const& centre, std::function<float(float, float)> const& height) {
    std::vector<vec3<float>> rim;
    for (int i = 0; i < 16; ++i) rim.emplace_back(static_cast<float>(-8 + i), -8.0f, 0.0f);
    for (int i = 0; i < 16; ++i) rim.emplace_back(8.0f, static_cast<float>(-8 + i), 0.0f);
    for (int i = 0; i < 16; ++i) rim.emplace_back(static_cast<float>(8 - i), 8.0f, 0.0f);
    for (int i = 0; i < 16; ++i) rim.emplace_back(-8.0f, static_cast<float>(8 - i), 0.0f);
    for (auto& p : rim) p.z = height(p.x, p.y);
    std::vector<triangle> fan;
    for (std::size_t i = 0; i < rim.size(); ++i)
        fan.push_back({centre, rim[i], rim[(i + 1) % rim.size()], static_cast<std::uint32_t>(i), 0});
    return fan;
}

// The 12 triangles of the box [lo, hi].
void append_box(std::vector<triangle>& out, vec3<float> const& lo, vec3<float> const& hi) {
    std::array<vec3<float>, 8> c;
    for (std::size_t i = 0; i < 8; ++i)
        c[i] = {(i & 1) ? hi.x : lo.x, (i & 2) ? hi.y : lo.y, (i & 4) ? hi.z : lo.z};
    constexpr std::array<std::array<std::size_t, 4>, 6> quads{
        {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}}};
    for (auto const& q : quads) {
        out.push_back({c[q[0]], c[q[1]], c[q[2]], 0, 0});
        out.push_back({c[q[0]], c[q[2]], c[q[3]], 0, 0});
    }
}

std::vector<triangle> translated(std::vector<triangle> tris, vec3<float> const& offset) {
    for (triangle& t : tris) {
        t.v0 = t.v0 + offset;
        t.v1 = t.v1 + offset;
        t.v2 = t.v2 + offset;
    }
    return tris;
}

// A scene of three instances of one mesh: identity (id 0), translated (id 1), rotated and scaled (id 2).
struct instanced_scene {
    std::vector<triangle> mesh;
    mesh_bvh object;
    std::vector<mesh_instance> instances;
    instance_bvh top;

    instanced_scene(instanced_scene const&) = delete; // the instances point at `object`
    instanced_scene(std::vector<triangle> mesh_, random_source& rng) : mesh(std::move(mesh_)) {
        renumber(mesh);
        object = build_bvh(mesh);
        instances.emplace_back(object, transform::identity(), 0);
        instances.emplace_back(object, make_transform(no_rotation, {1, 1, 1},
                                                      {6.5f, -1.25f, 2.0f}),
                               1);
        instances.emplace_back(object, make_transform(random_rotation_rows(rng), {0.75, 1.5, 1.0}, {-5.0f, 3.0f, 1.0f}), 2);
        top = build_bvh(instances);
    }
};

std::vector<record> brute_force_hits(ray const& r, std::vector<triangle> const& mesh) {
    std::vector<record> hits;
    for (triangle const& tri : mesh) {
        record const h = canopy::intersect(r, tri);
        if (h.hit) hits.push_back(h);
    }
    std::sort(hits.begin(), hits.end(),
              [](record const& a, record const& b) { return std::tuple(a.t, a.prim_id) < std::tuple(b.t, b.prim_id); });
    return hits;
}

record lane_of(packet_record const& p, int i) {
    record r;
    r.hit = p.hit[i];
    r.t = p.t[i];
    r.u = p.u[i];
    r.v = p.v[i];
    r.prim_id = static_cast<std::uint32_t>(p.prim_id[i]);
    r.geom_id = static_cast<std::uint32_t>(p.geom_id[i]);
    r.inst_id = static_cast<std::uint32_t>(p.inst_id[i]);
    for (std::size_t k = 0; k < r.inner_inst_id.size(); ++k)
        r.inner_inst_id[k] = static_cast<std::uint32_t>(p.inner_inst_id[k][i]);
    return r;
}

// A plain double-precision ray/triangle test (Möller–Trumbore), independent of the library.
// margin is the smallest barycentric weight: negative outside, near zero close to an edge.
struct reference_hit {
    bool hit = false;
    double t = std::numeric_limits<double>::infinity();
    double margin = -1.0;
};

reference_hit reference_intersect(dvec3 const& o, dvec3 const& d, dvec3 const& a, dvec3 const& b, dvec3 const& c) {
    dvec3 const e1 = b - a, e2 = c - a;
    dvec3 const p = canopy::cross(d, e2);
    double const det = canopy::dot(e1, p);
    if (det == 0.0) return {};
    dvec3 const s = o - a;
    double const u = canopy::dot(s, p) / det;
    dvec3 const q = canopy::cross(s, e1);
    double const v = canopy::dot(d, q) / det;
    double const t = canopy::dot(e2, q) / det;
    double const margin = std::min({u, v, 1.0 - u - v});
    return {margin >= 0.0 && t > 0.0, t, margin};
}

} // namespace

// 1 ------------------------------------------------------------------------------------------------

TEST_CASE("rays from inside a closed icosphere never miss") {
    int const level = sized(5, 7);
    vec3<float> const centre{0.25f, -0.5f, 0.75f};
    float const radius = 2.0f;
    auto const sphere = canopy::make_icosphere(level, centre, radius);
    REQUIRE(sphere.size() == (std::size_t(20) << (2 * level)));
    REQUIRE(features_of(sphere).open_edges == 0);
    mesh_bvh const b = build_bvh(sphere);

    random_source rng(101);
    failure_log closest_misses, any_misses;
    int const count = sized(20'000, 1'000'000);
    for (int i = 0; i < count; ++i) {
        // The centre and points within 0.99 of the radius: the flat faces are farther than that.
        vec3<float> const origin = i % 8 == 0 ? centre : centre + rng.in_ball() * (0.99f * radius);
        ray const r{origin, 0.0f, rng.direction(), inf};
        if (!closest(r, b).hit) closest_misses.add(describe(r));
        if (!canopy::any_hit(r, &b, &b + 1).hit) any_misses.add(describe(r));
    }
    INFO(count << " rays from inside a " << sphere.size() << "-triangle icosphere");
    require_no_failures(closest_misses, "closest_hit misses");
    require_no_failures(any_misses, "any_hit misses");
}

// 1b -----------------------------------------------------------------------------------------------

namespace {

// A closed cylinder of `segments` side quads from p0 to p1 with a triangle fan on each end. Each
// vertex is one expression of its (end, segment) indices, so neighbours share bit-identical corners.
std::vector<triangle> closed_cylinder(dvec3 p0, dvec3 p1, double radius, int segments) {
    dvec3 const axis = canopy::normalize(p1 - p0);
    dvec3 const helper = std::abs(axis.x) < 0.9 ? dvec3{1, 0, 0} : dvec3{0, 1, 0};
    dvec3 const u = canopy::normalize(canopy::cross(axis, helper)), w = canopy::cross(axis, u);
    auto const corner = [&](int end, int segment) {
        double const angle = 2.0 * std::numbers::pi * double(segment % segments) / double(segments);
        return vec3<float>((end == 0 ? p0 : p1) + (u * std::cos(angle) + w * std::sin(angle)) * radius);
    };
    vec3<float> const c0(p0), c1(p1);
    std::vector<triangle> out;
    for (int i = 0; i < segments; ++i) {
        out.push_back({corner(0, i), corner(0, i + 1), corner(1, i + 1)});
        out.push_back({corner(0, i), corner(1, i + 1), corner(1, i)});
        out.push_back({c0, corner(0, i + 1), corner(0, i)});
        out.push_back({c1, corner(1, i), corner(1, i + 1)});
    }
    for (std::size_t i = 0; i < out.size(); ++i) out[i].prim_id = std::uint32_t(i);
    return out;
}

// A closed bicone: 2 × segments slivers from an equator of `radius` around `centre` to the apices
// centre ± half_length · axis.
std::vector<triangle> closed_bicone(dvec3 centre, dvec3 axis, double half_length, double radius, int segments) {
    axis = canopy::normalize(axis);
    dvec3 const helper = std::abs(axis.x) < 0.9 ? dvec3{1, 0, 0} : dvec3{0, 1, 0};
    dvec3 const u = canopy::normalize(canopy::cross(axis, helper)), w = canopy::cross(axis, u);
    auto const equator = [&](int i) {
        double const angle = 2.0 * std::numbers::pi * double(i % segments) / double(segments);
        return vec3<float>(centre + (u * std::cos(angle) + w * std::sin(angle)) * radius);
    };
    vec3<float> const left(centre - axis * half_length), right(centre + axis * half_length);
    std::vector<triangle> out;
    for (int i = 0; i < segments; ++i) {
        out.push_back({left, equator(i + 1), equator(i)});
        out.push_back({right, equator(i), equator(i + 1)});
    }
    for (std::size_t i = 0; i < out.size(); ++i) out[i].prim_id = std::uint32_t(i);
    return out;
}

} // namespace

TEST_CASE("rays from inside a closed thin cylinder and a closed bicone of slivers never miss") {
    random_source rng(151);
    struct shape {
        std::string name;
        std::vector<triangle> tris;
        std::function<vec3<float>()> inside; // a random point well inside
        double size;                         // the largest extent
    };
    std::vector<shape> shapes;
    // Radius 0.01, length 16, 256 segments: side triangles of aspect ≈ 6.5e4, along an axis, along
    // a diagonal and along a random direction away from the origin.
    for (int k = 0; k < 3; ++k) {
        dvec3 const axis = k == 0 ? dvec3{1, 0, 0} : k == 1 ? canopy::normalize(dvec3{1, 1, 1}) : dvec3(rng.direction());
        dvec3 const centre = k == 2 ? dvec3{3.25, -7.5, 12.0} : dvec3{0, 0, 0};
        double const radius = 0.01, half = 8.0;
        dvec3 const helper = std::abs(axis.x) < 0.9 ? dvec3{1, 0, 0} : dvec3{0, 1, 0};
        dvec3 const u = canopy::normalize(canopy::cross(axis, helper)), w = canopy::cross(axis, u);
        shapes.push_back({"thin cylinder " + std::to_string(k), closed_cylinder(centre - axis * half, centre + axis * half, radius, 256),
                          [=, &rng] {
                              double const a = rng.uniform_double(0, 2 * std::numbers::pi);
                              double const r = 0.95 * radius * std::sqrt(rng.uniform_double(0, 1));
                              double const along = rng.uniform_double(-0.99, 0.99) * half;
                              return vec3<float>(centre + axis * along + (u * std::cos(a) + w * std::sin(a)) * r);
                          },
                          2 * half});
    }
    // 4,096 slivers meeting at two apices: half length 1, radius 0.05.
    for (int k = 0; k < 2; ++k) {
        dvec3 const axis = k == 0 ? dvec3{1, 0, 0} : dvec3(rng.direction());
        dvec3 const centre = k == 0 ? dvec3{0, 1.5, 0} : dvec3{-2.5, 4.0, 1.25};
        double const radius = 0.05, half = 1.0;
        dvec3 const helper = std::abs(axis.x) < 0.9 ? dvec3{1, 0, 0} : dvec3{0, 1, 0};
        dvec3 const u = canopy::normalize(canopy::cross(axis, helper)), w = canopy::cross(axis, u);
        shapes.push_back({"bicone " + std::to_string(k), closed_bicone(centre, axis, half, radius, 2048), [=, &rng] {
                              double const along = rng.uniform_double(-0.98, 0.98) * half;
                              double const room = radius * (1.0 - std::abs(along) / half);
                              double const a = rng.uniform_double(0, 2 * std::numbers::pi);
                              double const r = 0.9 * room * std::sqrt(rng.uniform_double(0, 1));
                              return vec3<float>(centre + axis * along + (u * std::cos(a) + w * std::sin(a)) * r);
                          },
                          2 * half});
    }
    int const count = sized_rays(250'000, 2'000'000);
    for (shape const& sh : shapes) {
        INFO(sh.name << ", " << sh.tris.size() << " triangles, " << count << " rays from inside");
        REQUIRE(features_of(sh.tris).open_edges == 0);
        mesh_bvh const b = build_bvh(sh.tris);
        failure_log closest_misses, any_misses, brute_misses;
        auto const edges = features_of(sh.tris).edges;
        for (int i = 0; i < count; ++i) {
            // Half the rays in random directions, half aimed at a random edge, a little way along
            // from the point of the edge closest to the origin: a ray grazing a long triangle
            // whose far corners are far away is where the watertight test's rounding (relative
            // to the corners' distance) outgrows the box test's (relative to the hit's distance).
            vec3<float> const origin = sh.inside();
            vec3<float> direction = rng.direction();
            if (i % 2 == 1) {
                auto const& e = edges[std::size_t(rng.uniform_double(0, 1) * double(edges.size())) % edges.size()];
                dvec3 const e0(e[0]), e1(e[1]);
                double const closest_f = canopy::dot(dvec3(origin) - e0, e1 - e0) / canopy::dot(e1 - e0, e1 - e0);
                double const along = rng.uniform_double(0.003, 0.12); // grazing: along ≫ across
                double const f = std::clamp(closest_f + (i % 4 == 1 ? along : -along), 0.0, 1.0);
                // Off the edge by up to a few units of the test's rounding (2^-22 of the mesh's
                // size): just outside the box of the triangle across the edge, where the box
                // test's own slack (relative to the short distance) does not reach.
                dvec3 const off = dvec3(rng.in_ball()) * (sh.size * 0x1p-22);
                direction = vec3<float>(e0 + (e1 - e0) * f + off - dvec3(origin));
            }
            ray const r{origin, 0.0f, direction, inf};
            bool const closest_hits = closest(r, b).hit, any_hits = canopy::any_hit(r, &b, &b + 1).hit;
            if (closest_hits && any_hits) continue;
            // Every ray from inside a closed mesh hits; brute force says whether the triangle
            // test alone would have.
            bool const brute = brute_force_closest(r, sh.tris).hit;
            if (!brute) brute_misses.add(describe(r));
            if (!closest_hits) closest_misses.add(describe(r) + (brute ? " (brute force hits)" : ""));
            if (!any_hits) any_misses.add(describe(r));
        }
        require_no_failures(brute_misses, "the triangle test alone misses");
        require_no_failures(closest_misses, "closest_hit misses");
        require_no_failures(any_misses, "any_hit misses");
    }
}

// 2 ------------------------------------------------------------------------------------------------

TEST_CASE("rays from inside aimed exactly at every vertex and edge midpoint hit a triangle touching it") {
    random_source rng(201);
    struct mesh_case {
        char const* name;
        std::vector<triangle> tris;
        bool dyadic; // vertices and midpoints minus small dyadic origins are exact
    };
    std::vector<mesh_case> const meshes{{"icosphere", canopy::make_icosphere(sized(4, 6)), false},
                                        {"dyadic sphere", make_dyadic_sphere(sized(4, 6), 12), true}};
    std::size_t rays = 0;
    for (auto const& m : meshes) {
        mesh_features const f = features_of(m.tris);
        REQUIRE(f.open_edges == 0);
        mesh_bvh const b = build_bvh(m.tris);
        failure_log vertex_failures, edge_failures;
        // Origins: the centre (0, 0, 0) and, for the dyadic mesh, small dyadic points around it.
        std::vector<vec3<float>> origins{{0.0f, 0.0f, 0.0f}};
        if (m.dyadic)
            for (int i = 0; i < 3; ++i) origins.push_back(rng.dyadic_point(-0.25f, 0.25f, 6));
        for (vec3<float> const& o : origins) {
            for (vec3<float> const& v : f.vertices) {
                ray const r{o, 0.0f, v - o, inf};
                record const h = closest(r, b);
                ++rays;
                if (!h.hit || !has_vertex(m.tris[h.prim_id], v))
                    vertex_failures.add(std::string(m.name) + ": " + describe(r) + " -> " + describe(h));
            }
            for (auto const& e : f.edges) {
                // From the centre the direction a + b aims at the midpoint (exactly for the dyadic
                // mesh); from the other origins (a + b) / 2 - o is exact.
                vec3<float> const d = o.x == 0.0f && o.y == 0.0f && o.z == 0.0f ? e[0] + e[1] : (e[0] + e[1]) * 0.5f - o;
                ray const r{o, 0.0f, d, inf};
                record const h = closest(r, b);
                ++rays;
                if (!h.hit || !has_vertex(m.tris[h.prim_id], e[0]) || !has_vertex(m.tris[h.prim_id], e[1]))
                    edge_failures.add(std::string(m.name) + ": " + describe(r) + " -> " + describe(h));
            }
        }
        require_no_failures(vertex_failures, "rays at vertices that missed or hit a triangle not touching the vertex");
        require_no_failures(edge_failures, "rays at edge midpoints that missed or hit a triangle not on the edge");
    }
    INFO(rays << " rays");
    CHECK(rays > 10'000);
}

namespace {

// Rays exactly through points of 64-triangle fans (flat, tilted with an off-centre hub, and a
// pyramid-shaped cone): from dyadic origins above and below, so that origin and direction are
// exact, and only rays that cross the fan's height field there (not rays that merely touch the
// cone's apex or crease), starting just before the target. Interior targets: the hub (shared by 64 triangles) and points of the
// spokes (shared by 2). Boundary targets: the rim vertices (shared by 2) and rim edge midpoints.
// On the open rim (boundary), the watertight test guarantees no gap between the two triangles
// sharing a rim vertex or edge, but not a hit: the rounded shear moves the target by up to an
// ulp, possibly to just outside the mesh. There a miss (or a hit farther on, beyond the target) is
// allowed and counted in rim_misses; a hit at the target on a triangle not touching it fails.
void trace_through_fans(bool boundary, failure_log& failures, std::size_t& rays, std::size_t& rim_misses) {
    struct fan_case {
        char const* name;
        std::vector<triangle> tris;
        std::function<double(double, double)> height; // the height field the fan spans
    };
    std::vector<fan_case> const fans{
        {"flat fan", make_fan({0.0f, 0.0f, 0.0f}, [](float, float) { return 0.0f; }), [](double, double) { return 0.0; }},
        {"tilted fan, off-centre hub", make_fan({1.0f, -2.0f, 0.0f}, [](float x, float y) { return x * 0.5f + y * 0.25f; }),
         [](double x, double y) { return x * 0.5 + y * 0.25; }},
        {"cone", make_fan({0.0f, 0.0f, 3.0f}, [](float, float) { return 0.0f; }),
         [](double x, double y) { return 3.0 * (1.0 - std::max(std::fabs(x), std::fabs(y)) / 8.0); }},
    };
    random_source rng(boundary ? 203 : 202);
    for (auto const& fan : fans) {
        REQUIRE(fan.tris.size() == 64);
        mesh_bvh const b = build_bvh(fan.tris);
        // Above (+) or below (-) the height field at a point of the ray, 0 on it (up to rounding
        // of the test itself: rays in the plane of a face are skipped).
        auto const side = [&](dvec3 const& p) {
            double const h = p.z - fan.height(p.x, p.y);
            return h > 1e-9 ? 1 : h < -1e-9 ? -1 : 0;
        };
        struct target {
            vec3<float> point;
            std::vector<vec3<float>> touches; // vertices the hit triangle must have
            char const* kind;
        };
        std::vector<target> targets;
        if (!boundary) targets.push_back({fan.tris[0].v0, {fan.tris[0].v0}, "hub"});
        for (triangle const& t : fan.tris) {
            if (boundary) {
                targets.push_back({t.v1, {t.v1}, "rim vertex"});
                targets.push_back({(t.v1 + t.v2) * 0.5f, {t.v1, t.v2}, "rim edge midpoint"});
            } else {
                targets.push_back({(t.v0 + t.v1) * 0.5f, {t.v0, t.v1}, "spoke midpoint"});
                targets.push_back({t.v0 * 0.25f + t.v1 * 0.75f, {t.v0, t.v1}, "spoke three-quarter point"});
            }
        }
        for (target const& tg : targets) {
            for (int i = 0; i < 32; ++i) {
                vec3<float> offset = rng.dyadic_point(-12.0f, 12.0f, 3);
                offset.z = (i % 2 == 0 ? 1.0f : -1.0f) * (1.0f + std::fabs(rng.dyadic(-11.0f, 11.0f, 3)));
                vec3<float> const o = tg.point + offset;
                dvec3 const step = dvec3(offset) * 1e-3;
                if (side(dvec3(tg.point) + step) * side(dvec3(tg.point) - step) != -1) continue;
                // The target is at t = 1; starting just before it skips other parts of the cone.
                ray const r{o, 1.0f - 0x1p-10f, tg.point - o, inf};
                record const h = closest(r, b);
                ++rays;
                // Rounded off the rim: no hit, or a hit farther on (the target is at t = 1).
                if (boundary && (!h.hit || h.t > 1.0f + 0x1p-10f)) {
                    ++rim_misses;
                    continue;
                }
                bool touches = h.hit;
                for (vec3<float> const& p : tg.touches) touches = touches && has_vertex(fan.tris[h.prim_id], p);
                if (!touches)
                    failures.add(std::string(fan.name) + ", " + tg.kind + " " + describe(tg.point) + ": " + describe(r) +
                                 " -> " + describe(h));
            }
        }
    }
}

} // namespace

TEST_CASE("rays exactly through the hub and the spokes of a 64-triangle fan hit a triangle touching them") {
    failure_log failures;
    std::size_t rays = 0;
    std::size_t rim_misses = 0;
    trace_through_fans(false, failures, rays, rim_misses);
    INFO(rays << " rays");
    CHECK(rays > 10'000);
    require_no_failures(failures, "rays through the hub or a spoke that missed or hit a triangle not touching it");
}

TEST_CASE("rays exactly through the rim vertices and rim edges of a 64-triangle fan never hit a triangle not touching them") {
    failure_log failures;
    std::size_t rays = 0, rim_misses = 0;
    trace_through_fans(true, failures, rays, rim_misses);
    INFO(rays << " rays, " << rim_misses << " rounded off the open rim (allowed)");
    CHECK(rays > 10'000);
    CHECK(rim_misses < rays / 2);
    require_no_failures(failures, "rays through a rim vertex or edge that hit a triangle not touching it");
}

// 3 ------------------------------------------------------------------------------------------------

TEST_CASE("closed meshes translated to 1e3, 1.5e5 and 1e6 from the origin are never missed from inside") {
    random_source rng(301);
    struct mesh_case {
        char const* name;
        std::vector<triangle> tris;
    };
    // Level 4 in both runs: finer unit spheres have vertices closer together than the float
    // spacing at 1e6 (0.0625), which merges them into T-junctions that no test can seal.
    std::vector<mesh_case> const meshes{{"icosphere", canopy::make_icosphere(4)},
                                        {"dyadic sphere", make_dyadic_sphere(4, 12)}};
    for (auto const& m : meshes) REQUIRE(features_of(m.tris).open_edges == 0);
    int const random_rays = sized(4000, 100'000);
    std::size_t rays = 0;
    for (float const distance : {1e3f, 1.5e5f, 1e6f}) {
        // Exactly representable, and every coordinate large: v - origin is exact (Sterbenz).
        vec3<float> const origin{distance, -0.75f * distance, 0.5f * distance};
        for (auto const& m : meshes) {
            // Translated in float: neighbours still share bit-identical vertices, and the mesh
            // stays closed however much rounding distorts it.
            auto const moved = translated(m.tris, origin);
            mesh_features const f = features_of(moved);
            mesh_bvh const b = build_bvh(moved);
            failure_log misses;
            std::string const where = std::string(m.name) + " at distance " + std::to_string(distance) + ": ";
            auto const trace = [&](vec3<float> const& d) {
                ray const r{origin, 0.0f, d, inf};
                ++rays;
                if (!closest(r, b).hit || !canopy::any_hit(r, &b, &b + 1).hit) misses.add(where + describe(r));
            };
            for (int i = 0; i < random_rays; ++i) trace(rng.direction());
            for (vec3<float> const& v : f.vertices) trace(v - origin);
            // (a - o) + (b - o) is exact: the ray passes exactly through the edge midpoint.
            for (auto const& e : f.edges) trace((e[0] - origin) + (e[1] - origin));
            require_no_failures(misses, "rays from the translated centre that missed");
        }
    }
    INFO(rays << " rays");
    CHECK(rays > 50'000);
}

// 4 ------------------------------------------------------------------------------------------------

namespace {

// Counts the ray/box tests it sees: traversal then tests child boxes one at a time through this
// hook instead of eight at once.
struct box_counting : canopy::basic_intersector<box_counting> {
    using canopy::basic_intersector<box_counting>::operator();
    std::size_t boxes = 0;
    template <typename Ray, typename... Args>
    auto operator()(Ray const& r, canopy::aabb const& box, Args&&... args) {
        ++boxes;
        return intersect(r, box, std::forward<Args>(args)...);
    }
};

} // namespace

TEST_CASE("axis-aligned rays against integer-grid geometry equal brute force and never give NaN") {
    random_source rng(401);
    // A height field with integer heights, and boxes with integer corners, many faces coplanar
    // with the rays' grid planes.
    auto scene = canopy::make_grid(16, 16, [](float x, float y) {
        return static_cast<float>((static_cast<int>(x) * 3 + static_cast<int>(y) * 5) % 4);
    });
    for (int i = 0; i < 24; ++i) {
        vec3<float> const lo(static_cast<float>(rng.integer(0, 14)), static_cast<float>(rng.integer(0, 14)),
                             static_cast<float>(rng.integer(-1, 4)));
        vec3<float> const size(static_cast<float>(rng.integer(1, 3)), static_cast<float>(rng.integer(1, 3)),
                               static_cast<float>(rng.integer(1, 3)));
        append_box(scene, lo, lo + size);
    }
    renumber(scene);
    mesh_bvh const b = build_bvh(scene);

    // Directions along one axis or a diagonal of two, every zero component as +0 or -0.
    std::vector<vec3<float>> directions;
    for (int axis = 0; axis < 3; ++axis)
        for (int signs = 0; signs < 8; ++signs) {
            vec3<float> d{(signs & 1) ? -0.0f : 0.0f, (signs & 2) ? -0.0f : 0.0f, (signs & 4) ? -0.0f : 0.0f};
            d[axis] = (signs & 4) ? -1.0f : 1.0f;
            directions.push_back(d);
            vec3<float> diagonal = d;
            diagonal[(axis + 1) % 3] = (signs & 2) ? -2.0f : 2.0f;
            directions.push_back(diagonal);
        }

    failure_log mismatches, nans, any_mismatches, hook_mismatches;
    std::size_t hits = 0;
    int const count = sized(3000, 50'000);
    box_counting counting;
    for (int i = 0; i < count; ++i) {
        // Integer and half-integer origins: many rays run exactly in grid and face planes.
        auto const half_step = [&](int lo, int hi) { return static_cast<float>(rng.integer(lo, hi)) * 0.5f; };
        vec3<float> const o{half_step(-4, 36), half_step(-4, 36), half_step(-4, 16)};
        vec3<float> d = directions[static_cast<std::size_t>(rng.integer(0, int(directions.size()) - 1))];
        d = d * std::ldexp(1.0f, rng.integer(-2, 2));
        ray const r{o, 0.0f, d, inf};
        record const expected = brute_force_closest(r, scene);
        record const got = closest(r, b);
        hits += expected.hit;
        if (!identical(got, expected)) mismatches.add(describe(r) + ": BVH " + describe(got) + ", brute force " + describe(expected));
        if (got.hit && (!std::isfinite(got.t) || !std::isfinite(got.u) || !std::isfinite(got.v)))
            nans.add(describe(r) + " -> " + describe(got));
        if (canopy::any_hit(r, &b, &b + 1).hit != expected.hit) any_mismatches.add(describe(r));
        if (!identical(canopy::closest_hit(r, &b, &b + 1, counting), expected)) hook_mismatches.add(describe(r));
    }
    INFO(count << " rays, " << hits << " hits");
    CHECK(hits > static_cast<std::size_t>(count) / 4);
    CHECK(counting.boxes > 0);
    require_no_failures(mismatches, "closest_hit through the BVH differs from brute force");
    require_no_failures(nans, "hits with a non-finite t, u or v");
    require_no_failures(any_mismatches, "any_hit disagrees with brute force");
    require_no_failures(hook_mismatches, "closest_hit with a box hook differs from brute force");
}

// 5 ------------------------------------------------------------------------------------------------

namespace {

// A valid ray with one or several fields made NaN or infinite, tmin > tmax, or a zero direction;
// and finite origins about 1e38 away, which overflow to Inf, and to NaN (inf - inf) inside an
// instance scaled by 1/8 and rotated by 45 degrees (such rays pass the scene at a distance of
// that order: misses).
std::vector<std::pair<ray, std::string>> broken_variants(ray const& r) {
    std::vector<std::pair<ray, std::string>> out;
    auto add = [&](ray const& v, std::string const& what) { out.emplace_back(v, what); };
    for (vec3<float> const far_origin : {vec3<float>{1e38f, -1e38f, r.origin.z}, vec3<float>{-1e38f, 1e38f, r.origin.z},
                                         vec3<float>{3e38f, -3e38f, 3e38f}, vec3<float>{r.origin.x, 3e38f, r.origin.z}}) {
        ray far = r;
        far.origin = far_origin;
        add(far, "origin far away " + describe(far_origin));
    }
    for (int axis = 0; axis < 3; ++axis)
        for (float const bad : {quiet_nan, inf, -inf}) {
            ray a = r;
            a.origin[axis] = bad;
            add(a, "origin[" + std::to_string(axis) + "] = " + std::to_string(bad));
            ray b = r;
            b.direction[axis] = bad;
            add(b, "direction[" + std::to_string(axis) + "] = " + std::to_string(bad));
        }
    ray all_nan = r;
    all_nan.origin = vec3<float>(quiet_nan);
    all_nan.direction = vec3<float>(quiet_nan);
    add(all_nan, "origin and direction NaN");
    ray all_inf = r;
    all_inf.direction = {inf, -inf, inf};
    add(all_inf, "direction (inf, -inf, inf)");
    for (vec3<float> const zero : {vec3<float>{0.0f, 0.0f, 0.0f}, vec3<float>{-0.0f, -0.0f, -0.0f},
                                   vec3<float>{0.0f, -0.0f, 0.0f}, vec3<float>{-0.0f, 0.0f, -0.0f}}) {
        ray z = r;
        z.direction = zero;
        add(z, "zero direction " + describe(zero));
    }
    ray a = r;
    a.tmin = quiet_nan;
    add(a, "tmin NaN");
    a = r;
    a.tmax = quiet_nan;
    add(a, "tmax NaN");
    a = r;
    a.tmin = a.tmax = quiet_nan;
    add(a, "tmin and tmax NaN");
    a = r;
    a.tmin = inf;
    add(a, "tmin +inf");
    a = r;
    a.tmax = -inf;
    add(a, "tmax -inf");
    a = r;
    a.tmin = -inf;
    a.tmax = -inf;
    add(a, "tmin = tmax = -inf");
    a = r;
    a.tmin = 2.0f;
    a.tmax = 1.0f;
    add(a, "tmin > tmax");
    a = r;
    a.tmin = 0.0f;
    a.tmax = -std::numeric_limits<float>::denorm_min();
    add(a, "tmax just below tmin = 0");
    a = r;
    a.tmin = quiet_nan;
    a.direction = {0.0f, 0.0f, 0.0f};
    add(a, "tmin NaN and zero direction");
    return out;
}

} // namespace

namespace {

// A scene, valid rays into it, and their broken variants.
struct broken_ray_scene {
    random_source rng{501};
    std::vector<triangle> mesh =
        concatenate(canopy::make_icosphere(3, {0.0f, 0.0f, 0.0f}, 1.5f), triangle_soup(rng, 200, 3.0f, 0.8f));
    instanced_scene scene{mesh, rng};
    // Scaled by 1/8 and rotated by 45 degrees about z: the inverse multiplies by about 5.66, so
    // finite world origins near 1e38 become Inf - Inf = NaN in object space.
    std::vector<mesh_instance> shrunk{mesh_instance(
        scene.object,
        transform::from_rows({0.08838835f, -0.08838835f, 0, 1.0f, 0.08838835f, 0.08838835f, 0, -2.0f, 0, 0, 0.125f, 0.5f}),
        7)};
    instance_bvh shrunk_top = build_bvh(shrunk);
    std::vector<ray> valid = random_rays(rng, scene.object.bounds(), sized(48, 400));
};

} // namespace

TEST_CASE("NaN and Inf rays, tmin > tmax and zero directions miss through a BVH without crashing") {
    broken_ray_scene const s;
    mesh_bvh const& b = s.scene.object;
    failure_log false_hits;
    std::size_t variants = 0, valid_hits = 0;
    auto const check_miss = [&](record const& h, std::string const& what) {
        if (h.hit) false_hits.add(what + " -> " + describe(h));
    };
    for (ray const& base : s.valid) {
        valid_hits += closest(base, b).hit;
        for (auto const& [r, what] : broken_variants(base)) {
            ++variants;
            std::string const w = what + ", " + describe(r);
            for (std::size_t i = 0; i < 16; ++i) {
                check_miss(canopy::intersect(r, s.mesh[i]), "triangle test, " + w);
                check_miss(canopy::intersect_moller_trumbore(r, s.mesh[i]), "Möller–Trumbore triangle test, " + w);
            }
            check_miss(closest(r, b), "closest_hit, " + w);
            check_miss(canopy::closest_hit(r, &b, &b + 1, canopy::moller_trumbore_intersector{}), "Möller–Trumbore, " + w);
            check_miss(canopy::closest_hit(r, &b, &b + 1, box_counting{}), "closest_hit with a box hook, " + w);
            check_miss(canopy::any_hit(r, &b, &b + 1), "any_hit, " + w);
            for (record const& h : canopy::multi_hit<4>(r, &b, &b + 1)) check_miss(h, "multi_hit, " + w);
        }
    }
    INFO(variants << " broken rays");
    CHECK(valid_hits > 10);
    require_no_failures(false_hits, "broken rays reported as hits");
}

TEST_CASE("NaN and Inf rays, tmin > tmax and zero directions miss through instanced BVHs without crashing") {
    broken_ray_scene const s;
    failure_log false_hits;
    std::size_t variants = 0, valid_hits = 0;
    auto const check_miss = [&](record const& h, std::string const& what) {
        if (h.hit) false_hits.add(what + " -> " + describe(h));
    };
    for (instance_bvh const* top : {&s.scene.top, &s.shrunk_top}) {
        for (ray const& base : s.valid) {
            valid_hits += closest(base, *top).hit;
            for (auto const& [r, what] : broken_variants(base)) {
                ++variants;
                std::string const w = what + ", " + describe(r);
                check_miss(closest(r, *top), "instanced closest_hit, " + w);
                check_miss(canopy::closest_hit(r, top, top + 1, box_counting{}), "instanced closest_hit with a box hook, " + w);
                check_miss(canopy::any_hit(r, top, top + 1), "instanced any_hit, " + w);
                for (record const& h : canopy::multi_hit<4>(r, top, top + 1)) check_miss(h, "instanced multi_hit, " + w);
            }
        }
    }
    INFO(variants << " broken rays");
    CHECK(valid_hits > 10);
    require_no_failures(false_hits, "broken rays reported as hits");
}

TEST_CASE("NaN and Inf rays, tmin > tmax and zero directions miss in packets without disturbing the other lanes") {
    broken_ray_scene s;
    failure_log false_hits, lane_mismatches;
    std::size_t variants = 0;
    for (ray const& base : s.valid) {
        auto const broken = broken_variants(base);
        // Broken rays in the odd lanes, valid rays in the even ones.
        for (std::size_t first = 0; first < broken.size(); first += 4) {
            std::array<ray, 8> lanes;
            for (std::size_t i = 0; i < 8; ++i) {
                std::size_t const k = std::min(first + i / 2, broken.size() - 1);
                lanes[i] = i % 2 == 0 ? ray{base.origin, 0.0f, base.direction + s.rng.point(-0.1f, 0.1f), inf}
                                      : broken[k].first;
            }
            variants += 4;
            packet_ray const p = pack(lanes);
            auto const compare = [&](auto const& structure, char const* name) {
                packet_record const c = canopy::closest_hit(p, &structure, &structure + 1);
                packet_record const a = canopy::any_hit(p, &structure, &structure + 1);
                for (int i = 0; i < 8; ++i) {
                    ray const& r = lanes[static_cast<std::size_t>(i)];
                    std::string const w = std::string(name) + " lane " + std::to_string(i) + ", " + describe(r);
                    if (i % 2 == 1) {
                        if (c.hit[i]) false_hits.add("packet closest_hit, " + w + " -> " + describe(lane_of(c, i)));
                        if (a.hit[i]) false_hits.add("packet any_hit, " + w);
                        continue;
                    }
                    record const scalar = closest(r, structure);
                    if (!identical(lane_of(c, i), scalar) || a.hit[i] != scalar.hit)
                        lane_mismatches.add(w + ": packet " + describe(lane_of(c, i)) + ", scalar " + describe(scalar));
                }
            };
            compare(s.scene.object, "BVH");
            compare(s.scene.top, "instanced BVH");
        }
    }
    INFO(variants << " broken lanes");
    require_no_failures(false_hits, "broken lanes reported as hits");
    require_no_failures(lane_mismatches, "valid lanes next to broken ones that differ from the scalar query");
}

// 6 ------------------------------------------------------------------------------------------------

TEST_CASE("scaling the direction by 2^k keeps the triangle and u, v bit for bit and scales t by exactly 2^-k") {
    random_source rng(601);
    auto const mesh = concatenate(canopy::make_icosphere(3, {0.0f, 0.0f, 0.0f}, 2.0f), triangle_soup(rng, 300, 4.0f, 1.0f));
    instanced_scene const scene(mesh, rng);
    failure_log failures;
    std::size_t hits = 0, rays = 0;
    auto const check = [&](auto const& structure, char const* name) {
        for (ray const& r : random_rays(rng, structure.bounds(), sized(300, 5000))) {
            record const reference = closest(r, structure);
            hits += reference.hit;
            for (int k = -20; k <= 20; ++k) {
                ray scaled = r;
                scaled.direction = r.direction * std::ldexp(1.0f, k);
                record const h = closest(scaled, structure);
                ++rays;
                record expected = reference;
                expected.t = std::ldexp(reference.t, -k);
                if (!identical(h, expected))
                    failures.add(std::string(name) + ", k = " + std::to_string(k) + ", " + describe(scaled) + ": " +
                                 describe(h) + ", expected " + describe(expected));
            }
        }
    };
    check(scene.object, "BVH");
    check(scene.top, "instanced BVH");
    INFO(rays << " rays");
    CHECK(hits > 100);
    require_no_failures(failures, "direction scaled by 2^k changed the hit");
}

// 7 ------------------------------------------------------------------------------------------------

TEST_CASE("zero-area triangles are never hit, directly or through a BVH, slivers give finite t, u, v") {
    random_source rng(701);
    // Collinear vertices with exact coordinates, and repeated vertices.
    std::vector<triangle> degenerate{{{0, 0, 0}, {1, 0, 0}, {3, 0, 0}},
                                     {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}},
                                     {{1, 2, 3}, {1, 2, 3}, {4, 5, 6}},
                                     {{1, 2, 3}, {4, 5, 6}, {4, 5, 6}},
                                     {{1, 2, 3}, {4, 5, 6}, {1, 2, 3}},
                                     {{1, 2, 3}, {1, 2, 3}, {1, 2, 3}}};
    for (int i = 0; i < 200; ++i) {
        vec3<float> const p = rng.dyadic_point(-8.0f, 8.0f, 4);
        vec3<float> const d = rng.dyadic_point(-2.0f, 2.0f, 3);
        float const k1 = static_cast<float>(rng.integer(-3, 3)), k2 = static_cast<float>(rng.integer(-3, 3));
        switch (i % 4) {
        case 0: degenerate.push_back({p, p + d * k1, p + d * k2}); break;
        case 1: degenerate.push_back({p + d * k1, p, p + d * k2}); break;
        case 2: degenerate.push_back({p, p, p + d}); break;
        default: degenerate.push_back({p, p + d, p + d}); break;
        }
    }
    renumber(degenerate);
    for (triangle const& t : degenerate) REQUIRE(exactly_degenerate(t));
    mesh_bvh const b = build_bvh(degenerate);

    failure_log degenerate_hits;
    std::size_t rays = 0;
    for (triangle const& t : degenerate) {
        // Targets on the segment: vertices, midpoints, quarter points (all exact).
        std::vector<vec3<float>> targets{t.v0, t.v1, t.v2, (t.v0 + t.v1) * 0.5f, (t.v1 + t.v2) * 0.5f,
                                         (t.v0 + t.v2) * 0.5f, t.v0 * 0.75f + t.v2 * 0.25f};
        for (vec3<float> const& target : targets) {
            for (int i = 0; i < 8; ++i) {
                vec3<float> const o = target + rng.dyadic_point(-8.0f, 8.0f, 2);
                for (ray const& r : {ray{o, 0.0f, target - o, inf}, ray{o, -inf, target - o, inf}}) {
                    ++rays;
                    std::string const w = describe(r) + " at prim " + std::to_string(t.prim_id);
                    if (canopy::intersect(r, t).hit) degenerate_hits.add("watertight, " + w);
                    if (canopy::intersect_moller_trumbore(r, t).hit) degenerate_hits.add("Möller–Trumbore, " + w);
                    if (closest(r, b).hit) degenerate_hits.add("closest_hit, " + w);
                    if (canopy::any_hit(r, &b, &b + 1).hit) degenerate_hits.add("any_hit, " + w);
                    if (canopy::multi_hit<2>(r, &b, &b + 1)[0].hit) degenerate_hits.add("multi_hit, " + w);
                }
            }
        }
        // Along the segment's own line.
        vec3<float> const along = t.v2 - t.v0;
        if (along.x != 0.0f || along.y != 0.0f || along.z != 0.0f) {
            ray const r{t.v0 - along * 2.0f, -inf, along, inf};
            ++rays;
            if (closest(r, b).hit) degenerate_hits.add("along the line, " + describe(r));
        }
    }
    INFO(rays << " rays at zero-area triangles");
    require_no_failures(degenerate_hits, "zero-area triangles hit");

    // Slivers: a vertex one ulp (or a few) off the line through the other two, needles, and thin
    // triangles down to 2^-23 of their length.
    std::vector<triangle> slivers;
    for (int i = 0; i < 300; ++i) {
        vec3<float> const p = rng.point(-4.0f, 4.0f), q = rng.point(-4.0f, 4.0f);
        vec3<float> m = (p + q) * 0.5f;
        int const axis = i % 3;
        switch (i % 4) {
        case 0: m[axis] = canopy::next_float_up(m[axis]); break;
        case 1:
            for (int k = 0; k < 4; ++k) m[axis] = canopy::next_float_down(m[axis]);
            break;
        case 2: m[axis] += std::ldexp(canopy::length(q - p), -rng.integer(8, 23)); break;
        default: m = p + (q - p) * 1e-6f + vec3<float>(std::ldexp(1.0f, -rng.integer(10, 30))); break;
        }
        triangle const t{p, m, q, 0, 0};
        if (!exactly_degenerate(t)) slivers.push_back(t);
    }
    renumber(slivers);
    REQUIRE(slivers.size() > 250);
    auto const all = concatenate(degenerate, slivers);
    mesh_bvh const mixed = build_bvh(all);
    failure_log non_finite, mixed_failures;
    std::size_t sliver_hits = 0;
    for (triangle const& t : slivers) {
        for (int i = 0; i < 24; ++i) {
            float u = rng.uniform(0.0f, 1.0f), v = rng.uniform(0.0f, 1.0f);
            if (u + v > 1.0f) u = 1.0f - u, v = 1.0f - v;
            vec3<float> const target = i < 3 ? (i == 0 ? t.v0 : i == 1 ? t.v1 : t.v2) : canopy::surface_point(t, u, v);
            vec3<float> const o = target + rng.direction() * 6.0f;
            ray const r{o, 0.0f, target - o, inf};
            for (record const& h : {canopy::intersect(r, t), canopy::intersect_moller_trumbore(r, t)}) {
                if (!h.hit) continue;
                ++sliver_hits;
                if (!std::isfinite(h.t) || !std::isfinite(h.u) || !std::isfinite(h.v) || h.u < 0.0f || h.v < 0.0f ||
                    h.u > 1.0f || h.v > 1.0f)
                    non_finite.add(describe(r) + " -> " + describe(h));
            }
            record const h = closest(r, mixed);
            if (h.hit && (h.prim_id < degenerate.size() || !std::isfinite(h.t) || !std::isfinite(h.u) ||
                          !std::isfinite(h.v)))
                mixed_failures.add(describe(r) + " -> " + describe(h));
        }
    }
    INFO(sliver_hits << " sliver hits");
    CHECK(sliver_hits > 1000);
    require_no_failures(non_finite, "sliver hits with t, u or v not finite (or u, v outside [0, 1])");
    require_no_failures(mixed_failures, "BVH of slivers and zero-area triangles: degenerate or non-finite hits");
}

// 8 ------------------------------------------------------------------------------------------------

namespace {

struct exact_case {
    triangle tri;
    ray r;      // tmin = 0, tmax = inf
    float t;    // the exact hit distance
};

// Triangles with small integer vertices and rays with integer origins and directions whose
// dominant component is ±1 and the others in {0, ±1/2}: every intermediate value of the
// watertight test then has at most 16 significant bits, so the test computes exactly, and the
// hit distance t (chosen exactly representable) is the float it must return.
std::vector<exact_case> exact_cases(random_source& rng, int count) {
    std::vector<exact_case> out;
    for (long attempt = 0; static_cast<int>(out.size()) < count && attempt < 1000L * count; ++attempt) {
        auto const integer_point = [&](int extent) {
            return dvec3(rng.integer(-extent, extent), rng.integer(-extent, extent), rng.integer(-extent, extent));
        };
        dvec3 const a = integer_point(4), b = integer_point(4), c = integer_point(4), o = integer_point(4);
        dvec3 d(rng.integer(-1, 1) * 0.5, rng.integer(-1, 1) * 0.5, rng.integer(-1, 1) * 0.5);
        d[rng.integer(0, 2)] = rng.integer(0, 1) == 0 ? -1.0 : 1.0;
        dvec3 const n = canopy::cross(b - a, c - a);
        double const den = canopy::dot(n, d), num = canopy::dot(n, a - o);
        if (den == 0.0) continue;
        double const t = num / den;
        if (!(t > 0.0) || t * den != num || static_cast<double>(static_cast<float>(t)) != t) continue;
        // Inside or on the boundary (exact in double for these small integers).
        dvec3 const p = o + d * t;
        double const ea = canopy::dot(canopy::cross(b - p, c - p), n), eb = canopy::dot(canopy::cross(c - p, a - p), n),
                     ec = canopy::dot(canopy::cross(a - p, b - p), n);
        if (ea < 0.0 || eb < 0.0 || ec < 0.0) continue;
        auto const f = [](dvec3 const& v) { return vec3<float>(v); };
        out.push_back({{f(a), f(b), f(c), 0, 0}, {f(o), 0.0f, f(d), inf}, static_cast<float>(t)});
    }
    return out;
}

struct interval_case {
    float tmin, tmax;
    char const* name;
};

std::vector<interval_case> intervals_around(float t) {
    float const up = canopy::next_float_up(t), down = canopy::next_float_down(t);
    return {{0.0f, inf, "[0, inf]"},        {t, inf, "[t, inf]"},         {up, inf, "[next_up(t), inf]"},
            {down, inf, "[next_down(t), inf]"}, {0.0f, t, "[0, t]"},       {0.0f, down, "[0, next_down(t)]"},
            {0.0f, up, "[0, next_up(t)]"},    {t, t, "[t, t]"},            {down, up, "[next_down(t), next_up(t)]"},
            {up, up, "[next_up(t), next_up(t)]"}, {down, down, "[next_down(t), next_down(t)]"},
            {t, down, "[t, next_down(t)]"}};
}

} // namespace

TEST_CASE("tmin and tmax at, just below and just above an exact hit distance: hit iff tmin <= t <= tmax") {
    random_source rng(801);
    auto const cases = exact_cases(rng, sized(300, 5000));
    REQUIRE(cases.size() == static_cast<std::size_t>(sized(300, 5000)));
    failure_log wrong_t, failures;
    std::size_t checks = 0;
    for (exact_case const& c : cases) {
        record const h = canopy::intersect(c.r, c.tri);
        if (!h.hit || h.t != c.t) wrong_t.add(describe(c.r) + " -> " + describe(h) + ", exact t " + std::to_string(c.t));

        // The same triangle through a BVH, an identity instance, an integer translation and a
        // scale by 2 (all exact: the object-space ray has the same t).
        std::vector<triangle> const one{c.tri};
        mesh_bvh const b = build_bvh(one);
        triangle half = c.tri;
        half.v0 = half.v0 * 0.5f, half.v1 = half.v1 * 0.5f, half.v2 = half.v2 * 0.5f;
        std::vector<triangle> const halves{half};
        mesh_bvh const half_bvh = build_bvh(halves);
        std::vector<triangle> const shifted = translated(one, {-3.0f, 5.0f, 1.0f});
        mesh_bvh const shifted_bvh = build_bvh(shifted);
        std::vector<mesh_instance> const instances{
            mesh_instance(b, transform::identity(), 0),
            mesh_instance(shifted_bvh, transform::from_rows({1, 0, 0, 3, 0, 1, 0, -5, 0, 0, 1, -1}), 1),
            mesh_instance(half_bvh, transform::from_rows({2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0}), 2)};

        auto const intervals = intervals_around(c.t);
        for (std::size_t first = 0; first < intervals.size(); first += 8) {
            std::array<ray, 8> lanes;
            for (std::size_t i = 0; i < 8; ++i) {
                interval_case const& iv = intervals[std::min(first + i, intervals.size() - 1)];
                lanes[i] = {c.r.origin, iv.tmin, c.r.direction, iv.tmax};
            }
            packet_ray const p = pack(lanes);
            packet_record const packet_closest = canopy::closest_hit(p, &b, &b + 1);
            packet_record const packet_any = canopy::any_hit(p, &b, &b + 1);
            for (std::size_t i = 0; i < 8 && first + i < intervals.size(); ++i) {
                interval_case const& iv = intervals[first + i];
                ray const& r = lanes[i];
                bool const expected = iv.tmin <= c.t && c.t <= iv.tmax;
                std::string const w = std::string(iv.name) + ", " + describe(r) + ", t " + std::to_string(c.t);
                auto const expect = [&](bool got, char const* path) {
                    ++checks;
                    if (got != expected) failures.add(std::string(path) + (expected ? " missed " : " hit ") + w);
                };
                expect(canopy::intersect(r, c.tri).hit, "triangle test");
                expect(closest(r, b).hit, "closest_hit");
                expect(canopy::any_hit(r, &b, &b + 1).hit, "any_hit");
                expect(canopy::multi_hit<2>(r, &b, &b + 1)[0].hit, "multi_hit");
                for (mesh_instance const& inst : instances) {
                    record const hi = closest(r, inst);
                    expect(hi.hit, ("instance " + std::to_string(inst.inst_id)).c_str());
                    if (hi.hit && hi.t != c.t) wrong_t.add("instance " + std::to_string(inst.inst_id) + ", " + w + " -> " + describe(hi));
                }
                expect(packet_closest.hit[static_cast<int>(i)], "packet closest_hit");
                expect(packet_any.hit[static_cast<int>(i)], "packet any_hit");
            }
        }
    }

    // Random geometry: the bounds are respected exactly around whatever t the test returns.
    auto const soup = triangle_soup(rng, 200, 4.0f, 1.0f);
    mesh_bvh const b = build_bvh(soup);
    std::size_t random_hits = 0;
    for (ray const& base : random_rays(rng, b.bounds(), sized(400, 5000))) {
        record const h = closest(base, b);
        if (!h.hit) continue;
        ++random_hits;
        for (interval_case const& iv : intervals_around(h.t)) {
            ray const r{base.origin, iv.tmin, base.direction, iv.tmax};
            bool const expected = iv.tmin <= h.t && h.t <= iv.tmax;
            record const single = canopy::intersect(r, soup[h.prim_id]);
            ++checks;
            if (single.hit != expected) failures.add(std::string("soup triangle, ") + iv.name + ", " + describe(r));
            // Through the BVH the closest hit in [tmin, tmax] is this one when it is inside the bounds.
            record const through = closest(r, b);
            if (expected && (!through.hit || through.t > h.t))
                failures.add(std::string("soup BVH, ") + iv.name + ", " + describe(r) + " -> " + describe(through));
        }
    }
    INFO(cases.size() << " exact cases, " << random_hits << " random hits, " << checks << " checks");
    CHECK(random_hits > 100);
    require_no_failures(wrong_t, "exact hit distances not returned exactly");
    require_no_failures(failures, "hit reported iff tmin <= t <= tmax violated");
}

// 9 ------------------------------------------------------------------------------------------------

namespace {

// multi_hit<N> against the first N brute-force hits (sorted by t, inst_id, prim_id), bit for bit,
// with every (instance, primitive) at most once.
template <std::size_t N, typename Structure>
void check_multi_hit(ray const& r, Structure const& s, std::vector<record> const& expected, failure_log& failures,
                     std::string const& where) {
    auto const got = canopy::multi_hit<N>(r, &s, &s + 1);
    std::set<std::pair<std::uint32_t, std::uint32_t>> seen;
    for (std::size_t i = 0; i < N; ++i) {
        bool ok = i < expected.size() ? identical(got[i], expected[i]) : !got[i].hit;
        if (got[i].hit) ok = ok && seen.insert({got[i].inst_id, got[i].prim_id}).second;
        if (!ok) {
            failures.add(where + ", N = " + std::to_string(N) + ", entry " + std::to_string(i) + ", " + describe(r) +
                         ": " + describe(got[i]) + ", expected " +
                         (i < expected.size() ? describe(expected[i]) : std::string("miss")));
            return;
        }
    }
}

template <typename Structure>
void check_multi_hits(ray const& r, Structure const& s, std::vector<record> const& expected, failure_log& failures,
                      std::string const& where) {
    check_multi_hit<1>(r, s, expected, failures, where);
    check_multi_hit<3>(r, s, expected, failures, where);
    check_multi_hit<8>(r, s, expected, failures, where);
    check_multi_hit<16>(r, s, expected, failures, where);
}

} // namespace

TEST_CASE("multi_hit<N> equals the first N brute-force hits on a soup, stacked coplanar copies and a mesh") {
    random_source rng(901);
    failure_log failures;
    std::size_t rays = 0, hits = 0, ties = 0;
    auto const run = [&](std::vector<triangle> const& tris, std::vector<ray> const& rs, char const* name) {
        for (canopy::bvh_build_options const options :
             {canopy::bvh_build_options{}, canopy::bvh_build_options{.max_leaf_size = 1}}) {
            mesh_bvh const b = build_bvh(tris, options);
            // Two identity instances (every hit twice, at equal t) and a translated one.
            std::vector<mesh_instance> const instances{
                mesh_instance(b, transform::identity(), 7), mesh_instance(b, transform::identity(), 3),
                mesh_instance(b, transform::from_rows({1, 0, 0, 0.5f, 0, 1, 0, 0.25f, 0, 0, 1, 0}), 5)};
            instance_bvh const top = build_bvh(instances);
            for (ray const& r : rs) {
                ++rays;
                auto const expected = brute_force_hits(r, tris);
                hits += expected.size();
                for (std::size_t i = 1; i < expected.size(); ++i) ties += expected[i].t == expected[i - 1].t;
                check_multi_hits(r, b, expected, failures, name);
                check_multi_hits(r, top, test_support::instanced_brute_force_hits(r, instances, tris), failures, std::string("instanced ") + name);
            }
        }
    };

    auto const soup = triangle_soup(rng, 400, 2.0f, 1.5f);
    run(soup, random_rays(rng, build_bvh(soup).bounds(), sized(300, 3000)), "soup");

    // Eight copies of one triangle (prim ids 0..7): every ray through it hits all eight at equal t,
    // also exactly through its vertices and edges.
    triangle const base{{-1.0f, -1.0f, 0.5f}, {2.0f, -0.5f, 0.25f}, {0.0f, 1.5f, -0.5f}, 0, 0};
    std::vector<triangle> stacked(8, base);
    renumber(stacked);
    std::vector<ray> through;
    for (int i = 0; i < sized(200, 2000); ++i) {
        std::array<vec3<float>, 4> const targets{base.v0, (base.v1 + base.v2) * 0.5f,
                                                 canopy::surface_point(base, 0.25f, 0.5f),
                                                 canopy::surface_point(base, rng.uniform(0.0f, 0.5f), rng.uniform(0.0f, 0.5f))};
        vec3<float> const target = targets[static_cast<std::size_t>(i % 4)];
        vec3<float> const o = target + rng.dyadic_point(-4.0f, 4.0f, 3);
        through.push_back({o, 0.0f, target - o, inf});
    }
    run(stacked, through, "stacked copies");

    // A mesh: two concentric icospheres, rays from outside, and rays through their vertices (where
    // several triangles are hit at once).
    auto const spheres = concatenate(canopy::make_icosphere(2, {0, 0, 0}, 1.0f), canopy::make_icosphere(2, {0, 0, 0}, 2.0f));
    std::vector<ray> mesh_rays = random_rays(rng, build_bvh(spheres).bounds(), sized(200, 2000));
    for (vec3<float> const& v : features_of(spheres).vertices) mesh_rays.push_back({v * 2.5f, 0.0f, -v * 1.5f, inf});
    run(spheres, mesh_rays, "mesh");

    INFO(rays << " rays, " << hits << " brute-force hits, " << ties << " ties in t");
    CHECK(ties > 1000);
    require_no_failures(failures, "multi_hit differs from the sorted brute-force list");
}

// 10 -----------------------------------------------------------------------------------------------

namespace {

// Procedural alpha: triangles with prim_id % 5 == 3 are transparent, the others where
// floor(8u) + floor(8v) is odd.
bool opaque(std::uint32_t prim_id, float u, float v) {
    if (prim_id % 5 == 3) return false;
    auto const cell = [](float x) { return static_cast<int>(std::floor(8.0f * std::clamp(x, 0.0f, 1.0f))); };
    return (cell(u) + cell(v)) % 2 == 0;
}

struct alpha_cutout : canopy::basic_intersector<alpha_cutout> {
    using canopy::basic_intersector<alpha_cutout>::operator();
    template <typename Ray>
    record operator()(Ray const& r, triangle const& tri) {
        record hr = intersect(r, tri);
        if (hr.hit) hr.hit = opaque(hr.prim_id, hr.u, hr.v);
        return hr;
    }
};

// The same rule, with a box hook of its own (traversal then tests boxes one at a time).
struct alpha_cutout_with_box_hook : canopy::basic_intersector<alpha_cutout_with_box_hook> {
    using canopy::basic_intersector<alpha_cutout_with_box_hook>::operator();
    std::size_t boxes = 0;
    template <typename Ray>
    record operator()(Ray const& r, triangle const& tri) {
        return alpha_cutout{}(r, tri);
    }
    template <typename Ray, typename... Args>
    auto operator()(Ray const& r, canopy::aabb const& box, Args&&... args) {
        ++boxes;
        return intersect(r, box, std::forward<Args>(args)...);
    }
};

} // namespace

TEST_CASE("closest hit through the BVH with an alpha intersector equals a brute-force loop with the same intersector") {
    random_source rng(1001);
    auto const mesh = concatenate(concatenate(canopy::make_icosphere(3, {0, 0, 0}, 2.0f), triangle_soup(rng, 400, 4.0f, 1.5f)),
                                  translated(canopy::make_grid(8, 8), {-4.0f, -4.0f, -1.0f}));
    instanced_scene const scene(mesh, rng);
    failure_log differences;
    std::size_t rays = 0, cut = 0;
    alpha_cutout_with_box_hook hooked;
    // Random rays, and rays through the icosphere's vertices (equal t in several triangles: the
    // smaller prim_id must win, as in the brute force).
    std::vector<ray> rays_in = random_rays(rng, scene.top.bounds(), sized(1500, 20'000));
    for (vec3<float> const& v : features_of(canopy::make_icosphere(3, {0, 0, 0}, 2.0f)).vertices)
        rays_in.push_back({v * 2.5f, 0.0f, -v * 1.5f, inf});
    for (ray const& r : rays_in) {
        ++rays;
        record const expected = brute_force_closest(r, mesh, alpha_cutout{});
        cut += !identical(expected, brute_force_closest(r, mesh));
        record const got = canopy::closest_hit(r, &scene.object, &scene.object + 1, alpha_cutout{});
        if (!identical(got, expected)) differences.add("BVH, " + describe(r) + ": " + describe(got) + ", brute force " + describe(expected));
        record const got_hooked = canopy::closest_hit(r, &scene.object, &scene.object + 1, hooked);
        if (!identical(got_hooked, expected)) differences.add("BVH with box hook, " + describe(r));
        record const mt = canopy::closest_hit(r, &scene.object, &scene.object + 1, canopy::moller_trumbore_intersector{});
        if (!identical(mt, brute_force_closest(r, mesh, canopy::moller_trumbore_intersector{})))
            differences.add("Möller–Trumbore BVH, " + describe(r));

        // Instanced: the brute force takes the ray into each instance with its stored inverse.
        record best;
        for (mesh_instance const& inst : scene.instances) {
            ray local = r;
            if (!inst.identity) {
                local.origin = inst.world_to_object.transform_point(r.origin);
                local.direction = inst.world_to_object.transform_vector(r.direction);
            }
            record h = brute_force_closest(local, mesh, alpha_cutout{});
            h.inst_id = inst.inst_id;
            if (h.hit && (!best.hit || std::tuple(h.t, h.inst_id, h.prim_id) < std::tuple(best.t, best.inst_id, best.prim_id)))
                best = h;
        }
        record const got_instanced = canopy::closest_hit(r, &scene.top, &scene.top + 1, alpha_cutout{});
        if (!identical(got_instanced, best))
            differences.add("instanced, " + describe(r) + ": " + describe(got_instanced) + ", brute force " + describe(best));
    }
    INFO(rays << " rays, " << cut << " whose closest hit the alpha rule changes");
    CHECK(cut > rays / 10);
    CHECK(hooked.boxes > 0);
    require_no_failures(differences, "closest hits that differ from the brute-force loop with the same intersector");
}

// 11 -----------------------------------------------------------------------------------------------

namespace {

// Directions leaving a surface with unit normal n: random on both sides, and grazing (a tangent
// tilted off the plane by 0, 1e-6, 1e-4, 1e-2).
std::vector<vec3<float>> leaving_directions(random_source& rng, vec3<float> const& n) {
    std::vector<vec3<float>> out;
    for (int i = 0; i < 4; ++i) out.push_back(rng.direction());
    for (float const tilt : {0.0f, 1e-6f, 1e-4f, 1e-2f})
        for (float const side : {1.0f, -1.0f}) {
            vec3<float> const tangent = canopy::normalize(canopy::cross(n, rng.direction()));
            out.push_back(tangent + n * (tilt * side));
        }
    return out;
}

// Targets p + k d of spawn_ray_to must lie clearly off the surface: a target on it (a tangent d)
// may be hit legitimately just before t = 1.
bool clearly_off_surface(vec3<float> const& d, vec3<float> const& n) {
    return std::fabs(canopy::dot(canopy::normalize(dvec3(d)), dvec3(n))) >= 1e-3;
}

vec3<float> unit_normal(triangle const& t) {
    return vec3<float>(canopy::normalize(canopy::cross(dvec3(t.v1) - dvec3(t.v0), dvec3(t.v2) - dvec3(t.v0))));
}

} // namespace

TEST_CASE("rays spawned from hit points never hit the triangle they leave, for coordinates from 1e-6 to 1e6") {
    random_source rng(1101);
    failure_log self_hits, plane_hits;
    std::size_t spawned = 0, mesh_spawned = 0;
    int const per_scale = sized(30, 300);
    for (int e = -6; e <= 6; ++e) {
        float const scale = static_cast<float>(std::pow(10.0, e));
        std::string const at = "scale 1e" + std::to_string(e) + ", ";

        // Lone triangles of size ~scale placed up to 8 scale from the origin (some straddle an
        // axis plane), and triangles a thousand times smaller at the same places.
        for (int i = 0; i < per_scale; ++i) {
            float const size = i % 2 == 0 ? scale : scale * 1e-3f;
            vec3<float> const c = rng.point(-8.0f, 8.0f) * scale;
            triangle const tri{c + rng.point(-1.0f, 1.0f) * size, c + rng.point(-1.0f, 1.0f) * size,
                               c + rng.point(-1.0f, 1.0f) * size, 0, 0};
            if (exactly_degenerate(tri)) continue;
            vec3<float> const n = unit_normal(tri);
            for (int j = 0; j < 4; ++j) {
                float u = rng.uniform(0.0f, 1.0f), v = rng.uniform(0.0f, 1.0f);
                if (u + v > 1.0f) u = 1.0f - u, v = 1.0f - v;
                vec3<float> const target = canopy::surface_point(tri, u, v);
                vec3<float> const o = target + rng.direction() * (4.0f * size);
                record const h = canopy::intersect(ray{o, 0.0f, target - o, inf}, tri);
                if (!h.hit) continue;
                vec3<float> const p = canopy::surface_point(tri, h.u, h.v);
                for (vec3<float> const& d : leaving_directions(rng, n)) {
                    ray const s = canopy::spawn_ray(tri, h.u, h.v, d);
                    ++spawned;
                    if (canopy::closest_hit(s, &tri, &tri + 1).hit) self_hits.add(at + "spawn_ray " + describe(s));
                    if (!clearly_off_surface(d, n)) continue;
                    ray const to = canopy::spawn_ray_to(tri, h.u, h.v, p + d * (3.0f * size));
                    ++spawned;
                    if (canopy::closest_hit(to, &tri, &tri + 1).hit) self_hits.add(at + "spawn_ray_to " + describe(to));
                }
            }
        }

        // Meshes: an icosphere (curved, closed) and a flat grid (coplanar neighbours: a spawned
        // ray must hit none of them), away from the origin and straddling it.
        for (vec3<float> const centre : {vec3<float>{3.0f, -2.0f, 1.0f}, vec3<float>{0.0f, 0.0f, 0.0f}}) {
            auto sphere = canopy::make_icosphere(3, centre * scale, scale);
            auto grid = canopy::make_grid(8, 8);
            for (triangle& t : grid) {
                for (vec3<float>* p : {&t.v0, &t.v1, &t.v2}) *p = (*p - vec3<float>(4.0f, 4.0f, 0.0f) + centre) * scale;
            }
            for (auto const* mesh : {&sphere, &grid}) {
                bool const flat = mesh == &grid;
                mesh_bvh const b = build_bvh(*mesh);
                for (int i = 0; i < per_scale; ++i) {
                    triangle const& aim = (*mesh)[static_cast<std::size_t>(rng.integer(0, int(mesh->size()) - 1))];
                    vec3<float> const target = canopy::surface_point(aim, 0.3f, 0.3f) + rng.point(-0.1f, 0.1f) * scale;
                    vec3<float> const o = target + rng.direction() * (8.0f * scale);
                    record const h = closest(ray{o, 0.0f, target - o, inf}, b);
                    if (!h.hit) continue;
                    triangle const& tri = (*mesh)[h.prim_id];
                    vec3<float> const p = canopy::surface_point(tri, h.u, h.v);
                    vec3<float> const n = unit_normal(tri);
                    for (vec3<float> const& d : leaving_directions(rng, n)) {
                        std::vector<ray> spawned_rays{canopy::spawn_ray(tri, h.u, h.v, d)};
                        if (clearly_off_surface(d, n)) spawned_rays.push_back(canopy::spawn_ray_to(tri, h.u, h.v, p + d * (2.0f * scale)));
                        for (ray const& s : spawned_rays) {
                            ++mesh_spawned;
                            record const again = closest(s, b);
                            std::string const w = at + (flat ? "grid" : "icosphere") + ", leaving prim " +
                                                  std::to_string(h.prim_id) + ", " + describe(s) + " -> " + describe(again);
                            if (again.hit && again.prim_id == h.prim_id) self_hits.add(w);
                            if (flat && again.hit) plane_hits.add(w);
                        }
                    }
                }
            }
        }
    }
    INFO(spawned << " rays spawned from lone triangles, " << mesh_spawned << " from meshes");
    CHECK(spawned > 10'000);
    CHECK(mesh_spawned > 10'000);
    require_no_failures(self_hits, "spawned rays that hit the triangle they leave");
    require_no_failures(plane_hits, "spawned rays that hit the flat grid they leave");
}

// 13 -----------------------------------------------------------------------------------------------

namespace {

struct indexed_mesh {
    std::vector<vec3<float>> vertices;
    std::vector<std::array<std::uint32_t, 3>> faces;
    std::string error; // empty when the file was read
};

// Minimal OBJ reader: "v x y z" and "f i j k ..." lines (1-based or negative indices, "i/t/n"
// forms, polygons split into fans); everything else is ignored.
indexed_mesh parse_obj(std::istream& in) {
    indexed_mesh m;
    std::string line;
    for (std::size_t number = 1; std::getline(in, line); ++number) {
        std::istringstream s(line);
        std::string tag;
        s >> tag;
        if (tag == "v") {
            vec3<float> p;
            if (!(s >> p.x >> p.y >> p.z)) m.error = "line " + std::to_string(number) + ": bad vertex";
            m.vertices.push_back(p);
        } else if (tag == "f") {
            std::vector<std::uint32_t> polygon;
            for (std::string item; s >> item;) {
                long const i = std::strtol(item.c_str(), nullptr, 10);
                long const index = i > 0 ? i - 1 : static_cast<long>(m.vertices.size()) + i;
                if (i == 0 || index < 0 || index >= static_cast<long>(m.vertices.size())) {
                    m.error = "line " + std::to_string(number) + ": bad index " + item;
                    return m;
                }
                polygon.push_back(static_cast<std::uint32_t>(index));
            }
            for (std::size_t k = 1; k + 1 < polygon.size(); ++k) m.faces.push_back({polygon[0], polygon[k], polygon[k + 1]});
        }
        if (!m.error.empty()) return m;
    }
    return m;
}

// Minimal OFF reader: "OFF", the vertex, face and edge counts, the vertices, then faces
// "n i0 ... i(n-1)" (split into fans); '#' starts a comment.
indexed_mesh parse_off(std::istream& in) {
    indexed_mesh m;
    std::stringstream tokens;
    for (std::string line; std::getline(in, line);) tokens << line.substr(0, line.find('#')) << '\n';
    std::string header;
    std::size_t vertex_count = 0, face_count = 0, edge_count = 0;
    if (!(tokens >> header) || header != "OFF" || !(tokens >> vertex_count >> face_count >> edge_count)) {
        m.error = "bad OFF header";
        return m;
    }
    m.vertices.resize(vertex_count);
    for (auto& p : m.vertices)
        if (!(tokens >> p.x >> p.y >> p.z)) {
            m.error = "truncated vertex list";
            return m;
        }
    for (std::size_t f = 0; f < face_count; ++f) {
        std::size_t n = 0;
        tokens >> n;
        std::vector<std::uint32_t> polygon(n);
        for (auto& i : polygon) tokens >> i;
        // Per-face colours, if any, end the line.
        std::string rest;
        std::getline(tokens, rest);
        if (!tokens || n < 3 || std::any_of(polygon.begin(), polygon.end(), [&](std::uint32_t i) { return i >= vertex_count; })) {
            m.error = "bad face " + std::to_string(f);
            return m;
        }
        for (std::size_t k = 1; k + 1 < n; ++k) m.faces.push_back({polygon[0], polygon[k], polygon[k + 1]});
    }
    return m;
}

// One member of a .tar.gz, through the system's tar; empty when it cannot be read.
std::string read_tar_member(std::string const& archive, std::string const& member) {
    std::string const command = "tar -xzOf '" + archive + "' --occurrence=1 '" + member + "' 2>/dev/null";
    FILE* pipe = popen(command.c_str(), "r");
    if (pipe == nullptr) return {};
    std::string out;
    std::array<char, 1 << 16> buffer;
    for (std::size_t n; (n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0;) out.append(buffer.data(), n);
    return pclose(pipe) == 0 ? out : std::string{};
}

// Edges (by vertex index) not shared by exactly two faces.
std::size_t open_edges(indexed_mesh const& m) {
    std::map<std::pair<std::uint32_t, std::uint32_t>, int> uses;
    for (auto const& f : m.faces)
        for (std::size_t k = 0; k < 3; ++k) ++uses[std::minmax(f[k], f[(k + 1) % 3])];
    return static_cast<std::size_t>(std::count_if(uses.begin(), uses.end(), [](auto const& e) { return e.second != 2; }));
}

// Crossings of the ray o + t d (t > 0) with the mesh in double; -1 when the ray passes within
// 1e-9 (barycentric) of an edge or vertex, where the count is not trustworthy.
int crossings(dvec3 const& o, dvec3 const& d, std::vector<triangle> const& tris) {
    int count = 0;
    for (triangle const& t : tris) {
        reference_hit const h = reference_intersect(o, d, dvec3(t.v0), dvec3(t.v1), dvec3(t.v2));
        if (h.t > 0.0 && std::fabs(h.margin) < 1e-9) return -1;
        count += h.hit;
    }
    return count;
}

// Points strictly inside a closed mesh: just inside random triangles (a tenth of the triangle's
// size along the inward normal), kept when three rays in random directions all cross the mesh an
// odd number of times (a point outside crosses every ray an even number of times).
std::vector<vec3<float>> interior_points(random_source& rng, std::vector<triangle> const& tris, int wanted) {
    double volume = 0.0;
    for (triangle const& t : tris) volume += canopy::dot(dvec3(t.v0), canopy::cross(dvec3(t.v1), dvec3(t.v2)));
    double const outward = volume > 0.0 ? 1.0 : -1.0;
    std::vector<vec3<float>> points;
    for (int attempt = 0; attempt < 50 * wanted && static_cast<int>(points.size()) < wanted; ++attempt) {
        triangle const& t = tris[static_cast<std::size_t>(rng.integer(0, int(tris.size()) - 1))];
        dvec3 const n = canopy::cross(dvec3(t.v1) - dvec3(t.v0), dvec3(t.v2) - dvec3(t.v0));
        double const twice_area = canopy::length(n);
        if (!(twice_area > 0.0)) continue;
        dvec3 const centroid = (dvec3(t.v0) + dvec3(t.v1) + dvec3(t.v2)) / 3.0;
        vec3<float> const p(centroid - n * (outward * 0.1 * std::sqrt(twice_area) / twice_area));
        bool inside = true;
        for (int k = 0; k < 3 && inside; ++k) {
            int const c = crossings(dvec3(p), dvec3(rng.direction()), tris);
            inside = c > 0 && c % 2 == 1;
        }
        if (inside) points.push_back(p);
    }
    return points;
}

} // namespace

TEST_CASE("rays from inside real closed meshes never miss (glmark2 bunny, CGAL sample meshes)") {
    struct source {
        std::string name;
        indexed_mesh mesh;
    };
    std::vector<source> sources;

    // glmark2-data: the Stanford bunny as a closed OBJ.
    std::string const bunny = "/usr/share/glmark2/models/bunny.obj";
    {
        INFO(bunny << " is missing: install the Debian package glmark2-data");
        REQUIRE(std::filesystem::exists(bunny));
    }
    std::ifstream bunny_file(bunny);
    sources.push_back({bunny, parse_obj(bunny_file)});

    // libcgal-demo: CGAL's sample meshes, as OFF files inside a tarball.
    std::string const archive = "/usr/share/doc/libcgal-dev/data.tar.gz";
    {
        INFO(archive << " is missing: install the Debian package libcgal-demo");
        REQUIRE(std::filesystem::exists(archive));
    }
    std::vector<std::string> members{"elephant.off", "knot1.off", "femur.off", "fandisk.off"};
    if (full_battery())
        for (char const* m : {"armadillo.off", "bunny00.off", "refined_elephant.off", "bear.off", "camel.off"})
            members.push_back(m);
    for (std::string const& m : members) {
        std::string const member = "data/meshes/" + m;
        std::string const text = read_tar_member(archive, member);
        INFO(member << " could not be read from " << archive << " (package libcgal-demo, and tar on the PATH)");
        REQUIRE(!text.empty());
        std::istringstream in(text);
        sources.push_back({archive + ":" + member, parse_off(in)});
    }

    random_source rng(1301);
    int const points_per_mesh = sized(4, 16);
    int const rays_per_point = sized(1500, 20'000);
    for (source const& s : sources) {
        INFO(s.name);
        REQUIRE(s.mesh.error.empty());
        REQUIRE(s.mesh.faces.size() > 1000);
        // Closed: every edge is shared by exactly two triangles (so every ray from a point of odd
        // parity must hit).
        REQUIRE(open_edges(s.mesh) == 0);
        std::vector<triangle> const tris = canopy::expand_indexed(s.mesh.vertices, s.mesh.faces);
        mesh_bvh const b = build_bvh(tris);
        auto const points = interior_points(rng, tris, points_per_mesh);
        REQUIRE(static_cast<int>(points.size()) == points_per_mesh);

        failure_log misses;
        std::size_t rays = 0;
        for (vec3<float> const& p : points) {
            for (int i = 0; i < rays_per_point; ++i) {
                ray const r{p, 0.0f, rng.direction(), inf};
                ++rays;
                if (!closest(r, b).hit) misses.add(describe(r));
            }
        }
        // Rays aimed at the vertices (every vertex in the full battery) from the first point.
        std::size_t const stride = full_battery() ? 1 : std::max<std::size_t>(1, s.mesh.vertices.size() / 3000);
        for (std::size_t i = 0; i < s.mesh.vertices.size(); i += stride) {
            ray const r{points[0], 0.0f, s.mesh.vertices[i] - points[0], inf};
            ++rays;
            if (!closest(r, b).hit) misses.add("at vertex " + std::to_string(i) + ", " + describe(r));
        }
        INFO(tris.size() << " triangles, " << rays << " rays from " << points.size() << " interior points");
        require_no_failures(misses, "rays from inside that missed");
    }
}

// 14 -----------------------------------------------------------------------------------------------

TEST_CASE("scaling the whole scene by 2^k gives the same triangles, u, v bit for bit and t scaled exactly") {
    random_source rng(1401);
    auto const mesh = concatenate(canopy::make_icosphere(3, {0, 0, 0}, 2.0f), triangle_soup(rng, 300, 4.0f, 1.0f));
    auto const rows = random_rotation_rows(rng);
    auto const rays = random_rays(rng, build_bvh(mesh).bounds(), sized(300, 5000));
    // Instances: identity, translated, rotated with a translation; all translations scale with the scene.
    std::array<transform, 3> const placements{
        transform::identity(), make_transform(no_rotation, {1, 1, 1}, {6.5f, -1.25f, 2.0f}),
        make_transform(rows, {0.75, 1.5, 1.0}, {-5.0f, 3.0f, 1.0f})};

    struct results {
        std::vector<record> flat, instanced;
    };
    auto const trace = [&](int k) {
        float const s = std::ldexp(1.0f, k);
        std::vector<triangle> scaled = mesh;
        for (triangle& t : scaled) t.v0 = t.v0 * s, t.v1 = t.v1 * s, t.v2 = t.v2 * s;
        mesh_bvh const b = build_bvh(scaled);
        std::vector<mesh_instance> instances;
        for (std::size_t i = 0; i < placements.size(); ++i) {
            transform m = placements[i];
            m.translation = m.translation * s;
            instances.emplace_back(b, m, static_cast<std::uint32_t>(i));
        }
        instance_bvh const top = build_bvh(instances);
        results out;
        for (ray r : rays) {
            r.origin = r.origin * s;
            out.flat.push_back(closest(r, b));
            out.instanced.push_back(closest(r, top));
        }
        return out;
    };
    results const reference = trace(0);
    failure_log failures;
    std::size_t hits = 0;
    for (record const& h : reference.flat) hits += h.hit;
    for (int k = -20; k <= 20; ++k) {
        if (k == 0) continue;
        results const scaled = trace(k);
        for (std::size_t i = 0; i < rays.size(); ++i)
            for (auto const& [got, ref, name] : {std::tuple(scaled.flat[i], reference.flat[i], "BVH"),
                                                 std::tuple(scaled.instanced[i], reference.instanced[i], "instanced")}) {
                record expected = ref;
                expected.t = std::ldexp(ref.t, k);
                if (!identical(got, expected))
                    failures.add(std::string(name) + ", k = " + std::to_string(k) + ", " + describe(rays[i]) + ": " +
                                 describe(got) + ", expected " + describe(expected));
            }
    }
    INFO(rays.size() << " rays at 40 scales");
    CHECK(hits > 100);
    require_no_failures(failures, "scene scaled by 2^k changed the hit");
}

// 15 -----------------------------------------------------------------------------------------------

TEST_CASE("rotating the vertex order of every triangle keeps hits and prims, with u, v permuted") {
    random_source rng(1501);
    auto const mesh = concatenate(concatenate(make_dyadic_sphere(3, 12), make_fan({1.0f, -2.0f, 0.5f}, [](float x, float y) {
                                                  return x * 0.5f + y * 0.25f;
                                              })),
                                  triangle_soup(rng, 100, 3.0f, 1.0f));
    auto rotate = [](std::vector<triangle> tris) {
        for (triangle& t : tris) t = {t.v1, t.v2, t.v0, t.prim_id, t.geom_id};
        return tris;
    };
    auto const rotated1 = rotate(mesh), rotated2 = rotate(rotated1);
    mesh_bvh const b = build_bvh(mesh), b1 = build_bvh(rotated1);

    // Rays: from inside the sphere at its vertices and edge midpoints, through the fan's vertices
    // and spokes exactly, and random.
    std::vector<ray> rays;
    mesh_features const f = features_of(mesh);
    for (vec3<float> const& v : f.vertices) rays.push_back({{0, 0, 0}, 0.0f, v, inf});
    for (auto const& e : f.edges) rays.push_back({{0, 0, 0}, 0.0f, e[0] + e[1], inf});
    for (auto const& e : f.edges) {
        vec3<float> const target = (e[0] + e[1]) * 0.5f;
        vec3<float> const o = target + rng.dyadic_point(-6.0f, 6.0f, 3);
        rays.push_back({o, 0.0f, target - o, inf});
    }
    for (ray const& r : random_rays(rng, b.bounds(), sized(1000, 10'000))) rays.push_back(r);

    // u, v of the rotated triangles come from the same edge functions divided by a sum taken in
    // another order: equal within 8 ulps.
    auto const close = [](float a, float b_) {
        return std::fabs(a - b_) <= 8.0f * std::numeric_limits<float>::epsilon() * std::max(std::fabs(a), std::fabs(b_));
    };
    failure_log per_triangle, bvh_failures;
    std::size_t tests = 0, hits = 0, ties = 0;
    for (ray const& r : rays) {
        for (std::size_t i = 0; i < mesh.size(); ++i) {
            record const h0 = canopy::intersect(r, mesh[i]), h1 = canopy::intersect(r, rotated1[i]),
                         h2 = canopy::intersect(r, rotated2[i]);
            ++tests;
            hits += h0.hit;
            if (h0.hit != h1.hit || h0.hit != h2.hit) {
                per_triangle.add("hit/miss differs for prim " + std::to_string(i) + ", " + describe(r));
            } else if (h0.hit && !(close(h0.v, h1.u) && close(h1.v, h2.u) && close(h2.v, h0.u))) {
                per_triangle.add("u, v not permuted for prim " + std::to_string(i) + ", " + describe(r) + ": " +
                                 describe(h0) + " / " + describe(h1) + " / " + describe(h2));
            }
        }
        // Closest hits: same hit/miss, same prim unless another triangle is hit within 8 ulps of t
        // (then rounding of t may pick either).
        record const c0 = closest(r, b), c1 = closest(r, b1);
        if (c0.hit != c1.hit) {
            bvh_failures.add("hit/miss differs, " + describe(r));
        } else if (c0.hit && c0.prim_id != c1.prim_id) {
            auto const all = brute_force_hits(r, mesh);
            bool const tie = all.size() > 1 && all[1].t - all[0].t <= 8.0f * std::numeric_limits<float>::epsilon() * all[0].t;
            ties += tie;
            if (!tie) bvh_failures.add("prim differs, " + describe(r) + ": " + describe(c0) + " / " + describe(c1));
        }
    }
    INFO(rays.size() << " rays, " << tests << " ray/triangle tests, " << hits << " hits, " << ties
                     << " closest hits decided by rounding of tied t");
    CHECK(hits > 5000);
    require_no_failures(per_triangle, "per-triangle results that change with the vertex order");
    require_no_failures(bvh_failures, "closest hits that change with the vertex order");
}

// 16 -----------------------------------------------------------------------------------------------

TEST_CASE("scalar, packet and two-thread tracing give bit-identical results") {
    random_source rng(1601);
    auto const mesh = concatenate(canopy::make_icosphere(3, {0, 0, 0}, 2.0f), triangle_soup(rng, 500, 4.0f, 1.0f));
    instanced_scene const scene(mesh, rng);
    std::vector<ray> rays = random_rays(rng, scene.top.bounds(), sized(4096, 65'536));
    // Some finite tmax, some tmin > 0, some inactive lanes.
    for (std::size_t i = 0; i < rays.size(); ++i) {
        if (i % 5 == 1) rays[i].tmax = rng.uniform(1.0f, 10.0f);
        if (i % 7 == 2) rays[i].tmin = rng.uniform(0.0f, 3.0f);
        if (i % 37 == 3) rays[i].tmin = quiet_nan;
    }

    failure_log failures;
    std::size_t hits = 0;
    auto const check = [&](auto const& structure, char const* name) {
        auto const first = &structure, last = &structure + 1;
        std::vector<record> scalar(rays.size());
        for (std::size_t i = 0; i < rays.size(); ++i) scalar[i] = canopy::closest_hit(rays[i], first, last);
        for (record const& h : scalar) hits += h.hit;

        // Packets of eight.
        for (std::size_t i = 0; i + 8 <= rays.size(); i += 8) {
            std::array<ray, 8> lanes;
            std::copy(rays.begin() + std::ptrdiff_t(i), rays.begin() + std::ptrdiff_t(i + 8), lanes.begin());
            packet_ray const p = pack(lanes);
            packet_record const c = canopy::closest_hit(p, first, last);
            packet_record const a = canopy::any_hit(p, first, last);
            for (int k = 0; k < 8; ++k) {
                record const& s = scalar[i + static_cast<std::size_t>(k)];
                if (!identical(lane_of(c, k), s))
                    failures.add(std::string(name) + " packet closest_hit, " + describe(lanes[static_cast<std::size_t>(k)]) +
                                 ": " + describe(lane_of(c, k)) + ", scalar " + describe(s));
                if (a.hit[k] != s.hit) failures.add(std::string(name) + " packet any_hit, " + describe(lanes[static_cast<std::size_t>(k)]));
            }
        }

        // Two threads, each tracing half of the rays (scalar), and again with packets.
        std::vector<record> threaded(rays.size()), threaded_packets(rays.size());
        auto const work = [&](std::size_t begin, std::size_t end) {
            for (std::size_t i = begin; i < end; ++i) threaded[i] = canopy::closest_hit(rays[i], first, last);
            for (std::size_t i = begin; i + 8 <= end; i += 8) {
                std::array<ray, 8> lanes;
                std::copy(rays.begin() + std::ptrdiff_t(i), rays.begin() + std::ptrdiff_t(i + 8), lanes.begin());
                packet_record const c = canopy::closest_hit(pack(lanes), first, last);
                for (int k = 0; k < 8; ++k) threaded_packets[i + static_cast<std::size_t>(k)] = lane_of(c, k);
            }
        };
        std::size_t const half = rays.size() / 16 * 8;
        std::thread other(work, std::size_t(0), half);
        work(half, rays.size());
        other.join();
        for (std::size_t i = 0; i < rays.size(); ++i) {
            if (!identical(threaded[i], scalar[i])) failures.add(std::string(name) + " threaded, " + describe(rays[i]));
            if (i < rays.size() / 8 * 8 && !identical(threaded_packets[i], scalar[i]))
                failures.add(std::string(name) + " threaded packets, " + describe(rays[i]));
        }
    };
    check(scene.object, "BVH");
    check(scene.top, "instanced BVH");
    INFO(rays.size() << " rays per scene, " << hits << " hits");
    CHECK(hits > rays.size() / 4);
    require_no_failures(failures, "paths that differ from the scalar single-thread results");
}
