// instancing — a forest of instanced meshes in two levels: one BVH per shared mesh, and a
// top-level BVH over 10 × 10 placed instances (each an affine transform and a reference to a mesh
// BVH). Prints the BVH statistics of both levels and renders one image.
//
//   instancing [OUT.png [WIDTHxHEIGHT]]     (defaults: instancing.png, 480x360)
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <numbers>
#include <random>
#include <utility>
import canopy;
import canopy.procedural;
import canopy.scene;
import canopy.image;

namespace {

using canopy::vec3;

void print_stats(char const* name, canopy::bvh_stats const& s) {
    std::printf("%-22s %7zu primitives, %6zu nodes (%zu leaves, %zu 8-wide), depth %2d, SAH cost %6.2f, %5.1f bytes/primitive\n",
                name, s.primitive_count, s.node_count, s.leaf_count, s.wide_node_count, s.depth, s.sah_cost,
                s.bytes_per_primitive);
}

// Object→world: scale by (sx, sy, sz), tilt about x, turn about y, then move to `at`.
canopy::affine_transform<float> placement(vec3<float> at, vec3<float> scale, float tilt, float turn) {
    float const ct = std::cos(tilt), st = std::sin(tilt), cy = std::cos(turn), sy = std::sin(turn);
    // rows of R_y(turn) · R_x(tilt) · S
    std::array<float, 12> const rows{cy * scale.x, sy * st * scale.y, sy * ct * scale.z, at.x,
                                     0.0f,         ct * scale.y,      -st * scale.z,     at.y,
                                     -sy * scale.x, cy * st * scale.y, cy * ct * scale.z, at.z};
    return canopy::affine_transform<float>::from_rows(rows);
}

} // namespace

int main(int argc, char** argv) try {
    std::filesystem::path const out = argc > 1 ? argv[1] : "instancing.png";
    int width = 480, height = 360;
    if (argc > 2 && std::sscanf(argv[2], "%dx%d", &width, &height) != 2) {
        std::fprintf(stderr, "usage: instancing [OUT.png [WIDTHxHEIGHT]]\n");
        return 2;
    }

    // Three shared meshes: the ground, a fine and a coarse sphere.
    canopy::compiled_scene scene;
    scene.materials = {canopy::material{{0.6f, 0.55f, 0.45f}}, canopy::material{{0.8f, 0.3f, 0.2f}},
                       canopy::material{{0.2f, 0.45f, 0.8f}}};
    canopy::compiled_mesh ground;
    ground.triangles = canopy::make_grid(24, 24);
    for (auto& t : ground.triangles)
        for (vec3<float>* v : {&t.v0, &t.v1, &t.v2}) *v = vec3<float>(v->x - 12.0f, 0.0f, v->y - 12.0f);
    ground.material = 0;
    canopy::compiled_mesh fine;
    fine.triangles = canopy::make_icosphere(4);
    fine.material = 1;
    canopy::compiled_mesh coarse;
    coarse.triangles = canopy::make_icosphere(1);
    coarse.material = 2;
    scene.meshes.push_back(std::move(ground));
    scene.meshes.push_back(std::move(fine));
    scene.meshes.push_back(std::move(coarse));

    // The ground once, then a 10 × 10 grid of squashed, tilted and turned spheres.
    scene.place(0, canopy::affine_transform<float>::identity());
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    float const pi = std::numbers::pi_v<float>;
    for (int j = 0; j < 10; ++j)
        for (int i = 0; i < 10; ++i) {
            float const size = 0.3f + 0.4f * unit(rng);
            vec3<float> const scale(size, size * (0.5f + unit(rng)), size * (0.6f + 0.6f * unit(rng)));
            vec3<float> const at(2.0f * float(i) - 9.0f, scale.y, 2.0f * float(j) - 9.0f);
            scene.place((i + j) % 2 == 0 ? 1 : 2, placement(at, scale, 0.4f * (unit(rng) - 0.5f), 2.0f * pi * unit(rng)));
        }
    scene.build();

    // What instancing saves: the triangles stored against the triangles placed in the world.
    std::size_t placed = 0;
    for (auto const& p : scene.top_meshes) placed += scene.meshes[p.index].triangles.size();
    std::size_t const stored =
        scene.meshes[0].triangles.size() + scene.meshes[1].triangles.size() + scene.meshes[2].triangles.size();
    std::printf("%zu instances of %zu meshes: %zu triangles stored, %zu placed in the world\n", scene.top_mesh_instances.size(),
                scene.meshes.size(), stored, placed);
    print_stats("ground BVH", canopy::compute_stats(scene.meshes[0].accel));
    print_stats("fine sphere BVH", canopy::compute_stats(scene.meshes[1].accel));
    print_stats("coarse sphere BVH", canopy::compute_stats(scene.meshes[2].accel));
    print_stats("top-level BVH", canopy::compute_stats(scene.top_meshes_bvh));

    // One image, primary visibility with sun shadows.
    auto const camera = canopy::pinhole_camera::look_at({0.0f, 9.0f, 17.0f}, {0.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f},
                                                        45.0f, float(width) / float(height));
    canopy::framebuffer fb(width, height);
    canopy::render_tiles(fb, [&](int x, int y) {
        return canopy::primary_kernel(scene, camera.primary_ray(float(x) + 0.5f, float(y) + 0.5f, width, height),
                                      canopy::default_intersector{});
    });
    canopy::write_framebuffer(out, fb); // sRGB-encoded
    std::printf("wrote %s (%dx%d)\n", out.string().c_str(), width, height);
    return 0;
} catch (std::exception const& e) {
    std::fprintf(stderr, "instancing: %s\n", e.what());
    return 1;
}
