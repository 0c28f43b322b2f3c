// figure1_billboards — the four images of Figure 1 of the custom-intersector paper, written with
// the paper's API the way an application would:
//
//   1. billboards with the alpha mask ignored (no intersector),
//   2. a texture alpha mask: an intersector that looks up the tree texture's alpha at the hit's
//      texture coordinates and rejects the hit where it is transparent (`hr.hit &= alpha >= .01f`),
//   3. a procedural alpha mask: the same, with a rule computed from the texture coordinates,
//      written as a filter (beyond the paper): called only for the candidates the library's own
//      test found, so leaves keep their SIMD test, where a triangle hook is called per triangle,
//   4. a BVH cost heat map: an intersector that counts every ray/box and ray/triangle test, at
//      every level of the instanced scene.
//
//   figure1_billboards [OUT_DIR [WIDTHxHEIGHT]]     (defaults: figure1, 640x480)
//
// The scene is the demo forest, the procedural plugin's billboard_forest generator compiled by
// compile() (what `canopy render` draws without a scene): instanced billboard quads (mesh 2,
// texture coordinates (0,0) top-left … (1,1) bottom-right) among spheres on a ground plane.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>
import canopy;
import canopy.image;
import canopy.scene;
import canopy.plugins.procedural;

namespace {

using canopy::vec2;
using canopy::vec4;

constexpr unsigned billboard_mesh = 2; // the generator's meshes compile as ground, sphere, billboard

// The paper's texture alpha mask: hits on billboards survive only where the texture is opaque.
struct texture_alpha_mask : canopy::basic_intersector<texture_alpha_mask> {
    using canopy::basic_intersector<texture_alpha_mask>::operator();

    template <typename Ray>
    auto operator()(Ray const& ray, canopy::triangle const& tri) {
        auto hr = intersect(ray, tri);
        if (hr.hit && hr.geom_id == billboard_mesh) hr.hit &= tex2D(*alpha, scene->uv(hr)).w >= .01f;
        return hr;
    }

    canopy::compiled_scene const* scene = nullptr;
    canopy::texture2d<vec4<float>> const* alpha = nullptr;
};

// A procedural alpha mask: concentric rings in texture space, cut off outside the unit disc. A
// filter: it sees each candidate hit (t, u, v, ids, instance path) and keeps or drops it.
struct procedural_alpha_mask : canopy::basic_intersector<procedural_alpha_mask> {
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) const {
        if (hr.geom_id != billboard_mesh) return true;
        vec2<float> const uv = scene->uv(hr);
        float const d = 2.0f * canopy::length(uv - vec2<float>(0.5f, 0.5f));
        return d < 1.0f && 5.0f * d - std::floor(5.0f * d) < 0.6f;
    }

    canopy::compiled_scene const* scene = nullptr;
};

// The paper's cost counter: intercepts the ray/box tests too, and forwards both to the library.
struct bvh_costs : canopy::basic_intersector<bvh_costs> {
    using canopy::basic_intersector<bvh_costs>::operator();

    template <typename Ray, typename... Args>
    auto operator()(Ray const& ray, canopy::aabb const& box, Args&&... args) {
        ++num_boxes;
        return intersect(ray, box, std::forward<Args>(args)...);
    }

    template <typename Ray>
    auto operator()(Ray const& ray, canopy::triangle const& tri) {
        ++num_tris;
        return intersect(ray, tri);
    }

    unsigned num_boxes = 0;
    unsigned num_tris = 0;
};

// Writes a framebuffer as an 8-bit image: linear colours are sRGB-encoded, heat colours are not.
void save(std::filesystem::path const& file, canopy::framebuffer const& fb, bool linear) {
    canopy::write_framebuffer(file, fb, {.linear = linear});
    std::printf("wrote %s\n", file.string().c_str());
}

} // namespace

int main(int argc, char** argv) try {
    std::filesystem::path const out = argc > 1 ? argv[1] : "figure1";
    int width = 640, height = 480;
    if (argc > 2 && std::sscanf(argv[2], "%dx%d", &width, &height) != 2) {
        std::fprintf(stderr, "usage: figure1_billboards [OUT_DIR [WIDTHxHEIGHT]]\n");
        return 2;
    }
    std::filesystem::create_directories(out);

    // The scene, compiled, and its camera.
    canopy::registry plugins;
    canopy::register_procedural_plugin(plugins);
    canopy::scene forest;
    plugins.generate(forest, "billboard_forest", {});
    canopy::compiled_scene const scene = canopy::compile(forest);
    auto const camera = scene.render_camera(float(width) / float(height));
    auto const primary_ray = [&](int x, int y) {
        return camera.primary_ray(float(x) + 0.5f, float(y) + 0.5f, width, height);
    };

    // Primary visibility with a given intersector: each pixel gets its own copy of it.
    auto const render = [&](auto const& isect) {
        canopy::framebuffer fb(width, height);
        canopy::render_tiles(fb, [&](int x, int y) { return canopy::primary_kernel(scene, primary_ray(x, y), isect); });
        return fb;
    };

    // 1. Alpha ignored: the billboards' quads are opaque.
    save(out / "1_billboards_alpha_ignored.png", render(canopy::default_intersector{}), true);

    // 2. The texture alpha mask, also on shadow rays: the trees cast tree-shaped shadows.
    texture_alpha_mask texture_mask;
    texture_mask.scene = &scene;
    texture_mask.alpha = &scene.textures[0];
    save(out / "2_texture_alpha_mask.png", render(texture_mask), true);

    // 3. The procedural alpha mask.
    procedural_alpha_mask rings;
    rings.scene = &scene;
    save(out / "3_procedural_alpha_mask.png", render(rings), true);

    // 4. The cost of each primary ray: box plus triangle tests, at every level of the scene.
    canopy::framebuffer costs(width, height);
    canopy::render_tiles(costs, [&](int x, int y) {
        bvh_costs counter;
        scene.closest_hit(primary_ray(x, y), counter);
        return vec4<float>(float(counter.num_boxes + counter.num_tris), 0.0f, 0.0f, 1.0f);
    });
    double total_cost = 0.0;
    float most = 0.0f;
    for (auto const& p : costs.pixels) {
        total_cost += double(p.x);
        most = std::max(most, p.x);
    }
    std::printf("BVH costs per primary ray: %.1f on average, %.0f at most\n", total_cost / double(costs.pixels.size()),
                double(most));
    // Red from the 99th percentile up, so that a few very expensive rays do not wash out the rest.
    canopy::heat_map(costs);
    save(out / "4_bvh_cost_heatmap.png", costs, false);
    return 0;
} catch (std::exception const& e) {
    std::fprintf(stderr, "figure1_billboards: %s\n", e.what());
    return 1;
}
