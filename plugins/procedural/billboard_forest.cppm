// canopy.billboard_forest — the demo scene of the paper's Figure 1: a forest of instanced,
// alpha-masked billboards standing on a ground plane, with solid spheres among and behind them.
//
//   make_billboard_forest(tree_texture, {.billboards = 160, .seed = 1})
//
// Meshes (geom_id): 0 ground (40 × 40 quads), 1 icosphere (3 subdivisions), 2 billboard quad
// (two triangles, texture coordinates (0,0) top-left … (1,1) bottom-right, masked material with
// the given RGBA texture). Every billboard faces the suggested camera. Deterministic in the seed.
module;
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <utility>
#include <vector>
export module canopy.billboard_forest;
export import canopy.scene;
import canopy.procedural;

export namespace canopy {

struct billboard_forest_options {
    int billboards = 160;
    int spheres = 7;
    std::uint32_t seed = 1;
};

struct billboard_forest {
    compiled_scene scene;
    vec3<float> camera_eye{0.0f, 3.2f, 17.0f};
    vec3<float> camera_target{0.0f, 2.0f, 0.0f};
    float camera_fovy = 45.0f;
};

inline billboard_forest make_billboard_forest(texture2d<vec4<float>> tree_texture,
                                              billboard_forest_options const& options = {}) {
    billboard_forest forest;
    compiled_scene& s = forest.scene;
    std::mt19937 rng(options.seed);
    auto uniform = [&](float lo, float hi) { return lo + (hi - lo) * float(double(rng()) / double(std::mt19937::max())); };

    s.materials = {material{{0.55f, 0.5f, 0.35f}}, material{{0.75f, 0.3f, 0.25f}},
                   material{{1.0f, 1.0f, 1.0f}, 0, true, 0.01f}};
    s.textures.push_back(std::move(tree_texture));

    compiled_mesh ground;
    ground.triangles = make_grid(40, 40);
    for (auto& t : ground.triangles)
        for (vec3<float>* v : {&t.v0, &t.v1, &t.v2}) *v = vec3<float>(v->x - 20.0f, 0.0f, v->y - 20.0f);
    ground.material = 0;
    compiled_mesh ball;
    ball.triangles = make_icosphere(3);
    ball.material = 1;
    compiled_mesh quad;
    vec3<float> const a(-0.5f, 1.0f, 0.0f), b(0.5f, 1.0f, 0.0f), c(0.5f, 0.0f, 0.0f), d(-0.5f, 0.0f, 0.0f);
    quad.triangles = {triangle{a, b, c, 0, 0}, triangle{a, c, d, 1, 0}};
    quad.uvs = {{vec2<float>(0, 0), vec2<float>(1, 0), vec2<float>(1, 1)},
                {vec2<float>(0, 0), vec2<float>(1, 1), vec2<float>(0, 1)}};
    quad.material = 2;
    s.meshes.push_back(std::move(ground));
    s.meshes.push_back(std::move(ball));
    s.meshes.push_back(std::move(quad));
    s.place(0, affine_transform<float>::identity());
    for (int k = 0; k < options.spheres; ++k) {
        float const r = uniform(0.6f, 1.6f);
        std::array<float, 12> const rows{r, 0, 0, uniform(-9.0f, 9.0f), 0, r, 0, r, 0, 0, r, uniform(-14.0f, 2.0f)};
        s.place(1, affine_transform<float>::from_rows(rows));
    }
    for (int k = 0; k < options.billboards; ++k) {
        float const x = uniform(-16.0f, 16.0f), z = uniform(-18.0f, 9.0f);
        float const height = uniform(1.8f, 3.6f), width = height * uniform(0.7f, 0.9f);
        // Face the camera: rotate the quad's normal (+z) about y towards the eye.
        float const yaw = std::atan2(forest.camera_eye.x - x, forest.camera_eye.z - z);
        float const cy = std::cos(yaw), sy = std::sin(yaw);
        std::array<float, 12> const rows{cy * width, 0, sy, x, 0, height, 0, 0, -sy * width, 0, cy, z};
        s.place(2, affine_transform<float>::from_rows(rows));
    }
    s.build();
    return forest;
}

} // namespace canopy
