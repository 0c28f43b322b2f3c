// A primitive type the library has never seen joins BVHs, instances, queries and intersectors
// through the documented customization points: get_bounds and intersect, found by ADL.
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>
import canopy.query;

namespace user {

// A disc in the plane z = center.z, facing ±z.
struct disc {
    canopy::vec3<float> center;
    float radius = 1.0f;
    std::uint32_t prim_id = 0;
    std::uint32_t geom_id = 0;
};

canopy::aabb get_bounds(disc const& d) {
    return {d.center - canopy::vec3<float>(d.radius, d.radius, 0.0f), d.center + canopy::vec3<float>(d.radius, d.radius, 0.0f)};
}

canopy::basic_hit_record<float> intersect(canopy::ray const& r, disc const& d) {
    canopy::basic_hit_record<float> hr;
    float const t = (d.center.z - r.origin.z) / r.direction.z;
    if (!(t >= r.tmin && t <= r.tmax)) return hr;
    float const x = r.origin.x + t * r.direction.x - d.center.x;
    float const y = r.origin.y + t * r.direction.y - d.center.y;
    if (!(x * x + y * y <= d.radius * d.radius)) return hr;
    hr.hit = true;
    hr.t = t;
    hr.prim_id = d.prim_id;
    hr.geom_id = d.geom_id;
    return hr;
}

// A structure of the user's own: discs in a list, tested one by one. It joins the library's BVHs
// and queries through the traversal protocol (canopy.bvh:protocol): a tag, bounds, and a traverse
// that hands every disc to call_hooks_or_descend.
struct disc_list {
    using acceleration_structure_tag = void;
    std::vector<disc> discs;
    int* traversals = nullptr; // counts the calls of traverse
};

canopy::aabb get_bounds(disc_list const& l) {
    canopy::aabb box;
    for (auto const& d : l.discs) box = canopy::extend(box, get_bounds(d));
    return box;
}

template <typename Ray, typename I, typename Collector>
bool traverse(Ray& ray, disc_list const& l, I& isect, Collector& collector) {
    if (l.traversals) ++*l.traversals;
    for (auto const& d : l.discs)
        if (canopy::call_hooks_or_descend(ray, d, isect, collector)) return true;
    return false;
}

} // namespace user

static_assert(canopy::primitive<user::disc> && !canopy::acceleration_structure<user::disc>);
static_assert(canopy::acceleration_structure<user::disc_list> && !canopy::primitive<user::disc_list>);
static_assert(canopy::acceleration_structure<canopy::bvh<user::disc_list>>);
static_assert(canopy::primitive<canopy::triangle> && canopy::acceleration_structure<canopy::bvh<canopy::triangle>>);

namespace {

std::vector<user::disc> make_discs(std::size_t n) {
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> pos(-10.0f, 10.0f), rad(0.2f, 1.5f);
    std::vector<user::disc> discs(n);
    for (auto& d : discs) d = {{pos(rng), pos(rng), pos(rng)}, rad(rng), 999u, 7u};
    return discs;
}

// Brute force in input order: the closest hit, ties to the smaller index.
canopy::basic_hit_record<float> brute_force(canopy::ray const& r, std::vector<user::disc> const& discs) {
    canopy::basic_hit_record<float> best;
    for (std::size_t i = 0; i < discs.size(); ++i) {
        user::disc d = discs[i];
        d.prim_id = std::uint32_t(i);
        auto const hr = user::intersect(r, d);
        if (hr.hit && (!best.hit || hr.t < best.t)) best = hr;
    }
    return best;
}

canopy::ray random_ray(std::mt19937& rng) {
    std::uniform_real_distribution<float> pos(-12.0f, 12.0f), dir(-1.0f, 1.0f);
    return {{pos(rng), pos(rng), 15.0f}, 0.0f, {0.3f * dir(rng), 0.3f * dir(rng), -1.0f}, 100.0f};
}

} // namespace

TEST_CASE("a user-defined primitive builds into a BVH and matches brute force") {
    auto const discs = make_discs(500);
    auto const b = canopy::build_binned_sah(discs);
    REQUIRE(b.primitives.size() == discs.size());
    std::mt19937 rng(11);
    int mismatches = 0, hits = 0;
    for (int k = 0; k < 2000; ++k) {
        auto const r = random_ray(rng);
        auto const expected = brute_force(r, discs);
        auto const got = canopy::closest_hit(r, &b, &b + 1);
        hits += expected.hit;
        mismatches += expected.hit != got.hit || (got.hit && (got.t != expected.t || got.prim_id != expected.prim_id ||
                                                               got.geom_id != 7u));
    }
    CHECK(hits > 200);
    CHECK(mismatches == 0);
}

TEST_CASE("a user-defined primitive is instanced and reached by a custom intersector at every level") {
    auto const discs = make_discs(200);
    auto const b = canopy::build_binned_sah(discs);
    using inst_t = canopy::instance<canopy::bvh<user::disc>>;
    std::vector<inst_t> instances{inst_t(b, canopy::affine_transform<float>::identity(), 0)};
    auto const top = canopy::build_binned_sah(instances);

    // A hook for the user's type that rejects odd prim ids; it must see every candidate.
    struct reject_odd : canopy::basic_intersector<reject_odd> {
        using canopy::basic_intersector<reject_odd>::operator();
        auto operator()(canopy::ray const& r, user::disc const& d) {
            ++calls;
            auto hr = intersect(r, d);
            if (hr.hit && hr.prim_id % 2 == 1) hr.hit = false;
            return hr;
        }
        int calls = 0;
    };

    std::mt19937 rng(5);
    int mismatches = 0, hits = 0;
    reject_odd isect;
    for (int k = 0; k < 1000; ++k) {
        auto const r = random_ray(rng);
        canopy::basic_hit_record<float> expected;
        for (std::size_t i = 0; i < discs.size(); i += 2) {
            user::disc d = discs[i];
            d.prim_id = std::uint32_t(i);
            auto const hr = user::intersect(r, d);
            if (hr.hit && (!expected.hit || hr.t < expected.t)) expected = hr;
        }
        auto const got = canopy::closest_hit(r, &top, &top + 1, isect);
        hits += expected.hit;
        mismatches += expected.hit != got.hit ||
                      (got.hit && (got.t != expected.t || got.prim_id != expected.prim_id || got.inst_id != 0u));
    }
    CHECK(hits > 50);
    CHECK(isect.calls > 0);
    CHECK(mismatches == 0);
}

TEST_CASE("a user-defined acceleration structure is traversed inside the library's BVHs and queries") {
    // Discs in 12 lists of 40, the lists in a BVH; every disc keeps its index as prim_id.
    auto discs = make_discs(480);
    for (std::size_t i = 0; i < discs.size(); ++i) discs[i].prim_id = std::uint32_t(i);
    int traversals = 0;
    std::vector<user::disc_list> lists(12);
    for (std::size_t i = 0; i < discs.size(); ++i) lists[i / 40].discs.push_back(discs[i]);
    for (auto& l : lists) l.traversals = &traversals;
    auto const b = canopy::build_binned_sah(lists);

    std::mt19937 rng(13);
    int mismatches = 0, hits = 0;
    for (int k = 0; k < 1000; ++k) {
        auto const r = random_ray(rng);
        // Brute force over the discs, with their own ids.
        canopy::basic_hit_record<float> expected;
        for (auto const& d : discs) {
            auto const hr = user::intersect(r, d);
            if (hr.hit && (!expected.hit || hr.t < expected.t || (hr.t == expected.t && hr.prim_id < expected.prim_id)))
                expected = hr;
        }
        auto const in_bvh = canopy::closest_hit(r, &b, &b + 1);
        auto const in_range = canopy::closest_hit(r, lists.begin(), lists.end());
        hits += expected.hit;
        for (auto const& got : {in_bvh, in_range})
            mismatches += expected.hit != got.hit || (got.hit && (got.t != expected.t || got.prim_id != expected.prim_id));
        // any_hit finds a hit exactly when there is one.
        mismatches += canopy::any_hit(r, &b, &b + 1).hit != expected.hit;
    }
    CHECK(hits > 100);
    CHECK(traversals > 0);
    CHECK(mismatches == 0);
}
