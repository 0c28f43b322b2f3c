// Tests of canopy.render and the alpha masks of canopy.scene, on rendered images. References are
// independent of the renderer: analytic ray/plane intersections in double precision with the
// shading formula written out, the procedural mask's rule written out, a second counting pass
// with a separately written counter, and the same image rendered under other thread counts.
#include <catch2/catch.hpp>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numbers>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>
#include <tbb/global_control.h>

import canopy.scene;
import canopy.plugins.procedural;

namespace {

using canopy::vec2;
using canopy::vec3;
using canopy::vec4;

constexpr int width = 64;
constexpr int height = 48;

// ---- a hand-built scene: a masked quad in front of a coloured backdrop -------------------

constexpr float front_half = 1.0f;  // front quad: [-1, 1]² in the plane z = 0
constexpr float front_z = 0.0f;
constexpr float back_half = 6.0f;   // backdrop: [-6, 6]² in the plane z = -1
constexpr float back_z = -1.0f;
constexpr int back_mesh = 0;
constexpr int front_mesh = 1;

vec3<float> const back_albedo{0.3f, 0.4f, 0.9f};
vec4<float> const transparent_texel{1.0f, 0.0f, 1.0f, 0.0f}; // left half of the texture
vec4<float> const opaque_texel{0.2f, 0.8f, 0.3f, 1.0f};      // right half

// A square facing +z with texture coordinates (0, 0) at the top-left corner (-half, half) and
// (1, 1) at the bottom-right one, as the billboards of the demo scene.
canopy::compiled_mesh make_quad(float half, float z, int material) {
    vec3<float> const a(-half, half, z), b(half, half, z), c(half, -half, z), d(-half, -half, z);
    canopy::compiled_mesh quad;
    quad.triangles = {canopy::triangle{a, b, c, 0, 0}, canopy::triangle{a, c, d, 1, 0}};
    quad.uvs = {{vec2<float>(0, 0), vec2<float>(1, 0), vec2<float>(1, 1)},
                {vec2<float>(0, 0), vec2<float>(1, 1), vec2<float>(0, 1)}};
    quad.material = material;
    return quad;
}

enum class front_kind { none, textured, procedural };

// Mesh 0 the backdrop, mesh 1 (unless `none`) the masked front quad: either textured with a
// 2 × 1 texture whose left texel is transparent, or untextured for the procedural mask. Both
// meshes are placed by identity instances, so hits report geom_id = mesh.
canopy::compiled_scene make_layered_scene(front_kind front) {
    canopy::compiled_scene s;
    s.materials = {canopy::material{back_albedo},
                   canopy::material{{1.0f, 1.0f, 1.0f}, front == front_kind::textured ? 0 : -1, canopy::alpha_mode::mask, 0.01f}};
    s.textures.emplace_back(2, 1, std::vector<vec4<float>>{transparent_texel, opaque_texel},
                            canopy::sampler{canopy::filter_mode::nearest, canopy::address_mode::clamp});
    s.meshes.push_back(make_quad(back_half, back_z, 0));
    if (front != front_kind::none) s.meshes.push_back(make_quad(front_half, front_z, 1));
    for (std::size_t k = 0; k < s.meshes.size(); ++k) {
        s.place(std::uint32_t(k), canopy::affine_transform<float>::identity());
    }
    s.build();
    return s;
}

canopy::pinhole_camera layered_camera(int w, int h) {
    return canopy::pinhole_camera::look_at({0.0f, 0.0f, 4.0f}, {0.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f}, 60.0f,
                                           float(w) / float(h));
}

canopy::ray pixel_ray(canopy::pinhole_camera const& camera, int x, int y, int w, int h) {
    return camera.primary_ray(float(x) + 0.5f, float(y) + 0.5f, w, h);
}

// Where a ray meets the plane z = plane_z, in double precision.
struct plane_point {
    double x, y;
};
plane_point meet_plane(canopy::ray const& r, double plane_z) {
    double const t = (plane_z - double(r.origin.z)) / double(r.direction.z);
    return {double(r.origin.x) + t * double(r.direction.x), double(r.origin.y) + t * double(r.direction.y)};
}

// Texture coordinates of a point of the front quad's plane (outside [0, 1]² when off the quad).
vec2<double> front_uv(plane_point p) {
    return {(p.x + double(front_half)) / (2.0 * double(front_half)),
            (double(front_half) - p.y) / (2.0 * double(front_half))};
}

// How far uv is from the quad's edges (negative outside).
double inside_distance(vec2<double> uv) {
    return std::min(std::min(uv.x, 1.0 - uv.x), std::min(uv.y, 1.0 - uv.y));
}

bool close(vec4<float> a, vec3<float> b, float tolerance = 1e-5f) {
    return std::fabs(a.x - b.x) <= tolerance && std::fabs(a.y - b.y) <= tolerance && std::fabs(a.z - b.z) <= tolerance;
}

bool same(vec4<float> a, vec4<float> b) { return a.x == b.x && a.y == b.y && a.z == b.z && a.w == b.w; }

std::string to_string(vec4<float> c) {
    return "(" + std::to_string(c.x) + ", " + std::to_string(c.y) + ", " + std::to_string(c.z) + ")";
}

template <typename I>
canopy::framebuffer render_primary(canopy::compiled_scene const& s, I const& isect, canopy::light_options const& light) {
    canopy::framebuffer fb(width, height);
    auto const camera = layered_camera(width, height);
    canopy::render_tiles(fb, [&](int x, int y) {
        return canopy::primary_kernel(s, pixel_ray(camera, x, y, width, height), isect, light);
    });
    return fb;
}

// ---- the demo forest, small -------------------------------------------------------------

// The demo forest (the procedural plugin's billboard_forest), small, compiled as the demo is.
canopy::compiled_scene small_forest() {
    canopy::registry r;
    canopy::register_procedural_plugin(r);
    canopy::scene s;
    r.generate(s, "billboard_forest", {{"billboards", "60"}, {"spheres", "5"}, {"seed", "7"}, {"texture_size", "32"}});
    return canopy::compile(s);
}

// The forest's own camera.
canopy::pinhole_camera forest_camera(canopy::compiled_scene const& forest) {
    return forest.render_camera(float(width) / float(height));
}

} // namespace

TEST_CASE("pixels over masked-out texels show what lies behind the billboard") {
    auto const scene = make_layered_scene(front_kind::textured);
    auto const backdrop_only = make_layered_scene(front_kind::none);
    canopy::texture_alpha_mask mask;
    mask.scene = &scene;
    canopy::texture_alpha_mask backdrop_mask;
    backdrop_mask.scene = &backdrop_only;

    // A slanted sun: the front quad's opaque half casts a shadow on the backdrop, its transparent
    // half does not.
    canopy::light_options light;
    light.sun_direction = canopy::normalize(vec3<float>(0.6f, 0.3f, 1.0f));
    float const cos_sun = light.sun_direction.z; // both quads face +z
    auto const lit = [&](vec3<float> albedo) { return albedo * light.ambient + albedo * light.sun_colour * cos_sun; };
    auto const shadowed = [&](vec3<float> albedo) { return albedo * light.ambient; };
    vec3<float> const front_opaque_albedo(opaque_texel.x, opaque_texel.y, opaque_texel.z);
    vec3<float> const front_hole_albedo(transparent_texel.x, transparent_texel.y, transparent_texel.z);

    auto const masked = render_primary(scene, mask, light);
    auto const unmasked = render_primary(scene, canopy::default_intersector{}, light);
    auto const behind = render_primary(backdrop_only, backdrop_mask, light);

    auto const camera = layered_camera(width, height);
    double const margin = 2e-3; // in texture coordinates of the front quad
    int over_hole = 0, over_opaque = 0, beside = 0, shadow_pixels = 0, mismatches = 0;
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            canopy::ray const r = pixel_ray(camera, x, y, width, height);
            vec2<double> const uv = front_uv(meet_plane(r, front_z));
            double const inside = inside_distance(uv);
            if (std::fabs(inside) < margin || (inside > 0.0 && std::fabs(uv.x - 0.5) < margin)) continue;
            bool const on_front = inside > 0.0;
            bool const on_opaque = on_front && uv.x > 0.5;

            // The backdrop point seen along the ray, and where its shadow ray crosses the front plane.
            plane_point const p = meet_plane(r, back_z);
            double const rise = double(front_z - back_z) / double(light.sun_direction.z);
            vec2<double> const shadow_uv = front_uv({p.x + rise * double(light.sun_direction.x),
                                                     p.y + rise * double(light.sun_direction.y)});
            double const shadow_inside = inside_distance(shadow_uv);
            if (!on_opaque && (std::fabs(shadow_inside) < margin ||
                               (shadow_inside > 0.0 && std::fabs(shadow_uv.x - 0.5) < margin)))
                continue;
            bool const in_shadow = shadow_inside > 0.0 && shadow_uv.x > 0.5;

            vec4<float> const got = masked.at(x, y);
            vec3<float> expected;
            if (on_opaque) {
                expected = lit(front_opaque_albedo);
                ++over_opaque;
            } else {
                expected = in_shadow ? shadowed(back_albedo) : lit(back_albedo);
                shadow_pixels += in_shadow;
                ++(on_front ? over_hole : beside);
            }
            bool ok = close(got, expected);
            // Through a hole, and with no shadow of the opaque half, the pixel is exactly the
            // pixel of the scene without the front quad.
            if (!on_opaque && !in_shadow) ok = ok && same(got, behind.at(x, y));
            // Without the mask, the whole front quad is seen, holes included.
            if (on_front) ok = ok && close(unmasked.at(x, y), lit(on_opaque ? front_opaque_albedo : front_hole_albedo));
            if (!ok) {
                ++mismatches;
                if (mismatches <= 5)
                    UNSCOPED_INFO("pixel (" << x << ", " << y << ") uv (" << uv.x << ", " << uv.y << "): got "
                                            << to_string(got) << ", expected " << to_string({expected, 1.0f})
                                            << ", without the mask " << to_string(unmasked.at(x, y)));
            }
        }
    CHECK(mismatches == 0);
    CHECK(over_hole > 100);
    CHECK(over_opaque > 100);
    CHECK(beside > 500);
    CHECK(shadow_pixels > 20);
}

TEST_CASE("the procedural mask pattern appears where its rule says") {
    auto const scene = make_layered_scene(front_kind::procedural);
    canopy::procedural_alpha_mask mask;
    mask.scene = &scene;
    int const w = 160, h = 120;
    auto const camera = layered_camera(w, h);

    // The rule, written out: d = 2·|uv − (½, ½)|; keep where d < 1 and frac(5d) < 0.6.
    double const margin = 2e-3;
    auto const rule = [&](vec2<double> uv) -> std::optional<bool> {
        double const d = 2.0 * std::hypot(uv.x - 0.5, uv.y - 0.5);
        double const rings = 5.0 * d;
        double const frac = rings - std::floor(rings);
        bool const near_ring_edge = std::fabs(rings - std::round(rings)) < 5.0 * margin ||
                                    std::fabs(frac - 0.6) < 5.0 * margin;
        if (near_ring_edge || std::fabs(d - 1.0) < margin) return std::nullopt;
        return d < 1.0 && frac < 0.6;
    };

    int checked = 0, kept = 0, cut = 0, mismatches = 0, uv_errors = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            canopy::ray const r = pixel_ray(camera, x, y, w, h);
            vec2<double> const uv = front_uv(meet_plane(r, front_z));
            double const inside = inside_distance(uv);
            if (std::fabs(inside) < margin) continue;
            bool expect_front = false;
            if (inside > 0.0) {
                auto const keeps = rule(uv);
                if (!keeps) continue;
                expect_front = *keeps;
                ++(expect_front ? kept : cut);
            }
            ++checked;
            auto const hit = scene.closest_hit(r, mask);
            REQUIRE(hit.hit);
            bool const got_front = hit.geom_id == std::uint32_t(front_mesh);
            if (got_front != expect_front) {
                ++mismatches;
                if (mismatches <= 5)
                    UNSCOPED_INFO("pixel (" << x << ", " << y << ") uv (" << uv.x << ", " << uv.y << "): front quad "
                                            << (got_front ? "hit" : "missed") << ", the rule says "
                                            << (expect_front ? "kept" : "cut"));
            }
            if (got_front) {
                vec2<float> const hit_uv = scene.uv(hit);
                uv_errors += std::fabs(double(hit_uv.x) - uv.x) > 1e-4 || std::fabs(double(hit_uv.y) - uv.y) > 1e-4;
            } else {
                CHECK(hit.geom_id == std::uint32_t(back_mesh));
            }
        }
    CHECK(mismatches == 0);
    CHECK(uv_errors == 0);
    CHECK(kept > 500);
    CHECK(cut > 500);
    CHECK(checked > w * h * 8 / 10);
}

namespace {

// A counter written independently of canopy::cost_counter: an overload set, no base class.
struct test_counter {
    std::uint64_t* boxes;
    std::uint64_t* triangles;

    template <typename Ray, typename InvDir>
    auto operator()(Ray const& r, canopy::aabb const& box, InvDir const& inv_dir) {
        ++*boxes;
        return intersect(r, box, inv_dir);
    }
    template <typename Ray>
    auto operator()(Ray const& r, canopy::triangle const& tri) {
        ++*triangles;
        return intersect(r, tri);
    }
};

// The separately written counter with the texture alpha mask's rule as its filter.
struct masked_test_counter : test_counter {
    canopy::texture_alpha_mask const* mask;

    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) const {
        return mask->keeps(hr);
    }
};

} // namespace

TEST_CASE("the heat map's total equals the counting intersector's totals") {
    auto const scene = small_forest();
    auto const camera = forest_camera(scene);

    // The cost image: per pixel the paper's bvh_costs counts (canopy::cost_counter), (boxes, triangles, sum).
    canopy::framebuffer costs(width, height);
    canopy::render_tiles(costs, [&](int x, int y) {
        canopy::cost_counter counter;
        scene.closest_hit(pixel_ray(camera, x, y, width, height), counter);
        return vec4<float>(float(counter.num_boxes), float(counter.num_tris),
                           float(counter.num_boxes + counter.num_tris), 1.0f);
    }, {.tile_size = 8, .progress = {}});
    std::uint64_t image_boxes = 0, image_triangles = 0, image_total = 0;
    for (auto const& p : costs.pixels) {
        image_boxes += std::uint64_t(p.x);
        image_triangles += std::uint64_t(p.y);
        image_total += std::uint64_t(p.z);
    }

    // A second pass over the same rays, one thread, the separately written counter.
    std::uint64_t boxes = 0, triangles = 0;
    std::vector<std::uint64_t> reference_costs;
    int pixel_mismatches = 0, hit_mismatches = 0, billboard_pixels = 0;
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            std::uint64_t pixel_boxes = 0, pixel_triangles = 0;
            test_counter counter{&pixel_boxes, &pixel_triangles};
            canopy::ray const r = pixel_ray(camera, x, y, width, height);
            auto const counted = scene.closest_hit(r, counter);
            boxes += pixel_boxes;
            triangles += pixel_triangles;
            reference_costs.push_back(pixel_boxes + pixel_triangles);
            pixel_mismatches += std::uint64_t(costs.at(x, y).x) != pixel_boxes ||
                                std::uint64_t(costs.at(x, y).y) != pixel_triangles;
            // Counting does not change what is hit.
            canopy::default_intersector none;
            auto const plain = scene.closest_hit(r, none);
            hit_mismatches += counted.hit != plain.hit || (plain.hit && (counted.t != plain.t ||
                                                                         counted.prim_id != plain.prim_id ||
                                                                         counted.inst_id != plain.inst_id));
            if (plain.hit && plain.geom_id == 2) {
                ++billboard_pixels;
                // Reaching a billboard's triangle takes at least the root box and one triangle test.
                CHECK(pixel_boxes >= 1);
                CHECK(pixel_triangles >= 1);
            }
        }
    CHECK(pixel_mismatches == 0);
    CHECK(hit_mismatches == 0);
    CHECK(image_boxes == boxes);
    CHECK(image_triangles == triangles);
    CHECK(image_total == boxes + triangles);
    CHECK(billboard_pixels > 50);
    CHECK(triangles > std::uint64_t(width * height));

    // The heat colours of the image are the heat colours of the second pass's counts.
    float const max_cost = float(image_total) / float(width * height) * 2.0f;
    int colour_mismatches = 0;
    for (std::size_t i = 0; i < costs.pixels.size(); ++i) {
        vec3<float> const a = canopy::heat_colour(costs.pixels[i].z, max_cost);
        vec3<float> const b = canopy::heat_colour(float(reference_costs[i]), max_cost);
        colour_mismatches += a.x != b.x || a.y != b.y || a.z != b.z;
    }
    CHECK(colour_mismatches == 0);
}

TEST_CASE("counting<texture_alpha_mask> counts every test while the mask decides the hits") {
    // Hooks for triangles and boxes make it a custom intersector (traversal calls it for every
    // test); it has the mask's filter, and counting<default_intersector> has none.
    using masked = canopy::counting<canopy::texture_alpha_mask>;
    STATIC_REQUIRE(canopy::primitive_hook_for<masked, canopy::ray, canopy::triangle>);
    STATIC_REQUIRE(canopy::box_hook_for<masked, canopy::ray, canopy::aabb, vec3<float>>);
    STATIC_REQUIRE(canopy::filter_hook_for<masked, canopy::ray>);
    STATIC_REQUIRE(canopy::primitive_hook_for<canopy::cost_counter, canopy::ray, canopy::triangle>);
    STATIC_REQUIRE(!canopy::filter_hook_for<canopy::cost_counter, canopy::ray>);
    auto const scene = small_forest();
    auto const camera = forest_camera(scene);
    canopy::texture_alpha_mask mask;
    mask.scene = &scene;

    int count_mismatches = 0, hit_mismatches = 0, masked_pixels = 0;
    std::uint64_t total = 0;
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            canopy::ray const r = pixel_ray(camera, x, y, width, height);
            canopy::counting<canopy::texture_alpha_mask> counter;
            counter.inner = mask;
            auto const counted = scene.closest_hit(r, counter);
            std::uint64_t boxes = 0, triangles = 0;
            masked_test_counter reference{{&boxes, &triangles}, &mask}; // the reference
            (void)scene.closest_hit(r, reference);
            count_mismatches += counter.num_boxes != boxes || counter.num_tris != triangles;
            total += boxes + triangles;
            // The hits are the mask's, and differ from the unmasked ones where the mask cuts.
            canopy::texture_alpha_mask masked = mask;
            auto const expected = scene.closest_hit(r, masked);
            hit_mismatches += counted.hit != expected.hit ||
                              (expected.hit && (counted.t != expected.t || counted.prim_id != expected.prim_id ||
                                                counted.inst_id != expected.inst_id));
            canopy::default_intersector none;
            auto const plain = scene.closest_hit(r, none);
            masked_pixels += plain.hit != expected.hit || (plain.hit && plain.t != expected.t);
        }
    CHECK(count_mismatches == 0);
    CHECK(hit_mismatches == 0);
    CHECK(total > std::uint64_t(width * height));
    CHECK(masked_pixels > 10);
}

TEST_CASE("heat_map colours costs against their 99th percentile, at least 1") {
    // Costs 0 … 199: the 99th percentile is the element at index 200 · 99 / 100 = 198, cost 198.
    canopy::framebuffer fb(200, 1);
    for (int x = 0; x < 200; ++x) fb.at(x, 0) = vec4<float>(float(x), 0.0f, 0.0f, 1.0f);
    CHECK(canopy::heat_map(fb) == 198.0f);
    vec3<float> const blue{0.05f, 0.05f, 0.4f}, red{0.9f, 0.1f, 0.05f};
    auto const colour = [&](int x) { return vec3<float>(fb.at(x, 0).x, fb.at(x, 0).y, fb.at(x, 0).z); };
    CHECK((colour(0).x == blue.x && colour(0).y == blue.y && colour(0).z == blue.z));
    CHECK((colour(198).x == red.x && colour(198).y == red.y && colour(198).z == red.z));
    CHECK((colour(199).x == red.x && colour(199).y == red.y && colour(199).z == red.z));
    CHECK(fb.at(100, 0).w == 1.0f);
    // A third of the way, 66 of 198: the second stop, green (0.1, 0.7, 0.2).
    CHECK(colour(66).x == Approx(0.1f));
    CHECK(colour(66).y == Approx(0.7f));

    // All costs 0: red stays at 1, every pixel blue.
    canopy::framebuffer zero(4, 4);
    CHECK(canopy::heat_map(zero) == 1.0f);
    CHECK(zero.at(3, 3).z == blue.z);
}

namespace {

enum class kernel_kind { primary, ao, path };

// The forest rendered with the texture alpha mask by one kernel, under `threads` worker threads.
canopy::framebuffer render_forest(canopy::compiled_scene const& forest, kernel_kind kernel, int threads,
                                  int tile_size = 16) {
    tbb::global_control const limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
    canopy::texture_alpha_mask mask;
    mask.scene = &forest;
    auto const camera = forest_camera(forest);
    int const spp = kernel == kernel_kind::path ? 2 : 1;
    canopy::framebuffer fb(width, height);
    canopy::render_tiles(fb, [&](int x, int y) {
        vec4<float> sum;
        for (int s = 0; s < spp; ++s) {
            canopy::pixel_random rng(3u, x, y, s);
            float const jx = spp > 1 ? rng.next() : 0.5f, jy = spp > 1 ? rng.next() : 0.5f;
            canopy::ray const r = camera.primary_ray(float(x) + jx, float(y) + jy, width, height);
            switch (kernel) {
            case kernel_kind::primary: sum = sum + canopy::primary_kernel(forest, r, mask); break;
            case kernel_kind::ao: sum = sum + canopy::ao_kernel(forest, r, mask, rng, {.samples = 8, .radius = 2.0f}); break;
            case kernel_kind::path: sum = sum + canopy::path_kernel(forest, r, mask, rng, {.bounces = 3}); break;
            }
        }
        return sum * (1.0f / float(spp));
    }, {.tile_size = tile_size, .progress = {}});
    return fb;
}

int differing_pixels(canopy::framebuffer const& a, canopy::framebuffer const& b) {
    int n = 0;
    for (std::size_t i = 0; i < a.pixels.size(); ++i) n += !same(a.pixels[i], b.pixels[i]);
    return n;
}

} // namespace

TEST_CASE("images are identical for 1 and 2 threads, across runs and tile sizes") {
    auto const forest = small_forest();
    for (auto const [kernel, name] : {std::pair{kernel_kind::primary, "primary"}, std::pair{kernel_kind::ao, "ao"},
                                      std::pair{kernel_kind::path, "path"}}) {
        INFO("kernel " << name);
        auto const one = render_forest(forest, kernel, 1);
        auto const two = render_forest(forest, kernel, 2);
        auto const again = render_forest(forest, kernel, 2);
        auto const odd_tiles = render_forest(forest, kernel, 2, 7);
        CHECK(differing_pixels(one, two) == 0);
        CHECK(differing_pixels(two, again) == 0);
        CHECK(differing_pixels(one, odd_tiles) == 0);

        // Not a blank image: several distinct colours.
        int distinct = 0;
        for (std::size_t i = 1; i < one.pixels.size(); ++i) distinct += one.pixels[i].x != one.pixels[i - 1].x;
        CHECK(distinct > int(one.pixels.size()) / 10);
    }
}

// ---- waves: the kernels over a tile's samples, traced in batches -------------------------

namespace {

// A compiled scene that counts the rays traced through it, one at a time or in batches, and the
// packets the batches made.
struct counted_scene {
    canopy::compiled_scene const* scene;
    std::atomic<std::uint64_t>* rays;
    std::atomic<std::uint64_t>* packets;

    template <typename I>
    canopy::basic_hit_record<float> closest_hit(canopy::ray const& r, I& isect) const {
        ++*rays;
        return scene->closest_hit(r, isect);
    }
    template <typename I>
    canopy::basic_hit_record<float> any_hit(canopy::ray const& r, I& isect) const {
        ++*rays;
        return scene->any_hit(r, isect);
    }
    template <typename I>
    void closest_hit(std::span<canopy::ray const> rs, std::span<canopy::basic_hit_record<float>> out, I& isect) const {
        *rays += rs.size();
        *packets += scene->closest_hit(rs, out, isect).packets;
    }
    template <typename I>
    void any_hit(std::span<canopy::ray const> rs, std::span<bool> out, I& isect) const {
        *rays += rs.size();
        *packets += scene->any_hit(rs, out, isect).packets;
    }
    canopy::surface_sample surface(canopy::basic_hit_record<float> const& hr, canopy::ray const& r) const {
        return scene->surface(hr, r);
    }
    vec3<float> background(canopy::ray const& r) const { return scene->background(r); }
};

// The paper's form of an alpha rule (a triangle hook that calls the library's test), serving
// scalar rays and packets: holes where u < 0.3.
struct hook_rule : canopy::basic_intersector<hook_rule> {
    using canopy::basic_intersector<hook_rule>::operator();
    template <typename Ray>
    auto operator()(Ray const& ray, canopy::triangle const& tri) const {
        auto hr = intersect(ray, tri);
        hr.hit &= hr.u >= 0.3f;
        return hr;
    }
};

// A filter declared for scalar records only: batches trace every ray on its own with it.
struct scalar_rule : canopy::basic_intersector<scalar_rule> {
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) const {
        return hr.u >= 0.3f;
    }
};

constexpr int wave_width = 61, wave_height = 45, wave_tile = 7, wave_spp = 2;

struct wave_render {
    canopy::framebuffer image;
    std::uint64_t rays = 0, packets = 0;
};

// Every pixel's wave_spp jittered samples through kernel(scene, ray, isect, rng), one sample at a
// time, each with its own copy of the intersector.
template <typename I, typename Kernel>
wave_render render_per_sample(canopy::compiled_scene const& scene, canopy::pinhole_camera const& camera,
                              I const& prototype, Kernel const& kernel) {
    std::atomic<std::uint64_t> rays{0}, packets{0};
    counted_scene const counted{&scene, &rays, &packets};
    wave_render out{canopy::framebuffer(wave_width, wave_height)};
    canopy::render_tiles(out.image, [&](int x, int y) {
        vec4<float> sum;
        for (int s = 0; s < wave_spp; ++s) {
            canopy::pixel_random rng(5u, x, y, s);
            float const jx = rng.next(), jy = rng.next();
            I isect = prototype;
            sum = sum + kernel(counted, camera.primary_ray(float(x) + jx, float(y) + jy, wave_width, wave_height),
                               isect, rng);
        }
        return sum * (1.0f / float(wave_spp));
    }, {.tile_size = wave_tile, .progress = {}});
    out.rays = rays;
    return out;
}

// The same samples, a tile's pixels at a time through wave(scene, rays, rngs, isect, colours).
template <typename I, typename Wave>
wave_render render_by_waves(canopy::compiled_scene const& scene, canopy::pinhole_camera const& camera,
                            I const& prototype, Wave const& wave) {
    std::atomic<std::uint64_t> rays{0}, packets{0};
    counted_scene const counted{&scene, &rays, &packets};
    wave_render out{canopy::framebuffer(wave_width, wave_height)};
    canopy::tile_shader const shade = [&](canopy::tile_grid::rect const& r, std::span<vec4<float>> pixels) {
        std::vector<canopy::ray> rs;
        std::vector<canopy::pixel_random> rngs;
        std::vector<vec4<float>> colours(pixels.size());
        for (auto& p : pixels) p = vec4<float>();
        for (int s = 0; s < wave_spp; ++s) {
            rs.clear();
            rngs.clear();
            for (int y = r.y0; y < r.y1; ++y)
                for (int x = r.x0; x < r.x1; ++x) {
                    canopy::pixel_random& rng = rngs.emplace_back(5u, x, y, s);
                    float const jx = rng.next(), jy = rng.next();
                    rs.push_back(camera.primary_ray(float(x) + jx, float(y) + jy, wave_width, wave_height));
                }
            I isect = prototype;
            wave(counted, std::span<canopy::ray const>(rs), std::span(rngs), isect, std::span(colours));
            for (std::size_t k = 0; k < pixels.size(); ++k) pixels[k] = pixels[k] + colours[k];
        }
        for (auto& p : pixels) p = p * (1.0f / float(wave_spp));
    };
    canopy::render_tiles(out.image, shade, {.tile_size = wave_tile, .progress = {}});
    out.rays = rays;
    out.packets = packets;
    return out;
}

// Pixels whose four floats differ in any bit (NaN payloads and the sign of zero included).
int differing_bits(canopy::framebuffer const& a, canopy::framebuffer const& b) {
    int n = 0;
    for (std::size_t i = 0; i < a.pixels.size(); ++i)
        n += std::memcmp(&a.pixels[i], &b.pixels[i], sizeof(vec4<float>)) != 0;
    return n;
}

// Renders scene both ways with every kernel and the intersector prototype, and compares.
template <typename I>
void check_waves(canopy::compiled_scene const& scene, canopy::pinhole_camera const& camera, I const& prototype,
                 bool expect_packets) {
    canopy::light_options light;
    light.sun_direction = canopy::normalize(vec3<float>(0.6f, 0.8f, 0.7f));
    float const diagonal = canopy::length(canopy::diagonal(scene.bounds()));
    canopy::ao_options const ao{.samples = 5, .radius = 0.2f * diagonal};
    canopy::path_options path{.bounces = 2, .light = light};
    path.light.point_light = true;
    path.light.point_position = canopy::center(scene.bounds()) + vec3<float>(0.0f, 0.5f * diagonal, 0.0f);
    path.light.point_intensity = vec3<float>(diagonal * diagonal);

    auto const compare = [&](char const* name, wave_render const& single, wave_render const& waves) {
        INFO("kernel " << name);
        CHECK(differing_bits(single.image, waves.image) == 0);
        CHECK(single.rays == waves.rays);
        CHECK((waves.packets > 0) == expect_packets);
        // Not a blank image.
        int distinct = 0;
        for (std::size_t i = 1; i < single.image.pixels.size(); ++i)
            distinct += single.image.pixels[i].x != single.image.pixels[i - 1].x;
        CHECK(distinct > 20);
    };
    compare("primary",
            render_per_sample(scene, camera, prototype, [&](auto const& s, canopy::ray const& r, I& isect, auto&) {
                return canopy::primary_kernel(s, r, isect, light);
            }),
            render_by_waves(scene, camera, prototype, [&](auto const& s, auto rs, auto, I& isect, auto colours) {
                canopy::primary_wave(s, rs, isect, colours, light);
            }));
    compare("ao",
            render_per_sample(scene, camera, prototype, [&](auto const& s, canopy::ray const& r, I& isect, auto& rng) {
                return canopy::ao_kernel(s, r, isect, rng, ao);
            }),
            render_by_waves(scene, camera, prototype, [&](auto const& s, auto rs, auto rngs, I& isect, auto colours) {
                canopy::ao_wave(s, rs, rngs, isect, colours, ao);
            }));
    compare("path",
            render_per_sample(scene, camera, prototype, [&](auto const& s, canopy::ray const& r, I& isect, auto& rng) {
                return canopy::path_kernel(s, r, isect, rng, path);
            }),
            render_by_waves(scene, camera, prototype, [&](auto const& s, auto rs, auto rngs, I& isect, auto colours) {
                canopy::path_wave(s, rs, rngs, isect, colours, path);
            }));
}

} // namespace

TEST_CASE("the waves render the per-sample kernels' images bit for bit, tracing the same rays") {
    // 61 × 45 pixels in 7-pixel tiles (narrow last row and column: waves of 7 × 3, 5 × 7, 5 × 3
    // rays beside full 49-ray tiles), two jittered samples, every kernel, with the point light.
    auto const forest = small_forest();
    auto const forest_view = forest.render_camera(float(wave_width) / float(wave_height));
    canopy::texture_alpha_mask texture_mask;
    texture_mask.scene = &forest;
    canopy::procedural_alpha_mask rings;
    rings.scene = &forest;
    SECTION("the forest (two instance levels), no intersector") {
        check_waves(forest, forest_view, canopy::default_intersector{}, true);
    }
    SECTION("the forest, the texture alpha mask (a filter, lane by lane for packets)") {
        check_waves(forest, forest_view, texture_mask, true);
    }
    SECTION("the forest, the procedural mask") { check_waves(forest, forest_view, rings, true); }
    SECTION("the forest, a triangle hook in the paper's form") { check_waves(forest, forest_view, hook_rule{}, true); }
    SECTION("the layered quads, the texture mask") {
        auto const layered = make_layered_scene(front_kind::textured);
        canopy::texture_alpha_mask mask;
        mask.scene = &layered;
        auto const camera = canopy::pinhole_camera::look_at({0.3f, -0.2f, 4.0f}, {0.0f, 0.0f, 0.0f},
                                                            {0.0f, 1.0f, 0.0f}, 60.0f,
                                                            float(wave_width) / float(wave_height));
        check_waves(layered, camera, mask, true);
    }
    SECTION("a scalar-only intersector: the waves trace one ray at a time, same image") {
        check_waves(forest, forest_view, scalar_rule{}, false);
    }
}

TEST_CASE("render_tiles with a tile shader gives the per-pixel image, whatever the tile size") {
    auto const forest = small_forest();
    auto const camera = forest_camera(forest);
    auto const shade = [&](int x, int y) { return canopy::primary_kernel(forest, pixel_ray(camera, x, y, width, height), canopy::default_intersector{}); };
    canopy::framebuffer per_pixel(width, height);
    canopy::render_tiles(per_pixel, shade, {.tile_size = 16, .progress = {}});
    for (int tile : {1, 5, 16, 100}) {
        INFO("tile " << tile);
        canopy::framebuffer tiled(width, height);
        int calls = 0;
        std::atomic<int> pixels{0};
        canopy::render_tiles(tiled, canopy::tile_shader([&](canopy::tile_grid::rect const& r, std::span<vec4<float>> out) {
            REQUIRE(out.size() == std::size_t(r.pixels()));
            std::size_t i = 0;
            for (int y = r.y0; y < r.y1; ++y)
                for (int x = r.x0; x < r.x1; ++x) out[i++] = shade(x, y);
            pixels += r.pixels();
        }), {.tile_size = tile, .progress = [&](float) { ++calls; }});
        CHECK(differing_bits(per_pixel, tiled) == 0);
        CHECK(pixels == width * height);
        CHECK(calls == canopy::tile_grid(width, height, tile).count());
    }
}

// ---- cameras and tone curves --------------------------------------------------------------

TEST_CASE("look_at refuses values that give no camera, and says why") {
    float const inf = std::numeric_limits<float>::infinity();
    float const nan = std::numeric_limits<float>::quiet_NaN();
    vec3<float> const eye(0, 0, 5), target(0, 0, 0), up(0, 1, 0);
    struct bad_camera {
        vec3<float> eye, target, up;
        float fovy, aspect;
        std::string problem;
    };
    std::vector<bad_camera> const cameras{
        {{nan, 0, 5}, target, up, 45, 1, "eye (nan, 0, 5) is not finite"},
        {eye, {0, inf, 0}, up, 45, 1, "target (0, inf, 0) is not finite"},
        {eye, target, {0, -inf, 0}, 45, 1, "up (0, -inf, 0) is not finite"},
        {eye, target, up, 0, 1, "field of view 0 is not in (0, 180) degrees"},
        {eye, target, up, 180, 1, "field of view 180 is not in (0, 180) degrees"},
        {eye, target, up, nan, 1, "field of view nan is not in (0, 180) degrees"},
        {eye, target, up, 45, 0, "aspect ratio 0 is not a positive number"},
        {eye, target, up, 45, inf, "aspect ratio inf is not a positive number"},
        {{1, 2, 3}, {1, 2, 3}, up, 45, 1, "eye and target coincide at (1, 2, 3): no view direction"},
        {eye, target, {0, 0, 0}, 45, 1, "up is zero: no orientation"},
        // A camera under a scale of 1e-30: the direction's squared length underflows.
        {{0, 0, 5e-30f}, target, up, 45, 1, "eye (0, 0, 5e-30) and target (0, 0, 0) are too close to give a view direction in float"},
        {{0, 0, 1e38f}, target, up, 45, 1,
         "eye (0, 0, 1e+38) and target (0, 0, 0) are 1e+38 apart, too far for a float view direction (its squared length overflows)"},
        {{0, 0, 2e19f}, target, up, 45, 1,
         "eye (0, 0, 2e+19) and target (0, 0, 0) are 2e+19 apart, too far for a float view direction (its squared length overflows)"},
        {eye, target, {0, 1e-30f, 0}, 45, 1, "up (0, 1e-30, 0) has no direction in float (its length under- or overflows)"},
        {{-3e38f, 0, 0}, {3e38f, 0, 0}, up, 45, 1, "eye (-3e+38, 0, 0) and target (3e+38, 0, 0) are too far apart for float"},
    };
    for (auto const& c : cameras) {
        INFO(c.problem);
        CHECK_THAT(canopy::pinhole_camera::look_at_problem(c.eye, c.target, c.up, c.fovy, c.aspect),
                   Catch::Contains(c.problem));
        CHECK_THROWS_WITH(canopy::pinhole_camera::look_at(c.eye, c.target, c.up, c.fovy, c.aspect),
                          Catch::StartsWith("camera: ") && Catch::Contains(c.problem));
    }
}

TEST_CASE("look_at's basis is orthonormal, and an up along the view falls back to +y, or -z looking along y") {
    auto const unit = [](vec3<float> v) { return std::fabs(double(canopy::length(v)) - 1.0) < 1e-6; };
    struct view {
        vec3<float> eye, target, up;
        vec3<float> expected_up; // unit, the image's up direction (written out)
    };
    std::vector<view> const views{
        {{0, 0, 5}, {0, 0, 0}, {0, 1, 0}, {0, 1, 0}},        // the usual case
        {{0, 0, 5}, {0, 0, 0}, {0, 3, 0}, {0, 1, 0}},        // a long up
        {{0, 5, 0}, {0, 0, 0}, {0, 1, 0}, {0, 0, -1}},       // straight down, up along the view
        {{0, -5, 0}, {0, 0, 0}, {0, 2, 0}, {0, 0, -1}},      // straight up
        {{0, 0, 5}, {0, 0, 0}, {0, 0, 1}, {0, 1, 0}},        // along -z with up +z
        {{7, 1, 1}, {0, 1, 1}, {-1, 0, 0}, {0, 1, 0}},       // along -x with up -x
        {{0, 5, 0}, {0, 0, 0}, {0, 1, 1e-5f}, {0, 0, -1}},   // within 0.06° of the view
    };
    for (auto const& v : views) {
        INFO("eye " << v.eye.x << " " << v.eye.y << " " << v.eye.z << ", up " << v.up.x << " " << v.up.y << " " << v.up.z);
        REQUIRE(canopy::pinhole_camera::look_at_problem(v.eye, v.target, v.up, 60.0f, 2.0f).empty());
        auto const c = canopy::pinhole_camera::look_at(v.eye, v.target, v.up, 60.0f, 2.0f);
        double const half_height = std::tan(30.0 * std::numbers::pi / 180.0);
        vec3<float> const u = c.up * float(1.0 / half_height), r = c.right * float(1.0 / (2.0 * half_height));
        CHECK(unit(c.forward));
        CHECK(unit(u));
        CHECK(unit(r));
        CHECK(std::fabs(canopy::dot(u, c.forward)) < 1e-6f);
        CHECK(std::fabs(canopy::dot(r, c.forward)) < 1e-6f);
        CHECK(std::fabs(canopy::dot(r, u)) < 1e-6f);
        CHECK(canopy::dot(u, v.expected_up) > 0.999999f);
        // Right-handed: right = forward × up.
        CHECK(canopy::dot(canopy::cross(c.forward, u), r) > 0.999999f);
    }
}

TEST_CASE("tone curves follow their formulas, and none at scale 1 leaves values as they are") {
    using canopy::tone_curve;
    float const nan = std::numeric_limits<float>::quiet_NaN();
    float const inf = std::numeric_limits<float>::infinity();
    for (float const x : {0.0f, 0.001f, 0.18f, 0.5f, 1.0f, 1.25f, 2.0f, 7.0f, 100.0f}) {
        INFO("x = " << x);
        double const v = double(x) * 0.5;
        CHECK(canopy::tone_map(x, tone_curve::none) == x); // bit for bit: Figure 1 as before
        CHECK(canopy::tone_map(x, tone_curve::none, 0.5f) == Approx(v).epsilon(1e-7));
        CHECK(canopy::tone_map(x, tone_curve::reinhard, 0.5f) == Approx(v / (1.0 + v)).epsilon(1e-6));
        double const aces = std::min(1.0, v * (2.51 * v + 0.03) / (v * (2.43 * v + 0.59) + 0.14));
        CHECK(canopy::tone_map(x, tone_curve::aces, 0.5f) == Approx(aces).epsilon(1e-6).margin(1e-7));
    }
    for (auto const curve : {tone_curve::none, tone_curve::reinhard, tone_curve::aces})
        CHECK(std::isnan(canopy::tone_map(nan, curve)));
    CHECK(canopy::tone_map(inf, tone_curve::reinhard) == Approx(1.0).margin(1e-5));
    CHECK(canopy::tone_map(inf, tone_curve::aces) == 1.0f);
    CHECK(canopy::tone_map(-1.0f, tone_curve::aces) == 0.0f);
}
