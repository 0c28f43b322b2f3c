// Tests of compile() on hostile graphs: chains as deep as 10^5 nodes or instances (no recursion:
// refused at the default depth by name, compiled when the limit allows), placements counted before
// they are made (a nest of 10^8 refused without allocating), large groups compiled in one pass
// (10^6 instances, 10^5 mesh nodes; results checked, not times), transforms that overflow or
// cannot be inverted once composed, constant-time marks and roll-backs, and running out of memory
// reported as a scene_error. Every input is generated here.
#include <catch2/catch.hpp>

#include <array>
#include <cmath>
#include <cstdint>
#include <new>
#include <optional>
#include <random>
#include <string>
#include <vector>

import canopy.scene;
import canopy.plugins.json;
import canopy.plugins.gltf;
import canopy.testing;
import canopy.testing.scene;

namespace {

using canopy::node_id;
using canopy::no_node;
using canopy::vec3;
using test_support::message_of;
using xf = canopy::affine_transform<float>;
using xf64 = canopy::affine_transform<double>;

xf translate(float x, float y, float z) { return xf::from_rows({1, 0, 0, x, 0, 1, 0, y, 0, 0, 1, z}); }
xf scale(float k) { return xf::from_rows({k, 0, 0, 0, 0, k, 0, 0, 0, 0, k, 0}); }

// The square [-h, h]² in the plane z = 0, two triangles.
canopy::mesh_data square(std::string name, float h = 1.0f) {
    canopy::mesh_data m;
    m.name = std::move(name);
    m.positions = {{-h, -h, 0}, {h, -h, 0}, {h, h, 0}, {-h, h, 0}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}};
    return m;
}

canopy::compile_options with_depth(std::string name, std::uint64_t max_depth) {
    canopy::compile_options o{.name = std::move(name)};
    o.limits.max_depth = max_depth;
    return o;
}

canopy::compile_options with_placements(std::string name, std::uint64_t max_placements) {
    canopy::compile_options o{.name = std::move(name)};
    o.limits.max_placements = max_placements;
    return o;
}

xf64 widen(xf const& a) {
    return {{vec3<double>(a.linear.col0), vec3<double>(a.linear.col1), vec3<double>(a.linear.col2)},
            vec3<double>(a.translation)};
}

// The closest hit of a levels-1 scene, by brute force over every placement and triangle: the
// placement index, or nullopt.
std::optional<std::uint32_t> brute_force_placement(canopy::compiled_scene const& c, canopy::ray const& r, double& best) {
    std::optional<std::uint32_t> found;
    best = INFINITY;
    for (std::uint32_t k = 0; k < c.top_meshes.size(); ++k) {
        xf64 const m = widen(c.top_meshes[k].transform);
        for (auto const& t : c.meshes[c.top_meshes[k].index].triangles) {
            std::array<vec3<double>, 3> const v{m.transform_point(vec3<double>(t.v0)), m.transform_point(vec3<double>(t.v1)),
                                                m.transform_point(vec3<double>(t.v2))};
            if (auto h = test_support::hit_double(r, v); h && *h < best) best = *h, found = k;
        }
    }
    return found;
}

// The closest hit of `r` in a levels-1 scene: the brute-force closest placement, at the same t
// (to 1e-5). Returns the hit for the caller's own checks.
canopy::basic_hit_record<float> check_closest_placement(canopy::compiled_scene const& c, canopy::ray const& r) {
    double t = 0.0;
    auto const expected = brute_force_placement(c, r, t);
    canopy::default_intersector isect;
    auto const hit = c.closest_hit(r, isect);
    REQUIRE(expected.has_value());
    REQUIRE(hit.hit);
    CHECK(hit.inst_id == *expected);
    CHECK(double(hit.t) == Approx(t).epsilon(1e-5));
    return hit;
}

// A JSON scene of prototypes p0 … p{n−1}, each an instance of the next (0.5 along x), the last
// holding the square; the scene places p0 once.
std::string json_chain(int n) {
    std::string text = R"({"version": 1, "meshes": [{"name": "square", "positions": [-1,-1,0, 1,-1,0, 1,1,0, -1,1,0], "indices": [0,1,2, 0,2,3]}], "prototypes": [)";
    for (int k = 0; k < n; ++k) {
        std::string const name = "p" + std::to_string(k);
        text += k ? ",\n" : "\n";
        if (k + 1 < n)
            text += R"({"name": ")" + name + R"(", "type": "group", "children": [{"type": "instance", "name": "i)" +
                    std::to_string(k) + R"(", "target": "p)" + std::to_string(k + 1) + R"(", "translate": [0.5, 0, 0]}]})";
        else
            text += R"({"name": ")" + name + R"(", "type": "group", "children": [{"type": "mesh", "mesh": "square"}]})";
    }
    return text + R"(], "nodes": [{"type": "instance", "name": "top", "target": "p0", "id": 5}]})";
}

// A JSON scene whose prototype "trees" nests 10 instances per level, `levels` deep, over one
// square: 10^levels placements after flattening, in a file of a few hundred bytes per level.
std::string json_nest(int levels) {
    std::string text = R"({"version": 1, "meshes": [{"name": "square", "positions": [-1,-1,0, 1,-1,0, 1,1,0, -1,1,0], "indices": [0,1,2, 0,2,3]}], "prototypes": [)";
    text += R"({"name": "n0", "type": "group", "children": [{"type": "mesh", "mesh": "square"}]})";
    for (int l = 1; l <= levels; ++l) {
        std::string const name = l == levels ? "trees" : "n" + std::to_string(l);
        text += R"(, {"name": ")" + name + R"(", "type": "group", "children": [)";
        for (int k = 0; k < 10; ++k)
            text += std::string(k ? ", " : "") + R"({"type": "instance", "target": "n)" + std::to_string(l - 1) +
                    R"(", "translate": [)" + std::to_string(3 * k) + ", 0, 0]}";
        text += "]}";
    }
    return text + R"(], "nodes": [{"type": "instance", "name": "forest", "target": "trees"}]})";
}

} // namespace

// ---- depth: no recursion, a limit by name ----------------------------------------------------

TEST_CASE("limits: a chain of 100000 transform nodes is refused at the default depth by name, compiled when allowed") {
    canopy::scene s;
    auto const m = s.add_mesh(square("square"));
    node_id n = s.root();
    for (int k = 0; k < 100000; ++k) n = s.add_transform(n, translate(0.5f, 0, 0), "t" + std::to_string(k));
    s.add_mesh_node(n, m, "tip");
    // t0 is one link below the root, so t4096 is the first node past 4096; the tip is 100001 deep.
    CHECK(message_of([&] { canopy::compile(s, {.name = "chain.json"}); }) ==
          "chain.json: transform 't4096': 100001 levels of nesting (children and instances) exceed the limit of 4096 "
          "(--max-depth)");
    CHECK(message_of([&] { canopy::compile(s, with_depth("chain.json", 100000)); })
              .find("chain.json: mesh 'tip': 100001 levels of nesting") == 0);

    auto const c = canopy::compile(s, with_depth("chain.json", 100001));
    REQUIRE(c.levels == 1);
    REQUIRE(c.top_meshes.size() == 1);
    CHECK(c.statistics.placements == 1);
    CHECK(c.top_meshes[0].transform.translation.x == 50000.0f); // 100000 · 0.5, exact in double
    CHECK(c.top_meshes[0].transform.translation.y == 0.0f);
    canopy::default_intersector isect;
    auto const hit = c.closest_hit(canopy::ray{{50000.25f, 0.5f, 4.0f}, 0.0f, {0, 0, -1}, INFINITY}, isect);
    REQUIRE(hit.hit);
    CHECK(hit.t == 4.0f);
    CHECK(hit.inst_id == 0);
    CHECK(!c.closest_hit(canopy::ray{{2.0f, 0.5f, 4.0f}, 0.0f, {0, 0, -1}, INFINITY}, isect).hit);
}

TEST_CASE("limits: a chain of 100000 prototypes, each an instance of the next, places its mesh once") {
    constexpr int n = 100000;
    canopy::scene s;
    auto const m = s.add_mesh(square("square"));
    std::vector<node_id> p(n + 1);
    for (int k = 0; k <= n; ++k) p[std::size_t(k)] = s.add_group(no_node, "p" + std::to_string(k));
    for (int k = 0; k < n; ++k)
        s.add_instance(p[std::size_t(k)], p[std::size_t(k) + 1], translate(0.5f, 0, 0), std::uint32_t(k), "i" + std::to_string(k));
    s.add_mesh_node(p[n], m, "tip");
    s.add_instance(s.root(), p[0], translate(0, 0, -1), 7777, "top");
    // root → top (1) → p0 (2) → i0 (3) → p1 (4) …: i2047 is 4097 deep, the tip 2n + 3.
    CHECK(message_of([&] { canopy::compile(s, {.name = "chain"}); }) ==
          "chain: instance 'i2047': 200003 levels of nesting (children and instances) exceed the limit of 4096 (--max-depth)");

    auto const c = canopy::compile(s, with_depth("chain", 200003));
    REQUIRE(c.levels == 1);
    REQUIRE(c.top_meshes.size() == 1);
    CHECK(c.top_meshes[0].transform.translation.x == 50000.0f);
    CHECK(c.top_meshes[0].transform.translation.z == -1.0f);
    CHECK(c.top_meshes[0].id == 7777); // the instance that placed the chain
    CHECK(c.statistics.subtrees_empty == 0);
    canopy::default_intersector isect;
    auto const hit = c.closest_hit(canopy::ray{{49999.5f, -0.25f, 4.0f}, 0.0f, {0, 0, -1}, INFINITY}, isect);
    REQUIRE(hit.hit);
    CHECK(hit.t == 5.0f);
    CHECK(c.instance_id(hit) == 7777);
}

TEST_CASE("limits: a chain of prototypes with two meshes per level is flattened into one group, in graph order") {
    // p_k holds meshes a, b (at y = 0 and y = 0.25 in its frame) and an instance of p_{k+1}
    // one unit up; p_2000 holds a and b only. 2 · 2001 placements; 4004 levels, under the default.
    constexpr int n = 2000;
    canopy::scene s;
    auto const a = s.add_mesh(square("a", 0.1f));
    auto const b = s.add_mesh(square("b", 0.1f));
    std::vector<node_id> p(n + 1);
    for (int k = 0; k <= n; ++k) p[std::size_t(k)] = s.add_group(no_node, "p" + std::to_string(k));
    for (int k = 0; k <= n; ++k) {
        s.add_mesh_node(p[std::size_t(k)], a);
        s.add_mesh_node(s.add_transform(p[std::size_t(k)], translate(0, 0.25f, 0)), b);
        if (k < n) s.add_instance(p[std::size_t(k)], p[std::size_t(k) + 1], translate(0, 1, 0), 0);
    }
    s.add_instance(s.root(), p[0], translate(0, 0, 0), 1, "left");
    s.add_instance(s.root(), p[0], translate(10, 0, 0), 2, "right");
    auto const c = canopy::compile(s);
    REQUIRE(c.levels == 2);
    REQUIRE(c.groups.size() == 1);
    auto const& g = c.groups[0].placements;
    REQUIRE(g.size() == 2 * (n + 1));
    CHECK(c.statistics.placements == 2 * (n + 1));
    CHECK(c.statistics.flattened_placements == 2 * n);
    for (int k = 0; k <= n; ++k) {
        INFO("level " << k);
        CHECK(g[2 * std::size_t(k)].index == 0);
        CHECK(g[2 * std::size_t(k)].transform.translation.y == float(k));
        CHECK(g[2 * std::size_t(k) + 1].index == 1);
        CHECK(g[2 * std::size_t(k) + 1].transform.translation.y == float(k) + 0.25f);
        CHECK(g[2 * std::size_t(k)].id == canopy::invalid_id);
    }
    canopy::default_intersector isect;
    auto const hit = c.closest_hit(canopy::ray{{10.05f, 1234.3f, 2.0f}, 0.0f, {0, 0, -1}, INFINITY}, isect);
    REQUIRE(hit.hit);
    CHECK(hit.inst_id == 1);
    CHECK(hit.inner_inst_id[0] == 2 * 1234 + 1);
    CHECK(c.instance_id(hit) == 2);
}

TEST_CASE("limits: a JSON chain of 20000 prototypes is refused at the default depth naming the file and node") {
    constexpr int n = 20000;
    std::string const text = json_chain(n);
    canopy::scene s;
    canopy::parse_json_scene(text, "chain.json", nullptr, s, s.root());
    // root → group 'chain' (1) → top (2) → prototype p0 (3) → its group node p0 (4) → i0 (5) → …:
    // i1364 is 4097 deep, the mesh 3n + 2.
    CHECK(message_of([&] { canopy::compile(s, {.name = "scene"}); }) ==
          "chain.json: instance 'i1364': 60002 levels of nesting (children and instances) exceed the limit of 4096 "
          "(--max-depth)");
    auto const c = canopy::compile(s, with_depth("scene", 60002));
    REQUIRE(c.top_meshes.size() == 1);
    CHECK(c.top_meshes[0].transform.translation.x == 0.5f * float(n - 1));
    CHECK(c.top_meshes[0].id == 5);
}

TEST_CASE("limits: a glTF node hierarchy 20000 deep is refused at the default depth naming the node") {
    constexpr int n = 20000;
    std::string text = R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [)";
    for (int k = 0; k < n; ++k)
        text += std::string(k ? "," : "") + R"({"translation": [0.5, 0, 0], )" +
                (k + 1 < n ? R"("children": [)" + std::to_string(k + 1) + "]}" : std::string(R"("mesh": 0})"));
    text += R"(], "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}]})";
    test_support::temp_folder folder("scene_limits_test");
    auto const file = folder.write("deep.gltf", text);
    canopy::registry r;
    canopy::register_gltf_plugin(r);
    // The loader refuses the hierarchy before building it: nodes[4096] is 4097 levels deep.
    canopy::scene refused;
    CHECK(message_of([&] { r.load(refused, file, refused.root()); }) ==
          file.string() + ": nodes[4096]: is 4097 levels deep in the node hierarchy, over the limit of 4096 (--max-depth)");
    // With the depth raised for the loader, compile() refuses it at its own default, naming the node
    // (root → group 'deep.gltf' (1) → nodes[0] (2) → …: nodes[4095] is 4097 deep, the mesh n + 2).
    canopy::scene s;
    {
        auto const saved = canopy::default_limits();
        canopy::default_limits().max_depth = 20002;
        r.load(s, file, s.root());
        canopy::default_limits() = saved;
    }
    std::string const message = message_of([&] { canopy::compile(s, {.name = file.string()}); });
    CHECK(message == file.string() +
                         ": transform 'nodes[4095]': 20002 levels of nesting (children and instances) exceed the limit of 4096 "
                         "(--max-depth)");
    auto const c = canopy::compile(s, with_depth(file.string(), 20002));
    REQUIRE(c.top_meshes.size() == 1);
    CHECK(c.top_meshes[0].transform.translation.x == 0.5f * float(n));
}

// ---- placements: counted before they are made -------------------------------------------------

TEST_CASE("limits: instances nested 10 per level are counted before flattening and refused over the limit") {
    canopy::scene s;
    std::string const eight = json_nest(8);
    CHECK(eight.size() < 8000);
    canopy::parse_json_scene(eight, "forest.json", nullptr, s, s.root());
    CHECK(message_of([&] { canopy::compile(s, {.name = "forest.json"}); }) ==
          "forest.json: group 'trees': 100000000 placements after flattening exceed the limit of 4194304 (--max-placements)");

    canopy::scene seven;
    canopy::parse_json_scene(json_nest(7), "forest.json", nullptr, seven, seven.root());
    CHECK(message_of([&] { canopy::compile(seven, {.name = "forest.json"}); }) ==
          "forest.json: group 'trees': 10000000 placements after flattening exceed the limit of 4194304 (--max-placements)");
    CHECK(message_of([&] { canopy::compile(seven, with_placements("forest.json", 1000000)); }) ==
          "forest.json: group 'trees': 10000000 placements after flattening exceed the limit of 1000000 (--max-placements)");

    // 10^30 does not fit 64 bits: the count saturates and says so.
    canopy::scene thirty;
    canopy::parse_json_scene(json_nest(30), "forest.json", nullptr, thirty, thirty.root());
    CHECK(message_of([&] { canopy::compile(thirty, {.name = "forest.json"}); }) ==
          "forest.json: group 'trees': at least 18446744073709551615 placements after flattening exceed the limit of "
          "4194304 (--max-placements)");

    // Under the limit, the same nest compiles: 10^3 placements, in graph order (the one
    // untransformed subtree is the top level).
    canopy::scene three;
    canopy::parse_json_scene(json_nest(3), "forest.json", nullptr, three, three.root());
    auto const c = canopy::compile(three, with_placements("forest.json", 1000));
    REQUIRE(c.top_meshes.size() == 1000);
    CHECK(c.statistics.placements == 1000);
    for (std::size_t k = 0; k < 1000; ++k)
        CHECK(c.top_meshes[k].transform.translation.x == float(3 * (k % 10) + 3 * (k / 10 % 10) + 3 * (k / 100)));
}

TEST_CASE("limits: the placements of the whole scene are limited, groups and direct placements together") {
    canopy::scene s;
    auto const m = s.add_mesh(square("square"));
    node_id const four = s.add_group(no_node, "four");
    for (int k = 0; k < 4; ++k) s.add_mesh_node(s.add_transform(four, translate(3.0f * float(k), 0, 0)), m);
    s.add_instance(s.root(), four, translate(0, 0, 0), 1);
    s.add_instance(s.root(), four, translate(0, 3, 0), 2);
    s.add_mesh_node(s.add_transform(s.root(), translate(0, 6, 0)), m);
    // Built: the group's 4 placements once, and the loose one; the top level holds 3 items.
    auto const c = canopy::compile(s, with_placements("grid.json", 5));
    CHECK(c.statistics.placements == 5);
    CHECK(c.statistics.group_instances == 2);
    CHECK(message_of([&] { canopy::compile(s, with_placements("grid.json", 4)); }) ==
          "grid.json: 5 placements after flattening exceed the limit of 4 (--max-placements)");
    CHECK(message_of([&] { canopy::compile(s, with_placements("grid.json", 3)); }) ==
          "grid.json: group 'four': 4 placements after flattening exceed the limit of 3 (--max-placements)");
    CHECK(message_of([&] { canopy::compile(s, with_placements("grid.json", 2)); }) ==
          "grid.json: 3 meshes, instances, cameras and lights at the top level exceed the limit of 2 (--max-placements)");
}

TEST_CASE("limits: children shared by several parents are counted per path, not walked per path") {
    // 70 levels, each group holding the next level twice: 2^70 paths to the bottom.
    auto const diamond = [](bool with_mesh) {
        canopy::scene s;
        node_id below = s.add_group(no_node, "bottom");
        if (with_mesh) s.add_mesh_node(below, s.add_mesh(square("square")), "tile");
        for (int level = 0; level < 70; ++level) {
            node_id const g = s.add_group(no_node, "level " + std::to_string(level));
            s.attach(g, below);
            s.attach(g, below);
            below = g;
        }
        s.attach(s.root(), below);
        return s;
    };
    auto const full = diamond(true);
    CHECK(message_of([&] { canopy::compile(full, {.name = "dag"}); }) ==
          "dag: at least 18446744073709551615 meshes, instances, cameras and lights at the top level exceed the limit of "
          "4194304 (--max-placements)");
    auto const empty = diamond(false);
    CHECK(message_of([&] { canopy::compile(empty, {.name = "dag"}); }) ==
          "dag: the scene has nothing to trace (no mesh with triangles is placed in it)");
}

// ---- large groups: one pass -------------------------------------------------------------------

TEST_CASE("limits: one small mesh placed 10^6 times through instance nodes in one group") {
    constexpr int side = 1000;
    canopy::scene s;
    node_id const tile = s.add_mesh_node(no_node, s.add_mesh(square("tile")), "tile");
    node_id const grid = s.add_group(s.root(), "grid");
    for (int y = 0; y < side; ++y)
        for (int x = 0; x < side; ++x)
            s.add_instance(grid, tile, translate(3.0f * float(x), 3.0f * float(y), 0), std::uint32_t(y * side + x));
    auto const c = canopy::compile(s);
    REQUIRE(c.levels == 1);
    REQUIRE(c.top_meshes.size() == std::size_t(side) * side);
    CHECK(c.meshes.size() == 1);
    CHECK(c.statistics.placements == std::size_t(side) * side);
    CHECK(c.statistics.triangles_placed == 2 * std::size_t(side) * side);
    CHECK(c.top_meshes[123457].id == 123457);
    CHECK(c.top_meshes[123457].transform.translation.x == 3.0f * 457);
    CHECK(c.top_meshes[123457].transform.translation.y == 3.0f * 123);
    // Rays at random tiles, straight and oblique: the closest hit is the brute-force closest.
    std::mt19937 rng(15);
    std::uniform_int_distribution<int> cell(0, side - 1);
    std::uniform_real_distribution<float> unit(-0.9f, 0.9f);
    for (int i = 0; i < 6; ++i) {
        int const x = cell(rng), y = cell(rng);
        vec3<float> const aim{3.0f * float(x) + unit(rng), 3.0f * float(y) + unit(rng), 0.0f};
        vec3<float> const origin = aim + vec3<float>(5.0f * unit(rng), 5.0f * unit(rng), 10.0f);
        INFO("ray " << i);
        auto const hit = check_closest_placement(c, {origin, 0.0f, aim - origin, INFINITY});
        CHECK(c.instance_id(hit) == hit.inst_id);
    }
}

TEST_CASE("limits: a group of 10^5 mesh nodes compiles to 10^5 placements") {
    constexpr int count = 100000;
    canopy::scene s;
    node_id const field = s.add_group(s.root(), "field");
    for (int k = 0; k < count; ++k) {
        canopy::mesh_data m;
        m.name = "tri" + std::to_string(k);
        float const x = float(k % 400) * 2.0f, y = float(k / 400) * 2.0f;
        m.positions = {{x, y, 0}, {x + 1, y, 0}, {x, y + 1, 0}};
        m.triangles = {{0, 1, 2}};
        s.add_mesh_node(field, s.add_mesh(std::move(m)));
    }
    auto const c = canopy::compile(s);
    REQUIRE(c.levels == 1);
    REQUIRE(c.top_meshes.size() == std::size_t(count));
    CHECK(c.meshes.size() == std::size_t(count));
    CHECK(c.statistics.identity_placements == std::size_t(count));
    std::mt19937 rng(16);
    std::uniform_int_distribution<int> pick(0, count - 1);
    std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
    for (int i = 0; i < 6; ++i) {
        int const k = pick(rng);
        vec3<float> const aim{float(k % 400) * 2.0f + 0.25f, float(k / 400) * 2.0f + 0.25f, 0.0f};
        vec3<float> const origin = aim + vec3<float>(3.0f * unit(rng), 3.0f * unit(rng), 8.0f);
        INFO("ray " << i);
        auto const hit = check_closest_placement(c, {origin, 0.0f, aim - origin, INFINITY});
        CHECK(c.top_meshes[hit.inst_id].index == hit.geom_id);
        CHECK(c.meshes[hit.geom_id].name == "tri" + std::to_string(k));
    }
}

// ---- transforms that fail only once composed ----------------------------------------------------

TEST_CASE("limits: transforms that overflow float once composed are refused naming the node") {
    auto const scene_with = [](std::vector<float> scales, float half) {
        canopy::scene s;
        node_id n = s.root();
        for (std::size_t k = 0; k < scales.size(); ++k) n = s.add_transform(n, scale(scales[k]), "s" + std::to_string(k));
        s.add_mesh_node(n, s.add_mesh(square("square", half)), "leaf");
        return s;
    };
    // 1e30 · 1e30 = 1e60: finite in double, not in float.
    auto const two = scene_with({1e30f, 1e30f}, 1.0f);
    CHECK(message_of([&] { canopy::compile(two, {.name = "big.json"}); }) ==
          "big.json: mesh 'leaf': the transforms above it, composed and rounded to float: transform has a value that is "
          "not finite");
    // 1e19 · 1e19 = 1e38 fits a float, the square of half-side 10 placed by it does not.
    auto const bounds = scene_with({1e19f, 1e19f}, 10.0f);
    CHECK(message_of([&] { canopy::compile(bounds, {.name = "big.json"}); }) ==
          "big.json: mesh 'leaf': placed by the transforms above it, its bounds are not finite in float");
    // Eleven of them leave double range on the way down.
    auto const eleven = scene_with(std::vector<float>(11, 1e30f), 1.0f);
    CHECK(message_of([&] { canopy::compile(eleven, {.name = "big.json"}); }) ==
          "big.json: transform 's0': the transforms composed through it leave double range (a value is not finite)");

    // In a group: the group's placements are finite, its instance scales their bounds past float.
    canopy::scene g;
    auto const m = g.add_mesh(square("square"));
    node_id const pair = g.add_group(no_node, "pair");
    g.add_mesh_node(g.add_transform(pair, scale(1e30f)), m, "a");
    g.add_mesh_node(pair, m, "b");
    g.add_instance(g.root(), pair, scale(1e30f), 3, "huge");
    g.add_instance(g.root(), pair, translate(5, 0, 0), 4, "fine");
    CHECK(message_of([&] { canopy::compile(g, {.name = "group.json"}); }) ==
          "group.json: instance 'huge': placed by the transforms above it, the bounds of its subtree are not finite in float");
    // A single-mesh subtree placed directly names the mesh and the instance.
    canopy::scene d;
    node_id const one = d.add_group(no_node, "one");
    d.add_mesh_node(d.add_transform(one, scale(1e30f)), d.add_mesh(square("square")), "only");
    d.add_instance(d.root(), one, scale(1e30f), 3, "huge");
    CHECK(message_of([&] { canopy::compile(d, {.name = "one.json"}); }) ==
          "one.json: mesh 'only' placed by instance 'huge': the transforms above it, composed and rounded to float: "
          "transform has a value that is not finite");

    // Cameras and lights placed where they are not finite.
    canopy::scene cam = scene_with({2.0f}, 1.0f);
    node_id const rig = cam.add_transform(cam.add_transform(cam.root(), scale(1e30f), "rig"), scale(1e30f));
    cam.add_camera(rig, {.eye = {0, 0, 5}, .target = {0, 0, 0}}, "cam");
    CHECK(message_of([&] { canopy::compile(cam, {.name = "cam.json"}); }) ==
          "cam.json: camera 'cam': placed by the transforms above it, the camera's eye, target or up is not finite in float");
    canopy::scene light = scene_with({2.0f}, 1.0f);
    canopy::light_data bulb;
    bulb.kind = canopy::light_data::point;
    bulb.position = {1, 2, 3};
    light.add_light(light.add_transform(light.add_transform(light.root(), scale(1e30f)), scale(1e30f)), bulb, "bulb");
    CHECK(message_of([&] { canopy::compile(light, {.name = "light.json"}); }) ==
          "light.json: light 'bulb': placed by the transforms above it, the light's position or direction is not finite in float");
}

TEST_CASE("limits: singular transforms are refused where they enter and when the scene is compiled") {
    canopy::scene s;
    auto const m = s.add_mesh(square("square"));
    // A scale whose inverse overflows float cannot be inverted in float.
    CHECK(message_of([&] { s.add_transform(s.root(), scale(1e-39f), "tiny"); }) ==
          "scene: node 'tiny': transform is singular (it cannot be inverted)");
    // Made singular after it was added (at() gives write access): refused by compile, by name.
    node_id const t = s.add_transform(s.root(), translate(1, 0, 0), "flat");
    s.add_mesh_node(t, m);
    s.at(t).transform.linear.col2 = {0, 0, 0};
    CHECK(message_of([&] { canopy::compile(s, {.name = "flat.json"}); }) ==
          "flat.json: transform 'flat': transform is singular (it cannot be inverted)");
    s.at(t).transform = translate(1, 0, 0);
    node_id const proto = s.add_group(no_node, "proto");
    s.add_mesh_node(proto, m);
    node_id const i = s.add_instance(s.root(), proto, translate(0, 3, 0), 9, "pinned");
    s.at(i).transform.translation.x = NAN;
    CHECK(message_of([&] { canopy::compile(s, {.name = "flat.json"}); }) ==
          "flat.json: instance 'pinned': transform has a value that is not finite");
    s.at(i).transform = translate(0, 3, 0);
    CHECK(canopy::compile(s).statistics.placements == 2);

    // 1e-30 · 1e-30 = 1e-60: each invertible, the composition rounds to zero in float.
    canopy::scene small;
    node_id const a = small.add_transform(small.root(), scale(1e-30f), "a");
    small.add_mesh_node(small.add_transform(a, scale(1e-30f), "b"), small.add_mesh(square("square")), "dust");
    CHECK(message_of([&] { canopy::compile(small, {.name = "dust.json"}); }) ==
          "dust.json: mesh 'dust': the transforms above it, composed and rounded to float: transform is singular (it "
          "cannot be inverted)");
}

// ---- the graph's marks, and memory ------------------------------------------------------------

TEST_CASE("limits: marks and roll-backs undo exactly what was added since, nested") {
    canopy::scene s;
    node_id const g = s.add_group(s.root(), "g");
    auto const m = s.add_mesh(square("square"));
    s.add_mesh_node(g, m, "kept");
    auto const outer = s.make_mark();
    s.add_mesh_node(g, m, "outer");
    node_id const free = s.add_group(no_node, "free");
    auto const inner = s.make_mark();
    s.add_mesh_node(g, m, "inner");
    s.attach(s.root(), free);
    s.add_mesh_node(free, m, "in free");
    s.roll_back(inner);
    CHECK(s.nodes().size() == std::size_t(free) + 1);
    CHECK(s.at(g).children.size() == 2);
    CHECK(s.at(s.root()).children.size() == 1);
    CHECK(s.at(free).children.empty());
    s.add_mesh_node(g, m, "again");
    s.roll_back(outer);
    CHECK(s.nodes().size() == std::size_t(g) + 2);
    REQUIRE(s.at(g).children.size() == 1);
    CHECK(s.at(s.at(g).children[0]).name == "kept");
}

TEST_CASE("limits: running out of memory while compiling is a scene_error naming the scene") {
    canopy::registry r;
    r.add_node_type("hog", "test", "asks for more memory than there is",
                    [](canopy::scene&, node_id, canopy::parameters const&) -> node_id { throw std::bad_alloc(); });
    canopy::scene s;
    s.add_mesh_node(s.root(), s.add_mesh(square("square")));
    s.add_custom(s.root(), "hog", {});
    auto const e = test_support::error_of([&] { canopy::compile(s, {.plugins = &r, .name = "hog.json"}); });
    CHECK(e.file() == "hog.json");
    CHECK(e.problem().starts_with("out of memory while compiling the scene"));
}
