// Tests of canopy.query:batch: closest_hit, any_hit and multi_hit<4> over spans of rays, through
// a mesh BVH, a BVH of instances (rotated, scaled) and a two-level nesting, with and without
// intersectors. The reference is the single-ray query of each ray; every field of every result is
// compared bit for bit.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <random>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

import canopy.query;
import canopy.testing;

namespace {

using canopy::ray;
using canopy::triangle;
using canopy::vec3;
using record = canopy::basic_hit_record<float>;
using test_support::checkerboard_opaque;
using test_support::make_ray;
using test_support::mesh_bvh;
using test_support::nested_scene;
using test_support::random_rays;
using test_support::random_source;
using test_support::triangle_soup;

constexpr float quiet_nan = std::numeric_limits<float>::quiet_NaN();
constexpr float inf = std::numeric_limits<float>::infinity();

bool identical(record const& a, record const& b) {
    return a.hit == b.hit && std::bit_cast<std::uint32_t>(a.t) == std::bit_cast<std::uint32_t>(b.t) &&
           std::bit_cast<std::uint32_t>(a.u) == std::bit_cast<std::uint32_t>(b.u) &&
           std::bit_cast<std::uint32_t>(a.v) == std::bit_cast<std::uint32_t>(b.v) && a.prim_id == b.prim_id &&
           a.geom_id == b.geom_id && a.inst_id == b.inst_id && a.inner_inst_id == b.inner_inst_id;
}

// A pinhole camera outside the box looking at its centre: w × h rays, row by row. side -1 puts
// the camera on the opposite side of the box (its rays' z signs flip).
std::vector<ray> camera_rays(canopy::aabb const& box, int w, int h, float side = 1.0f) {
    auto const c = canopy::center(box);
    float const extent = canopy::length(canopy::diagonal(box));
    vec3<float> const eye = c + vec3<float>(0.3f, 0.4f, 1.0f) * (side * extent);
    vec3<float> const forward = canopy::normalize(c - eye);
    vec3<float> const right = canopy::normalize(canopy::cross(forward, vec3<float>(0, 1, 0)));
    vec3<float> const up = canopy::cross(right, forward);
    std::vector<ray> rays;
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            float const x = (float(i) + 0.5f) / float(w) - 0.5f, y = (float(j) + 0.5f) / float(h) - 0.5f;
            rays.push_back(make_ray(eye, forward + right * (0.9f * x) + up * (0.9f * y)));
        }
    return rays;
}

// The same camera's rays in blocks of bw × bh pixels (w and h multiples of them), the blocks row by
// row, each block's pixels row by row.
std::vector<ray> camera_rays_in_blocks(canopy::aabb const& box, int w, int h, int bw, int bh, float side = 1.0f) {
    auto const rows = camera_rays(box, w, h, side);
    std::vector<ray> blocks;
    for (int by = 0; by < h; by += bh)
        for (int bx = 0; bx < w; bx += bw)
            for (int j = by; j < by + bh; ++j)
                for (int i = bx; i < bx + bw; ++i) blocks.push_back(rows[std::size_t(j * w + i)]);
    return blocks;
}

// Runs of `run` rays of a and of b in turn (a and b the same size, a multiple of run).
std::vector<ray> alternate_runs(std::vector<ray> const& a, std::vector<ray> const& b, std::size_t run) {
    std::vector<ray> out;
    for (std::size_t i = 0; i < a.size(); i += run) {
        out.insert(out.end(), a.begin() + std::ptrdiff_t(i), a.begin() + std::ptrdiff_t(i + run));
        out.insert(out.end(), b.begin() + std::ptrdiff_t(i), b.begin() + std::ptrdiff_t(i + run));
    }
    return out;
}

// Shadow-like rays: from points close together (a few per group of 8) towards one light.
std::vector<ray> shadow_rays(random_source& rng, canopy::aabb const& box, int count) {
    auto const c = canopy::center(box);
    float const extent = canopy::length(canopy::diagonal(box));
    vec3<float> const light = c + vec3<float>(-0.5f, 1.0f, 0.5f) * extent;
    std::vector<ray> rays;
    vec3<float> base = rng.point_in(box);
    for (int k = 0; k < count; ++k) {
        if (k % 8 == 0) base = rng.point_in(box);
        vec3<float> const p = base + rng.point(-1e-3f, 1e-3f) * extent;
        rays.push_back({p, 1e-4f, light - p, 1.0f});
    }
    return rays;
}

// Invalid rays in some groups: NaN tmin, NaN or infinite origin or direction, tmin > tmax.
void spoil(std::vector<ray>& rays) {
    for (std::size_t i = 0; i < rays.size(); i += 37) {
        switch (i % 5) {
        case 0: rays[i].tmin = quiet_nan; break;
        case 1: rays[i].origin.y = quiet_nan; break;
        case 2: rays[i].direction.z = inf; break;
        case 3: rays[i].tmax = -1.0f; break;
        default: rays[i].direction.x = quiet_nan; break;
        }
    }
}

// The checkerboard alpha rule as a filter, for scalar rays and packets.
struct alpha_filter : canopy::basic_intersector<alpha_filter> {
    template <typename Ray, typename T>
    canopy::simd::mask_type_t<T> filter(Ray const&, canopy::basic_hit_record<T> const& hr) const {
        if constexpr (canopy::simd::simd_width_v<T> == 1) {
            return checkerboard_opaque(hr.u, hr.v);
        } else {
            canopy::simd::mask_type_t<T> keep;
            for (int k = 0; k < canopy::simd::simd_width_v<T>; ++k) keep.set(k, checkerboard_opaque(hr.u[k], hr.v[k]));
            return keep;
        }
    }
};

// The same rule in a triangle hook, which also counts its calls and the candidates (hit lanes)
// the library's test gives it.
struct alpha_hook : canopy::basic_intersector<alpha_hook> {
    using canopy::basic_intersector<alpha_hook>::operator();
    std::uint64_t calls = 0, candidates = 0;
    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) {
        ++calls;
        auto hr = intersect(r, tri);
        using T = canopy::ray_value_t<Ray>;
        if constexpr (canopy::simd::simd_width_v<T> == 1) {
            candidates += hr.hit;
            hr.hit = hr.hit && checkerboard_opaque(hr.u, hr.v);
        } else {
            candidates += unsigned(std::popcount(canopy::simd::movemask(hr.hit)));
            for (int k = 0; k < canopy::simd::simd_width_v<T>; ++k)
                if (hr.hit[k] && !checkerboard_opaque(hr.u[k], hr.v[k])) hr.hit.set(k, false);
        }
        return hr;
    }
};

// Hooks for scalar rays only: the batch traces every ray on its own.
struct scalar_only_hook : canopy::basic_intersector<scalar_only_hook> {
    using canopy::basic_intersector<scalar_only_hook>::operator();
    std::uint64_t calls = 0;
    record operator()(ray const& r, triangle const& tri) {
        ++calls;
        return intersect(r, tri);
    }
};
struct scalar_template_hook : canopy::basic_intersector<scalar_template_hook> {
    using canopy::basic_intersector<scalar_template_hook>::operator();
    template <typename Ray>
    record operator()(Ray const& r, triangle const& tri) {
        auto hr = intersect(r, tri);
        hr.hit = hr.hit && checkerboard_opaque(hr.u, hr.v);
        return hr;
    }
};
struct scalar_only_filter : canopy::basic_intersector<scalar_only_filter> {
    template <typename Ray>
    bool filter(Ray const&, record const& hr) const {
        return checkerboard_opaque(hr.u, hr.v);
    }
};

struct tally {
    std::size_t packets = 0, single_rays = 0, hits = 0, mismatches = 0; // packets: in packets of 8 rays
    void add(canopy::batch_stats s) {
        packets += s.packets + 2 * s.wide_packets;
        single_rays += s.single_rays;
    }
};

// Every batch query of `rays` against the single-ray queries, with intersector `isect` (one
// fresh copy per query kind and path): closest_hit and any_hit with every coherent group a packet
// (batch_packing::always: the packets counted in `t`), then again with the adaptive policy.
template <typename It, typename I>
void compare(std::vector<ray> const& rays, It first, It last, I const& isect, tally& t) {
    using canopy::batch_packing;
    std::vector<record> single_closest, single_any;
    for (std::size_t i = 0; i < rays.size(); ++i) {
        auto b = isect;
        single_closest.push_back(canopy::closest_hit(rays[i], first, last, b));
        t.hits += single_closest.back().hit;
        b = isect;
        single_any.push_back(canopy::any_hit(rays[i], first, last, b));
    }
    for (auto packing : {batch_packing::always, batch_packing::adaptive}) {
        std::vector<record> out(rays.size());
        auto a = isect;
        auto const stats = canopy::closest_hit(rays, first, last, out, a, packing);
        if (packing == batch_packing::always) {
            t.add(stats);
            t.mismatches += stats.unpacked_rays != 0;
        }
        for (std::size_t i = 0; i < rays.size(); ++i) t.mismatches += !identical(out[i], single_closest[i]);
        std::vector<record> any(rays.size());
        a = isect;
        auto const any_stats = canopy::any_hit(rays, first, last, any, a, packing);
        if (packing == batch_packing::always) t.add(any_stats);
        std::unique_ptr<bool[]> occluded(new bool[rays.size() + 1]);
        auto c = isect;
        canopy::any_hit(rays, first, last, std::span<bool>(occluded.get(), rays.size()), c, packing);
        for (std::size_t i = 0; i < rays.size(); ++i) {
            t.mismatches += !identical(any[i], single_any[i]);
            t.mismatches += occluded[i] != single_any[i].hit;
        }
    }
    auto a = isect, b = isect;
    std::vector<std::array<record, 4>> multi(rays.size());
    t.add(canopy::multi_hit<4>(rays, first, last, std::span<std::array<record, 4>>(multi), a));
    for (std::size_t i = 0; i < rays.size(); ++i) {
        auto const s = canopy::multi_hit<4>(rays[i], first, last, b);
        for (std::size_t k = 0; k < 4; ++k) t.mismatches += !identical(multi[i][k], s[k]);
    }
}

struct scenes {
    std::vector<triangle> soup;
    mesh_bvh mesh;
    nested_scene nested{1401};
    explicit scenes(random_source& rng) : soup(triangle_soup(rng, 3000, 8.0f, 1.0f)), mesh(canopy::build_binned_sah(soup)) {}
};

template <typename I>
void compare_everywhere(I const& isect, tally& coherent, tally& incoherent) {
    random_source rng(1402);
    scenes const s(rng);
    auto run = [&](canopy::aabb const& box, auto first, auto last) {
        auto cam = camera_rays(box, 40, 25);
        spoil(cam);
        compare(cam, first, last, isect, coherent);
        compare(shadow_rays(rng, box, 400), first, last, isect, coherent);
        compare(random_rays(rng, box, 600), first, last, isect, incoherent);
    };
    run(s.mesh.bounds(), &s.mesh, &s.mesh + 1);
    run(s.nested.middle.bounds(), &s.nested.middle, &s.nested.middle + 1);
    run(s.nested.top.bounds(), &s.nested.top, &s.nested.top + 1);
    // A range of instances (no top-level BVH).
    run(s.nested.middle.bounds(), s.nested.level1.begin(), s.nested.level1.end());
}

} // namespace

TEST_CASE("batch queries equal the single-ray queries bit for bit, without an intersector") {
    tally coherent, incoherent;
    compare_everywhere(canopy::default_intersector{}, coherent, incoherent);
    CHECK(coherent.mismatches == 0);
    CHECK(incoherent.mismatches == 0);
    CHECK(coherent.hits > 1000);
    CHECK(incoherent.hits > 500);
    // Camera and shadow rays form packets; random rays almost never share an octant.
    CHECK(coherent.packets * 8 > coherent.single_rays);
    CHECK(incoherent.packets * 50 < incoherent.single_rays);
}

TEST_CASE("batch queries equal the single-ray queries with an alpha filter and an alpha triangle hook") {
    tally coherent, incoherent;
    compare_everywhere(alpha_filter{}, coherent, incoherent);
    CHECK(coherent.mismatches == 0);
    CHECK(incoherent.mismatches == 0);
    CHECK(coherent.packets > 100);
    tally coherent_hook, incoherent_hook;
    compare_everywhere(alpha_hook{}, coherent_hook, incoherent_hook);
    CHECK(coherent_hook.mismatches == 0);
    CHECK(incoherent_hook.mismatches == 0);
    CHECK(coherent_hook.packets == coherent.packets);
}

TEST_CASE("intersectors with hooks or filters for scalar rays only make the batch trace single rays") {
    tally coherent, incoherent;
    compare_everywhere(scalar_only_hook{}, coherent, incoherent);
    CHECK(coherent.mismatches == 0);
    CHECK(coherent.packets == 0);
    tally coherent_filter, incoherent_filter;
    compare_everywhere(scalar_only_filter{}, coherent_filter, incoherent_filter);
    CHECK(coherent_filter.mismatches == 0);
    CHECK(coherent_filter.packets == 0);
    tally coherent_template, incoherent_template;
    compare_everywhere(scalar_template_hook{}, coherent_template, incoherent_template);
    CHECK(coherent_template.mismatches == 0);
    CHECK(coherent_template.packets == 0);
    // The hook is called once per triangle test of each ray, as in the single-ray queries.
    random_source rng(1403);
    scenes const s(rng);
    auto const rays = camera_rays(s.mesh.bounds(), 16, 16);
    std::vector<record> out(rays.size());
    scalar_only_hook batch, single;
    canopy::closest_hit(rays, &s.mesh, &s.mesh + 1, out, batch);
    for (auto const& r : rays) canopy::closest_hit(r, &s.mesh, &s.mesh + 1, single);
    CHECK(batch.calls == single.calls);
    CHECK(batch.calls > rays.size());
}

TEST_CASE("batch any_hit gives a triangle hook the candidates of the single rays, lane by lane") {
    random_source rng(1404);
    scenes const s(rng);
    auto check = [&](auto first, auto last, canopy::aabb const& box) {
        auto rays = camera_rays(box, 32, 32);
        spoil(rays);
        std::vector<record> out(rays.size());
        alpha_hook batch, single;
        auto const stats = canopy::any_hit(rays, first, last, out, batch);
        for (auto const& r : rays) canopy::any_hit(r, first, last, single);
        CHECK(stats.packets + 2 * stats.wide_packets > 50);
        CHECK(batch.candidates == single.candidates);
        CHECK(single.candidates > 50);
        // Calls are per packet, shared by its lanes. Their number is not compared with the single
        // rays': a packet visits the union of its lanes' leaves and goes on through a leaf after
        // some lanes found their hit, so it may make more calls or fewer depending on the tree's
        // shape (blocks of 4 or 8, the collapse to wide nodes). The candidates above are equal.
    };
    check(&s.mesh, &s.mesh + 1, s.mesh.bounds());
    check(&s.nested.top, &s.nested.top + 1, s.nested.top.bounds());
}

TEST_CASE("batches of 0, 1, 7, 9 and 1000 rays, and the decision per group of 8") {
    random_source rng(1405);
    scenes const s(rng);
    auto const all = camera_rays(s.mesh.bounds(), 40, 25);
    for (std::size_t n : {std::size_t(0), std::size_t(1), std::size_t(7), std::size_t(9), std::size_t(1000)}) {
        std::vector<ray> const rays(all.begin(), all.begin() + std::ptrdiff_t(n));
        tally t;
        compare(rays, &s.mesh, &s.mesh + 1, canopy::default_intersector{}, t);
        CHECK(t.mismatches == 0);
        std::vector<record> out(n);
        auto const stats = canopy::closest_hit(rays, &s.mesh, &s.mesh + 1, out);
        CHECK(stats.packets * 8 + stats.wide_packets * 16 + stats.single_rays == n);
        CHECK(stats.single_rays >= n % 8);
    }
    // One group of 8 from one origin: a packet while the directions share an octant.
    std::vector<ray> group(8, make_ray({0, 0, -20}, {0.1f, 0.2f, 1.0f}));
    for (std::size_t k = 0; k < 8; ++k) group[k].direction.x += 0.01f * float(k);
    std::vector<record> out(8);
    CHECK(canopy::closest_hit(group, &s.mesh, &s.mesh + 1, out).packets == 1);
    group[3].direction.y = -0.2f; // another octant
    CHECK(canopy::closest_hit(group, &s.mesh, &s.mesh + 1, out).packets == 0);
    group[3].direction.y = 0.2f;
    // Origins apart by just under, then just over, batch_origin_spread of the box's largest side.
    auto const d = canopy::diagonal(s.mesh.bounds());
    float const limit = std::max({d.x, d.y, d.z}) * canopy::batch_origin_spread;
    group[5].origin.x += 0.95f * limit;
    CHECK(canopy::closest_hit(group, &s.mesh, &s.mesh + 1, out).packets == 1);
    group[5].origin.x = group[0].origin.x + 1.05f * limit;
    CHECK(canopy::closest_hit(group, &s.mesh, &s.mesh + 1, out).packets == 0);
    group[5].origin.x = group[0].origin.x;
    for (std::size_t k = 1; k < 8; ++k) group[k].tmin = quiet_nan; // one ray takes part: traced alone
    CHECK(canopy::closest_hit(group, &s.mesh, &s.mesh + 1, out).packets == 0);
    group[1].tmin = 0.0f; // two: a packet, the other lanes inactive
    CHECK(canopy::closest_hit(group, &s.mesh, &s.mesh + 1, out).packets == 1);
    for (std::size_t k = 0; k < 8; ++k) CHECK(identical(out[k], canopy::closest_hit(group[k], &s.mesh, &s.mesh + 1)));
    // Fewer results than rays: an error, nothing traced.
    std::vector<record> short_out(7);
    CHECK_THROWS_AS(canopy::closest_hit(group, &s.mesh, &s.mesh + 1, short_out), std::invalid_argument);
}

TEST_CASE("with spatial splits, batch queries are bit-identical too, any hit included") {
    // build_quality::high: one needle may sit in several leaves, each box bounding only its part.
    // A packet tests a leaf only for the lanes that reached it: a lane never meets a needle in a
    // leaf it would not visit alone, so its first any-hit candidate is the single ray's.
    random_source rng(1406);
    auto const soup = test_support::needle_soup(rng, 3000, 8.0f, 0.05f);
    mesh_bvh const b = canopy::build_binned_sah(soup, {.quality = canopy::build_quality::high, .split_budget = 3.0f});
    auto rays = camera_rays(b.bounds(), 64, 48);
    spoil(rays);
    tally t;
    compare(rays, &b, &b + 1, canopy::default_intersector{}, t);
    compare(rays, &b, &b + 1, alpha_filter{}, t);
    CHECK(t.packets > 400);
    CHECK(t.hits > 1000);
    CHECK(t.mismatches == 0);
    alpha_hook batch, single;
    std::vector<record> out(rays.size());
    canopy::any_hit(rays, &b, &b + 1, out, batch);
    for (auto const& r : rays) canopy::any_hit(r, &b, &b + 1, single);
    CHECK(batch.candidates == single.candidates);
}

TEST_CASE("packets down to one or two lanes continue as single rays with the single rays' results") {
    // Below packet_lanes_alone_below lanes at a node (or a leaf of instances), a packet with no
    // intersector traces each lane from there alone. Packets whose lanes spread over the scene
    // split early, at every level of instancing; packets with two rays taking part do so where
    // the two part.
    static_assert(canopy::packet_lanes_alone_below >= 2, "the cases below would not reach lanes traced alone");
    random_source rng(1407);
    scenes const s(rng);
    auto check = [&](canopy::aabb const& box, auto first, auto last) {
        tally t;
        // Groups of 8 from one origin whose directions share an octant but fan out widely. Groups
        // look from opposite corners in turn (octants + + + and - - -), so that no run of 16 rays
        // is coherent (where 16-lane vectors are native) and each group of 8 is decided alone.
        auto const c = canopy::center(box);
        float const extent = canopy::length(canopy::diagonal(box));
        std::vector<ray> rays;
        for (int g = 0; g < 120; ++g) {
            float const side = g % 2 == 0 ? 1.0f : -1.0f;
            vec3<float> const eye = c + vec3<float>(-0.7f, -0.6f, -1.0f) * (side * extent) + rng.point(-0.01f, 0.01f) * extent;
            for (int k = 0; k < 8; ++k) {
                vec3<float> const target = rng.point_in(box);
                vec3<float> const towards = (target - eye) * side;
                rays.push_back(make_ray(eye, canopy::max(towards, vec3<float>(1e-3f, 1e-3f, 1e-3f)) * side));
            }
            // Some groups keep one or two rays taking part.
            if (g % 3 == 1)
                for (std::size_t k = 1; k < 8; ++k) rays[rays.size() - 8 + k].tmin = quiet_nan;
            if (g % 3 == 2)
                for (std::size_t k = 2; k < 8; ++k) rays[rays.size() - 8 + k].tmax = -1.0f;
        }
        canopy::detail::packet_occupancy_tally = {};
        compare(rays, first, last, canopy::default_intersector{}, t);
        CHECK(canopy::detail::packet_occupancy_tally.lanes_alone > 0); // the case under test happened
        CHECK(t.mismatches == 0);
        CHECK(t.packets == 2 * 80); // closest and any: the groups of 2 and of 8 rays taking part
        CHECK(t.hits > 80);
    };
    check(s.mesh.bounds(), &s.mesh, &s.mesh + 1);
    check(s.nested.top.bounds(), &s.nested.top, &s.nested.top + 1);
    check(s.nested.middle.bounds(), s.nested.level1.begin(), s.nested.level1.end());
}

TEST_CASE("adaptive packing keeps packets where their lanes stay together and traces single rays where they part") {
    // The same camera over a few large triangles (a packet's lanes reach the same nodes) and over
    // 60,000 small ones (8 neighbouring rays part near the root). The adaptive policy measures the
    // packets' lanes per node visit and lanes gone on alone (canopy.bvh:traverse,
    // packet_occupancy) and unpacks only the second; the results are the single rays' either way,
    // and the choices the same on every run.
    using canopy::batch_packing;
    random_source rng(1408);
    auto const coarse_soup = triangle_soup(rng, 200, 8.0f, 4.0f);
    auto const fine_soup = triangle_soup(rng, 60000, 8.0f, 0.05f);
    mesh_bvh const coarse = canopy::build_binned_sah(coarse_soup);
    mesh_bvh const fine = canopy::build_binned_sah(fine_soup);
    // In squares of 4 × 2 already: packets of 8 consecutive rays (rows would make squares of 4 × 4,
    // packets of 16, where 16-lane vectors are native). The squares of two cameras on opposite
    // sides in turn, so that no run of 16 rays is coherent either (their z signs differ).
    auto const rays = alternate_runs(camera_rays_in_blocks(coarse.bounds(), 64, 48, 4, 2),
                                     camera_rays_in_blocks(coarse.bounds(), 64, 48, 4, 2, -1.0f), 8);

    // Over every coherent group traced as a packet: the lanes per node visit, in eighths of a
    // lane, and the lanes gone on alone per packet, in halves.
    struct measure {
        double occupancy_eighths, alone_halves;
    };
    auto measure_packets = [&](mesh_bvh const& b) {
        std::vector<record> out(rays.size());
        canopy::detail::packet_occupancy_tally = {};
        auto const stats =
            canopy::closest_hit(rays, &b, &b + 1, out, canopy::default_intersector{}, batch_packing::always);
        auto const o = canopy::detail::packet_occupancy_tally;
        REQUIRE(o.node_visits > 0);
        REQUIRE(stats.packets > 0);
        return measure{double(8 * o.node_lanes) / double(o.node_visits), double(2 * o.lanes_alone) / double(stats.packets)};
    };
    auto const paying = double(canopy::batch_paying_occupancy_eighths);
    auto const alone_limit = double(canopy::batch_lanes_alone_halves);
    auto const c = measure_packets(coarse);
    CHECK(c.occupancy_eighths >= paying);
    CHECK(c.alone_halves <= alone_limit);
    auto const f = measure_packets(fine);
    CHECK((f.occupancy_eighths < paying || f.alone_halves > alone_limit));

    auto check = [&](mesh_bvh const& b, auto const& isect, bool expect_unpacked) {
        std::vector<record> single(rays.size());
        for (std::size_t i = 0; i < rays.size(); ++i) single[i] = canopy::closest_hit(rays[i], &b, &b + 1, isect);
        std::vector<record> always(rays.size()), adaptive(rays.size()), again(rays.size());
        auto const s_always = canopy::closest_hit(rays, &b, &b + 1, always, isect, batch_packing::always);
        auto const s_adaptive = canopy::closest_hit(rays, &b, &b + 1, adaptive, isect);
        auto const s_again = canopy::closest_hit(rays, &b, &b + 1, again, isect, batch_packing::adaptive);
        std::size_t mismatches = 0;
        for (std::size_t i = 0; i < rays.size(); ++i)
            mismatches += !identical(always[i], single[i]) + !identical(adaptive[i], single[i]) + !identical(again[i], single[i]);
        CHECK(mismatches == 0);
        // Coherent groups: all but those whose rays change octant in the image's middle.
        std::size_t const coherent = s_always.packets * 8;
        CHECK(coherent + s_always.single_rays == rays.size());
        CHECK(coherent > rays.size() / 2);
        CHECK(s_always.unpacked_rays == 0);
        CHECK(s_adaptive.packets * 8 + s_adaptive.unpacked_rays == coherent);
        CHECK(s_adaptive.single_rays == s_always.single_rays + s_adaptive.unpacked_rays);
        CHECK(s_again.packets == s_adaptive.packets);
        CHECK(s_again.unpacked_rays == s_adaptive.unpacked_rays);
        if (expect_unpacked) {
            // The first window is packets; then mostly single rays, one group in 16 probing again.
            CHECK(s_adaptive.packets >= canopy::batch_first_probe_packets);
            CHECK(s_adaptive.unpacked_rays > coherent / 2);
        } else {
            CHECK(s_adaptive.unpacked_rays == 0);
        }
    };
    check(coarse, canopy::default_intersector{}, false);
    check(fine, canopy::default_intersector{}, true);
    // An intersector with a filter sees packets as documented, whatever they cost: never unpacked.
    check(fine, alpha_filter{}, false);
}

TEST_CASE("rays laid out in rows are traced in squares of 4 × 2, with the single rays' results") {
    random_source rng(1411);
    scenes const s(rng);
    auto const box = s.mesh.bounds();
    auto const row_length = [&](std::vector<ray> const& rays, auto first, auto last) {
        std::vector<record> out(rays.size());
        return canopy::closest_hit(rays, first, last, out, canopy::default_intersector{}, canopy::batch_packing::always)
            .row_length;
    };
    // Packets of 16 exactly where 16-lane vectors are native, every ray traced once, and the
    // single rays' results without an intersector, with `isect`, and through instances.
    auto const check_packets_of_16 = [&](std::vector<ray> const& rays, auto const& isect) {
        std::vector<record> out(rays.size());
        auto const stats = canopy::closest_hit(rays, &s.mesh, &s.mesh + 1, out, canopy::default_intersector{},
                                               canopy::batch_packing::always);
        CHECK((stats.wide_packets > 0) == canopy::simd::native_width<16>);
        CHECK(stats.packed_rays() + stats.single_rays == rays.size());
        tally t;
        compare(rays, &s.mesh, &s.mesh + 1, canopy::default_intersector{}, t);
        compare(rays, &s.mesh, &s.mesh + 1, isect, t);
        compare(rays, &s.nested.top, &s.nested.top + 1, canopy::default_intersector{}, t);
        CHECK(t.mismatches == 0);
        CHECK(t.packets > 0);
    };
    // Widths that are and are not multiples of 4; heights that leave a tail past the last band.
    // (camera_rays spans the same angle across and down: its pixels are w / h times as tall as wide.)
    for (auto [w, h] : {std::pair{40, 25}, std::pair{38, 20}, std::pair{64, 51}, std::pair{9, 30}}) {
        CAPTURE(w, h);
        auto const rays = camera_rays(box, w, h);
        CHECK(row_length(rays, &s.mesh, &s.mesh + 1) == std::size_t(w));
        // Squares of 4 × 4 as packets of 16 where 16-lane vectors are native; 4 × 2 as packets of 8
        // elsewhere.
        check_packets_of_16(rays, alpha_filter{});
        // A span that starts inside a row: the length is found from the first two row ends.
        std::vector<ray> const shifted(rays.begin() + 13, rays.end());
        CHECK(row_length(shifted, &s.mesh, &s.mesh + 1) == std::size_t(w));
        tally u;
        compare(shifted, &s.mesh, &s.mesh + 1, canopy::default_intersector{}, u);
        CHECK(u.mismatches == 0);
    }
    // Squares that are no tighter than runs of 8: rays already in tiles, random rays, one row, and
    // pixels 9 times as tall as wide (a square of 4 × 2 spans 3 widths and a height, a run of 8 spans
    // 7 widths).
    CHECK(row_length(camera_rays(box, 64, 7), &s.mesh, &s.mesh + 1) == 0);
    CHECK(row_length(camera_rays_in_blocks(box, 40, 24, 4, 4), &s.mesh, &s.mesh + 1) == 0);
    // Rays already in tiles of 4 × 4: runs of 16 as packets of 16 where 16-lane vectors are native,
    // with the single rays' results.
    check_packets_of_16(camera_rays_in_blocks(box, 40, 24, 4, 4), alpha_hook{});
    CHECK(row_length(random_rays(rng, box, 2000), &s.mesh, &s.mesh + 1) == 0);
    CHECK(row_length(camera_rays(box, 600, 1), &s.mesh, &s.mesh + 1) == 0);
    // Invalid rays in the rows change nothing but their own results.
    auto spoilt = camera_rays(box, 40, 25);
    spoil(spoilt);
    CHECK(row_length(spoilt, &s.mesh, &s.mesh + 1) == 40);
    tally v;
    compare(spoilt, &s.mesh, &s.mesh + 1, alpha_hook{}, v);
    CHECK(v.mismatches == 0);
}
