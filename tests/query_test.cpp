// Tests of canopy.query: closest_hit, any_hit and multi_hit<N> through BVHs, ranges of BVHs and
// nested instances, with and without custom intersectors, for scalar and packet rays. The
// reference is always a plain loop over every primitive (in world space for instanced scenes).
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <random>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

import canopy.query;
import canopy.testing;

namespace {

using canopy::ray;
using canopy::sphere;
using canopy::triangle;
using canopy::vec3;
using float8 = canopy::simd::float8;
using test_support::mesh_bvh;
using test_support::mesh_instance;
using test_support::three_level;
using test_support::two_level;
using test_support::two_level_instance;
using record = canopy::hit_record<ray, triangle>;

using test_support::checkerboard_opaque;
using test_support::make_ray;
using test_support::pack;
using test_support::random_rays;
using test_support::random_source;
using test_support::random_transform;
using test_support::triangle_soup;

constexpr float inf = std::numeric_limits<float>::infinity();
constexpr std::uint32_t invalid = canopy::invalid_id;

// Rays from around the box towards points near the targets (instanced scenes are sparse: aiming
// at their triangles makes most rays hit).
std::vector<ray> rays_towards(random_source& rng, canopy::aabb const& bounds, std::vector<vec3<float>> const& targets,
                              int count) {
    vec3<float> const c = (bounds.min + bounds.max) * 0.5f;
    float const r = canopy::length(bounds.max - bounds.min);
    std::vector<ray> rays;
    for (int i = 0; i < count; ++i) {
        vec3<float> const origin = c + rng.point(-r, r);
        vec3<float> const target = targets[std::size_t(rng.integer(0, int(targets.size()) - 1))] + rng.point(-0.2f, 0.2f);
        rays.push_back(make_ray(origin, target - origin));
    }
    return rays;
}

template <typename F>
auto bits(F x) {
    return std::bit_cast<std::conditional_t<sizeof(F) == 4, std::uint32_t, std::uint64_t>>(x);
}

// The reference order: t, then (inst_id, inner_inst_id…, prim_id).
template <typename H>
bool reference_precedes(H const& a, H const& b) {
    return std::tuple(a.t, a.inst_id, a.inner_inst_id[0], a.inner_inst_id[1], a.inner_inst_id[2], a.prim_id) <
           std::tuple(b.t, b.inst_id, b.inner_inst_id[0], b.inner_inst_id[1], b.inner_inst_id[2], b.prim_id);
}

template <typename H>
bool same_record(H const& a, H const& b) {
    if (a.hit != b.hit) return false;
    if (!a.hit) return bits(a.t) == bits(b.t);
    return bits(a.t) == bits(b.t) && bits(a.u) == bits(b.u) && bits(a.v) == bits(b.v) && a.prim_id == b.prim_id &&
           a.geom_id == b.geom_id && a.inst_id == b.inst_id && a.inner_inst_id == b.inner_inst_id;
}

// Every hit a plain loop over the primitives finds, in the reference order.
template <typename Ray, typename Prims, typename Test>
auto brute_force_hits(Ray const& r, Prims const& prims, Test test) {
    std::vector<decltype(test(r, prims[0]))> hits;
    for (auto const& p : prims) {
        auto const hr = test(r, p);
        if (hr.hit) hits.push_back(hr);
    }
    std::sort(hits.begin(), hits.end(), [](auto const& a, auto const& b) { return reference_precedes(a, b); });
    return hits;
}

auto const library_test = [](auto const& r, auto const& prim) { return canopy::intersect(r, prim); };

// closest_hit, any_hit and multi_hit<1, 4, 16> over [first, last) against the brute-force hits.
struct query_agreement {
    int rays = 0, hits = 0, closest_mismatches = 0, any_mismatches = 0, multi_mismatches = 0;
};

template <typename Ray, typename It, typename Hits, typename MakeIsect>
void compare_queries(Ray const& r, It first, It last, Hits const& expected, MakeIsect make_isect, query_agreement& out) {
    ++out.rays;
    out.hits += !expected.empty();
    auto const closest = canopy::closest_hit(r, first, last, make_isect());
    bool const closest_ok = expected.empty() ? !closest.hit && closest.t == inf : same_record(closest, expected[0]);
    out.closest_mismatches += !closest_ok;

    // any_hit: a hit iff one exists, and then one of the genuine hits.
    auto const any = canopy::any_hit(r, first, last, make_isect());
    bool any_ok = any.hit == !expected.empty();
    if (any.hit)
        any_ok = any_ok && std::any_of(expected.begin(), expected.end(), [&](auto const& e) { return same_record(any, e); });
    out.any_mismatches += !any_ok;

    auto const multi_ok = [&](auto const& got) {
        for (std::size_t i = 0; i < got.size(); ++i) {
            if (i < expected.size() ? !same_record(got[i], expected[i]) : got[i].hit) return false;
        }
        return true;
    };
    bool const multi = multi_ok(canopy::multi_hit<1>(r, first, last, make_isect())) &&
                       multi_ok(canopy::multi_hit<4>(r, first, last, make_isect())) &&
                       multi_ok(canopy::multi_hit<16>(r, first, last, make_isect()));
    out.multi_mismatches += !multi;
}

void require_agreement(query_agreement const& a, int min_hits) {
    INFO(a.rays << " rays, " << a.hits << " with hits");
    CHECK(a.hits >= min_hits);
    CHECK(a.closest_mismatches == 0);
    CHECK(a.any_mismatches == 0);
    CHECK(a.multi_mismatches == 0);
}

struct alpha_mask : canopy::basic_intersector<alpha_mask> {
    using canopy::basic_intersector<alpha_mask>::operator();
    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) {
        auto hr = intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        return hr;
    }
};

} // namespace

TEST_CASE("closest_hit, any_hit and multi_hit through a BVH equal brute force on a triangle soup") {
    random_source rng(101);
    auto const soup = triangle_soup(rng, 3000, 10.0f, 1.0f);
    for (canopy::bvh_build_options const options :
         {canopy::bvh_build_options{}, canopy::bvh_build_options{.max_leaf_size = 1, .bins = 4}}) {
        mesh_bvh const b = canopy::build_binned_sah(soup, options);
        query_agreement via_bvh, via_range;
        for (ray const& r : random_rays(rng, b.bounds(), 1500)) {
            auto const expected = brute_force_hits(r, soup, library_test);
            compare_queries(r, &b, &b + 1, expected, [] { return canopy::default_intersector{}; }, via_bvh);
            CHECK(same_record(canopy::intersect(r, b), canopy::closest_hit(r, &b, &b + 1)));
            if (via_range.rays < 200)
                compare_queries(r, soup.begin(), soup.end(), expected, [] { return canopy::default_intersector{}; }, via_range);
        }
        require_agreement(via_bvh, 600);
        require_agreement(via_range, 50);
    }
}

TEST_CASE("queries through a BVH of spheres equal brute force") {
    random_source rng(102);
    std::vector<sphere> spheres;
    for (int i = 0; i < 2000; ++i)
        spheres.push_back({rng.point(-10, 10), rng.uniform(0.05f, 0.8f), std::uint32_t(i), std::uint32_t(i % 4)});
    auto const b = canopy::build_binned_sah(spheres);
    query_agreement agreement;
    for (ray const& r : random_rays(rng, b.bounds(), 1500)) {
        compare_queries(r, &b, &b + 1, brute_force_hits(r, spheres, library_test),
                        [] { return canopy::default_intersector{}; }, agreement);
    }
    require_agreement(agreement, 600);
}

TEST_CASE("equal t: the smaller prim_id wins, and multi_hit lists duplicates in id order") {
    random_source rng(103);
    auto soup = triangle_soup(rng, 800, 8.0f, 1.0f);
    // Exact duplicates of every other triangle, later in the input (larger prim_id).
    for (std::size_t i = 0; i < 800; i += 2) {
        triangle copy = soup[i];
        copy.prim_id = std::uint32_t(soup.size());
        soup.push_back(copy);
    }
    mesh_bvh const b = canopy::build_binned_sah(soup, {.max_leaf_size = 2});
    query_agreement agreement;
    int ties = 0;
    for (ray const& r : random_rays(rng, b.bounds(), 1500)) {
        auto const expected = brute_force_hits(r, soup, library_test);
        ties += expected.size() >= 2 && expected[0].t == expected[1].t;
        compare_queries(r, &b, &b + 1, expected, [] { return canopy::default_intersector{}; }, agreement);
    }
    CHECK(ties > 200);
    require_agreement(agreement, 500);
}

// Drops the candidates whose prim_id is a multiple of 3 (a filter: it sees the library's candidates).
struct every_third_dropped : canopy::basic_intersector<every_third_dropped> {
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) const {
        return hr.prim_id % 3 != 0;
    }
};

TEST_CASE("rays through a vertex where a fan of triangles meets: the first in (t, prim_id) order, with and without a filter") {
    // Three fans of 64 triangles around the vertices c (a disk in a plane, a cone, a flat fan with
    // every triangle given twice: exact ties), in shuffled order, so that the tied lanes of a block
    // are not in id order. Rays from random origins through c: every triangle of the fan is a candidate at
    // nearly or exactly the same t, and the closest hit is the first of them in (t, prim_id) order.
    random_source rng(111);
    std::vector<triangle> fans;
    auto const add = [&](vec3<float> a, vec3<float> b, vec3<float> c) {
        fans.push_back({a, b, c, std::uint32_t(fans.size()), 0});
    };
    std::vector<vec3<float>> const centres{{0.0f, 0.0f, 0.0f}, {3.0f, 1.0f, -2.0f}, {-2.5f, 0.5f, 1.5f}};
    for (int fan = 0; fan < 3; ++fan) {
        vec3<float> const c = centres[std::size_t(fan)];
        for (int i = 0; i < 64; ++i) {
            auto const rim = [&](int k) {
                double const angle = 2.0 * 3.14159265358979 * double(k % 64) / 64.0;
                float const height = fan == 1 ? 0.75f : 0.0f; // the cone's rim below its apex
                return c + vec3<float>(float(std::cos(angle)), -height, float(std::sin(angle)));
            };
            add(c, rim(i), rim(i + 1));
            if (fan == 2) add(rim(i + 1), c, rim(i)); // the same triangle again, its corners rotated
        }
    }
    // Shuffled, then numbered as the builder numbers them (prim_id = input index).
    std::shuffle(fans.begin(), fans.end(), std::mt19937(5));
    for (std::uint32_t i = 0; i < fans.size(); ++i) fans[i].prim_id = i;
    auto const dropped_test = [](ray const& r, triangle const& tri) {
        auto hr = canopy::intersect(r, tri);
        if (hr.hit) hr.hit = tri.prim_id % 3 != 0;
        return hr;
    };
    for (canopy::bvh_build_options const options :
         {canopy::bvh_build_options{}, canopy::bvh_build_options{.quality = canopy::build_quality::high}}) {
        mesh_bvh const b = canopy::build_binned_sah(fans, options);
        query_agreement plain, filtered;
        int crowded = 0; // rays with 8 or more candidates within 1e-5 relative of the nearest t
        for (int k = 0; k < 600; ++k) {
            vec3<float> const c = centres[std::size_t(k % 3)];
            vec3<float> const o = c + rng.point(-4.0f, 4.0f);
            ray const r = make_ray(o, c - o);
            auto const expected = brute_force_hits(r, fans, library_test);
            crowded += expected.size() >= 8 && expected[7].t <= expected[0].t * 1.00001f;
            compare_queries(r, &b, &b + 1, expected, [] { return canopy::default_intersector{}; }, plain);
            compare_queries(r, &b, &b + 1, brute_force_hits(r, fans, dropped_test),
                            [] { return every_third_dropped{}; }, filtered);
        }
        CHECK(crowded > 100);
        require_agreement(plain, 300);
        require_agreement(filtered, 300);
    }
}

TEST_CASE("an alpha-mask intersector gives the brute-force results with the same rule") {
    random_source rng(104);
    auto const soup = triangle_soup(rng, 2000, 8.0f, 1.5f);
    mesh_bvh const b = canopy::build_binned_sah(soup);
    auto const masked_test = [](ray const& r, triangle const& tri) {
        auto hr = canopy::intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        return hr;
    };
    query_agreement agreement;
    int culled = 0;
    for (ray const& r : random_rays(rng, b.bounds(), 1500)) {
        auto const expected = brute_force_hits(r, soup, masked_test);
        culled += brute_force_hits(r, soup, library_test).size() > expected.size();
        compare_queries(r, &b, &b + 1, expected, [] { return alpha_mask{}; }, agreement);
    }
    CHECK(culled > 300);
    require_agreement(agreement, 500);
}

TEST_CASE("a range of several BVHs (multiple roots) equals one BVH over their union") {
    random_source rng(105);
    auto soup = triangle_soup(rng, 2400, 10.0f, 1.0f);
    std::array<std::size_t, 4> const offsets{0, 500, 1600, 2400};
    std::vector<mesh_bvh> parts;
    for (std::size_t k = 0; k < 3; ++k) {
        for (std::size_t i = offsets[k]; i < offsets[k + 1]; ++i) soup[i].geom_id = std::uint32_t(k);
        parts.push_back(canopy::build_binned_sah(
            std::vector<triangle>(soup.begin() + std::ptrdiff_t(offsets[k]), soup.begin() + std::ptrdiff_t(offsets[k + 1]))));
    }
    mesh_bvh const whole = canopy::build_binned_sah(soup);
    auto const roots = canopy::build_binned_sah(parts);   // a BVH over the BVHs
    // A part's (geom_id, local prim_id) names the union's triangle offsets[geom_id] + prim_id.
    auto const global = [&](record hr) {
        if (hr.hit) hr.prim_id += std::uint32_t(offsets[hr.geom_id]);
        return hr;
    };
    int hits = 0, mismatches = 0, any_mismatches = 0, multi_mismatches = 0;
    for (ray const& r : random_rays(rng, whole.bounds(), 1500)) {
        auto const expected = canopy::closest_hit(r, &whole, &whole + 1);
        hits += expected.hit;
        mismatches += !same_record(global(canopy::closest_hit(r, parts.begin(), parts.end())), expected);
        mismatches += !same_record(global(canopy::closest_hit(r, &roots, &roots + 1)), expected);
        any_mismatches += canopy::any_hit(r, parts.begin(), parts.end()).hit != expected.hit;
        any_mismatches += canopy::any_hit(r, &roots, &roots + 1).hit != expected.hit;
        auto const m_parts = canopy::multi_hit<4>(r, parts.begin(), parts.end());
        auto const m_whole = canopy::multi_hit<4>(r, &whole, &whole + 1);
        for (std::size_t i = 0; i < 4; ++i) {
            multi_mismatches += !(m_parts[i].hit == m_whole[i].hit && bits(m_parts[i].t) == bits(m_whole[i].t) &&
                                  global(m_parts[i]).prim_id == m_whole[i].prim_id);
        }
    }
    CHECK(hits > 600);
    CHECK(mismatches == 0);
    CHECK(any_mismatches == 0);
    CHECK(multi_mismatches == 0);
}

TEST_CASE("double-precision BVHs and rays equal brute force") {
    random_source rng(106);
    std::vector<canopy::basic_triangle<double>> soup;
    for (triangle const& t : triangle_soup(rng, 1500, 10.0f, 1.0f))
        soup.push_back({vec3<double>(t.v0), vec3<double>(t.v1), vec3<double>(t.v2), t.prim_id, t.geom_id});
    auto const b = canopy::build_binned_sah(soup);
    query_agreement agreement;
    for (ray const& rf : random_rays(rng, canopy::aabb{{-10, -10, -10}, {10, 10, 10}}, 1000)) {
        canopy::basic_ray<double> const r{vec3<double>(rf.origin), 0.0, vec3<double>(rf.direction),
                                          std::numeric_limits<double>::infinity()};
        auto const expected = brute_force_hits(r, soup, library_test);
        ++agreement.rays;
        agreement.hits += !expected.empty();
        auto const closest = canopy::closest_hit(r, &b, &b + 1);
        agreement.closest_mismatches += expected.empty() ? closest.hit : !same_record(closest, expected[0]);
        agreement.any_mismatches += canopy::any_hit(r, &b, &b + 1).hit == expected.empty();
        auto const multi = canopy::multi_hit<4>(r, &b, &b + 1);
        for (std::size_t i = 0; i < 4; ++i)
            agreement.multi_mismatches += i < expected.size() ? !same_record(multi[i], expected[i]) : multi[i].hit;
    }
    require_agreement(agreement, 400);
}

// ---------------------------------------------------------------------------------------------
// Instanced scenes with exactly representable transforms (power-of-two uniform scales, dyadic
// translations, dyadic vertices): object-space rays are exact, so the world-space brute force in
// float gives bit-identical hits.

namespace {

struct world_triangle {
    triangle tri;   // world-space vertices; prim_id/geom_id of the object-space triangle
    std::uint32_t inst_id = invalid;
    std::uint32_t inner_inst_id = invalid;
};

// Brute-force test of one world triangle, stamped with its instance chain.
template <typename Test>
auto stamped(Test test) {
    return [test](ray const& r, world_triangle const& w) {
        auto hr = test(r, w.tri);
        hr.inst_id = w.inst_id;
        hr.inner_inst_id[0] = w.inner_inst_id;
        return hr;
    };
}

vec3<float> scale_translate(vec3<float> p, float s, vec3<float> t) { return p * s + t; }

struct exact_scene {
    std::vector<std::vector<triangle>> soups;
    std::vector<mesh_bvh> meshes;
    std::vector<mesh_instance> level1;
    two_level middle;
    std::vector<two_level_instance> level2;
    three_level top;
    std::vector<world_triangle> world2, world3;   // world-space triangles of middle and of top
    std::vector<std::pair<float, vec3<float>>> xf1, xf2;

    explicit exact_scene(std::uint32_t seed) {
        random_source rng(seed);
        for (int m = 0; m < 2; ++m) {
            std::vector<triangle> soup;
            for (int i = 0; i < 150; ++i) {
                vec3<float> const c = rng.dyadic_point(-1, 1, 12);
                soup.push_back({c + rng.dyadic_point(-0.4f, 0.4f, 12), c + rng.dyadic_point(-0.4f, 0.4f, 12),
                                c + rng.dyadic_point(-0.4f, 0.4f, 12), std::uint32_t(i), std::uint32_t(m)});
            }
            soups.push_back(soup);
        }
        for (auto const& soup : soups) meshes.push_back(canopy::build_binned_sah(soup));
        std::array<float, 3> const scales{0.5f, 1.0f, 2.0f};
        for (std::uint32_t k = 0; k < 6; ++k) {
            float const s = scales[std::size_t(rng.integer(0, 2))];
            vec3<float> const t = rng.dyadic_point(-6, 6, 4);
            xf1.emplace_back(s, t);
            level1.emplace_back(meshes[k % 2], canopy::affine_transform<float>::from_rows({s, 0, 0, t.x, 0, s, 0, t.y, 0, 0, s, t.z}), 10 + k);
        }
        middle = canopy::build_binned_sah(level1);
        for (std::uint32_t j = 0; j < 3; ++j) {
            float const s = scales[std::size_t(rng.integer(0, 2))];
            vec3<float> const t = rng.dyadic_point(-8, 8, 4);
            xf2.emplace_back(s, t);
            level2.emplace_back(middle, canopy::affine_transform<float>::from_rows({s, 0, 0, t.x, 0, s, 0, t.y, 0, 0, s, t.z}), 100 + j);
        }
        top = canopy::build_binned_sah(level2);
        // World geometry from the inputs (each step exact).
        for (std::uint32_t k = 0; k < 6; ++k) {
            for (triangle tri : soups[k % 2]) {
                auto const [s, t] = xf1[k];
                tri.v0 = scale_translate(tri.v0, s, t);
                tri.v1 = scale_translate(tri.v1, s, t);
                tri.v2 = scale_translate(tri.v2, s, t);
                world2.push_back({tri, 10 + k, invalid});
            }
        }
        for (std::uint32_t j = 0; j < 3; ++j) {
            for (world_triangle w : world2) {
                auto const [s, t] = xf2[j];
                w.tri.v0 = scale_translate(w.tri.v0, s, t);
                w.tri.v1 = scale_translate(w.tri.v1, s, t);
                w.tri.v2 = scale_translate(w.tri.v2, s, t);
                w.inner_inst_id = w.inst_id;
                w.inst_id = 100 + j;
                world3.push_back(w);
            }
        }
    }
};

std::vector<vec3<float>> centroids(std::vector<world_triangle> const& world) {
    std::vector<vec3<float>> points;
    for (auto const& w : world) points.push_back((w.tri.v0 + w.tri.v1 + w.tri.v2) * (1.0f / 3.0f));
    return points;
}

// Rays towards the world triangles, with origins on a 2^-12 grid.
std::vector<ray> dyadic_rays(random_source& rng, canopy::aabb const& bounds, std::vector<world_triangle> const& world, int count) {
    std::vector<ray> rays;
    for (ray r : rays_towards(rng, bounds, centroids(world), count)) {
        for (int a = 0; a < 3; ++a) r.origin[a] = std::round(r.origin[a] * 4096.0f) / 4096.0f;
        rays.push_back(r);
    }
    return rays;
}

} // namespace

TEST_CASE("two- and three-level instancing with exact transforms equals world-space brute force bit for bit") {
    exact_scene const scene(201);
    random_source rng(202);
    query_agreement middle, middle_range, top, top_range;
    for (ray const& r : dyadic_rays(rng, scene.top.bounds(), scene.world3, 800)) {
        auto const expected3 = brute_force_hits(r, scene.world3, stamped(library_test));
        compare_queries(r, &scene.top, &scene.top + 1, expected3, [] { return canopy::default_intersector{}; }, top);
        compare_queries(r, scene.level2.begin(), scene.level2.end(), expected3, [] { return canopy::default_intersector{}; }, top_range);
    }
    for (ray const& r : dyadic_rays(rng, scene.middle.bounds(), scene.world2, 800)) {
        auto const expected2 = brute_force_hits(r, scene.world2, stamped(library_test));
        compare_queries(r, &scene.middle, &scene.middle + 1, expected2, [] { return canopy::default_intersector{}; }, middle);
        compare_queries(r, scene.level1.begin(), scene.level1.end(), expected2, [] { return canopy::default_intersector{}; }, middle_range);
    }
    require_agreement(middle, 300);
    require_agreement(middle_range, 300);
    require_agreement(top, 300);
    require_agreement(top_range, 300);
}

TEST_CASE("an alpha mask acts through every instance level, for all three queries") {
    exact_scene const scene(203);
    random_source rng(204);
    auto const masked_test = [](ray const& r, triangle const& tri) {
        auto hr = canopy::intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        return hr;
    };
    query_agreement middle, top;
    int culled = 0;
    for (ray const& r : dyadic_rays(rng, scene.top.bounds(), scene.world3, 800)) {
        auto const expected = brute_force_hits(r, scene.world3, stamped(masked_test));
        culled += brute_force_hits(r, scene.world3, stamped(library_test)).size() > expected.size();
        compare_queries(r, &scene.top, &scene.top + 1, expected, [] { return alpha_mask{}; }, top);
    }
    for (ray const& r : dyadic_rays(rng, scene.middle.bounds(), scene.world2, 800))
        compare_queries(r, &scene.middle, &scene.middle + 1, brute_force_hits(r, scene.world2, stamped(masked_test)),
                        [] { return alpha_mask{}; }, middle);
    CHECK(culled > 100);
    require_agreement(middle, 200);
    require_agreement(top, 200);
}

TEST_CASE("identity instances give bit-identical results to the bare BVH") {
    random_source rng(205);
    auto const soup = triangle_soup(rng, 1500, 8.0f, 1.0f);
    mesh_bvh const b = canopy::build_binned_sah(soup);
    auto const identity = canopy::affine_transform<float>::identity();
    std::vector<mesh_instance> const inner{mesh_instance(b, identity, 5)};
    two_level const middle = canopy::build_binned_sah(inner);
    std::vector<two_level_instance> const outer{two_level_instance(middle, identity, 6)};
    three_level const top = canopy::build_binned_sah(outer);
    int hits = 0, mismatches = 0;
    auto const with_chain = [](record hr, std::uint32_t inst, std::uint32_t inner_inst) {
        if (hr.hit) {
            hr.inst_id = inst;
            hr.inner_inst_id[0] = inner_inst;
        }
        return hr;
    };
    for (ray const& r : random_rays(rng, b.bounds(), 1000)) {
        auto const bare = canopy::closest_hit(r, &b, &b + 1);
        hits += bare.hit;
        mismatches += !same_record(canopy::closest_hit(r, &middle, &middle + 1), with_chain(bare, 5, invalid));
        mismatches += !same_record(canopy::closest_hit(r, inner.begin(), inner.end()), with_chain(bare, 5, invalid));
        mismatches += !same_record(canopy::closest_hit(r, &top, &top + 1), with_chain(bare, 6, 5));
        auto const bare_multi = canopy::multi_hit<4>(r, &b, &b + 1);
        auto const top_multi = canopy::multi_hit<4>(r, &top, &top + 1);
        for (std::size_t i = 0; i < 4; ++i) mismatches += !same_record(top_multi[i], with_chain(bare_multi[i], 6, 5));
        mismatches += canopy::any_hit(r, &top, &top + 1).hit != bare.hit;
    }
    CHECK(hits > 300);
    CHECK(mismatches == 0);
}

// ---------------------------------------------------------------------------------------------
// Instanced scenes with general transforms (rotations, non-uniform scales, translations) against
// a world-space brute force in long double.

namespace {

struct vec3l {
    long double x = 0, y = 0, z = 0;
};
vec3l widen(vec3<float> v) { return {v.x, v.y, v.z}; }
vec3l operator+(vec3l a, vec3l b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
vec3l operator-(vec3l a, vec3l b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
vec3l operator*(vec3l a, long double s) { return {a.x * s, a.y * s, a.z * s}; }
long double dot(vec3l a, vec3l b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
vec3l cross(vec3l a, vec3l b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
long double length(vec3l a) { return std::sqrt(dot(a, a)); }

// The exact image of p under m (m's float entries taken as exact).
vec3l apply(canopy::affine_transform<float> const& m, vec3l p) {
    return widen(m.linear.col0) * p.x + widen(m.linear.col1) * p.y + widen(m.linear.col2) * p.z + widen(m.translation);
}

struct exact_world_triangle {
    vec3l a, b, c;
    std::uint32_t prim_id, geom_id, inst_id, inner_inst_id;
};

// The nested scene with every triangle also in world space, exactly (long double), at level 2
// (through the eight mesh instances) and level 3 (through the three instances of those).
struct general_scene : test_support::nested_scene {
    std::vector<exact_world_triangle> world2, world3;

    explicit general_scene(std::uint32_t seed) : nested_scene(seed) {
        for (std::uint32_t k = 0; k < 8; ++k) {
            auto const& m = level1[k].object_to_world;
            for (triangle const& tri : soups[k % 2])
                world2.push_back({apply(m, widen(tri.v0)), apply(m, widen(tri.v1)), apply(m, widen(tri.v2)), tri.prim_id,
                                  tri.geom_id, 10 + k, invalid});
        }
        for (std::uint32_t j = 0; j < 3; ++j) {
            auto const& m = level2[j].object_to_world;
            for (exact_world_triangle w : world2) {
                w.a = apply(m, w.a);
                w.b = apply(m, w.b);
                w.c = apply(m, w.c);
                w.inner_inst_id = w.inst_id;
                w.inst_id = 100 + j;
                world3.push_back(w);
            }
        }
    }
};

std::vector<vec3<float>> centroids(std::vector<exact_world_triangle> const& world) {
    std::vector<vec3<float>> points;
    for (auto const& w : world) {
        vec3l const c = (w.a + w.b + w.c) * (1.0L / 3);
        points.push_back({static_cast<float>(c.x), static_cast<float>(c.y), static_cast<float>(c.z)});
    }
    return points;
}

struct reference_hit {
    long double t;
    long double slack;     // how far along the ray float rounding may move this hit (in t)
    long double cosine;    // |cos| of the angle between the ray and the triangle's normal
    std::uint32_t prim_id, geom_id, inst_id, inner_inst_id;
};

// All hits of the exact world-space ray, sorted by t. ambiguous: some triangle, edge, alpha cell
// boundary or tie lies so close to the ray that rounding (≈1e-5 of the scene size, amplified by
// 1/cos at grazing incidence) may legitimately decide it either way.
struct reference_result {
    std::vector<reference_hit> hits;
    bool ambiguous = false;
};

constexpr long double position_tolerance = 5e-5L;   // world units; the scene spans about 30

reference_result world_reference(ray const& r, std::vector<exact_world_triangle> const& world, bool alpha) {
    reference_result result;
    vec3l const o = widen(r.origin), d = widen(r.direction);
    long double const dl = length(d);
    for (auto const& w : world) {
        vec3l const e1 = w.b - w.a, e2 = w.c - w.a, s = o - w.a;
        vec3l const n = cross(e1, e2);
        long double const nl = length(n), dn = dot(d, n);
        if (dn == 0) continue;
        long double const cosine = std::fabs(dn) / (nl * dl);
        long double const slack_distance = position_tolerance / std::max(cosine, 1e-12L);
        long double const det = -dn;
        long double const t = dot(s, n) / det;
        long double const u = -dot(d, cross(s, e2)) / det;
        long double const v = -dot(d, cross(e1, s)) / det;
        // Signed distances of the plane hit point to the three edges.
        long double const edge_distance =
            std::min({(1 - u - v) * nl / length(w.c - w.b), u * nl / length(e2), v * nl / length(e1)});
        if (edge_distance < -slack_distance) continue;
        if (std::fabs(t) * dl < slack_distance || edge_distance < slack_distance) {
            if (t * dl > -slack_distance) result.ambiguous = true;
            continue;
        }
        if (t < 0) continue;
        if (alpha) {
            auto const cell_distance = [](long double x) { return std::fabs(8 * x - std::round(8 * x)) / 8; };
            if (std::min(cell_distance(u) * nl / length(e2), cell_distance(v) * nl / length(e1)) < slack_distance) {
                result.ambiguous = true;
                continue;
            }
            if ((static_cast<int>(std::floor(8 * u)) + static_cast<int>(std::floor(8 * v))) % 2 != 0) continue;
        }
        result.hits.push_back({t, slack_distance / dl, cosine, w.prim_id, w.geom_id, w.inst_id, w.inner_inst_id});
    }
    std::sort(result.hits.begin(), result.hits.end(), [](auto const& a, auto const& b) { return a.t < b.t; });
    for (std::size_t i = 0; i + 1 < std::min<std::size_t>(result.hits.size(), 6); ++i) {
        if (result.hits[i + 1].t - result.hits[i].t < result.hits[i].slack + result.hits[i + 1].slack) result.ambiguous = true;
    }
    return result;
}

struct tolerance_agreement {
    int rays = 0, clean = 0, hits = 0, mismatches = 0;
    long double max_relative_t_error = 0;   // over hits with cos θ ≥ 0.1
    long double max_slack_ratio = 0;        // |t − t_exact| / slack
};

bool matches(record const& got, reference_hit const& e, tolerance_agreement& out) {
    if (!got.hit || got.prim_id != e.prim_id || got.geom_id != e.geom_id || got.inst_id != e.inst_id ||
        got.inner_inst_id[0] != e.inner_inst_id || got.inner_inst_id[1] != invalid)
        return false;
    long double const error = std::fabs(got.t - e.t);
    out.max_slack_ratio = std::max(out.max_slack_ratio, error / e.slack);
    if (e.cosine >= 0.1L)
        out.max_relative_t_error = std::max(out.max_relative_t_error, error / e.t);
    return error <= e.slack;
}

template <typename It, typename MakeIsect>
void compare_with_reference(ray const& r, It first, It last, reference_result const& ref, MakeIsect make_isect,
                            tolerance_agreement& out) {
    ++out.rays;
    if (ref.ambiguous) return;
    ++out.clean;
    out.hits += !ref.hits.empty();
    auto const closest = canopy::closest_hit(r, first, last, make_isect());
    out.mismatches += ref.hits.empty() ? closest.hit : !matches(closest, ref.hits[0], out);
    auto const any = canopy::any_hit(r, first, last, make_isect());
    out.mismatches += any.hit == ref.hits.empty();
    auto const multi = canopy::multi_hit<4>(r, first, last, make_isect());
    for (std::size_t i = 0; i < 4; ++i)
        out.mismatches += i < ref.hits.size() ? !matches(multi[i], ref.hits[i], out) : multi[i].hit;
}

void require_tolerance_agreement(tolerance_agreement const& a) {
    INFO(a.rays << " rays, " << a.clean << " clean, " << a.hits << " clean with hits; max |t error| / slack "
                << double(a.max_slack_ratio) << ", max relative t error (cos >= 0.1) " << double(a.max_relative_t_error));
    CHECK(a.mismatches == 0);
    CHECK(a.clean >= a.rays * 9 / 10);
    CHECK(a.hits >= a.clean / 4);
    // Stated bound: for incidence cos θ ≥ 0.1, t is within 1e-5 relative of the exact value.
    CHECK(a.max_relative_t_error <= 1e-5L);
}

} // namespace

TEST_CASE("two- and three-level instancing with rotations and non-uniform scales equals a world-space brute force") {
    general_scene const scene(301);
    random_source rng(302);
    tolerance_agreement middle, middle_range, top, top_range, masked;
    auto const plain = [] { return canopy::default_intersector{}; };
    for (ray const& r : rays_towards(rng, scene.middle.bounds(), centroids(scene.world2), 700)) {
        auto const ref = world_reference(r, scene.world2, false);
        compare_with_reference(r, &scene.middle, &scene.middle + 1, ref, plain, middle);
        compare_with_reference(r, scene.level1.begin(), scene.level1.end(), ref, plain, middle_range);
    }
    for (ray const& r : rays_towards(rng, scene.top.bounds(), centroids(scene.world3), 700)) {
        auto const ref = world_reference(r, scene.world3, false);
        compare_with_reference(r, &scene.top, &scene.top + 1, ref, plain, top);
        compare_with_reference(r, scene.level2.begin(), scene.level2.end(), ref, plain, top_range);
        compare_with_reference(r, &scene.top, &scene.top + 1, world_reference(r, scene.world3, true),
                               [] { return alpha_mask{}; }, masked);
    }
    require_tolerance_agreement(middle);
    require_tolerance_agreement(middle_range);
    require_tolerance_agreement(top);
    require_tolerance_agreement(top_range);
    require_tolerance_agreement(masked);
}

namespace {

// Checks in every hook that the ray's tmax is never beyond the closest hit accepted so far.
struct tmax_witness : canopy::basic_intersector<tmax_witness> {
    using canopy::basic_intersector<tmax_witness>::operator();

    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) {
        ++primitive_calls;
        violations += !(r.tmax <= best);
        culled_calls += r.tmax < initial_tmax;
        auto hr = intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        if (hr.hit && hr.t < best) best = hr.t;
        return hr;
    }
    template <typename Ray, typename... Args>
    auto operator()(Ray const& r, canopy::aabb const& box, Args&&... args) {
        ++box_calls;
        violations += !(r.tmax <= best);
        return intersect(r, box, std::forward<Args>(args)...);
    }

    float initial_tmax = inf;
    float best = inf;
    unsigned primitive_calls = 0, box_calls = 0, violations = 0, culled_calls = 0;
};

// Counts the tests made after the first accepted hit.
struct stop_witness : canopy::basic_intersector<stop_witness> {
    using canopy::basic_intersector<stop_witness>::operator();

    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) {
        tests_after_accept += accepted;
        auto hr = intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        accepted = accepted || hr.hit;
        ++tests;
        return hr;
    }
    template <typename Ray, typename... Args>
    auto operator()(Ray const& r, canopy::aabb const& box, Args&&... args) {
        tests_after_accept += accepted;
        return intersect(r, box, std::forward<Args>(args)...);
    }

    bool accepted = false;
    unsigned tests = 0, tests_after_accept = 0;
};

} // namespace

TEST_CASE("closest_hit hands every hook a ray whose tmax is the closest accepted hit so far, at every level") {
    general_scene const scene(401);
    exact_scene const flat(402);
    random_source rng(403);
    unsigned violations = 0, culled = 0, wrong_final = 0, calls = 0;
    auto run = [&](ray const& r, auto first, auto last) {
        tmax_witness w;
        w.initial_tmax = w.best = r.tmax;
        auto const hr = canopy::closest_hit(r, first, last, w);
        violations += w.violations;
        culled += w.culled_calls;
        calls += w.primitive_calls;
        wrong_final += hr.hit ? hr.t != w.best : w.best != r.tmax;
    };
    for (ray r : rays_towards(rng, scene.top.bounds(), centroids(scene.world3), 600)) {
        run(r, &scene.top, &scene.top + 1);
        run(r, scene.level2.begin(), scene.level2.end());
        r.tmax = rng.uniform(0.2f, 1.5f);   // a finite tmax to start with
        run(r, &scene.top, &scene.top + 1);
    }
    for (ray const& r : rays_towards(rng, flat.middle.bounds(), centroids(flat.world2), 300)) {
        run(r, &flat.middle, &flat.middle + 1);
        run(r, &flat.meshes[0], &flat.meshes[0] + 1);
    }
    CHECK(calls > 10000);
    CHECK(culled > 1000);   // tmax was tightened while tests were still running
    CHECK(violations == 0);
    CHECK(wrong_final == 0);
}

TEST_CASE("any_hit stops the whole traversal at the first accepted hit, through nested instances") {
    general_scene const scene(501);
    random_source rng(502);
    unsigned after = 0, hits = 0, rejected_before_accepting = 0, disagreements = 0;
    for (ray const& r : rays_towards(rng, scene.top.bounds(), centroids(scene.world3), 1000)) {
        stop_witness w;
        auto const hr = canopy::any_hit(r, &scene.top, &scene.top + 1, w);
        after += w.tests_after_accept;
        hits += hr.hit;
        disagreements += hr.hit != w.accepted;
        rejected_before_accepting += w.accepted && w.tests > 1;
        stop_witness range_witness;
        canopy::any_hit(r, scene.level2.begin(), scene.level2.end(), range_witness);
        after += range_witness.tests_after_accept;
    }
    CHECK(hits > 300);
    CHECK(rejected_before_accepting > 50);
    CHECK(disagreements == 0);
    CHECK(after == 0);
}

namespace {

template <typename Packet>
bool lane_equals(Packet const& p, int lane, record const& s) {
    if (bool(p.hit[lane]) != s.hit) return false;
    if (!s.hit) return bits(p.t[lane]) == bits(s.t);
    bool same = bits(p.t[lane]) == bits(s.t) && bits(p.u[lane]) == bits(s.u) && bits(p.v[lane]) == bits(s.v) &&
                std::uint32_t(p.prim_id[lane]) == s.prim_id && std::uint32_t(p.geom_id[lane]) == s.geom_id &&
                std::uint32_t(p.inst_id[lane]) == s.inst_id;
    for (std::size_t k = 0; k < s.inner_inst_id.size(); ++k)
        same = same && std::uint32_t(p.inner_inst_id[k][lane]) == s.inner_inst_id[k];
    return same;
}

} // namespace

TEST_CASE("packet closest_hit and any_hit equal the scalar queries lane by lane") {
    general_scene const scene(601);
    random_source rng(602);
    auto const soup = triangle_soup(rng, 2000, 8.0f, 1.0f);
    mesh_bvh const b = canopy::build_binned_sah(soup);
    int closest_mismatches = 0, any_mismatches = 0, hits = 0, inactive = 0;
    auto run = [&](std::vector<ray> const& rays, auto first, auto last) {
        for (std::size_t i = 0; i + 8 <= rays.size(); i += 8) {
            std::array<ray, 8> lanes;
            std::copy(rays.begin() + std::ptrdiff_t(i), rays.begin() + std::ptrdiff_t(i + 8), lanes.begin());
            // Inactive lanes: tmin > tmax, NaN; and a lane with a finite tmax.
            if (i % 24 == 0) lanes[2].tmin = lanes[2].tmax = std::numeric_limits<float>::quiet_NaN();
            if (i % 16 == 0) lanes[5].tmax = -1;
            lanes[6].tmax = 0.7f;
            auto const packet = pack(lanes);
            auto const closest = canopy::closest_hit(packet, first, last);
            auto const any = canopy::any_hit(packet, first, last);
            for (int lane = 0; lane < 8; ++lane) {
                ray const& r = lanes[std::size_t(lane)];
                auto const scalar = canopy::closest_hit(r, first, last);
                hits += scalar.hit;
                inactive += !(r.tmin <= r.tmax);
                closest_mismatches += !lane_equals(closest, lane, scalar);
                any_mismatches += bool(any.hit[lane]) != canopy::any_hit(r, first, last).hit;
                if (!(r.tmin <= r.tmax)) any_mismatches += any.hit[lane] || closest.hit[lane];
            }
        }
    };
    run(random_rays(rng, b.bounds(), 800), &b, &b + 1);
    run(rays_towards(rng, scene.top.bounds(), centroids(scene.world3), 800), &scene.top, &scene.top + 1);
    run(rays_towards(rng, scene.middle.bounds(), centroids(scene.world2), 400), scene.level1.begin(), scene.level1.end());
    CHECK(hits > 500);
    CHECK(inactive > 50);
    CHECK(closest_mismatches == 0);
    CHECK(any_mismatches == 0);
}

namespace {

// Forwards box tests through a hook of its own: traversal then tests child boxes one by one
// instead of with its SIMD wide test.
struct box_hook_passthrough : canopy::basic_intersector<box_hook_passthrough> {
    using canopy::basic_intersector<box_hook_passthrough>::operator();
    template <typename Ray, typename... Args>
    auto operator()(Ray const& r, canopy::aabb const& box, Args&&... args) {
        return intersect(r, box, std::forward<Args>(args)...);
    }
};

} // namespace

TEST_CASE("rays with zero direction components through the edges and vertices of a grid mesh hit it, with every box test") {
    // 8 × 8 unit squares in z = 0, two triangles each, diagonals alternating. The rays reach
    // z = 0 exactly on edges and vertices (t = 4, all arithmetic exact), travelling in the
    // boundary planes of the BVH's boxes (direction components +0 or −0).
    std::vector<triangle> grid;
    for (int i = 0; i < 8; ++i) {
        for (int j = 0; j < 8; ++j) {
            vec3<float> const p00(float(i), float(j), 0), p10(float(i + 1), float(j), 0);
            vec3<float> const p01(float(i), float(j + 1), 0), p11(float(i + 1), float(j + 1), 0);
            auto const id = [&] { return std::uint32_t(grid.size()); };
            if ((i + j) % 2 == 0) {
                grid.push_back({p00, p10, p11, id()});
                grid.push_back({p00, p11, p01, id()});
            } else {
                grid.push_back({p00, p10, p01, id()});
                grid.push_back({p10, p11, p01, id()});
            }
        }
    }
    mesh_bvh const b = canopy::build_binned_sah(grid, {.max_leaf_size = 2});
    std::array<vec3<float>, 8> const directions{vec3<float>{0, 0, -1}, {-0.0f, 0, -1}, {0, -0.0f, -1}, {-0.0f, -0.0f, -1},
                                               {0, 0.25f, -1}, {-0.0f, -0.25f, -1}, {0.25f, -0.0f, -1}, {-0.5f, 0, -1}};
    query_agreement plain, hooked;
    int packet_mismatches = 0, hits_at_4 = 0, rays = 0;
    std::array<ray, 8> lanes;
    for (int xi = 0; xi <= 16; ++xi) {
        for (int yi = 0; yi <= 16; ++yi) {
            vec3<float> const target(0.5f * float(xi), 0.5f * float(yi), 0);
            for (std::size_t k = 0; k < directions.size(); ++k) {
                ray const r = make_ray(target - directions[k] * 4.0f, directions[k]);
                auto const expected = brute_force_hits(r, grid, library_test);
                ++rays;
                hits_at_4 += !expected.empty() && expected[0].t == 4.0f;
                compare_queries(r, &b, &b + 1, expected, [] { return canopy::default_intersector{}; }, plain);
                compare_queries(r, &b, &b + 1, expected, [] { return box_hook_passthrough{}; }, hooked);
                lanes[k] = r;
            }
            auto const packet = canopy::closest_hit(pack(lanes), &b, &b + 1);
            for (int lane = 0; lane < 8; ++lane)
                packet_mismatches += !lane_equals(packet, lane, canopy::closest_hit(lanes[std::size_t(lane)], &b, &b + 1));
        }
    }
    CHECK(hits_at_4 == rays);   // watertight: every one of them hits, at t = 4
    require_agreement(plain, rays);
    require_agreement(hooked, rays);
    CHECK(packet_mismatches == 0);
}

TEST_CASE("queries over empty ranges and rays with an empty interval miss") {
    random_source rng(701);
    auto const soup = triangle_soup(rng, 100, 2.0f, 1.0f);
    mesh_bvh const b = canopy::build_binned_sah(soup);
    ray const r = make_ray({0, 0, -10}, {0, 0, 1});
    REQUIRE(canopy::closest_hit(r, &b, &b + 1).hit);
    CHECK_FALSE(canopy::closest_hit(r, &b, &b).hit);
    CHECK_FALSE(canopy::any_hit(r, soup.begin(), soup.begin()).hit);
    ray empty_interval = r;
    empty_interval.tmin = 5;
    empty_interval.tmax = 4;
    CHECK_FALSE(canopy::closest_hit(empty_interval, &b, &b + 1).hit);
    CHECK_FALSE(canopy::any_hit(empty_interval, &b, &b + 1).hit);
    CHECK_FALSE(canopy::multi_hit<2>(empty_interval, &b, &b + 1)[0].hit);
    ray nan_ray = r;
    nan_ray.tmin = std::numeric_limits<float>::quiet_NaN();
    CHECK_FALSE(canopy::closest_hit(nan_ray, &b, &b + 1).hit);
    CHECK_FALSE(canopy::multi_hit<2>(nan_ray, &b, &b + 1)[0].hit);
}

// ---------------------------------------------------------------------------------------------
// BVHs built with spatial splits (build_quality::high): one triangle may sit in several leaves.

namespace {

// The checkerboard alpha as a filter (the library's SIMD test, then the rule on u, v).
struct alpha_filter : canopy::basic_intersector<alpha_filter> {
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) const {
        return checkerboard_opaque(hr.u, hr.v);
    }
};

// Counts the calls of its triangle hook, and of its filter, per prim_id.
struct counting_hooks : canopy::basic_intersector<counting_hooks> {
    using canopy::basic_intersector<counting_hooks>::operator();
    std::map<std::uint32_t, int>* hook_calls = nullptr;
    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) {
        ++(*hook_calls)[tri.prim_id];
        return intersect(r, tri);
    }
};
struct counting_filter : canopy::basic_intersector<counting_filter> {
    std::map<std::uint32_t, int>* filter_calls = nullptr;
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) {
        ++(*filter_calls)[hr.prim_id];
        return true;
    }
};

// Random rays, and rays aimed exactly at vertices and edge midpoints of random triangles.
std::vector<ray> rays_for(std::vector<triangle> const& tris, canopy::aabb const& bounds, random_source& rng, int count) {
    auto rays = random_rays(rng, bounds, count);
    for (int i = 0; i < count; ++i) {
        triangle const& t = tris[std::size_t(rng.integer(0, int(tris.size()) - 1))];
        vec3<float> const target = i % 2 == 0 ? t.v0 : (t.v1 + t.v2) * 0.5f;
        vec3<float> const origin = target + rng.point(-2.0f, 2.0f);
        rays.push_back({origin, 0.0f, target - origin, inf});
    }
    return rays;
}

} // namespace

TEST_CASE("queries through BVHs built with spatial splits equal brute force on slivers and long thin triangles") {
    random_source rng(111);
    auto const needles = test_support::needle_soup(rng, 1200, 5.0f, 0.02f);
    auto const masked_test = [](ray const& r, triangle const& tri) {
        auto hr = canopy::intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        return hr;
    };
    std::vector<std::vector<triangle>> const inputs{needles, test_support::sliver_mesh()};
    for (auto const& input : inputs) {
        for (canopy::bvh_build_options const options :
             {canopy::bvh_build_options{.quality = canopy::build_quality::high},
              canopy::bvh_build_options{.max_leaf_size = 1, .quality = canopy::build_quality::high, .split_budget = 1.0f}}) {
            mesh_bvh const b = canopy::build_binned_sah(input, options);
            std::size_t references = 0;
            canopy::for_each_primitive(b, [&](triangle const&) { ++references; });
            REQUIRE(references > input.size() + input.size() / 20);
            query_agreement plain, hook, filtered;
            int packet_mismatches = 0;
            auto const rays = rays_for(input, b.bounds(), rng, 300);
            for (std::size_t i = 0; i < rays.size(); ++i) {
                ray const& r = rays[i];
                compare_queries(r, &b, &b + 1, brute_force_hits(r, input, library_test),
                                [] { return canopy::default_intersector{}; }, plain);
                auto const masked = brute_force_hits(r, input, masked_test);
                compare_queries(r, &b, &b + 1, masked, [] { return alpha_mask{}; }, hook);
                compare_queries(r, &b, &b + 1, masked, [] { return alpha_filter{}; }, filtered);
                if (i % 8 == 7) {
                    std::array<ray, 8> lanes;
                    for (std::size_t k = 0; k < 8; ++k) lanes[k] = rays[i - 7 + k];
                    auto const packet = canopy::closest_hit(pack(lanes), &b, &b + 1);
                    for (int k = 0; k < 8; ++k)
                        packet_mismatches += !lane_equals(packet, k, canopy::closest_hit(lanes[std::size_t(k)], &b, &b + 1));
                }
            }
            require_agreement(plain, 150);
            require_agreement(hook, 100);
            require_agreement(filtered, 100);
            CHECK(packet_mismatches == 0);
        }
    }
}

TEST_CASE("multi_hit reports a triangle referenced from several leaves once, whose hooks may see it once per leaf") {
    random_source rng(112);
    // A long triangle in the tilted plane z = 0.1 x, and small triangles around it (off the ray).
    std::vector<triangle> tris{{{-10, 0, -1}, {10, 0.002f, 1}, {10, -0.002f, 1}, 0, 0}};
    for (int i = 1; i <= 300; ++i) {
        float const x = rng.uniform(-10, 10), side = rng.uniform(0.2f, 1.0f) * (i % 2 ? 1.0f : -1.0f);
        vec3<float> const c(x, side, 0.1f * x);
        tris.push_back({c, c + rng.point(-0.1f, 0.1f), c + rng.point(-0.1f, 0.1f), std::uint32_t(i), 0});
    }
    mesh_bvh const b = canopy::build_binned_sah(tris, {.quality = canopy::build_quality::high});
    int leaves_of_long = 0;
    canopy::for_each_primitive(b, [&](triangle const& t) { leaves_of_long += t.prim_id == 0; });
    REQUIRE(leaves_of_long >= 3);
    int duplicated_rays = 0;
    query_agreement agreement;
    for (int k = 0; k < 50; ++k) {
        // Nearly along the long triangle, crossing its plane once, near x = 0: through the boxes
        // of several of its parts.
        float const x0 = rng.uniform(-2, 2);
        ray const r{{-10, rng.uniform(-0.0005f, 0.0005f), -1 + 0.05f}, 0.0f, {20, 0, 2.0f - 0.1f + 0.01f * x0}, inf};
        auto const expected = brute_force_hits(r, tris, library_test);
        REQUIRE(!expected.empty());
        REQUIRE(expected[0].prim_id == 0);
        compare_queries(r, &b, &b + 1, expected, [] { return canopy::default_intersector{}; }, agreement);
        std::map<std::uint32_t, int> hook_calls, filter_calls;
        counting_hooks hooks;
        hooks.hook_calls = &hook_calls;
        counting_filter filter;
        filter.filter_calls = &filter_calls;
        for (auto const& got : {canopy::multi_hit<8>(r, &b, &b + 1, hooks), canopy::multi_hit<8>(r, &b, &b + 1, filter)}) {
            CHECK(std::count_if(got.begin(), got.end(), [](auto const& h) { return h.hit && h.prim_id == 0; }) == 1);
            CHECK(same_record(got[0], expected[0]));
        }
        CHECK(hook_calls[0] >= 1);
        CHECK(filter_calls[0] >= 1);
        duplicated_rays += hook_calls[0] >= 2;
    }
    require_agreement(agreement, 50);
    CHECK(duplicated_rays >= 10); // the rays did meet the triangle in several leaves
}

TEST_CASE("double-precision BVHs built with spatial splits equal brute force") {
    random_source rng(113);
    std::vector<canopy::basic_triangle<double>> tris;
    auto const slivers = test_support::sliver_mesh();
    for (triangle const& t : slivers)
        tris.push_back({vec3<double>(t.v0), vec3<double>(t.v1), vec3<double>(t.v2), t.prim_id, t.geom_id});
    auto const b = canopy::build_binned_sah(tris, {.quality = canopy::build_quality::high});
    REQUIRE(b.primitives.size() > tris.size());
    query_agreement agreement;
    for (ray const& rf : rays_for(slivers, canopy::aabb{{-2, -2, -1}, {4, 2, 1}}, rng, 300)) {
        canopy::basic_ray<double> const r{vec3<double>(rf.origin), 0.0, vec3<double>(rf.direction),
                                          std::numeric_limits<double>::infinity()};
        auto const expected = brute_force_hits(r, tris, library_test);
        compare_queries(r, &b, &b + 1, expected, [] { return canopy::default_intersector{}; }, agreement);
    }
    require_agreement(agreement, 100);
}

// ---------------------------------------------------------------------------------------------
// Refit: a BVH built for one mesh, refitted to the mesh moved, answers as a fresh build over the
// moved mesh does, and as brute force.

namespace {

using test_support::deformation;

struct refit_case {
    char const* name;
    deformation how;
    float amount;
};

constexpr refit_case refit_cases[] = {
    {"random displacement", deformation::displace, 0.6f},
    {"a large twist", deformation::twist, 1.5f},
    {"a collapse to a plane", deformation::collapse, 0.0f},
};

// closest_hit and multi_hit<16> of a and b agree bit for bit, any_hit finds a hit in both or in
// neither; counted in `mismatches`.
template <typename A, typename B>
void compare_trees(ray const& r, A const& a, B const& b, int& mismatches) {
    bool same = same_record(canopy::closest_hit(r, &a, &a + 1), canopy::closest_hit(r, &b, &b + 1));
    same = same && canopy::any_hit(r, &a, &a + 1).hit == canopy::any_hit(r, &b, &b + 1).hit;
    auto const ma = canopy::multi_hit<16>(r, &a, &a + 1), mb = canopy::multi_hit<16>(r, &b, &b + 1);
    for (std::size_t i = 0; i < ma.size(); ++i) same = same && same_record(ma[i], mb[i]);
    mismatches += !same;
}

} // namespace

TEST_CASE("after a refit, queries equal brute force and a fresh build's, at both build qualities") {
    random_source rng(121);
    std::vector<std::pair<char const*, std::vector<triangle>>> const meshes{
        {"soup", triangle_soup(rng, 1500, 3.0f, 0.5f)}, {"slivers", test_support::sliver_mesh()}};
    for (auto const& [mesh_name, mesh] : meshes) {
        for (auto const quality : {canopy::build_quality::fast, canopy::build_quality::high}) {
            for (auto const& c : refit_cases) {
                INFO(mesh_name << ", " << c.name << ", quality " << (quality == canopy::build_quality::high ? "high" : "fast"));
                auto const moved = test_support::deformed(mesh, c.how, c.amount, rng);
                mesh_bvh refitted = canopy::build_binned_sah(mesh, {.quality = quality});
                canopy::refit(refitted, moved);
                mesh_bvh const fresh = canopy::build_binned_sah(moved, {.quality = quality});
                query_agreement agreement;
                int fresh_mismatches = 0, packet_mismatches = 0;
                auto const rays = rays_for(moved, fresh.bounds(), rng, 150);
                for (std::size_t i = 0; i < rays.size(); ++i) {
                    ray const& r = rays[i];
                    compare_queries(r, &refitted, &refitted + 1, brute_force_hits(r, moved, library_test),
                                    [] { return canopy::default_intersector{}; }, agreement);
                    compare_trees(r, refitted, fresh, fresh_mismatches);
                    if (i % 8 == 7) {
                        std::array<ray, 8> lanes;
                        for (std::size_t k = 0; k < 8; ++k) lanes[k] = rays[i - 7 + k];
                        auto const packet = canopy::closest_hit(pack(lanes), &refitted, &refitted + 1);
                        for (int k = 0; k < 8; ++k)
                            packet_mismatches +=
                                !lane_equals(packet, k, canopy::closest_hit(lanes[std::size_t(k)], &fresh, &fresh + 1));
                    }
                }
                require_agreement(agreement, 100);
                CHECK(fresh_mismatches == 0);
                CHECK(packet_mismatches == 0);
            }
        }
    }
}

TEST_CASE("a top level refitted over refitted instances equals a fresh two-level build and brute force") {
    random_source rng(122);
    auto const mesh = triangle_soup(rng, 800, 2.0f, 0.4f);
    std::vector<canopy::affine_transform<float>> transforms;
    for (int k = 0; k < 12; ++k) transforms.push_back(random_transform(rng, 6.0f));
    for (auto const quality : {canopy::build_quality::fast, canopy::build_quality::high}) {
        for (auto const& c : refit_cases) {
            INFO(c.name << ", quality " << (quality == canopy::build_quality::high ? "high" : "fast"));
            auto const moved = test_support::deformed(mesh, c.how, c.amount * 2.0f, rng);
            auto const instances_of = [&](mesh_bvh const& b) {
                std::vector<mesh_instance> out;
                for (std::size_t k = 0; k < transforms.size(); ++k) out.emplace_back(b, transforms[k], std::uint32_t(k));
                return out;
            };
            mesh_bvh refitted = canopy::build_binned_sah(mesh, {.quality = quality});
            auto const instances = instances_of(refitted);
            two_level top = canopy::build_binned_sah(instances);
            canopy::refit(refitted, moved);
            canopy::refit(top);
            mesh_bvh const fresh = canopy::build_binned_sah(moved, {.quality = quality});
            auto const fresh_instances = instances_of(fresh);
            two_level const fresh_top = canopy::build_binned_sah(fresh_instances);

            std::vector<vec3<float>> targets;
            for (auto const& inst : instances)
                for (std::size_t i = 0; i < moved.size(); i += 40) targets.push_back(inst.object_to_world.transform_point(moved[i].v0));
            query_agreement agreement;
            int fresh_mismatches = 0;
            for (ray const& r : rays_towards(rng, fresh_top.bounds(), targets, 250)) {
                auto const expected = test_support::instanced_brute_force_hits(r, instances, moved);
                compare_queries(r, &top, &top + 1, expected, [] { return canopy::default_intersector{}; }, agreement);
                compare_trees(r, top, fresh_top, fresh_mismatches);
            }
            require_agreement(agreement, 150);
            CHECK(fresh_mismatches == 0);
        }
    }
}
