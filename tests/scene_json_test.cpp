// Tests of canopy.plugins.json, Canopy's JSON scene description. Scenes are written here with
// values the tests know (transforms checked against hand-computed points, counts against what
// the file holds); every error the loader reports is provoked by a malformed file and checked
// for the file, the JSON path of the element and the problem. The committed example
// (examples/scenes/forest.json) is loaded and compiled, its statistics checked against counts
// taken from the file by hand.
#include <catch2/catch.hpp>

#include <array>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <vector>
#include <sys/stat.h>

import canopy.scene;
import canopy.plugins.json;
import canopy.plugins.obj;
import canopy.plugins.oiio;
import canopy.image;
import canopy.testing;
import canopy.testing.scene;

namespace {

namespace fs = std::filesystem;
using test_support::load_failure;
using test_support::message_of;
using test_support::limits_guard;
using test_support::temp_folder;
using canopy::vec3;

// The parameters the test generator and node type were last called with.
canopy::parameters last_generator_params, last_node_params;

canopy::registry json_registry() {
    canopy::registry r;
    canopy::register_oiio_plugin(r);
    canopy::register_obj_plugin(r);
    canopy::register_json_plugin(r);
    // A generator making one triangle scaled by "size", and a node type that expands to a group.
    r.add_generator("test_triangle", "test", "one triangle", [](canopy::scene& s, canopy::node_id parent, canopy::parameters const& p) {
        last_generator_params = p;
        float const size = float(p.get_number("size", 1.0, "test_triangle"));
        canopy::mesh_data m;
        m.name = "triangle";
        m.positions = {{0, 0, 0}, {size, 0, 0}, {0, size, 0}};
        m.triangles = {{0, 1, 2}};
        return s.add_mesh_node(parent, s.add_mesh(std::move(m)), "generated");
    });
    r.add_node_type("test_node", "test", "a custom node", [](canopy::scene& s, canopy::node_id parent, canopy::parameters const& p) {
        last_node_params = p;
        return s.add_group(parent, "expanded");
    });
    return r;
}

bool same(vec3<float> a, vec3<float> b) { return a.x == b.x && a.y == b.y && a.z == b.z; }
bool close(vec3<float> a, vec3<float> b) {
    return std::abs(a.x - b.x) < 1e-5f && std::abs(a.y - b.y) < 1e-5f && std::abs(a.z - b.z) < 1e-5f;
}

canopy::node_id child_named(canopy::scene const& s, canopy::node_id parent, std::string const& name) {
    for (auto c : s.at(parent).children)
        if (s.at(c).name == name) return c;
    FAIL("no child named " << name);
    return canopy::no_node;
}

} // namespace

TEST_CASE("json: inline meshes, materials and transforms hold the values written") {
    temp_folder const tmp("canopy_json_test");
    auto const file = tmp.write("inline.json", R"({
      "materials": [{"name": "red", "colour": [1, 0, 0]}, {"name": "plain"}],
      "meshes": [{"name": "tri", "material": "red", "positions": [0,0,0, 1,0,0, 0,1,0, 5,5,5],
                  "indices": [0,1,2, 2,1,3], "uvs": [0,0, 1,0, 0,1, 0.5,0.25]}],
      "nodes": [
        {"type": "transform", "name": "trs", "translate": [1, 2, 3], "rotate": [90, 0, 0, 2], "scale": 2,
         "children": [{"type": "mesh", "mesh": "tri"}]},
        {"type": "transform", "name": "rows", "matrix": [1,2,3,4, 0,1,0,5, 0,0,1,6]},
        {"type": "transform", "name": "nonuniform", "scale": [1, 2, 4]},
        {"type": "group", "name": "empty"},
        {"type": "camera", "name": "cam", "eye": [0, 1, 9], "fovy": 30},
        {"type": "light", "name": "sun", "direction": [0, 3, 4], "colour": [2, 2, 2]},
        {"type": "light", "name": "bulb", "light": "point", "position": [1, 2, 3]}
      ]})");
    auto const r = json_registry();
    canopy::scene s;
    auto const group = r.load(s, file);
    CHECK(s.at(group).name == "inline");
    REQUIRE(s.at(group).children.size() == 7);

    REQUIRE(s.materials().size() == 2);
    CHECK(same(s.materials()[0].colour, {1, 0, 0}));
    CHECK(same(s.materials()[1].colour, {0.7f, 0.7f, 0.7f}));
    CHECK(s.materials()[1].alpha == canopy::alpha_mode::opaque);
    REQUIRE(s.meshes().size() == 1);
    auto const& m = s.meshes()[0];
    CHECK(m.material == 0);
    REQUIRE(m.triangles.size() == 2);
    CHECK(m.triangles[1] == std::array<std::uint32_t, 3>{2, 1, 3});
    REQUIRE(m.uvs.size() == 2);
    CHECK(m.uvs[1][2].x == 0.5f);
    CHECK(m.uvs[1][2].y == 0.25f);

    // translate · rotate(90° about z) · scale 2: (1,0,0) → (2,0,0) → (0,2,0) → (1,4,3).
    auto const trs = child_named(s, group, "trs");
    auto const& xf = s.at(trs).transform;
    CHECK(close(xf.transform_point(vec3<float>{1, 0, 0}), {1, 4, 3}));
    CHECK(close(xf.transform_point(vec3<float>{0, 1, 0}), {-1, 2, 3}));
    CHECK(close(xf.transform_point(vec3<float>{0, 0, 1}), {1, 2, 5}));
    REQUIRE(s.at(trs).children.size() == 1);
    CHECK(s.at(s.at(trs).children[0]).kind == canopy::node_kind::mesh);
    CHECK(s.at(s.at(trs).children[0]).name == "tri");
    // Row-major 3×4: (1,1,1) → (1+2+3+4, 1+5, 1+6).
    CHECK(same(s.at(child_named(s, group, "rows")).transform.transform_point(vec3<float>{1, 1, 1}), {10, 6, 7}));
    CHECK(same(s.at(child_named(s, group, "nonuniform")).transform.transform_point(vec3<float>{1, 1, 1}), {1, 2, 4}));
    CHECK(s.at(child_named(s, group, "empty")).kind == canopy::node_kind::group);
    auto const& cam = s.at(child_named(s, group, "cam")).camera;
    CHECK(same(cam.eye, {0, 1, 9}));
    CHECK(same(cam.target, {0, 0, 0}));
    CHECK(cam.fovy_degrees == 30.0f);
    auto const& sun = s.at(child_named(s, group, "sun")).light;
    CHECK(sun.kind == canopy::light_data::directional);
    CHECK(close(sun.direction, {0, 0.6f, 0.8f}));
    CHECK(same(sun.colour, {2, 2, 2}));
    auto const& bulb = s.at(child_named(s, group, "bulb")).light;
    CHECK(bulb.kind == canopy::light_data::point);
    CHECK(same(bulb.position, {1, 2, 3}));
}

TEST_CASE("json: file meshes and textures load through the registry, relative to the JSON file") {
    temp_folder const tmp("canopy_json_test");
    tmp.write("models/quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
    canopy::rgba_image img;
    img.width = 2;
    img.height = 1;
    img.pixels = {1, 0, 0, 1, 0, 0, 1, 0};
    fs::create_directories(tmp.path / "textures");
    canopy::write_image(tmp.path / "textures" / "leaf.png", img);
    auto const file = tmp.write("scenes/files.json", R"({
      "materials": [{"name": "leaf", "texture": "../textures/leaf.png", "alphaMode": "MASK", "alphaCutoff": 0.25}],
      "meshes": [{"name": "quad", "file": "../models/quad.obj"},
                 {"name": "quad again", "file": "../models/quad.obj", "loader": "obj"}],
      "nodes": [{"type": "mesh", "mesh": "quad"}, {"type": "mesh", "name": "second", "mesh": "quad"},
                {"type": "mesh", "mesh": "quad again"}]})");
    auto const r = json_registry();
    canopy::scene s;
    auto const group = r.load(s, file);
    REQUIRE(s.materials().size() == 1);
    auto const& leaf = s.materials()[0];
    CHECK(leaf.alpha == canopy::alpha_mode::mask);
    CHECK(leaf.alpha_cutoff == 0.25f);
    REQUIRE(leaf.image == 0);
    REQUIRE(s.images()[0].width == 2);
    CHECK(s.images()[0].texels[0].x == 1.0f);
    CHECK(s.images()[0].texels[1].w == 0.0f);
    // Each file is loaded once (the two "meshes" entries name the same file and, by default or
    // by name, the same loader); every mesh node is a group of its own (named after the node)
    // whose one child is the file's node tree, shared.
    REQUIRE(s.meshes().size() == 1);
    CHECK(s.meshes()[0].triangles.size() == 2);
    auto const& kids = s.at(group).children;
    REQUIRE(kids.size() == 3);
    CHECK(s.at(kids[0]).name == "quad");
    CHECK(s.at(kids[1]).name == "second");
    CHECK(s.at(kids[2]).name == "quad again");
    REQUIRE(s.at(kids[0]).children.size() == 1);
    canopy::node_id const shared = s.at(kids[0]).children[0];
    CHECK(s.at(shared).name == "quad");
    for (std::size_t k = 0; k < 3; ++k) {
        CHECK(s.at(kids[k]).kind == canopy::node_kind::group);
        REQUIRE(s.at(kids[k]).children.size() == 1);
        CHECK(s.at(kids[k]).children[0] == shared);
    }
    REQUIRE(s.at(shared).children.size() == 1);
    auto const& mesh_node = s.at(s.at(shared).children[0]);
    CHECK(mesh_node.kind == canopy::node_kind::mesh);
    CHECK(mesh_node.mesh == 0);
    auto const c = canopy::compile(s, {.plugins = &r});
    CHECK(c.statistics.meshes_built == 1);
    CHECK(c.statistics.placements == 3);
    CHECK(c.statistics.triangles_placed == 6);
}

TEST_CASE("json: a file placed by 10^5 mesh nodes is loaded once and shared: one node per reference") {
    temp_folder const tmp("canopy_json_test");
    tmp.write("quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
    // 1000 transforms of 100 mesh nodes each, every one naming the file (through two "meshes"
    // entries, one with the loader by name).
    constexpr int rows = 1000, per_row = 100;
    std::string text = R"({"meshes": [{"name": "q", "file": "quad.obj"}, {"name": "q2", "file": "./quad.obj", "loader": "obj"}], "nodes": [)";
    for (int i = 0; i < rows; ++i) {
        text += std::string(i ? ",\n" : "") + R"({"type": "transform", "translate": [)" + std::to_string(2 * (i % 40)) +
                ", " + std::to_string(2 * (i / 40)) + R"(, 0], "children": [)";
        for (int k = 0; k < per_row; ++k) text += std::string(k ? "," : "") + R"({"type": "mesh", "mesh": "q)" + (k % 2 ? "2" : "") + "\"}";
        text += "]}";
    }
    text += "]}";
    auto const r = json_registry();
    canopy::scene s;
    auto const before = s.nodes().size();
    r.load(s, tmp.write("many.json", text));
    // The file's group, the transforms, one group per reference, and the OBJ's nodes once: its
    // holder, its group and its mesh node.
    CHECK(s.nodes().size() == before + 1 + rows + rows * per_row + 3);
    CHECK(s.meshes().size() == 1);
    auto const c = canopy::compile(s, {.plugins = &r});
    CHECK(c.levels == 1);
    CHECK(c.statistics.meshes_built == 1);
    CHECK(c.statistics.triangles_stored == 2);
    CHECK(c.statistics.placements == std::size_t(rows * per_row));
    REQUIRE(c.meshes.size() == 1);
    CHECK(c.meshes[0].accel.primitive_count() == 2); // the quad's BVH, built once
    CHECK(c.top_meshes_bvh.primitive_count() == std::size_t(rows * per_row));
}

TEST_CASE("json: mesh files nested through scene files are loaded once each, placements multiply at compile time") {
    temp_folder const tmp("canopy_json_test");
    tmp.write("quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
    // level0.json places quad.obj 10 times; level k places level k-1 10 times (and quad.obj once).
    auto const level = [&](int k) {
        std::string const inner = k == 0 ? "quad.obj" : "level" + std::to_string(k - 1) + ".json";
        std::string text = R"({"meshes": [{"name": "in", "file": ")" + inner + R"("}, {"name": "q", "file": "quad.obj"}], "nodes": [{"type": "mesh", "mesh": "q"})";
        for (int i = 0; i < 10; ++i)
            text += R"(, {"type": "transform", "translate": [0, 0, )" + std::to_string(i) + R"(], "children": [{"type": "mesh", "mesh": "in"}]})";
        return tmp.write("level" + std::to_string(k) + ".json", text + "]}");
    };
    for (int k = 0; k < 7; ++k) level(k);
    auto const r = json_registry();
    {
        canopy::scene s;
        auto const before = s.nodes().size();
        r.load(s, tmp.path / "level3.json");
        CHECK(s.meshes().size() == 1);
        // Per scene file: its group, 10 transforms, 11 groups of references; quad.obj's 3 nodes
        // once; each nested scene file's holder once.
        CHECK(s.nodes().size() == before + 4 * 22 + 3 + 3);
        auto const c = canopy::compile(s, {.plugins = &r});
        // 10^4 through the nest, and quad.obj placed directly at each level: 1 + 10 + 100 + 1000.
        CHECK(c.statistics.placements == 10000 + 1111);
        CHECK(c.statistics.meshes_built == 1);
    }
    {
        // 10^7 placements: a few hundred nodes, refused by compile() before it makes any.
        canopy::scene s;
        r.load(s, tmp.path / "level6.json");
        CHECK(s.nodes().size() < 200);
        CHECK(message_of([&] { (void)canopy::compile(s, {.plugins = &r, .name = "level6.json"}); }) ==
              "level6.json: 11111111 meshes, instances, cameras and lights at the top level exceed the limit of " +
                  std::to_string(canopy::default_limits().max_placements) + " (--max-placements)");
    }
    {
        // A load that fails after loading files leaves nothing shared behind: the next load into
        // the same scene loads them again.
        canopy::scene s;
        auto const broken = tmp.write("broken.json", R"({"meshes": [{"name": "in", "file": "level0.json"}], "nodes": [
          {"type": "mesh", "mesh": "in"}, {"type": "mesh", "mesh": "missing"}]})");
        CHECK(message_of([&] { r.load(s, broken); }) == broken.string() + ": nodes[1]: mesh 'missing' is not defined");
        CHECK(s.nodes().size() == 1);
        CHECK(s.meshes().empty());
        r.load(s, tmp.path / "level1.json");
        CHECK(s.meshes().size() == 1);
        CHECK(canopy::compile(s, {.plugins = &r}).statistics.placements == 100 + 11);
    }
}

TEST_CASE("json: shared file meshes trace the same hits as the same scene written inline") {
    temp_folder const tmp("canopy_json_test");
    // Two meshes (usemtl splits them): a unit square at z = 0 and a triangle at z = 0.5.
    tmp.write("two.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 0.5\nv 1 0 0.5\nv 0 1 0.5\n"
                         "usemtl a\nf 1 2 3\nf 1 3 4\nusemtl b\nf 5 6 7\n");
    tmp.write("inner.json", R"({"meshes": [{"name": "m", "file": "two.obj"}], "nodes": [
      {"type": "transform", "translate": [2, 0, -1], "children": [{"type": "mesh", "mesh": "m"}]},
      {"type": "transform", "translate": [0, 0, -1], "scale": 0.5, "children": [{"type": "mesh", "mesh": "m"}]}]})");
    auto const shared = tmp.write("shared.json", R"({"meshes": [{"name": "m", "file": "two.obj"}, {"name": "inner", "file": "inner.json"}], "nodes": [
      {"type": "mesh", "mesh": "m"},
      {"type": "transform", "translate": [2, 0, 0], "rotate": [30, 0, 0, 1], "children": [{"type": "mesh", "mesh": "m"}]},
      {"type": "transform", "translate": [0, 2, 0], "children": [{"type": "mesh", "mesh": "inner"}]},
      {"type": "transform", "translate": [2.5, 2.5, 0.25], "children": [{"type": "mesh", "mesh": "m"}]}]})");
    // The same placements with the meshes written out where each reference is.
    std::string const two = R"({"type": "group", "children": [{"type": "mesh", "mesh": "a"}, {"type": "mesh", "mesh": "b"}]})";
    auto const inline_file = tmp.write("inline.json", R"({"meshes": [
      {"name": "a", "positions": [0,0,0, 1,0,0, 1,1,0, 0,1,0], "indices": [0,1,2, 0,2,3]},
      {"name": "b", "positions": [0,0,0.5, 1,0,0.5, 0,1,0.5], "indices": [0,1,2]}], "nodes": [)" + two + R"(,
      {"type": "transform", "translate": [2, 0, 0], "rotate": [30, 0, 0, 1], "children": [)" + two + R"(]},
      {"type": "transform", "translate": [0, 2, 0], "children": [{"type": "group", "children": [
        {"type": "transform", "translate": [2, 0, -1], "children": [)" + two + R"(]},
        {"type": "transform", "translate": [0, 0, -1], "scale": 0.5, "children": [)" + two + R"(]}]}]},
      {"type": "transform", "translate": [2.5, 2.5, 0.25], "children": [)" + two + R"(]}]})");
    auto const r = json_registry();
    canopy::scene a, b;
    r.load(a, shared);
    r.load(b, inline_file);
    CHECK(a.meshes().size() == 2); // two.obj once, for both scene files
    auto const ca = canopy::compile(a, {.plugins = &r});
    auto const cb = canopy::compile(b, {.plugins = &r});
    REQUIRE(ca.statistics.placements == 10);
    REQUIRE(cb.statistics.placements == 10);
    CHECK(ca.levels == cb.levels);
    canopy::default_intersector isect;
    int hits = 0;
    for (int i = 0; i <= 60; ++i)
        for (int k = 0; k <= 60; ++k) {
            vec3<float> const origin{-0.5f + 0.075f * float(i), -0.5f + 0.075f * float(k), 5.0f};
            canopy::ray const ray{origin, 0.0f, {0.01f, 0.02f, -1.0f}, INFINITY};
            auto const ha = ca.closest_hit(ray, isect), hb = cb.closest_hit(ray, isect);
            INFO("ray " << i << ", " << k);
            REQUIRE(ha.hit == hb.hit);
            if (!ha.hit) continue;
            ++hits;
            CHECK(ha.t == hb.t);
            CHECK(ha.u == hb.u);
            CHECK(ha.v == hb.v);
            CHECK(ha.prim_id == hb.prim_id);
            CHECK(ha.geom_id == hb.geom_id);
            CHECK(ha.inst_id == hb.inst_id);
        }
    CHECK(hits > 600);
}

TEST_CASE("json: textures count against --max-total-texels together, a texture named twice is loaded once") {
    temp_folder const tmp("canopy_json_test");
    limits_guard const guard;
    canopy::rgba_image img;
    img.width = img.height = 4;
    img.pixels.assign(64, 1.0f);
    for (char const* name : {"a.png", "b.png", "c.png"}) canopy::write_image(tmp.path / name, img);
    auto const file = tmp.write("textures.json", R"({"materials": [{"name": "a", "texture": "a.png"},
      {"name": "a again", "texture": "./a.png"}, {"name": "b", "texture": "b.png"}, {"name": "c", "texture": "c.png"}]})");
    auto const r = json_registry();
    canopy::default_limits().max_total_texels = 48;
    canopy::scene s;
    r.load(s, file);
    CHECK(s.images().size() == 3);
    CHECK(s.texels() == 48);
    CHECK(s.materials()[1].image == s.materials()[0].image);
    canopy::default_limits().max_total_texels = 47;
    auto const f = load_failure(r, file);
    CHECK(f.where == "materials[3].texture");
    CHECK(f.problem == (tmp.path / "c.png").string() +
                           ": image is 4 × 4 (16 texels): with the 32 texels of the images loaded before it, 48 texels "
                           "in all exceed the limit of 47 (--max-total-texels)");
    // The images the scene holds already count: a second file loaded into the same scene.
    canopy::default_limits().max_total_texels = 60;
    canopy::scene two;
    r.load(two, tmp.write("one.json", R"({"materials": [{"name": "a", "texture": "a.png"}]})"));
    CHECK(message_of([&] { r.load(two, file); }) ==
          file.string() + ": materials[3].texture: " + (tmp.path / "c.png").string() +
              ": image is 4 × 4 (16 texels): with the 48 texels of the images loaded before it, 64 texels in all exceed "
              "the limit of 60 (--max-total-texels)");
    CHECK(two.texels() == 16);
}

TEST_CASE("json: instances target prototypes by name, ids default to the count of instances before them") {
    temp_folder const tmp("canopy_json_test");
    auto const file = tmp.write("instances.json", R"({
      "meshes": [{"name": "tri", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,2]}],
      "prototypes": [
        {"name": "pair", "type": "group", "children": [
          {"type": "instance", "target": "one"},
          {"type": "instance", "target": "one", "translate": [3, 0, 0], "id": 40}]},
        {"name": "one", "type": "mesh", "mesh": "tri"}
      ],
      "nodes": [
        {"type": "instance", "name": "a", "target": "pair"},
        {"type": "instance", "name": "b", "target": "pair", "translate": [0, 5, 0]},
        {"type": "instance", "name": "c", "target": "one", "id": 4294967295}
      ]})");
    auto const r = json_registry();
    canopy::scene s;
    auto const group = r.load(s, file);
    auto const a = child_named(s, group, "a"), b = child_named(s, group, "b"), c = child_named(s, group, "c");
    CHECK(s.at(a).kind == canopy::node_kind::instance);
    CHECK(s.at(a).instance_id == 2);
    CHECK(s.at(b).instance_id == 3);
    CHECK(s.at(c).instance_id == 4294967295u);
    CHECK(s.at(a).target == s.at(b).target);
    auto const pair = s.at(a).target;
    CHECK(s.at(pair).name == "pair");
    REQUIRE(s.at(pair).children.size() == 1); // the prototype's root group holds its node
    auto const pair_group = s.at(pair).children[0];
    REQUIRE(s.at(pair_group).children.size() == 2);
    CHECK(s.at(s.at(pair_group).children[0]).instance_id == 0);
    CHECK(s.at(s.at(pair_group).children[1]).instance_id == 40);
    CHECK(same(s.at(b).transform.translation, {0, 5, 0}));
    auto const compiled = canopy::compile(s, {.plugins = &r});
    // pair holds two placements of one mesh (a group, built once), instanced twice; c places the
    // single-mesh prototype directly.
    CHECK(compiled.statistics.levels == 2);
    CHECK(compiled.statistics.group_instances == 2);
    CHECK(compiled.statistics.meshes_built == 1);
}

TEST_CASE("json: an array of 10^5 nodes loads in linear time (nesting is checked on the text)") {
    temp_folder const tmp("canopy_json_test");
    std::string text = R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,2]}], "nodes": [)";
    for (int i = 0; i < 100000; ++i) text += std::string(i ? "," : "") + R"({"type": "mesh", "mesh": "t"})";
    text += "]}";
    auto const file = tmp.write("wide.json", text);
    canopy::registry r;
    canopy::register_json_plugin(r);
    canopy::scene s;
    auto const start = std::chrono::steady_clock::now();
    auto const group = r.load(s, file, s.root());
    double const seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    CHECK(s.at(group).children.size() == 100000);
    CHECK(seconds < 5.0); // quadratic parsing took ~25 s here
}

TEST_CASE("json: instance cycles reach the graph and compile reports them") {
    temp_folder const tmp("canopy_json_test");
    auto const file = tmp.write("cycle.json", R"({
      "prototypes": [
        {"name": "a", "type": "instance", "target": "b"},
        {"name": "b", "type": "group", "children": [{"type": "instance", "target": "a"}]},
        {"name": "self", "type": "instance", "target": "self"}
      ],
      "nodes": [{"type": "instance", "target": "a"}]})");
    auto const r = json_registry();
    canopy::scene s;
    REQUIRE_NOTHROW(r.load(s, file));
    try {
        (void)canopy::compile(s, {.plugins = &r});
        FAIL("compile accepted an instance cycle");
    } catch (canopy::scene_error const& e) {
        CHECK_THAT(std::string(e.what()), Catch::Contains("'a'") && Catch::Contains("'b'"));
    }
}

TEST_CASE("json: generators and custom node types receive their params as text") {
    temp_folder const tmp("canopy_json_test");
    auto const file = tmp.write("generated.json", R"({"nodes": [
        {"type": "generator", "name": "big", "generator": "test_triangle",
         "params": {"size": 2.5, "count": 3, "flag": true, "label": "x y", "list": [1, 0.5, "z"]}},
        {"type": "test_node", "name": "custom", "params": {"height": -4}}
      ]})");
    auto const r = json_registry();
    canopy::scene s;
    auto const group = r.load(s, file);
    auto const big = child_named(s, group, "big");
    CHECK(s.at(big).kind == canopy::node_kind::mesh);
    CHECK(same(s.meshes().at(s.at(big).mesh).positions[1], {2.5f, 0, 0}));
    auto const& p = last_generator_params.values();
    CHECK(p.at("size") == "2.5");
    CHECK(p.at("count") == "3");
    CHECK(p.at("flag") == "true");
    CHECK(p.at("label") == "x y");
    CHECK(p.at("list") == "1 0.5 z");
    auto const custom = child_named(s, group, "custom");
    CHECK(s.at(custom).kind == canopy::node_kind::custom);
    CHECK(s.at(custom).custom_type == "test_node");
    CHECK(s.at(custom).params.get_string("height", "") == "-4");
    r.expand_custom_nodes(s);
    CHECK(last_node_params.get_string("height", "") == "-4");
    CHECK(s.at(s.at(custom).children.at(0)).name == "expanded");
}

TEST_CASE("json: bad input names the file, the JSON path and the problem, the scene is left as it was") {
    temp_folder const tmp("canopy_json_test");
    auto const r = json_registry();
    std::string const tri = R"({"name": "tri", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,2]})";
    struct bad_case {
        std::string text, where, problem;
    };
    std::vector<bad_case> const cases = {
        {"{\n  \"nodes\": [\n    {\"type\": \"group\",]\n}", "", "parse error at line 3, column 22"},
        {"[1, 2]", "", "the document must be a JSON object, not an array"},
        {R"({"version": 2})", "version", "must be 1"},
        {R"({"nodez": []})", "nodez", "unknown key"},
        {R"({"nodes": {}})", "nodes", "must be an array, not an object"},
        {R"({"nodes": [{"name": "x"}]})", "nodes[0]", "needs the key 'type'"},
        {R"({"nodes": [{"type": 3}]})", "nodes[0].type", "must be a string, not a number"},
        {R"({"nodes": [{"type": "tree"}]})", "nodes[0].type", "'tree' is neither a built-in node type"},
        {R"({"nodes": [{"type": "group", "translate": [1, 2, 3]}]})", "nodes[0].translate", "unknown key"},
        {R"({"prototypes": [{"name": "tree", "type": "group"}], "nodes": [{"type": "group"}, {"type": "group"}, {"type": "group"},
            {"type": "group", "children": [{"type": "instance", "target": "tree"}, {"type": "instance", "target": "oak"}]}]})",
         "nodes[3].children[1]", "instance target 'oak' is not defined"},
        {R"({"nodes": [{"type": "mesh", "mesh": "nothing"}]})", "nodes[0]", "mesh 'nothing' is not defined"},
        {R"({"materials": [{"name": "m"}, {"name": "m"}]})", "materials[1].name", "duplicate material name 'm'"},
        {R"({"meshes": [)" + tri + "," + tri + "]}", "meshes[1].name", "duplicate mesh name 'tri'"},
        {R"({"prototypes": [{"name": "p", "type": "group"}, {"name": "p", "type": "group"}]})", "prototypes[1].name",
         "duplicate prototype name 'p'"},
        {R"({"prototypes": [{"type": "group"}]})", "prototypes[0]", "needs the key 'name'"},
        {R"({"materials": [{"name": "m", "colour": [1, 1]}]})", "materials[0].colour", "must be an array of 3 numbers"},
        {R"({"materials": [{"name": "m", "colour": [1, "x", 1]}]})", "materials[0].colour[1]", "must be a number, not a string"},
        {R"({"materials": [{"name": "m", "colour": [1, 1e39, 1]}]})", "materials[0].colour[1]", "value 1e+39 overflows a float"},
        {R"({"materials": [{"name": "m", "alphaCutoff": 1.5}]})", "materials[0].alphaCutoff", "must be in [0, 1]"},
        {R"({"materials": [{"name": "m", "alphaMode": "BLEND"}]})", "materials[0].alphaMode", "'BLEND' is not OPAQUE or MASK"},
        {R"({"materials": [{"name": "m", "alphaMode": "MASK"}]})", "materials[0].alphaMode", "MASK needs a texture"},
        {R"({"materials": [{"name": "m", "texture": "none.png"}]})", "materials[0].texture", "none.png: file not found"},
        {R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1], "indices": [0,1,2]}]})", "meshes[0].positions",
         "must hold 3 numbers per vertex (8 given)"},
        {R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,4000000000]}]})",
         "meshes[0].indices[2]", "4000000000 is out of range (3 vertices)"},
        {R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,-1]}]})", "meshes[0].indices[2]",
         "-1 is out of range"},
        {R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,1.5]}]})", "meshes[0].indices[2]",
         "must be an integer, not 1.5"},
        {R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1]}]})", "meshes[0].indices",
         "3 vertex indices per triangle"},
        {R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,2], "uvs": [0,0]}]})",
         "meshes[0].uvs", "2 numbers per vertex (2 given for 3 vertices)"},
        {R"({"meshes": [{"name": "t", "positions": [0,0,0], "material": "x", "indices": []}]})", "meshes[0].material",
         "material 'x' is not defined"},
        {R"({"meshes": [{"name": "t", "indices": []}]})", "meshes[0]", "needs the key 'positions'"},
        {R"({"meshes": [{"name": "t", "file": "gone.obj"}]})", "meshes[0].file", "gone.obj: file not found"},
        {R"({"meshes": [{"name": "t", "file": "gone.xyz"}]})", "meshes[0].file", "unknown extension '.xyz'"},
        {R"({"meshes": [{"name": "t", "file": "bad.obj", "loader": "openmesh2"}]})", "meshes[0].file",
         "plugin 'openmesh2' does not load '.obj' files"},
        {R"({"meshes": [{"name": "t", "file": "bad.obj"}]})", "meshes[0].file", "bad.obj:2: bad number 'q'"},
        {R"({"nodes": [{"type": "transform", "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0], "scale": 2}]})", "nodes[0].matrix",
         "cannot be combined"},
        {R"({"nodes": [{"type": "transform", "matrix": [1,0,0,0, 0,1,0,0, 0,0,0,0]}]})", "nodes[0]", "singular"},
        {R"({"nodes": [{"type": "transform", "rotate": [45, 0, 0, 0]}]})", "nodes[0].rotate", "axis must not be zero"},
        {R"({"nodes": [{"type": "transform", "scale": [1, 1, 1e300]}]})", "nodes[0].scale[2]", "value 1e+300 overflows a float"},
        {R"({"nodes": [{"type": "instance", "target": "x", "id": 1}]})", "nodes[0]", "instance target 'x' is not defined"},
        {R"({"prototypes": [{"name": "p", "type": "group"}], "nodes": [{"type": "instance", "target": "p", "id": 4294967296}]})",
         "nodes[0].id", "out of range"},
        {R"({"nodes": [{"type": "camera", "eye": [0, 0, 0]}]})", "nodes[0]", "eye and target coincide"},
        {R"({"nodes": [{"type": "light", "light": "spot"}]})", "nodes[0].light", "'spot' is not point or directional"},
        {R"({"nodes": [{"type": "light", "direction": [0, 0, 0]}]})", "nodes[0].direction", "must not be zero"},
        {R"({"nodes": [{"type": "generator", "generator": "nope"}]})", "nodes[0].generator", "generator 'nope' is not registered"},
        {R"({"nodes": [{"type": "generator", "generator": "test_triangle", "params": {"size": "big"}}]})", "nodes[0]",
         "'big' is not a finite number"},
        {R"({"nodes": [{"type": "generator", "generator": "test_triangle", "params": {"size": {}}}]})",
         "nodes[0].params.size", "must be a string, number, boolean or an array of those, not an object"},
        {R"({"nodes": [{"type": "test_node", "params": [1]}]})", "nodes[0].params", "must be an object, not an array"},
    };
    tmp.write("bad.obj", "v 0 0 0\nv q 0 0\n");
    tmp.write("gone.xyz", "1 2 3\n"); // exists: its extension is what is refused
    for (std::size_t i = 0; i < cases.size(); ++i) {
        auto const& c = cases[i];
        INFO("case " << i << ": " << c.problem);
        auto const file = tmp.write("bad" + std::to_string(i) + ".json", c.text);
        auto const f = load_failure(r, file);
        CHECK(f.file == file.string());
        CHECK(f.where == c.where);
        CHECK_THAT(f.problem, Catch::Contains(c.problem));
    }
}

TEST_CASE("json: nodes nested too deep and scenes that load themselves are errors, not crashes") {
    temp_folder const tmp("canopy_json_test");
    auto const r = json_registry();
    std::string deep = R"({"nodes": [)";
    for (int i = 0; i < 1000; ++i) deep += R"({"type": "group", "children": [)";
    for (int i = 0; i < 1000; ++i) deep += "]}";
    deep += "]}";
    auto const f = load_failure(r, tmp.write("deep.json", deep));
    CHECK_THAT(f.problem, Catch::Contains("nested deeper than 256 levels"));

    tmp.write("a.json", R"({"meshes": [{"name": "b", "file": "b.json"}]})");
    tmp.write("b.json", R"({"meshes": [{"name": "a", "file": "a.json"}]})");
    auto const loop = load_failure(r, tmp.path / "a.json");
    CHECK(loop.where == "meshes[0].file");
    CHECK_THAT(loop.problem, Catch::Contains("a.json: the scene refers to itself"));
}

TEST_CASE("json: parse_json_scene reads a buffer, without a registry files and generators are errors") {
    canopy::scene s;
    auto const group = canopy::parse_json_scene(
        R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,2]}], "nodes": [{"type": "mesh", "mesh": "t"}]})",
        "buffer.json", nullptr, s, s.root());
    CHECK(s.at(group).children.size() == 1);
    CHECK(s.meshes().size() == 1);
    try {
        canopy::parse_json_scene(R"({"meshes": [{"name": "t", "file": "x.obj"}]})", "buffer.json", nullptr, s, s.root());
        FAIL("no error");
    } catch (canopy::scene_error const& e) {
        CHECK(e.where() == "meshes[0].file");
        CHECK_THAT(e.problem(), Catch::Contains("needs a plugin registry"));
    }
    CHECK(s.meshes().size() == 1);
}

TEST_CASE("json: the example forest.json loads and compiles to the counts its file implies") {
    auto const r = json_registry();
    canopy::scene s;
    auto const group = r.load(s, fs::path(CANOPY_SOURCE_DIR) / "examples" / "scenes" / "forest.json");
    CHECK(s.at(group).children.size() == 6);
    // Meshes: trunk (from trunk.obj, 6 quads), billboard (2 triangles), ground (2 triangles).
    REQUIRE(s.meshes().size() == 3);
    CHECK(s.meshes()[0].triangles.size() == 12);
    // Materials: leaves, grass (the JSON file), bark (trunk.mtl); one image (tree.png).
    CHECK(s.materials().size() == 3);
    CHECK(s.images().size() == 1);
    auto const c = canopy::compile(s, {.plugins = &r});
    auto const& st = c.statistics;
    // Top level: the ground (loose), two groves and a lone tree. A tree is 3 placements (trunk and
    // two billboards): a group; a grove is 3 trees flattened into 9 placements: a group.
    CHECK(st.levels == 2);
    CHECK(st.group_instances == 3);
    CHECK(st.flattened_placements == 9);
    CHECK(st.meshes_built == 3);
    CHECK(st.triangles_stored == 16);
    // Placements built: grove 9 (3·(12+2+2) = 48 triangles), tree 3 (16), ground 1 (2). In the
    // world: two groves, one tree and the ground, 2·48 + 16 + 2 = 114 triangles.
    CHECK(st.placements == 13);
    CHECK(st.triangles_placed == 114);
    CHECK(st.cameras == 1);
    CHECK(st.lights == 1);
    CHECK(st.masked_materials_used == 1);
    CHECK(st.alpha_mask_needed);
    REQUIRE(c.camera.has_value());
    CHECK(same(c.camera->eye, {0, 4, 16}));
}

TEST_CASE("json: only regular files are read: the scene, its mesh files and its textures") {
    temp_folder const tmp("canopy_json_test");
    auto const& dir = tmp.path;
    auto const r = json_registry();
    REQUIRE(test_support::make_special_files(dir, {".json", ".obj", ".png"}));
    for (auto const& [name, kind] : test_support::special_files()) {
        INFO(name);
        auto const scene = load_failure(r, dir / (name + ".json"));
        CHECK(scene.file == (dir / (name + ".json")).string());
        CHECK(scene.where == "");
        CHECK(scene.problem == "is " + kind + ", not a regular file");

        auto const mesh = load_failure(r, tmp.write("mesh_" + name + ".json",
                                                    R"({"meshes": [{"name": "m", "file": ")" + name + R"(.obj"}]})"));
        CHECK(mesh.where == "meshes[0].file");
        CHECK(mesh.problem == (dir / (name + ".obj")).string() + ": is " + kind + ", not a regular file");

        auto const texture = load_failure(r, tmp.write("texture_" + name + ".json",
                                                       R"({"materials": [{"name": "m", "texture": ")" + name + R"(.png"}]})"));
        CHECK(texture.where == "materials[0].texture");
        CHECK(texture.problem == (dir / (name + ".png")).string() + ": is " + kind + ", not a regular file (texture)");
    }
}

TEST_CASE("json: values that overflow a float or a double, deep nesting and declared counts are refused by name") {
    temp_folder const tmp("canopy_json_test");
    auto const r = json_registry();
    std::string const big(1 << 20, 'k');
    std::string const prefix(40, 'k');
    struct bad_case {
        std::string text, where, problem;
    };
    std::vector<bad_case> const cases = {
        {R"({"meshes": [{"name": "t", "positions": [0,0,0, 1,0,0, 0,1e300,0], "indices": [0,1,2]}]})",
         "meshes[0].positions[7]", "value 1e+300 overflows a float"},
        {R"({"nodes": [{"type": "camera", "fovy": -3.5e38}]})", "nodes[0].fovy", "value -3.5e+38 overflows a float"},
        {R"({"nodes": [{"type": "transform", "translate": [1e400, 0, 0]}]})", "",
         "number overflow parsing '1e400'"},
        {R"({"nodes": [{"type": "transform", "translate": [1)" + std::string(100000, '0') + R"(, 0, 0]}]})", "",
         "number overflow parsing '1" + std::string(39, '0') + "…'"},
        // Column 1048598: the control byte after the 21 bytes before the string and its 2^20 bytes.
        {R"({"nodes": [{"type": ")" + big + "\x01" + R"("}]})", "",
         "parse error at line 1, column 1048598: syntax error while parsing value - invalid string: control character "
         "U+0001 (SOH) must be escaped to \\u0001; last read: '\"" + std::string(39, 'k') + "…'"},
        {R"({"nodes": [{"type": ")" + big + R"("}]})", "nodes[0].type",
         "'" + prefix + "…' is neither a built-in node type (group, transform, mesh, instance, camera, light, generator) "
                        "nor one a plugin registers"},
        {R"({")" + big + R"(": 1})", prefix + "…", "unknown key (known here: version, materials, meshes, prototypes, nodes)"},
        {R"({"meshes": [{"name": "m", "file": ")" + big + R"(.obj"}]})", "meshes[0].file",
         "file name of 1048580 bytes is too long ('" + prefix + "…')"},
        {R"({"nodes": [{"type": "mesh", "mesh": ")" + big + R"("}]})", "nodes[0]", "mesh '" + prefix + "…' is not defined"},
    };
    for (std::size_t i = 0; i < cases.size(); ++i) {
        auto const& c = cases[i];
        INFO("case " << i);
        auto const file = tmp.write("overflow" + std::to_string(i) + ".json", c.text);
        auto const f = load_failure(r, file);
        CHECK(f.file == file.string());
        CHECK(f.where == c.where);
        CHECK(f.problem == c.problem);
        CHECK(f.message.size() < 400 + file.string().size());
    }

    // Arrays nested deeper than --max-depth, refused while parsing (before any element is checked).
    std::string const deep = R"({"nodes": [{"type": "test_node", "params": {"a": )" + std::string(5000, '[') +
                             std::string(5000, ']') + "}}]}";
    auto const nested = load_failure(r, tmp.write("deep_arrays.json", deep));
    CHECK(nested.where == "");
    CHECK(nested.problem == "4097 levels of nested arrays and objects exceed the limit of 4096 (--max-depth)");

    // Counts an inline mesh declares are checked against --max-triangles before it is built.
    auto const saved = canopy::default_limits();
    canopy::default_limits().max_triangles = 2;
    auto const vertices = load_failure(r, tmp.write("vertices.json", R"({"meshes": [{"name": "t",
        "positions": [0,0,0, 1,0,0, 0,1,0], "indices": [0,1,2]}]})"));
    CHECK(vertices.where == "meshes[0].positions");
    CHECK(vertices.problem == "3 vertices exceed the limit of 2 (--max-triangles)");
    auto const triangles = load_failure(r, tmp.write("triangles.json", R"({"meshes": [{"name": "t",
        "positions": [0,0,0, 1,0,0], "indices": [0,1,1, 0,1,1, 0,1,1]}]})"));
    CHECK(triangles.where == "meshes[0].indices");
    CHECK(triangles.problem == "3 triangles exceed the limit of 2 (--max-triangles)");
    canopy::default_limits() = saved;
}
