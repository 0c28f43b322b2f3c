// The numerical stress battery, instancing part (SPEC §3.8, §4): identity
// instances give bit-identical results to no instance, and instances with power-of-two scales,
// rotations and two levels give the closest hit of a world-space brute force in double precision
// (world-space vertices computed in double from the float transforms, a double ray, a plain
// double Möller–Trumbore test). The rest of the battery is in stress_test.cpp.
//
// The default sizes run in a second or so; the full battery runs with
//     CANOPY_STRESS_FULL=1 ctest -R stress --output-on-failure
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

import canopy.query;
import canopy.procedural;
import canopy.testing;

namespace {

using namespace stress_support;
using nested_instance = canopy::instance<instance_bvh>;
using nested_bvh = canopy::bvh<nested_instance>;

constexpr std::uint32_t invalid = canopy::invalid_id;

template <typename Structure>
record closest(ray const& r, Structure const& s) {
    return canopy::closest_hit(r, &s, &s + 1);
}

// An icosphere and a few small triangles around it, prim_id = position.
std::vector<triangle> object_mesh(random_source& rng) {
    auto mesh = canopy::make_icosphere(2, {0.0f, 0.0f, 0.0f}, 1.0f);
    for (int i = 0; i < 40; ++i) {
        vec3<float> const c = rng.point(-1.5f, 1.5f);
        mesh.push_back({c + rng.point(-0.3f, 0.3f), c + rng.point(-0.3f, 0.3f), c + rng.point(-0.3f, 0.3f), 0, 0});
    }
    for (std::size_t i = 0; i < mesh.size(); ++i) mesh[i].prim_id = static_cast<std::uint32_t>(i);
    return mesh;
}

// The float transform applied in double.
dvec3 apply(transform const& m, dvec3 const& p) {
    return dvec3(m.linear.col0) * p.x + dvec3(m.linear.col1) * p.y + dvec3(m.linear.col2) * p.z + dvec3(m.translation);
}

// A triangle of the scene in world space (double), with the ids its hit reports.
struct world_triangle {
    std::array<dvec3, 3> v;
    std::uint32_t prim_id, inst_id, inner_id;
};

void append_world(std::vector<world_triangle>& out, std::vector<triangle> const& mesh, std::uint32_t inst_id,
                  std::uint32_t inner_id, transform const& inner, transform const* outer) {
    for (triangle const& t : mesh) {
        world_triangle w{{dvec3(t.v0), dvec3(t.v1), dvec3(t.v2)}, t.prim_id, inst_id, inner_id};
        for (dvec3& p : w.v) {
            p = apply(inner, p);
            if (outer != nullptr) p = apply(*outer, p);
        }
        out.push_back(w);
    }
}

// A plain double-precision ray/triangle test (Möller–Trumbore); margin is the smallest
// barycentric weight (negative outside, near zero close to an edge) times |cos| of the angle
// between the ray and the normal: a grazing ray moves its hit point along the plane by the
// rounding error of the ray divided by that cosine.
struct reference_hit {
    bool hit = false;
    double t = std::numeric_limits<double>::infinity();
    double margin = -1.0;
};

reference_hit reference_intersect(dvec3 const& o, dvec3 const& d, std::array<dvec3, 3> const& v) {
    dvec3 const e1 = v[1] - v[0], e2 = v[2] - v[0];
    dvec3 const p = canopy::cross(d, e2);
    double const det = canopy::dot(e1, p);
    if (det == 0.0) return {};
    dvec3 const s = o - v[0];
    double const u = canopy::dot(s, p) / det;
    dvec3 const q = canopy::cross(s, e1);
    double const w = canopy::dot(d, q) / det;
    double const t = canopy::dot(e2, q) / det;
    double const cosine = std::fabs(canopy::dot(canopy::normalize(d), canopy::normalize(canopy::cross(e1, e2))));
    double const margin = std::min({u, w, 1.0 - u - w});
    return {margin >= 0.0 && t > 0.0, t, margin * cosine};
}

// Rays within this margin (barycentric, times the cosine above) of an edge of a triangle in front
// of the closest hit, or whose two closest hits are within this relative distance, are not
// compared: rounding may legitimately decide them either way.
constexpr double edge_margin = 1e-4;
constexpr double tie_margin = 1e-5;
// The hit point's error across the triangle's plane, |t - t_ref| |d . n|, relative to the largest
// coordinate magnitude involved (origin or hit point): the float object-space ray carries a few
// rounding errors of the inverse transform. Bound 2^-18 (about 32 ulps).
constexpr double t_bound = 0x1p-18;

struct reference_comparison {
    std::size_t rays = 0, hits = 0, skipped = 0;
    double max_plane_error = 0.0;
    failure_log failures;
};

void compare_with_world(ray const& r, record const& got, std::vector<world_triangle> const& world,
                        reference_comparison& c) {
    ++c.rays;
    dvec3 const o(r.origin), d(r.direction);
    std::vector<std::pair<reference_hit, world_triangle const*>> candidates;
    reference_hit best;
    world_triangle const* best_tri = nullptr;
    double second = std::numeric_limits<double>::infinity();
    for (world_triangle const& w : world) {
        reference_hit const h = reference_intersect(o, d, w.v);
        if (!(h.t > 0.0)) continue;
        if (std::fabs(h.margin) < edge_margin) candidates.push_back({h, &w});
        if (!h.hit) continue;
        if (h.t < best.t) {
            second = best.t;
            best = h;
            best_tri = &w;
        } else if (h.t < second) {
            second = h.t;
        }
    }
    bool ambiguous = best.hit && second <= best.t * (1.0 + tie_margin);
    for (auto const& [h, w] : candidates) ambiguous = ambiguous || h.t <= best.t * (1.0 + tie_margin);
    if (ambiguous) {
        ++c.skipped;
        return;
    }
    c.hits += best.hit;
    std::string const w = describe(r) + ": " + describe(got);
    if (got.hit != best.hit) {
        c.failures.add(w + (best.hit ? ", reference hits" : ", reference misses"));
        return;
    }
    if (!best.hit) return;
    if (got.prim_id != best_tri->prim_id || got.inst_id != best_tri->inst_id || got.inner_inst_id[0] != best_tri->inner_id) {
        c.failures.add(w + ", reference prim " + std::to_string(best_tri->prim_id) + " inst " +
                       std::to_string(best_tri->inst_id) + " inner " + std::to_string(best_tri->inner_id));
        return;
    }
    // The hit point's error across the plane, relative to the size of the coordinates involved.
    auto const& v = best_tri->v;
    dvec3 const n = canopy::normalize(canopy::cross(v[1] - v[0], v[2] - v[0]));
    double const scale = std::max(canopy::length(o), canopy::length(o + d * best.t));
    double const error = std::fabs(static_cast<double>(got.t) - best.t) * std::fabs(canopy::dot(d, n)) / scale;
    c.max_plane_error = std::max(c.max_plane_error, error);
    if (error > t_bound) c.failures.add(w + ", reference t " + std::to_string(best.t));
}

// Rays towards random points of random world triangles, from 20 to 80 units away.
std::vector<ray> rays_at(random_source& rng, std::vector<world_triangle> const& world, int count) {
    std::vector<ray> rays;
    for (int i = 0; i < count; ++i) {
        world_triangle const& w = world[static_cast<std::size_t>(rng.integer(0, int(world.size()) - 1))];
        double u = rng.uniform_double(0, 1), v = rng.uniform_double(0, 1);
        if (u + v > 1) u = 1 - u, v = 1 - v;
        vec3<float> const target(w.v[0] * (1 - u - v) + w.v[1] * u + w.v[2] * v);
        vec3<float> const origin = target + rng.direction() * rng.uniform(20.0f, 80.0f);
        rays.push_back({origin, 0.0f, target - origin, inf});
    }
    return rays;
}

void require_agreement(reference_comparison const& c) {
    INFO(c.rays << " rays, " << c.hits << " compared hits, " << c.skipped << " skipped within " << edge_margin
                << " of an edge or " << tie_margin << " of a tie; largest hit-point error across the plane " << c.max_plane_error
                << " (bound " << t_bound << ")");
    CHECK(c.hits > c.rays / 2);
    CHECK(c.skipped < c.rays / 20);
    require_no_failures(c.failures, "closest hits that differ from the world-space double-precision brute force");
}

} // namespace

TEST_CASE("an identity instance gives bit-identical results to no instance, at one and two levels") {
    random_source rng(1201);
    auto const mesh = object_mesh(rng);
    mesh_bvh const b = build_bvh(mesh);
    // The identity, and the identity written with -0 entries.
    std::vector<mesh_instance> const one{mesh_instance(b, transform::identity(), 9)};
    std::vector<mesh_instance> const negative_zeros{
        mesh_instance(b, transform::from_rows({1, -0.0f, 0, -0.0f, 0, 1, -0.0f, 0, -0.0f, 0, 1, -0.0f}), 4)};
    instance_bvh const level1 = build_bvh(one);
    instance_bvh const level1_zeros = build_bvh(negative_zeros);
    std::vector<nested_instance> const outer{nested_instance(level1, transform::identity(), 2)};
    nested_bvh const level2 = build_bvh(outer);

    std::vector<ray> rays;
    for (int i = 0; i < sized(2000, 50'000); ++i) {
        vec3<float> const o = rng.point(-4.0f, 4.0f);
        rays.push_back({o, 0.0f, rng.point(-1.5f, 1.5f) - o, inf});
    }
    // Through the icosphere's vertices: ties between triangles.
    for (std::size_t i = 0; i < 320; ++i) rays.push_back({mesh[i].v0 * 3.0f, 0.0f, mesh[i].v0 * -2.0f, inf});

    failure_log failures;
    std::size_t hits = 0;
    auto const expect = [&](record got, std::uint32_t inst, std::uint32_t inner, record const& bare, ray const& r,
                            char const* path) {
        bool const ids = !got.hit || (got.inst_id == inst && got.inner_inst_id[0] == inner);
        got.inst_id = invalid;
        got.inner_inst_id[0] = invalid;
        if (!ids || !identical(got, bare)) failures.add(std::string(path) + ", " + describe(r) + ": " + describe(got) + ", bare " + describe(bare));
    };
    for (ray const& r : rays) {
        record const bare = closest(r, b);
        hits += bare.hit;
        expect(closest(r, one[0]), 9, invalid, bare, r, "instance");
        expect(closest(r, level1), 9, invalid, bare, r, "BVH of an identity instance");
        expect(closest(r, level1_zeros), 4, invalid, bare, r, "identity with -0 entries");
        expect(closest(r, level2), 2, 9, bare, r, "two identity levels");
        auto const bare_multi = canopy::multi_hit<8>(r, &b, &b + 1);
        auto const multi = canopy::multi_hit<8>(r, &level2, &level2 + 1);
        for (std::size_t k = 0; k < 8; ++k) expect(multi[k], 2, 9, bare_multi[k], r, "multi_hit through two identity levels");
        if (canopy::any_hit(r, &level2, &level2 + 1).hit != bare.hit) failures.add("any_hit, " + describe(r));
    }
    // Packets through the identity levels.
    for (std::size_t i = 0; i + 8 <= rays.size(); i += 8) {
        packet_ray p;
        for (int k = 0; k < 8; ++k) {
            ray const& r = rays[i + static_cast<std::size_t>(k)];
            canopy::set_lane(p.origin, k, r.origin);
            canopy::set_lane(p.direction, k, r.direction);
            p.tmin.set(k, r.tmin);
            p.tmax.set(k, r.tmax);
        }
        packet_record const c = canopy::closest_hit(p, &level2, &level2 + 1);
        for (int k = 0; k < 8; ++k) {
            record got;
            got.hit = c.hit[k];
            got.t = c.t[k], got.u = c.u[k], got.v = c.v[k];
            got.prim_id = static_cast<std::uint32_t>(c.prim_id[k]);
            got.geom_id = static_cast<std::uint32_t>(c.geom_id[k]);
            got.inst_id = static_cast<std::uint32_t>(c.inst_id[k]);
            got.inner_inst_id[0] = static_cast<std::uint32_t>(c.inner_inst_id[0][k]);
            ray const& r = rays[i + static_cast<std::size_t>(k)];
            expect(got, 2, 9, closest(r, b), r, "packet through two identity levels");
        }
    }
    INFO(rays.size() << " rays, " << hits << " hits");
    CHECK(hits > rays.size() / 3);
    require_no_failures(failures, "identity instances that change a result");
}

namespace {

// Sixteen instances of one random mesh, instance i placed by place(i) with id first_id + i: the
// closest hits of rays at the world's triangles are those of a world-space brute force in double.
template <typename Place>
void check_sixteen_instances(random_source& rng, std::uint32_t first_id, Place&& place) {
    auto const mesh = object_mesh(rng);
    mesh_bvh const b = build_bvh(mesh);
    std::vector<mesh_instance> instances;
    std::vector<world_triangle> world;
    for (std::uint32_t i = 0; i < 16; ++i) {
        transform const m = place(i);
        instances.emplace_back(b, m, first_id + i);
        append_world(world, mesh, first_id + i, invalid, m, nullptr);
    }
    instance_bvh const top = build_bvh(instances);
    reference_comparison c;
    for (ray const& r : rays_at(rng, world, sized(1500, 20'000))) compare_with_world(r, closest(r, top), world, c);
    require_agreement(c);
}

} // namespace

TEST_CASE("instances scaled by 2^k give the closest hit of a world-space brute force in double") {
    random_source rng(1202);
    check_sixteen_instances(rng, 100, [&](std::uint32_t i) {
        // Uniform 2^k, k in [-6, 6], or a different power of two per axis, k in [-4, 4].
        int const k = rng.integer(-6, 6);
        dvec3 const scale = i % 2 == 0 ? dvec3(std::ldexp(1.0, k))
                                       : dvec3(std::ldexp(1.0, rng.integer(-4, 4)), std::ldexp(1.0, rng.integer(-4, 4)),
                                               std::ldexp(1.0, rng.integer(-4, 4)));
        return make_transform(no_rotation, scale, rng.point(-40.0f, 40.0f));
    });
}

TEST_CASE("rotated and scaled instances give the closest hit of a world-space brute force in double") {
    random_source rng(1203);
    check_sixteen_instances(rng, 200, [&](std::uint32_t i) {
        double const s = rng.uniform_double(0.5, 2.0);
        dvec3 const scale = i % 2 == 0 ? dvec3(s) : dvec3(s, rng.uniform_double(0.5, 2.0), rng.uniform_double(0.5, 2.0));
        return make_transform(random_rotation_rows(rng), scale, rng.point(-30.0f, 30.0f));
    });
}

TEST_CASE("two levels of rotated, scaled instances give the closest hit of a world-space brute force in double") {
    random_source rng(1204);
    auto const mesh = object_mesh(rng);
    mesh_bvh const b = build_bvh(mesh);
    std::vector<mesh_instance> inner;
    std::vector<transform> inner_transforms;
    for (std::uint32_t i = 0; i < 4; ++i) {
        dvec3 const scale = i == 0 ? dvec3(0.5) : dvec3(rng.uniform_double(0.5, 2.0));
        inner_transforms.push_back(make_transform(random_rotation_rows(rng), scale, rng.point(-5.0f, 5.0f)));
        inner.emplace_back(b, inner_transforms.back(), 10 + i);
    }
    instance_bvh const middle = build_bvh(inner);
    std::vector<nested_instance> outer;
    std::vector<world_triangle> world;
    for (std::uint32_t j = 0; j < 4; ++j) {
        dvec3 const scale = j == 0 ? dvec3(4.0) : dvec3(rng.uniform_double(0.5, 2.0));
        transform const m = make_transform(random_rotation_rows(rng), scale, rng.point(-30.0f, 30.0f));
        outer.emplace_back(middle, m, 20 + j);
        for (std::uint32_t i = 0; i < 4; ++i) append_world(world, mesh, 20 + j, 10 + i, inner_transforms[i], &m);
    }
    nested_bvh const top = build_bvh(outer);
    reference_comparison c;
    for (ray const& r : rays_at(rng, world, sized(1500, 20'000))) compare_with_world(r, closest(r, top), world, c);
    require_agreement(c);
}
