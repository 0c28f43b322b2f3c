// Tests of canopy.intersector: the paper's custom intersectors (CRTP, lambdas, overload sets), the
// fallback to the default tests, and that hooks reach every level of nested BVHs and instances.
#include <catch2/catch.hpp>

#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

import canopy.query;
import canopy.testing;

using canopy::aabb;
using canopy::basic_triangle;
using canopy::intersect;

// The paper's heat-map intersector (§4), with Canopy's names: counts ray/box and ray/triangle tests.
struct bvh_costs : canopy::basic_intersector<bvh_costs> {
    using canopy::basic_intersector<
        bvh_costs
    >::operator();

    // Intercept and count ray/aabb tests
    template <typename Ray, typename ...Args>
    auto operator() (
        Ray const& ray,
        aabb const& box,
        Args&&... args
    )
    {
        ++num_boxes;
        return intersect(
            ray,
            box,
            std::forward<Args>(args)...
        );
    }

    // Intercept and count ray/triangle tests
    template <typename Ray>
    auto operator() (
        Ray const& ray,
        basic_triangle<float> const& tri
    )
    {
        ++num_tris;
        return intersect(ray, tri);
    }

    unsigned num_boxes = 0;
    unsigned num_tris = 0;
};

namespace {

using canopy::ray;
using canopy::triangle;
using canopy::vec3;
using test_support::mesh_bvh;
using test_support::mesh_instance;
using test_support::nested_scene;
using test_support::three_level;
using test_support::two_level;
using test_support::two_level_instance;

using test_support::checkerboard_opaque;
using test_support::make_ray;
using test_support::random_rays;
using test_support::random_source;
using test_support::random_transform;
using test_support::triangle_soup;

template <typename H>
bool same_record(H const& a, H const& b) {
    auto const bits = [](float x) { return std::bit_cast<std::uint32_t>(x); };
    return a.hit == b.hit && bits(a.t) == bits(b.t) && bits(a.u) == bits(b.u) && bits(a.v) == bits(b.v) &&
           a.prim_id == b.prim_id && a.geom_id == b.geom_id && a.inst_id == b.inst_id &&
           a.inner_inst_id == b.inner_inst_id;
}

template <typename H, std::size_t N>
bool same_records(std::array<H, N> const& a, std::array<H, N> const& b) {
    for (std::size_t i = 0; i < N; ++i)
        if (!same_record(a[i], b[i])) return false;
    return true;
}

template <typename... F>
struct overload_set : F... {
    using F::operator()...;
};
template <typename... F>
overload_set(F...) -> overload_set<F...>;

// The same alpha mask written with and without the using-declaration.
struct alpha_mask : canopy::basic_intersector<alpha_mask> {
    using canopy::basic_intersector<alpha_mask>::operator();
    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) {
        ++calls;
        auto hr = intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        return hr;
    }
    unsigned calls = 0;
};

struct alpha_mask_without_using : canopy::basic_intersector<alpha_mask_without_using> {
    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) {
        ++calls;
        auto hr = intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        return hr;
    }
    unsigned calls = 0;
};

// Only a box hook, and no using-declaration: triangles must still be tested by default.
struct box_counter_without_using : canopy::basic_intersector<box_counter_without_using> {
    template <typename Ray, typename... Args>
    auto operator()(Ray const& r, aabb const& box, Args&&... args) {
        ++calls;
        return intersect(r, box, std::forward<Args>(args)...);
    }
    unsigned calls = 0;
};

// Three triangles stacked along z over the same square: a BVH of them is a single leaf.
std::vector<triangle> stacked_triangles() {
    return {triangle{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, triangle{{0, 0, 0.125f}, {1, 0, 0.125f}, {0, 1, 0.125f}},
            triangle{{0, 0, 0.25f}, {1, 0, 0.25f}, {0, 1, 0.25f}}};
}

} // namespace

TEST_CASE("bvh_costs from the paper counts every ray/box and ray/triangle test, at every level") {
    auto const tris = stacked_triangles();
    ray const through = make_ray({0.25f, 0.25f, 5}, {0, 0, -1});
    ray const beside = make_ray({3, 3, 5}, {0, 0, -1});

    SECTION("a range of primitives: one test per primitive, no boxes") {
        bvh_costs costs;
        auto const hr = canopy::closest_hit(through, tris.begin(), tris.end(), costs);
        CHECK(hr.hit);
        CHECK(costs.num_tris == 3);
        CHECK(costs.num_boxes == 0);
    }

    mesh_bvh const leaf = canopy::build_binned_sah(tris);
    REQUIRE(canopy::compute_stats(leaf).leaf_count == 1);
    auto const xf = canopy::affine_transform<float>::from_rows({0, -2, 0, 1, 1, 0, 0, -3, 0, 0, 0.5f, 2});
    std::vector<mesh_instance> const one{mesh_instance(leaf, xf, 7)};
    two_level const middle = canopy::build_binned_sah(one);
    auto const xf2 = canopy::affine_transform<float>::from_rows({1, 0, 0, -4, 0, 1, 0, 0, 0, 0, 2, 1});
    std::vector<two_level_instance> const two{two_level_instance(middle, xf2, 8)};
    three_level const top = canopy::build_binned_sah(two);
    // World-space images of the point (0.25, 0.25, ·) of the stacked triangles, and rays through them.
    ray const through2 = make_ray(canopy::transform_point(xf, vec3<float>(0.25f, 0.25f, 5)),
                                  canopy::transform_vector(xf, vec3<float>(0, 0, -1)));
    ray const through3 = make_ray(canopy::transform_point(xf2, through2.origin), canopy::transform_vector(xf2, through2.direction));

    SECTION("one BVH: the root box, then the leaf's triangles") {
        bvh_costs costs;
        CHECK(canopy::closest_hit(through, &leaf, &leaf + 1, costs).hit);
        CHECK(costs.num_boxes == 1);
        CHECK(costs.num_tris == 3);
        bvh_costs missed;
        CHECK_FALSE(canopy::closest_hit(beside, &leaf, &leaf + 1, missed).hit);
        CHECK(missed.num_boxes == 1);
        CHECK(missed.num_tris == 0);
    }
    SECTION("two levels: the instance BVH's root box and the mesh's root box") {
        bvh_costs costs;
        auto const hr = canopy::closest_hit(through2, &middle, &middle + 1, costs);
        CHECK(hr.hit);
        CHECK(hr.inst_id == 7u);
        CHECK(costs.num_boxes == 2);
        CHECK(costs.num_tris == 3);
    }
    SECTION("three levels: one root box per level") {
        bvh_costs costs;
        auto const hr = canopy::closest_hit(through3, &top, &top + 1, costs);
        CHECK(hr.hit);
        CHECK(hr.inst_id == 8u);
        CHECK(hr.inner_inst_id[0] == 7u);
        CHECK(costs.num_boxes == 3);
        CHECK(costs.num_tris == 3);
        bvh_costs any;
        CHECK(canopy::any_hit(through3, &top, &top + 1, any).hit);
        CHECK(any.num_boxes == 3);
        CHECK(any.num_tris == 1);
    }
}

TEST_CASE("bvh_costs counts equal those of an independently written overload set of lambdas") {
    nested_scene const scene(21);
    random_source rng(22);
    auto check_counts = [&](auto const& structure, char const* name) {
        unsigned boxes = 0, tris = 0;
        auto counting = overload_set{
            [&](auto const& r, aabb const& box, vec3<float> const& inv_dir) {
                ++boxes;
                return canopy::intersect(r, box, inv_dir);
            },
            [&](ray const& r, triangle const& tri) {
                ++tris;
                return canopy::intersect(r, tri);
            }};
        bvh_costs costs, any_costs;
        unsigned hits = 0;
        for (ray const& r : random_rays(rng, structure.bounds(), 400)) {
            auto const a = canopy::closest_hit(r, &structure, &structure + 1, costs);
            auto const b = canopy::closest_hit(r, &structure, &structure + 1, counting);
            CHECK(same_record(a, b));
            // Box hooks see every box test; without one the library tests boxes its own way:
            // the hits must not differ.
            CHECK(same_record(a, canopy::closest_hit(r, &structure, &structure + 1)));
            hits += a.hit;
            canopy::any_hit(r, &structure, &structure + 1, any_costs);
        }
        INFO(name);
        CHECK(hits > 50);
        CHECK(costs.num_boxes == boxes);
        CHECK(costs.num_tris == tris);
        CHECK(costs.num_tris > 0);
        CHECK(any_costs.num_tris > 0);
        CHECK(any_costs.num_tris <= costs.num_tris);
        // Any-hit in the same structure again, counted by the lambdas.
        boxes = tris = 0;
        rng = random_source(23);
        bvh_costs again;
        for (ray const& r : random_rays(rng, structure.bounds(), 200)) {
            canopy::any_hit(r, &structure, &structure + 1, again);
            canopy::any_hit(r, &structure, &structure + 1, counting);
        }
        CHECK(again.num_boxes == boxes);
        CHECK(again.num_tris == tris);
    };
    check_counts(scene.meshes[0], "one BVH");
    check_counts(scene.middle, "two levels");
    check_counts(scene.top, "three levels");
}

TEST_CASE("forgetting the using-declaration still reaches every level, with default tests for the rest") {
    nested_scene const scene(31);
    random_source rng(32);
    int hits = 0;
    unsigned rejected_somewhere = 0, triangle_tests = 0;
    for (ray const& r : random_rays(rng, scene.top.bounds(), 600)) {
        alpha_mask with_using;
        alpha_mask_without_using without_using;
        bvh_costs costs;
        auto const a = canopy::closest_hit(r, &scene.top, &scene.top + 1, with_using);
        auto const b = canopy::closest_hit(r, &scene.top, &scene.top + 1, without_using);
        CHECK(same_record(a, b));
        // Without the using-declaration the hook still sees every triangle test.
        CHECK(without_using.calls == with_using.calls);
        triangle_tests += without_using.calls;
        auto const c = canopy::closest_hit(r, &scene.top, &scene.top + 1, costs);
        hits += c.hit;
        rejected_somewhere += !same_record(a, c);
        // A box hook alone: triangles fall back to the default test.
        box_counter_without_using boxes_only;
        bvh_costs box_reference;
        auto const d = canopy::closest_hit(r, &scene.top, &scene.top + 1, boxes_only);
        auto const e = canopy::closest_hit(r, &scene.top, &scene.top + 1, box_reference);
        CHECK(same_record(c, d));
        CHECK(same_record(c, e));
        CHECK(boxes_only.calls == box_reference.num_boxes);
        // Same for any_hit and multi_hit.
        CHECK(same_record(canopy::any_hit(r, &scene.top, &scene.top + 1, alpha_mask{}),
                          canopy::any_hit(r, &scene.top, &scene.top + 1, alpha_mask_without_using{})));
        CHECK(same_records(canopy::multi_hit<4>(r, &scene.top, &scene.top + 1, alpha_mask{}),
                           canopy::multi_hit<4>(r, &scene.top, &scene.top + 1, alpha_mask_without_using{})));
    }
    CHECK(hits > 100);
    CHECK(triangle_tests > 1000);
    CHECK(rejected_somewhere > 10);   // the alpha mask did act, through all three levels
}

TEST_CASE("a lambda is an intersector") {
    random_source rng(41);
    auto const soup = triangle_soup(rng, 1500, 5.0f, 1.0f);
    mesh_bvh const b = canopy::build_binned_sah(soup);
    unsigned calls = 0;
    auto even_only = [&calls](auto const& r, triangle const& tri) {
        ++calls;
        auto hr = canopy::intersect(r, tri);
        hr.hit = hr.hit && tri.prim_id % 2 == 0;
        return hr;
    };
    int hits = 0;
    for (ray const& r : random_rays(rng, b.bounds(), 1000)) {
        // Brute force over the even triangles.
        canopy::hit_record<ray, triangle> expected;
        for (std::size_t i = 0; i < soup.size(); i += 2) {
            auto const hr = canopy::intersect(r, soup[i]);
            if (hr.hit && hr.t < expected.t) expected = hr;
        }
        auto const via_bvh = canopy::closest_hit(r, &b, &b + 1, even_only);
        auto const via_range = canopy::closest_hit(r, soup.begin(), soup.end(), even_only);
        CHECK(same_record(via_bvh, expected));
        CHECK(same_record(via_range, expected));
        hits += expected.hit;
        auto const any = canopy::any_hit(r, &b, &b + 1, even_only);
        CHECK(any.hit == expected.hit);
        if (any.hit) CHECK(any.prim_id % 2 == 0);
    }
    CHECK(hits > 300);
    CHECK(calls > 1500u);
}

TEST_CASE("default_intersector{} given explicitly gives the same results as no intersector") {
    nested_scene const scene(51);
    random_source rng(52);
    std::vector<triangle> soup = triangle_soup(rng, 800, 4.0f, 1.0f);
    mesh_bvh const b = canopy::build_binned_sah(soup);
    auto check = [&](auto first, auto last, canopy::aabb const& bounds) {
        for (ray const& r : random_rays(rng, bounds, 300)) {
            CHECK(same_record(canopy::closest_hit(r, first, last), canopy::closest_hit(r, first, last, canopy::default_intersector{})));
            CHECK(same_record(canopy::any_hit(r, first, last), canopy::any_hit(r, first, last, canopy::default_intersector{})));
            CHECK(same_records(canopy::multi_hit<4>(r, first, last),
                               canopy::multi_hit<4>(r, first, last, canopy::default_intersector{})));
        }
    };
    check(soup.cbegin(), soup.cend(), b.bounds());
    check(&b, &b + 1, b.bounds());
    check(&scene.top, &scene.top + 1, scene.top.bounds());
    check(scene.level1.cbegin(), scene.level1.cend(), scene.middle.bounds());
    for (ray const& r : random_rays(rng, b.bounds(), 100)) {
        canopy::default_intersector isect;
        CHECK(same_record(canopy::intersect(r, b), canopy::intersect(r, b, isect)));
        CHECK(same_record(canopy::intersect(r, b), canopy::closest_hit(r, &b, &b + 1)));
    }
}

TEST_CASE("moller_trumbore_intersector gives the Möller–Trumbore results") {
    random_source rng(61);
    std::vector<triangle> soup = triangle_soup(rng, 1200, 5.0f, 1.0f);
    mesh_bvh const b = canopy::build_binned_sah(soup);
    int hits = 0;
    for (ray const& r : random_rays(rng, b.bounds(), 1000)) {
        canopy::hit_record<ray, triangle> expected;
        for (auto const& tri : soup) {
            auto const hr = canopy::intersect_moller_trumbore(r, tri);
            if (hr.hit && (hr.t < expected.t || (hr.t == expected.t && hr.prim_id < expected.prim_id))) expected = hr;
        }
        hits += expected.hit;
        CHECK(same_record(canopy::closest_hit(r, &b, &b + 1, canopy::moller_trumbore_intersector{}), expected));
        CHECK(same_record(canopy::closest_hit(r, soup.begin(), soup.end(), canopy::moller_trumbore_intersector{}), expected));
        CHECK(canopy::any_hit(r, &b, &b + 1, canopy::moller_trumbore_intersector{}).hit == expected.hit);
    }
    CHECK(hits > 300);
}

TEST_CASE("the intersector concepts detect the hooks an intersector provides") {
    using inv_dir = vec3<float>;
    STATIC_REQUIRE(canopy::acceleration_structure<mesh_bvh>);
    STATIC_REQUIRE(canopy::acceleration_structure<mesh_instance>);
    STATIC_REQUIRE(canopy::acceleration_structure<three_level>);
    STATIC_REQUIRE_FALSE(canopy::acceleration_structure<triangle>);
    STATIC_REQUIRE(canopy::primitive_hook_for<bvh_costs, ray, triangle>);
    STATIC_REQUIRE(canopy::box_hook_for<bvh_costs, ray, aabb, inv_dir>);
    STATIC_REQUIRE(canopy::primitive_hook_for<alpha_mask_without_using, ray, triangle>);
    STATIC_REQUIRE_FALSE(canopy::box_hook_for<alpha_mask_without_using, ray, aabb, inv_dir>);
    STATIC_REQUIRE(canopy::box_hook_for<box_counter_without_using, ray, aabb, inv_dir>);
    // The forwarding operator inherited from basic_intersector is not a hook of its own.
    STATIC_REQUIRE_FALSE(canopy::primitive_hook_for<canopy::default_intersector, ray, canopy::sphere>);
    STATIC_REQUIRE_FALSE(canopy::box_hook_for<canopy::default_intersector, ray, aabb, inv_dir>);
    STATIC_REQUIRE(canopy::primitive_hook_for<canopy::moller_trumbore_intersector, ray, triangle>);
    STATIC_REQUIRE_FALSE(canopy::primitive_hook_for<canopy::moller_trumbore_intersector, ray, canopy::sphere>);
}

// Records, for every triangle its hook is called for, the instance path the hook sees, and
// checks it against the triangle: under instance 10 + k the triangle must be one of soup k % 2.
struct path_checker : canopy::basic_intersector<path_checker> {
    using canopy::basic_intersector<path_checker>::operator();

    template <typename Ray>
    auto operator()(Ray const& ray, triangle const& tri) {
        auto const ids = canopy::instance_ids(ray);
        ++calls;
        empty_paths += ids.empty() ? 1 : 0;
        bool ok = ids.size() == 2 && ids[0] >= 100 && ids[0] < 103 && ids[1] >= 10 && ids[1] < 18;
        if (ok) {
            auto const& soup = scene->soups[(ids[1] - 10) % 2];
            ok = tri.prim_id < soup.size() && tri.v0.x == soup[tri.prim_id].v0.x && tri.v1.y == soup[tri.prim_id].v1.y &&
                 tri.v2.z == soup[tri.prim_id].v2.z;
        }
        wrong += ok ? 0 : 1;
        return intersect(ray, tri);
    }

    // The filter sees the same path in the candidate's ids.
    template <typename Ray>
    bool filter(Ray const& ray, canopy::basic_hit_record<float> const& hr) {
        auto const ids = canopy::instance_ids(ray);
        ++filtered;
        wrong += ids.size() == 2 && hr.inst_id == ids[0] && hr.inner_inst_id[0] == ids[1] &&
                         hr.inner_inst_id[1] == canopy::invalid_id
                     ? 0
                     : 1;
        return true;
    }

    test_support::nested_scene const* scene = nullptr;
    int calls = 0, filtered = 0, wrong = 0, empty_paths = 0;
};

TEST_CASE("hooks and filters see the instance path they run in, at every level") {
    test_support::nested_scene const s(91);
    random_source rng(92);
    auto const rays = random_rays(rng, s.top.bounds(), 300);
    path_checker check;
    check.scene = &s;
    int hits = 0;
    for (auto const& r : rays) {
        auto const hr = canopy::closest_hit(r, &s.top, &s.top + 1, check);
        hits += hr.hit ? 1 : 0;
        // The accepted hit's ids are the path of its triangle.
        if (hr.hit) CHECK((hr.inst_id >= 100 && hr.inst_id < 103 && hr.inner_inst_id[0] >= 10 && hr.inner_inst_id[0] < 18));
    }
    CHECK(check.wrong == 0);
    CHECK(check.calls > 1000);
    CHECK(check.filtered >= hits);
    CHECK(hits > 50);
    // Outside traversal (a plain range of triangles) the path is empty.
    auto const& soup = s.soups[0];
    path_checker plain;
    plain.scene = &s;
    for (auto const& r : rays) (void)canopy::closest_hit(r, soup.begin(), soup.end(), plain);
    CHECK(plain.calls == int(rays.size() * soup.size()));
    CHECK(plain.empty_paths == plain.calls);
    CHECK(check.empty_paths == 0);
}

// ---- mistakes are loud (SPEC §3.9); tests/compile_fail/ shows the queries refuse them ----------

namespace {

using canopy::intersector_mistake;
using packet_ray = canopy::basic_ray<canopy::simd::float8>;

// The alpha mask with const hooks and a const filter: a const intersector that works.
struct const_alpha_mask : canopy::basic_intersector<const_alpha_mask> {
    using canopy::basic_intersector<const_alpha_mask>::operator();
    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) const {
        ++*hook_calls;
        auto hr = intersect(r, tri);
        if (hr.hit) hr.hit = checkerboard_opaque(hr.u, hr.v);
        return hr;
    }
    template <typename Ray, typename... Args>
    auto operator()(Ray const& r, aabb const& box, Args&&... args) const {
        ++*box_calls;
        return intersect(r, box, std::forward<Args>(args)...);
    }
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) const {
        ++*filter_calls;
        return hr.prim_id % 3 != 0;
    }
    unsigned* hook_calls;
    unsigned* box_calls;
    unsigned* filter_calls;
};

// The same, non-const: the reference for the const one.
struct alpha_mask_filtered : alpha_mask {
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) {
        return hr.prim_id % 3 != 0;
    }
};

struct filter_only : canopy::basic_intersector<filter_only> {
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) {
        return hr.prim_id % 2 == 0;
    }
};

struct non_const_filter : canopy::basic_intersector<non_const_filter> {
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const&) {
        return true;
    }
};

struct filter_returning_a_record : canopy::basic_intersector<filter_returning_a_record> {
    template <typename Ray>
    canopy::basic_hit_record<float> filter(Ray const&, canopy::basic_hit_record<float> const& hr) {
        return hr;
    }
};

struct box_hook_returning_bool : canopy::basic_intersector<box_hook_returning_bool> {
    using canopy::basic_intersector<box_hook_returning_bool>::operator();
    template <typename Ray, typename... Args>
    bool operator()(Ray const& r, aabb const& box, Args&&... args) {
        return intersect(r, box, std::forward<Args>(args)...).hit;
    }
};

struct scalar_ray_hook : canopy::basic_intersector<scalar_ray_hook> {
    using canopy::basic_intersector<scalar_ray_hook>::operator();
    auto operator()(ray const& r, triangle const& tri) { return intersect(r, tri); }
};

struct float_box_hook_only : canopy::basic_intersector<float_box_hook_only> {
    using canopy::basic_intersector<float_box_hook_only>::operator();
    template <typename Ray, typename... Args>
    auto operator()(Ray const& r, aabb const& box, Args&&... args) {
        return intersect(r, box, std::forward<Args>(args)...);
    }
};

template <typename I, typename Elem, typename Ray = ray>
constexpr intersector_mistake mistake = canopy::intersector_mistake_v<I, Ray, Elem>;

} // namespace

TEST_CASE("intersectors whose hooks would be ignored are told apart from those that are fine") {
    using dtriangle = basic_triangle<double>;
    using dray = canopy::basic_ray<double>;
    // Fine: hooks that serve, a box hook or a filter alone, the library's own intersectors,
    // lambdas and overload sets, const intersectors with const hooks.
    STATIC_REQUIRE(mistake<bvh_costs, mesh_bvh> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<bvh_costs, three_level> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<bvh_costs, triangle> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<alpha_mask_without_using, mesh_bvh> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<box_counter_without_using, mesh_bvh> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<filter_only, mesh_bvh> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<canopy::default_intersector, mesh_bvh> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<canopy::default_intersector const, canopy::sphere> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<canopy::moller_trumbore_intersector, canopy::bvh<dtriangle>, dray> == intersector_mistake::none);
    // moller_trumbore_intersector says `using`: over spheres its triangle hook is simply not needed.
    STATIC_REQUIRE(mistake<canopy::moller_trumbore_intersector, canopy::bvh<canopy::sphere>> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<const_alpha_mask const, three_level> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<scalar_ray_hook, mesh_bvh> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<bvh_costs, mesh_bvh, packet_ray> == intersector_mistake::none);
    STATIC_REQUIRE(mistake<float_box_hook_only, triangle> == intersector_mistake::none);
    auto lambda = [](auto const& r, triangle const& tri) { return intersect(r, tri); };
    STATIC_REQUIRE(mistake<decltype(lambda), mesh_bvh> == intersector_mistake::none);
    auto generic = [](auto const& r, auto const& p) { return intersect(r, p); };
    STATIC_REQUIRE(mistake<decltype(generic), three_level> == intersector_mistake::none);

    // Mistakes.
    STATIC_REQUIRE(mistake<alpha_mask const, mesh_bvh> == intersector_mistake::const_hooks_not_const);
    STATIC_REQUIRE(mistake<bvh_costs const, triangle> == intersector_mistake::const_hooks_not_const);
    STATIC_REQUIRE(mistake<non_const_filter const, mesh_bvh> == intersector_mistake::const_hooks_not_const);
    STATIC_REQUIRE(mistake<filter_returning_a_record, mesh_bvh> == intersector_mistake::filter_result);
    STATIC_REQUIRE(mistake<box_hook_returning_bool, mesh_bvh> == intersector_mistake::box_result);
    STATIC_REQUIRE(mistake<bvh_costs, canopy::bvh<dtriangle>, dray> == intersector_mistake::other_precision);
    STATIC_REQUIRE(mistake<float_box_hook_only, canopy::bvh<dtriangle>, dray> == intersector_mistake::other_precision);
    STATIC_REQUIRE(mistake<scalar_ray_hook, mesh_bvh, packet_ray> == intersector_mistake::scalar_hooks_for_packets);
    // The forgotten using-declaration is fine where a hook serves, a mistake where none does.
    STATIC_REQUIRE(mistake<alpha_mask_without_using, canopy::bvh<canopy::sphere>> == intersector_mistake::no_usable_hook);
    auto swapped = [](triangle const& tri, auto const& r) { return intersect(r, tri); };
    STATIC_REQUIRE(mistake<decltype(swapped), mesh_bvh> == intersector_mistake::swapped_parameters);
    auto sphere_only = [](auto const& r, canopy::sphere const& s) { return intersect(r, s); };
    STATIC_REQUIRE(mistake<decltype(sphere_only), mesh_bvh> == intersector_mistake::no_usable_hook);
}

TEST_CASE("a const intersector with const hooks and a const filter has them called, at every level") {
    nested_scene const scene(121);
    random_source rng(122);
    unsigned hooks = 0, boxes = 0, filtered = 0;
    const_alpha_mask const isect{{}, &hooks, &boxes, &filtered};
    int hits = 0, differ_from_default = 0;
    for (ray const& r : random_rays(rng, scene.top.bounds(), 300)) {
        alpha_mask_filtered reference;
        auto const a = canopy::closest_hit(r, &scene.top, &scene.top + 1, isect);
        auto const b = canopy::closest_hit(r, &scene.top, &scene.top + 1, reference);
        CHECK(same_record(a, b));
        CHECK(canopy::any_hit(r, &scene.top, &scene.top + 1, isect).hit ==
              canopy::any_hit(r, &scene.top, &scene.top + 1, reference).hit);
        hits += a.hit;
        differ_from_default += !same_record(a, canopy::closest_hit(r, &scene.top, &scene.top + 1));
    }
    CHECK(hits > 50);
    CHECK(differ_from_default > 10); // the mask and the filter acted
    CHECK(hooks > 1000u);
    CHECK(boxes > 1000u);
    CHECK(filtered > 0u);
}

TEST_CASE("an instance with a transform that has no inverse is refused when it is made") {
    mesh_bvh const b = canopy::build_binned_sah(stacked_triangles());
    using xf = canopy::affine_transform<float>;
    auto const refused = [&](xf const& t, std::uint32_t id) -> std::string {
        try {
            mesh_instance const inst(b, t, id);
            return "accepted";
        } catch (std::invalid_argument const& e) {
            return e.what();
        }
    };
    // Rank 2: the third row is the sum of the first two.
    CHECK(refused(xf::from_rows({1, 0, 0, 0, 0, 1, 0, 0, 1, 1, 0, 0}), 4) ==
          "canopy::instance 4: the object-to-world transform is singular (determinant 0): it has no inverse, "
          "so rays cannot enter the instance");
    CHECK(refused(xf::from_rows({0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3}), 5) ==
          "canopy::instance 5: the object-to-world transform is singular (determinant 0): it has no inverse, "
          "so rays cannot enter the instance");
    float const nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
    CHECK(refused(xf::from_rows({1, 0, 0, nan, 0, 1, 0, 0, 0, 0, 1, 0}), 6) ==
          "canopy::instance 6: the object-to-world transform has a NaN or infinite entry");
    CHECK(refused(xf::from_rows({1, 0, 0, 0, 0, inf, 0, 0, 0, 0, 1, 0}), 7) ==
          "canopy::instance 7: the object-to-world transform has a NaN or infinite entry");
    // Invertible in double, but the inverse (1e39 on the diagonal) overflows float.
    CHECK(refused(xf::from_rows({1e-39f, 0, 0, 0, 0, 1e-39f, 0, 0, 0, 0, 1e-39f, 0}), 8) ==
          "canopy::instance 8: the object-to-world transform is nearly singular (determinant 1e-117): its inverse "
          "overflows");
    // Tiny but invertible scales, and reflections, are accepted.
    CHECK(refused(xf::from_rows({1e-20f, 0, 0, 0, 0, 1e-20f, 0, 0, 0, 0, 1e-20f, 0}), 9) == "accepted");
    CHECK(refused(xf::from_rows({-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0}), 10) == "accepted");
}

TEST_CASE("instances stay valid when their BVH moves (a growing vector of BVHs)") {
    random_source rng(131);
    auto const soup = triangle_soup(rng, 300, 1.0f, 0.4f);
    std::vector<mesh_bvh> meshes;
    meshes.push_back(canopy::build_binned_sah(soup));
    auto const nodes = meshes[0].wide_nodes.data();
    std::vector<mesh_instance> placed;
    for (std::uint32_t k = 0; k < 6; ++k) placed.emplace_back(meshes[0], random_transform(rng, 3.0f), k);
    // Grow the vector until the first BVH has moved to new storage several times.
    auto const first_address = &meshes[0];
    for (int k = 0; k < 40; ++k) meshes.push_back(canopy::build_binned_sah(stacked_triangles()));
    REQUIRE(&meshes[0] != first_address);
    REQUIRE(meshes[0].wide_nodes.data() == nodes); // the arrays the instances use stayed in place
    two_level const top = canopy::build_binned_sah(placed);
    // Reference: the same instances of a copy of the BVH that never moved (the build is
    // deterministic): every result bit for bit.
    mesh_bvh const still = canopy::build_binned_sah(soup);
    std::vector<mesh_instance> placed_still;
    for (auto const& inst : placed) placed_still.emplace_back(still, inst.object_to_world, inst.inst_id);
    two_level const top_still = canopy::build_binned_sah(placed_still);
    int hits = 0;
    for (ray const& r : random_rays(rng, top.bounds(), 400)) {
        auto const hr = canopy::closest_hit(r, &top, &top + 1);
        CHECK(same_record(hr, canopy::closest_hit(r, &top_still, &top_still + 1)));
        CHECK(same_records(canopy::multi_hit<3>(r, &top, &top + 1), canopy::multi_hit<3>(r, &top_still, &top_still + 1)));
        hits += hr.hit;
    }
    CHECK(hits > 100);
}
