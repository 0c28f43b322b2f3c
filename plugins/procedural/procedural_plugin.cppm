// canopy.plugins.procedural — procedural geometry as scene-graph content.
//
// ### Procedural scenes (`procedural` plugin: generators and the `procedural` node type)
//
// The `procedural` plugin (`plugins/procedural/procedural_plugin.cppm`, module
// `canopy.plugins.procedural`) builds geometry from parameters, through
// `registry::generate(scene, name, params, parent)`. Each generator makes one group named after
// itself under `parent`, and is deterministic in its parameters: the same parameters give the same
// bits. Parameters are text (`canopy::parameters`); numbers are plain decimals, a point is three
// numbers separated by spaces or commas (`"1 2 3"`, `"[1, 2, 3]"`).
//
// | generator | what it builds | parameters (type, default, range) |
// | --- | --- | --- |
// | `sphere` | a closed icosphere: 20·4^s triangles over 10·4^s + 2 shared vertices, every edge in two faces | `subdivisions` integer 3 [0, 8]; `radius` number 1 (0, 1e6]; `centre` point `0 0 0` (each coordinate in [−1e6, 1e6]) |
// | `terrain` | a height field over [−size/2, size/2]² in the x-z plane, y up: 2·n² triangles over (n + 1)² vertices. Heights are value noise (a 4 × 4 lattice over the square, frequency doubled and weight halved per octave), scaled so that \|y\| ≤ amplitude | `size` number 10 (0, 1e6]; `resolution` (n, cells per side) integer 64 [1, 2048]; `amplitude` number 1 [0, 1e6]; `octaves` integer 4 [1, 8]; `seed` integer 1 [0, 2³² − 1] |
// | `triangle_soup` | `count` independent random triangles: one corner uniform in [−extent, extent]³, the other two within ±size of it per axis; 3 vertices per triangle, triangle i is the i-th drawn | `count` integer 1000 [1, 10⁷]; `size` number 0.1 (0, 1e6]; `extent` number 1 (0, 1e6]; `seed` integer 1 [0, 2³² − 1] |
// | `billboard_forest` | the demo scene of the paper's Figure 1 (what `canopy render` draws without a scene, and the `figure1_billboards` example) as a scene graph: a 40 × 40 ground grid, one icosphere mesh (3 subdivisions) placed `spheres` times, one billboard quad (two triangles, an alpha-masked material with a procedural RGBA tree texture and the paper's alpha cutoff 0.01) placed `billboards` times facing the camera, all through instance nodes of free-standing prototypes, and the demo's camera | `billboards` integer 160 [0, 100000]; `spheres` integer 7 [0, 10000]; `seed` integer 1 [0, 2³² − 1]; `texture_size` integer 128 [8, 4096] |
//
// `compile()` builds each mesh of the forest once: three BLAS (ground, sphere, billboard), one top
// level over 1 + spheres + billboards placements, and `statistics.alpha_mask_needed` is true. The
// tree texture (`canopy::make_tree_texture(size)`, exported by the module) is a trunk and three
// stacked tiers on a transparent background, alpha exactly 0 or 1, made in code: the plugin needs
// no file.
//
// The node type `procedural` places any of these generators as a node of a scene (from code, or
// from a scene file whose loader makes custom nodes): a custom node with the parameter `generator`
// (the name) and that generator's parameters. `compile(s, {.plugins = &registry})` expands it into
// the generator's group, as the node's child, under the transforms above the node.
//
// A parameter the generator does not have, a value that does not parse, and a value out of range
// are errors; a failing generator leaves the scene as it was:
//
//     generator 'sphere': parameter 'radius': '-1' must be > 0
//     generator 'terrain': parameter 'resolution': '5000' is not an integer in [1, 2048]
//     generator 'sphere': parameter 'centre': '1 2' is not a point (three numbers: x y z)
//     generator 'sphere': parameter 'radus': is not a parameter of this generator (it has: subdivisions, radius, centre)
//     forest.json: node 'hills': generator 'terrain': parameter 'seed': '-1' is not an integer in [0, 4294967295]
//     forest.json: node 'hills': generator 'cube' is not registered (known: billboard_forest sphere terrain triangle_soup)
//
// Example: a terrain with a sphere on it, one as a generated group, one as a node.
//
// ```cpp
// import canopy.plugins;
//
// canopy::registry& r = canopy::builtin_registry();
// canopy::scene s;
// r.generate(s, "terrain", {{"size", "20"}, {"resolution", "128"}, {"amplitude", "1.5"}, {"seed", "7"}});
// auto lift = s.add_transform(s.root(), canopy::affine_transform<float>::from_rows({1, 0, 0, 0, 0, 1, 0, 3, 0, 0, 1, 0}));
// s.add_custom(lift, "procedural", {{"generator", "sphere"}, {"subdivisions", "4"}}, "ball");
// canopy::compiled_scene c = canopy::compile(s, {.plugins = &r}); // 32768 + 5120 triangles, levels 1
// ```
module;
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <functional>
#include <map>
#include <random>
#include <string>
#include <utility>
#include <vector>
export module canopy.plugins.procedural;
import canopy.scene;
import canopy.procedural;

export namespace canopy {

// The billboards' tree: a trunk and three stacked green tiers on a transparent background
// (alpha exactly 0 or 1), size × size texels, row 0 at the top (v = 0).
image_data make_tree_texture(int size);

void register_procedural_plugin(registry& r);

} // namespace canopy

namespace canopy {

namespace {

constexpr double max_coordinate = 1e6;

std::string context_of(std::string const& generator) { return "generator '" + generator + "'"; }

[[noreturn]] void bad_parameter(std::string const& context, std::string const& key, std::string const& problem) {
    throw scene_error(context, "parameter '" + key + "'", problem);
}

// Every given parameter must be one the generator reads.
void check_known(parameters const& p, std::string const& context, std::vector<std::string> const& known) {
    for (auto const& [key, value] : p.values()) {
        bool found = false;
        for (auto const& k : known) found |= k == key;
        if (found) continue;
        std::string list;
        for (auto const& k : known) list += (list.empty() ? "" : ", ") + k;
        bad_parameter(context, key, "is not a parameter of this generator (it has: " + list + ")");
    }
}

std::string format_number(double v) {
    std::string s = std::to_string(v);
    while (s.size() > 1 && s.back() == '0') s.pop_back();
    if (!s.empty() && s.back() == '.') s.pop_back();
    return s;
}

// A number in [lo, hi] (in (lo, hi] when open_low).
double number_in(parameters const& p, std::string const& key, double fallback, double lo, double hi,
                 std::string const& context, bool open_low = false) {
    double const v = p.get_number(key, fallback, context);
    if (open_low ? !(v > lo) : !(v >= lo))
        bad_parameter(context, key, "'" + p.get_string(key, "") + "' must be " + (open_low ? "> " : "≥ ") + format_number(lo));
    if (!(v <= hi)) bad_parameter(context, key, "'" + p.get_string(key, "") + "' must be ≤ " + format_number(hi));
    return v;
}

double positive(parameters const& p, std::string const& key, double fallback, std::string const& context) {
    return number_in(p, key, fallback, 0.0, max_coordinate, context, true);
}

std::uint32_t seed_of(parameters const& p, std::string const& context) {
    return std::uint32_t(p.get_integer("seed", 1, 0, 4294967295LL, context));
}

// Three numbers separated by spaces or commas, optionally in brackets.
vec3<float> point_in(parameters const& p, std::string const& key, vec3<float> fallback, std::string const& context) {
    if (!p.has(key)) return fallback;
    std::string text = p.get_string(key, "");
    for (char& c : text)
        if (c == ',' || c == '[' || c == ']' || c == '(' || c == ')' || c == '\t') c = ' ';
    std::array<double, 3> xyz{};
    std::size_t count = 0, pos = 0;
    while (pos < text.size()) {
        std::size_t const start = text.find_first_not_of(' ', pos);
        if (start == std::string::npos) break;
        std::size_t const end = std::min(text.find(' ', start), text.size());
        parameters one{{key, text.substr(start, end - start)}};
        double const v = one.get_number(key, 0.0, context);
        if (count < 3) xyz[count] = v;
        ++count;
        pos = end;
    }
    if (count != 3)
        bad_parameter(context, key, "'" + p.get_string(key, "") + "' is not a point (three numbers: x y z)");
    for (double v : xyz)
        if (std::abs(v) > max_coordinate)
            bad_parameter(context, key, "'" + p.get_string(key, "") + "' has a coordinate outside [-1e6, 1e6]");
    return {float(xyz[0]), float(xyz[1]), float(xyz[2])};
}

// Indexed mesh from a triangle list, vertices shared where their positions have the same bits
// (canopy.procedural copies every shared vertex bit for bit).
mesh_data weld(std::vector<triangle> const& triangles, std::string name) {
    mesh_data m;
    m.name = std::move(name);
    std::map<std::array<std::uint32_t, 3>, std::uint32_t> index;
    auto vertex = [&](vec3<float> const& v) {
        std::array<std::uint32_t, 3> const key{std::bit_cast<std::uint32_t>(v.x), std::bit_cast<std::uint32_t>(v.y),
                                               std::bit_cast<std::uint32_t>(v.z)};
        auto const [it, fresh] = index.try_emplace(key, std::uint32_t(m.positions.size()));
        if (fresh) m.positions.push_back(v);
        return it->second;
    };
    m.triangles.reserve(triangles.size());
    for (auto const& t : triangles) {
        std::uint32_t const a = vertex(t.v0), b = vertex(t.v1), c = vertex(t.v2);
        m.triangles.push_back({a, b, c});
    }
    return m;
}

// One mesh in a group named after the generator.
node_id place_mesh(scene& s, node_id parent, std::string const& name, mesh_data m) {
    node_id const group = s.add_group(parent, name);
    std::uint32_t const mesh = s.add_mesh(std::move(m));
    s.add_mesh_node(group, mesh, name);
    return group;
}

node_id generate_sphere(scene& s, node_id parent, parameters const& p) {
    std::string const context = context_of("sphere");
    check_known(p, context, {"subdivisions", "radius", "centre"});
    int const subdivisions = int(p.get_integer("subdivisions", 3, 0, 8, context));
    double const radius = positive(p, "radius", 1.0, context);
    vec3<float> const centre = point_in(p, "centre", {0.0f, 0.0f, 0.0f}, context);
    return place_mesh(s, parent, "sphere", weld(make_icosphere(subdivisions, centre, float(radius)), "sphere"));
}

// Value noise: hashed lattice values in [-1, 1], smoothstep-interpolated. Integer hashing and
// double arithmetic only, so the heights are the same on every machine.
std::uint64_t mix(std::uint64_t z) {
    z += 0x9e3779b97f4a7c15ull; // splitmix64 finaliser
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

double lattice(std::uint32_t seed, int octave, std::int64_t i, std::int64_t j) {
    std::uint64_t const h = mix(mix(mix(seed) ^ std::uint64_t(octave)) ^ ((std::uint64_t(i) << 32) | std::uint32_t(j)));
    return double(h >> 11) * 0x1p-52 - 1.0;
}

double value_noise(std::uint32_t seed, int octave, double x, double y) {
    double const fx = std::floor(x), fy = std::floor(y);
    auto const i = std::int64_t(fx), j = std::int64_t(fy);
    auto const smooth = [](double t) { return t * t * (3.0 - 2.0 * t); };
    double const sx = smooth(x - fx), sy = smooth(y - fy);
    double const a = lattice(seed, octave, i, j), b = lattice(seed, octave, i + 1, j);
    double const c = lattice(seed, octave, i, j + 1), d = lattice(seed, octave, i + 1, j + 1);
    return (a + (b - a) * sx) + ((c + (d - c) * sx) - (a + (b - a) * sx)) * sy;
}

node_id generate_terrain(scene& s, node_id parent, parameters const& p) {
    std::string const context = context_of("terrain");
    check_known(p, context, {"size", "resolution", "amplitude", "octaves", "seed"});
    double const size = positive(p, "size", 10.0, context);
    int const resolution = int(p.get_integer("resolution", 64, 1, 2048, context));
    double const amplitude = number_in(p, "amplitude", 1.0, 0.0, max_coordinate, context);
    int const octaves = int(p.get_integer("octaves", 4, 1, 8, context));
    std::uint32_t const seed = seed_of(p, context);

    auto const height = [&](double u, double v) {
        double sum = 0.0, weight = 0.0, w = 1.0, frequency = 4.0;
        for (int o = 0; o < octaves; ++o, w *= 0.5, frequency *= 2.0) {
            sum += w * value_noise(seed, o, u * frequency, v * frequency);
            weight += w;
        }
        return amplitude * sum / weight;
    };
    double const n = double(resolution);
    // make_grid's (i, j) → x = i, z = -j (so that the triangles face +y), centred.
    auto grid = make_grid(resolution, resolution, [&](float i, float j) { return float(height(i / n, j / n)); });
    for (auto& t : grid)
        for (vec3<float>* v : {&t.v0, &t.v1, &t.v2})
            *v = vec3<float>(float((double(v->x) / n - 0.5) * size), v->z, float((0.5 - double(v->y) / n) * size));
    return place_mesh(s, parent, "terrain", weld(grid, "terrain"));
}

node_id generate_triangle_soup(scene& s, node_id parent, parameters const& p) {
    std::string const context = context_of("triangle_soup");
    check_known(p, context, {"count", "size", "extent", "seed"});
    auto const count = std::size_t(p.get_integer("count", 1000, 1, 10'000'000, context));
    double const size = positive(p, "size", 0.1, context);
    auto const extent = float(positive(p, "extent", 1.0, context));
    std::uint32_t const seed = seed_of(p, context);
    aabb const box{vec3<float>(-extent), vec3<float>(extent)};
    mesh_data m;
    m.name = "triangle_soup";
    m.positions.reserve(3 * count);
    m.triangles.reserve(count);
    for (auto const& t : make_triangle_soup(count, seed, box, float(size))) {
        auto const first = std::uint32_t(m.positions.size());
        m.positions.insert(m.positions.end(), {t.v0, t.v1, t.v2});
        m.triangles.push_back({first, first + 1, first + 2});
    }
    return place_mesh(s, parent, "triangle_soup", std::move(m));
}

node_id generate_billboard_forest(scene& s, node_id parent, parameters const& p) {
    std::string const context = context_of("billboard_forest");
    check_known(p, context, {"billboards", "spheres", "seed", "texture_size"});
    int const billboards = int(p.get_integer("billboards", 160, 0, 100'000, context));
    int const spheres = int(p.get_integer("spheres", 7, 0, 10'000, context));
    std::uint32_t const seed = seed_of(p, context);
    int const texture_size = int(p.get_integer("texture_size", 128, 8, 4096, context));

    // The demo's camera; billboards turn towards its eye.
    camera_data camera;
    camera.eye = {0.0f, 3.2f, 17.0f};
    camera.target = {0.0f, 2.0f, 0.0f};
    camera.fovy_degrees = 45.0f;

    int const ground_material = s.add_material({"ground", {0.55f, 0.5f, 0.35f}});
    int const ball_material = s.add_material({"ball", {0.75f, 0.3f, 0.25f}});
    int const tree_image = s.add_image(make_tree_texture(texture_size));
    // The paper's cutoff (`hr.hit &= color.w >= .01f`): a billboard is cut only where the texture
    // is (nearly) fully transparent around the hit.
    int const tree_material = s.add_material({"tree", {1.0f, 1.0f, 1.0f}, tree_image, alpha_mode::mask, 0.01f});

    auto ground_triangles = make_grid(40, 40);
    for (auto& t : ground_triangles)
        for (vec3<float>* v : {&t.v0, &t.v1, &t.v2}) *v = vec3<float>(v->x - 20.0f, 0.0f, v->y - 20.0f);
    mesh_data ground = weld(ground_triangles, "ground");
    ground.material = ground_material;
    mesh_data ball = weld(make_icosphere(3), "sphere");
    ball.material = ball_material;
    mesh_data quad;
    quad.name = "billboard";
    quad.positions = {{-0.5f, 1.0f, 0.0f}, {0.5f, 1.0f, 0.0f}, {0.5f, 0.0f, 0.0f}, {-0.5f, 0.0f, 0.0f}};
    quad.triangles = {{0, 1, 2}, {0, 2, 3}};
    quad.uvs = {{vec2<float>(0, 0), vec2<float>(1, 0), vec2<float>(1, 1)},
                {vec2<float>(0, 0), vec2<float>(1, 1), vec2<float>(0, 1)}};
    quad.material = tree_material;

    node_id const group = s.add_group(parent, "billboard_forest");
    s.add_camera(group, camera, "camera");
    s.add_mesh_node(group, s.add_mesh(std::move(ground)), "ground");
    node_id const ball_prototype = s.add_mesh_node(no_node, s.add_mesh(std::move(ball)), "sphere");
    node_id const quad_prototype = s.add_mesh_node(no_node, s.add_mesh(std::move(quad)), "billboard");

    // Every sphere, then every billboard, drawn from one stream: deterministic in the seed.
    std::mt19937 rng(seed);
    auto uniform = [&](float lo, float hi) { return lo + (hi - lo) * float(double(rng()) / double(std::mt19937::max())); };
    for (int k = 0; k < spheres; ++k) {
        float const r = uniform(0.6f, 1.6f);
        float const x = uniform(-9.0f, 9.0f);
        float const z = uniform(-14.0f, 2.0f);
        std::array<float, 12> const rows{r, 0, 0, x, 0, r, 0, r, 0, 0, r, z};
        s.add_instance(group, ball_prototype, affine_transform<float>::from_rows(rows), std::uint32_t(k));
    }
    for (int k = 0; k < billboards; ++k) {
        float const x = uniform(-16.0f, 16.0f);
        float const z = uniform(-18.0f, 9.0f);
        float const height = uniform(1.8f, 3.6f);
        float const width = height * uniform(0.7f, 0.9f);
        // Face the camera: rotate the quad's normal (+z) about y towards the eye.
        float const yaw = std::atan2(camera.eye.x - x, camera.eye.z - z);
        float const cy = std::cos(yaw), sy = std::sin(yaw);
        std::array<float, 12> const rows{cy * width, 0, sy, x, 0, height, 0, 0, -sy * width, 0, cy, z};
        s.add_instance(group, quad_prototype, affine_transform<float>::from_rows(rows), std::uint32_t(k));
    }
    return group;
}

struct procedural_generator {
    char const* name;
    char const* description;
    node_id (*build)(scene&, node_id, parameters const&);
};

constexpr std::array<procedural_generator, 4> generators{{
    {"sphere", "closed icosphere (subdivisions, radius, centre)", generate_sphere},
    {"terrain", "value-noise height field (size, resolution, amplitude, octaves, seed)", generate_terrain},
    {"triangle_soup", "random triangles in a box (count, size, extent, seed)", generate_triangle_soup},
    {"billboard_forest", "the demo scene: instanced alpha-masked billboards (billboards, spheres, seed, texture_size)",
     generate_billboard_forest},
}};

// The `procedural` node type: {generator: NAME, ...} → generator NAME (of any plugin) under the node.
node_id expand_procedural_node(scene& s, node_id node, parameters const& p, registry const& r) {
    std::string const file = s.at(node).source;
    std::string const where = "node '" + s.at(node).name + "'";
    if (!p.has("generator"))
        throw scene_error(file, where, "a 'procedural' node needs a 'generator' parameter");
    std::string const name = p.get_string("generator", "");
    parameters rest;
    for (auto const& [key, value] : p.values())
        if (key != "generator") rest.set(key, value);
    if (!r.has_generator(name)) {
        std::string known;
        for (auto const& g : r.generators()) known += (known.empty() ? "" : " ") + g.name;
        throw scene_error(file, where, "generator '" + name + "' is not registered (known: " + known + ")");
    }
    try {
        return r.generate(s, name, rest, node);
    } catch (scene_error const& e) {
        throw scene_error(file, where, e.what());
    }
}

} // namespace

image_data make_tree_texture(int size) {
    image_data img;
    img.source = "procedural tree";
    img.width = img.height = size;
    img.texels.resize(std::size_t(size) * std::size_t(size));
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) {
            double const u = (x + 0.5) / size, v = (y + 0.5) / size;
            double const off = std::abs(u - 0.5);
            vec4<float> texel{0.0f, 0.0f, 0.0f, 0.0f};
            if (v > 0.7 && off < 0.06) texel = {0.35f, 0.22f, 0.1f, 1.0f}; // trunk
            for (int tier = 0; tier < 3; ++tier) {
                double const apex = 0.02 + 0.22 * tier, base = apex + 0.36, half_width = 0.28 + 0.1 * tier;
                if (v >= apex && v <= base && off <= half_width * (v - apex) / (base - apex))
                    texel = {0.1f, float(0.55 - 0.25 * v), 0.12f, 1.0f};
            }
            img.texels[std::size_t(y) * std::size_t(size) + std::size_t(x)] = texel;
        }
    return img;
}

void register_procedural_plugin(registry& r) {
    for (auto const& g : generators) r.add_generator(g.name, "procedural", g.description, g.build);
    r.add_node_type("procedural", "procedural",
                    "content of a procedural generator: {generator: NAME, ...its parameters}", expand_procedural_node);
}

} // namespace canopy
