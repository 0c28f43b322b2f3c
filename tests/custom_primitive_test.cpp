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

} // namespace user

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
