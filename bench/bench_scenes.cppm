// canopy.bench_scenes — the scenes of the Embree comparison (bench/embree_compare.cpp), generated
// deterministically or loaded through the scene plugins.
//
//   sphere   closed icosphere, 8 subdivisions (1,310,720 triangles)
//   terrain  height field over a 1000 × 1000 grid (2,000,000 triangles), a few smooth sines
//   soup     500,000 random triangles in a cube
//   forest   10,000 instances of a 51,528-triangle tree (closed thin cylinders for the trunk and
//            branches, 25,200 thin leaf quads), on a jittered ground grid, each turned about the
//            vertical axis (+y) and scaled
//   engine   /usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb
//   bunny    /usr/share/glmark2/models/bunny.obj
//   slivers  77,264 thin triangles in one mesh: a disk fan (aspect 1e4), a needle fan (aspect
//            ~1.6e6), a closed bicone spindle of 4,096 slivers and a closed thin cylinder (r 0.01)
//
// A scene may also list points inside its closed thin solids (`interior`, for the ray set of rays
// from inside, canopy.bench_tracing): the slivers' spindle and cylinder. The other scenes list none.
//
// `quick` shrinks every generated scene about 16× (the files are loaded as they are). Files are
// compiled by canopy.scene and flattened to world-space triangles (prim_id = running index), so
// that both libraries trace the same single-level list; a missing or unreadable file gives a
// scene with `skipped` set instead of an error. Random numbers come from the raw mt19937 stream
// (the standard distributions differ between standard libraries): same scene on every machine.
module;
#include <array>
#include <cmath>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>
export module canopy.bench_scenes;
import canopy.plugins;
import canopy.procedural;

export namespace canopy::bench {

struct bench_scene {
    std::string name;                               // as in --scenes
    std::string description;                        // for the table heading
    std::vector<triangle> mesh;                     // the mesh (of every instance, when instanced)
    std::vector<affine_transform<float>> instances; // object→world per instance; empty: one level
    std::string skipped;                            // why the scene is absent (a missing file)
    std::vector<vec3<float>> interior;              // points strictly inside closed thin solids (may be empty)
};

// The names make_bench_scene knows, in the order of the default run.
std::vector<std::string> const& bench_scene_names();

// The scene called `name`; throws std::invalid_argument for a name not in bench_scene_names().
bench_scene make_bench_scene(std::string const& name, bool quick);

// The tree of the forest: trunk, 7 branches, 35 twigs, leaves_per_twig leaf quads on each twig.
std::vector<triangle> make_tree(int leaves_per_twig, std::uint32_t seed);

// Every placement of a compiled scene's meshes as world-space triangles, prim_id = running index.
std::vector<triangle> flatten(compiled_scene const& scene);

} // namespace canopy::bench

namespace canopy::bench {

namespace {

using vec = vec3<float>;
constexpr double two_pi = 2.0 * std::numbers::pi;

// Uniform floats from the raw mt19937 stream (portable, unlike std::uniform_real_distribution).
class random_stream {
public:
    explicit random_stream(std::uint32_t seed) : rng_(seed) {}

    float uniform(float lo, float hi) { return lo + (hi - lo) * float(double(rng_()) / double(std::mt19937::max())); }

    // A unit vector, uniform over the sphere (rejection sampling in the cube).
    vec direction() {
        for (;;) {
            vec const p(uniform(-1, 1), uniform(-1, 1), uniform(-1, 1));
            float const l = length(p);
            if (l > 0.1f && l <= 1.0f) return p / l;
        }
    }

private:
    std::mt19937 rng_;
};

void add_triangle(std::vector<triangle>& out, vec a, vec b, vec c) {
    out.push_back(triangle{a, b, c, std::uint32_t(out.size()), 0});
}

// Two unit vectors perpendicular to unit `axis` and to each other.
std::pair<vec, vec> perpendicular_basis(vec axis) {
    vec const helper = std::fabs(axis.y) < 0.9f ? vec(0, 1, 0) : vec(1, 0, 0);
    vec const u = normalize(cross(axis, helper));
    return {u, cross(axis, u)};
}

// A closed cylinder (a cone frustum when r0 != r1) from p0 to p1: `rings` × `segments` side
// quads and a triangle fan on each end. Every vertex is computed by one expression from its
// (ring, segment) indices, so neighbouring triangles share bit-identical corners.
void add_cylinder(std::vector<triangle>& out, vec p0, vec p1, float r0, float r1, int segments, int rings = 1) {
    auto const [u, w] = perpendicular_basis(normalize(p1 - p0));
    auto const corner = [&](int ring, int segment) {
        double const along = double(ring) / double(rings);
        double const angle = two_pi * double(segment % segments) / double(segments);
        float const r = float(double(r0) + (double(r1) - double(r0)) * along);
        return p0 + (p1 - p0) * float(along) + (u * float(std::cos(angle)) + w * float(std::sin(angle))) * r;
    };
    for (int k = 0; k < rings; ++k)
        for (int i = 0; i < segments; ++i) {
            add_triangle(out, corner(k, i), corner(k, i + 1), corner(k + 1, i + 1));
            add_triangle(out, corner(k, i), corner(k + 1, i + 1), corner(k + 1, i));
        }
    for (int i = 0; i < segments; ++i) {
        add_triangle(out, p0, corner(0, i + 1), corner(0, i));
        add_triangle(out, p1, corner(rings, i), corner(rings, i + 1));
    }
}

// A thin leaf (0.12 × 0.03) centred at p, lying along the random direction `along`: two triangles.
void add_leaf(std::vector<triangle>& out, vec p, vec along, vec across_hint) {
    vec const across = normalize(cross(along, across_hint));
    vec const l = along * 0.06f, c = across * 0.015f;
    add_triangle(out, p - l - c, p + l - c, p + l + c);
    add_triangle(out, p - l - c, p + l + c, p - l + c);
}

float terrain_height(float x, float y) {
    return 30.0f * std::sin(0.0123f * x + 0.4f) * std::cos(0.0091f * y) + 12.0f * std::sin(0.047f * x + 0.031f * y) +
           4.0f * std::sin(0.21f * x) * std::cos(0.17f * y) + 1.0f * std::sin(0.9f * x + 0.7f * y);
}

// A grid of n × n tree positions 5 apart, jittered, each turned about +y and scaled (0.7–1.3).
std::vector<affine_transform<float>> forest_placements(int count, std::uint32_t seed) {
    random_stream random(seed);
    int const side = int(std::ceil(std::sqrt(double(count))));
    std::vector<affine_transform<float>> out;
    for (int k = 0; k < count; ++k) {
        float const x = 5.0f * float(k % side) + random.uniform(-1.0f, 1.0f);
        float const z = 5.0f * float(k / side) + random.uniform(-1.0f, 1.0f);
        float const angle = random.uniform(0.0f, float(two_pi));
        float const s = random.uniform(0.7f, 1.3f);
        float const c = s * std::cos(angle), n = s * std::sin(angle);
        out.push_back(affine_transform<float>::from_rows({c, 0, n, x, 0, s, 0, 0, -n, 0, c, z}));
    }
    return out;
}

// A fan of `count` triangles around `center` in the xy plane, each spanning 2π/full_count of
// the circle: aspect (radius / chord) full_count / 2π whatever count is.
void add_disk_fan(std::vector<triangle>& out, vec center, float radius, int count, int full_count) {
    auto const rim = [&](int i) {
        double const angle = two_pi * double(i) / double(full_count);
        return center + vec(float(std::cos(angle)), float(std::sin(angle)), 0.0f) * radius;
    };
    for (int i = 0; i < count; ++i) add_triangle(out, center, rim(i), rim(i + 1));
}

// `count` needles of length `length` from a common apex back to a base line along y, each
// length / aspect wide. The base is centred on y = 0, where floats are finest.
void add_needle_fan(std::vector<triangle>& out, vec apex, float length, double aspect, int count) {
    double const width = double(length) / aspect;
    auto const base = [&](int i) { return vec(apex.x - length, float(width * (double(i) - 0.5 * count)), apex.z); };
    for (int i = 0; i < count; ++i) add_triangle(out, apex, base(i), base(i + 1));
}

// A closed bicone along x: 2 × segments slivers from an equator of radius `radius` to the apices
// at center ± (half_length, 0, 0).
void add_spindle(std::vector<triangle>& out, vec center, float half_length, float radius, int segments) {
    auto const equator = [&](int i) {
        double const angle = two_pi * double(i % segments) / double(segments);
        return center + vec(0.0f, float(std::cos(angle)), float(std::sin(angle))) * radius;
    };
    vec const left = center - vec(half_length, 0, 0), right = center + vec(half_length, 0, 0);
    for (int i = 0; i < segments; ++i) {
        add_triangle(out, left, equator(i + 1), equator(i));
        add_triangle(out, right, equator(i), equator(i + 1));
    }
}

// The slivers' two closed solids, for make_slivers and sliver_interior: a spindle along x and a
// thin cylinder along x. In quick mode the spindle has fewer slivers, its radius shrunk alike so
// that each keeps its aspect.
struct sliver_solids {
    explicit sliver_solids(int shrink) : spindle_radius(0.05f / float(shrink)) {}
    vec spindle_center{0, 1.5f, 0};
    float spindle_half_length = 1.0f;
    float spindle_radius;
    vec cylinder_start{-1.5f, -1.5f, 0}, cylinder_end{1.5f, -1.5f, 0};
    float cylinder_radius = 0.01f;
};

std::vector<triangle> make_slivers(int shrink) {
    std::vector<triangle> out;
    int const disk_full = 62832; // 2π · 1e4: aspect 1e4
    add_disk_fan(out, vec(0, 0, 0), 1.0f, disk_full / shrink, disk_full);
    add_needle_fan(out, vec(3.5f, 0, 0), 2.0f, 1.6e6, 4096 / shrink);
    sliver_solids const solids(shrink);
    add_spindle(out, solids.spindle_center, solids.spindle_half_length, solids.spindle_radius, 2048 / shrink);
    add_cylinder(out, solids.cylinder_start, solids.cylinder_end, solids.cylinder_radius, solids.cylinder_radius, 48,
                 64 / shrink);
    return out;
}

// `count` points strictly inside make_slivers' closed solids (sliver_solids), half in the spindle
// and half in the cylinder: within 0.9 of each solid's length and of its radius there (the
// polygons' inscribed radii are above 0.99 of it), uniform over the cross-section. From the raw
// mt19937 stream. Both solids lie along x, so the cross-section is in y and z.
std::vector<vec> sliver_interior(int shrink, int count) {
    sliver_solids const solids(shrink);
    std::mt19937 rng(91);
    auto const u01 = [&] { return float(rng() >> 8) * (1.0f / 16777216.0f); };
    std::vector<vec> out;
    for (int i = 0; i < count; ++i) {
        bool const spindle = i % 2 == 0;
        float const along = 0.9f * (2.0f * u01() - 1.0f); // in (-0.9, 0.9) of the half length
        float const radius =
            spindle ? solids.spindle_radius * (1.0f - std::fabs(along)) : solids.cylinder_radius;
        float const r = 0.9f * radius * std::sqrt(u01());
        double const angle = two_pi * double(u01());
        vec const across(0.0f, r * float(std::cos(angle)), r * float(std::sin(angle)));
        vec const axis_point = spindle ? solids.spindle_center + vec(solids.spindle_half_length * along, 0.0f, 0.0f)
                                       : (solids.cylinder_start + solids.cylinder_end) * 0.5f +
                                             vec(0.5f * (solids.cylinder_end.x - solids.cylinder_start.x) * along, 0.0f, 0.0f);
        out.push_back(axis_point + across);
    }
    return out;
}

bench_scene loaded_scene(std::string name, std::filesystem::path const& file) {
    bench_scene s{std::move(name), file.filename().string(), {}, {}, {}, {}};
    std::error_code ec;
    if (!std::filesystem::exists(file, ec)) {
        s.skipped = file.string() + " not found";
        return s;
    }
    try {
        registry& plugins = builtin_registry();
        compiled_scene const compiled = compile(load_scene(file, plugins), {.plugins = &plugins, .name = file.string()});
        s.mesh = flatten(compiled);
    } catch (std::exception const& e) {
        s.skipped = e.what();
    }
    return s;
}

} // namespace

std::vector<std::string> const& bench_scene_names() {
    static std::vector<std::string> const names{"sphere", "terrain", "soup", "forest", "engine", "bunny", "slivers"};
    return names;
}

std::vector<triangle> make_tree(int leaves_per_twig, std::uint32_t seed) {
    random_stream random(seed);
    std::vector<triangle> out;
    vec const trunk_top(0, 4, 0);
    add_cylinder(out, vec(0, 0, 0), trunk_top, 0.18f, 0.10f, 16);
    for (int b = 0; b < 7; ++b) {
        float const height = 1.6f + 2.2f * (float(b) + 0.5f) / 7.0f;
        float const angle = 2.4f * float(b) + random.uniform(-0.3f, 0.3f); // golden-angle spiral
        vec const dir = normalize(vec(std::cos(angle), random.uniform(0.6f, 1.0f), std::sin(angle)));
        vec const start(0, height, 0);
        vec const end = start + dir * random.uniform(1.5f, 2.2f);
        add_cylinder(out, start, end, 0.06f, 0.025f, 8);
        for (int t = 0; t < 5; ++t) {
            vec const twig_start = lerp(start, end, 0.3f + 0.7f * (float(t) + 0.5f) / 5.0f);
            vec const twig_dir = normalize(dir + random.direction() * 0.9f);
            float const twig_length = random.uniform(0.6f, 1.0f);
            add_cylinder(out, twig_start, twig_start + twig_dir * twig_length, 0.02f, 0.008f, 6);
            for (int l = 0; l < leaves_per_twig; ++l) {
                vec const on_twig = twig_start + twig_dir * (twig_length * random.uniform(0.1f, 1.0f));
                vec const p = on_twig + random.direction() * random.uniform(0.0f, 0.25f);
                add_leaf(out, p, random.direction(), random.direction());
            }
        }
    }
    return out;
}

std::vector<triangle> flatten(compiled_scene const& scene) {
    std::vector<triangle> out;
    auto const place = [&](std::uint32_t mesh, affine_transform<float> const& xf) {
        for (triangle const& t : scene.meshes.at(mesh).triangles)
            add_triangle(out, xf.transform_point(t.v0), xf.transform_point(t.v1), xf.transform_point(t.v2));
    };
    if (scene.levels == 0)
        place(0, affine_transform<float>::identity());
    else if (scene.levels == 1)
        for (placement const& p : scene.top_meshes) place(p.index, p.transform);
    else
        for (placement const& g : scene.top_groups)
            for (placement const& p : scene.groups.at(g.index).placements) place(p.index, g.transform * p.transform);
    return out;
}

bench_scene make_bench_scene(std::string const& name, bool quick) {
    int const shrink = quick ? 16 : 1;
    if (name == "sphere")
        return {name, "closed icosphere", make_icosphere(quick ? 6 : 8), {}, {}, {}};
    if (name == "terrain") {
        // Quick: a quarter of the cells per side over the same landscape, scaled down 4×.
        int const n = quick ? 250 : 1000;
        float const cell = 1000.0f / float(n);
        auto height = [cell](float x, float y) { return terrain_height(cell * x, cell * y) / cell; };
        return {name, "height field", make_grid(n, n, height), {}, {}, {}};
    }
    if (name == "soup") {
        aabb const cube{vec(-1, -1, -1), vec(1, 1, 1)};
        return {name, "random triangle soup", make_triangle_soup(std::size_t(500000 / shrink), 1234, cube, 0.02f), {},
                {}, {}};
    }
    if (name == "forest") {
        // Quick: a quarter of the leaves and a quarter of the trees.
        return {name, "instanced trees", make_tree(quick ? 180 : 720, 42), forest_placements(quick ? 2500 : 10000, 43),
                {}, {}};
    }
    if (name == "engine")
        return loaded_scene(name, "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb");
    if (name == "bunny") return loaded_scene(name, "/usr/share/glmark2/models/bunny.obj");
    if (name == "slivers") return {name, "thin triangles", make_slivers(shrink), {}, {}, sliver_interior(shrink, 16384)};
    throw std::invalid_argument("unknown scene '" + name + "'");
}

} // namespace canopy::bench
