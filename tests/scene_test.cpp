// Tests of canopy.scene: the scene graph's input checks, the registry's loading rules (an
// extension's default loader chosen by rank, in every order of registration), and
// compile()'s skip rules — each rule observable in the statistics and in the result. Hits of
// compiled scenes are checked against a brute-force loop over every placed triangle in world
// space, with the placements' transforms composed by hand in double precision.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>
#include <sys/stat.h>

import canopy.scene;
import canopy.procedural;
import canopy.testing;
import canopy.testing.scene;

namespace {

using canopy::node_id;
using test_support::message_of;
using canopy::vec3;
using xf = canopy::affine_transform<float>;

// ---- building blocks -----------------------------------------------------------------------

canopy::mesh_data mesh_from(std::vector<canopy::triangle> const& tris, std::string name) {
    canopy::mesh_data m;
    m.name = std::move(name);
    for (auto const& t : tris) {
        auto const base = std::uint32_t(m.positions.size());
        m.positions.insert(m.positions.end(), {t.v0, t.v1, t.v2});
        m.triangles.push_back({base, base + 1, base + 2});
    }
    return m;
}

canopy::mesh_data sphere(std::string name, int subdivisions = 1) {
    return mesh_from(canopy::make_icosphere(subdivisions), std::move(name));
}

xf translate(float x, float y, float z) { return xf::from_rows({1, 0, 0, x, 0, 1, 0, y, 0, 0, 1, z}); }
xf scale_rotate_z(float s, float degrees, vec3<float> t) {
    double const a = double(degrees) * 3.14159265358979323846 / 180.0;
    float const c = float(std::cos(a)) * s, n = float(std::sin(a)) * s;
    return xf::from_rows({c, -n, 0, t.x, n, c, 0, t.y, 0, 0, s, t.z});
}

// ---- the reference: every placed triangle in world space, in double --------------------------

struct world_triangle {
    std::array<vec3<double>, 3> v;
    std::uint32_t geom, prim;
    std::uint32_t inst, inner; // placement ids as the compiled scene reports them
};

using xf64 = canopy::affine_transform<double>;
xf64 widen(xf const& a) {
    return {{vec3<double>(a.linear.col0), vec3<double>(a.linear.col1), vec3<double>(a.linear.col2)},
            vec3<double>(a.translation)};
}

// The compiled scene's placements, flattened: this reads only the placement lists (what compile
// decided), not the BVHs or instances that trace them.
std::vector<world_triangle> world_of(canopy::compiled_scene const& c) {
    std::vector<world_triangle> out;
    auto const emit = [&](std::uint32_t mesh, xf64 const& m, std::uint32_t inst, std::uint32_t inner) {
        auto const& tris = c.meshes[mesh].triangles;
        for (std::uint32_t p = 0; p < tris.size(); ++p) {
            world_triangle w{{m.transform_point(vec3<double>(tris[p].v0)), m.transform_point(vec3<double>(tris[p].v1)),
                              m.transform_point(vec3<double>(tris[p].v2))},
                             mesh, p, inst, inner};
            out.push_back(w);
        }
    };
    if (c.levels == 0) emit(0, xf64::identity(), canopy::invalid_id, canopy::invalid_id);
    for (std::uint32_t k = 0; k < c.top_meshes.size() && c.levels == 1; ++k)
        emit(c.top_meshes[k].index, widen(c.top_meshes[k].transform), k, canopy::invalid_id);
    for (std::uint32_t k = 0; k < c.top_groups.size() && c.levels == 2; ++k) {
        auto const& g = c.groups[c.top_groups[k].index];
        for (std::uint32_t j = 0; j < g.placements.size(); ++j)
            emit(g.placements[j].index, widen(c.top_groups[k].transform) * widen(g.placements[j].transform), k, j);
    }
    return out;
}

// Rays from outside the scene at the centroids of random world triangles: the compiled scene's
// closest hit must be the brute-force closest (same mesh, triangle and placement ids, t close).
void check_against_brute_force(canopy::compiled_scene const& c, int rays, std::uint32_t seed) {
    auto const world = world_of(c);
    REQUIRE(!world.empty());
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
    auto const box = c.bounds();
    float const extent = length(diagonal(box));
    int hits = 0;
    for (int i = 0; i < rays; ++i) {
        auto const& target = world[rng() % world.size()];
        vec3<double> const centroid = (target.v[0] + target.v[1] + target.v[2]) / 3.0;
        vec3<float> const origin = center(box) + normalize(vec3<float>(unit(rng), unit(rng), unit(rng))) * extent;
        canopy::ray r{origin, 0.0f, vec3<float>(centroid) - origin, 2.0f};
        std::optional<double> best;
        world_triangle const* best_w = nullptr;
        for (auto const& w : world)
            if (auto t = test_support::hit_double(r, w.v); t && (!best || *t < *best)) best = t, best_w = &w;
        canopy::default_intersector isect;
        auto const hr = c.closest_hit(r, isect);
        INFO("ray " << i);
        REQUIRE(hr.hit == best.has_value());
        if (!best) continue;
        ++hits;
        CHECK(hr.geom_id == best_w->geom);
        CHECK(hr.prim_id == best_w->prim);
        CHECK(hr.inst_id == best_w->inst);
        if (c.levels == 2) CHECK(hr.inner_inst_id[0] == best_w->inner);
        // The hit point's distance from the plane of the triangle: float rounding of the rays
        // at each level, a few ulps of the scene's extent (t itself varies more on grazing rays).
        vec3<double> const n = normalize(cross(best_w->v[1] - best_w->v[0], best_w->v[2] - best_w->v[0]));
        double const off_plane = std::abs(double(hr.t) - *best) * std::abs(dot(n, vec3<double>(r.direction)));
        CHECK(off_plane <= 1e-5 * double(extent));
        // surface() places the triangle with the same composed transform.
        auto const s = c.surface(hr, r);
        for (int k = 0; k < 3; ++k) {
            vec3<float> const got = k == 0 ? s.world_triangle.v0 : k == 1 ? s.world_triangle.v1 : s.world_triangle.v2;
            CHECK(length(vec3<double>(got) - best_w->v[std::size_t(k)]) <= 1e-5 * (1.0 + length(best_w->v[std::size_t(k)])));
        }
    }
    CHECK(hits > rays / 2);
}

bool decided(canopy::compiled_scene const& c, std::string const& words) {
    for (auto const& d : c.statistics.decisions)
        if (d.find(words) != std::string::npos) return true;
    return false;
}

} // namespace

// ---- the graph refuses bad data where it enters ---------------------------------------------

TEST_CASE("add_mesh refuses non-finite vertices, out-of-range indices and mismatched attributes") {
    canopy::scene s;
    auto m = sphere("ball");
    m.source = "ball.ply";
    auto bad = m;
    bad.positions[7].y = std::nanf("");
    CHECK(message_of([&] { s.add_mesh(bad); }) == "ball.ply: mesh 'ball': vertex 7 has a coordinate that is not finite");
    bad = m;
    bad.positions[2].x = INFINITY;
    CHECK(message_of([&] { s.add_mesh(bad); }).find("vertex 2") != std::string::npos);
    bad = m;
    bad.triangles[5][1] = std::uint32_t(bad.positions.size());
    CHECK(message_of([&] { s.add_mesh(bad); }) ==
          "ball.ply: mesh 'ball': triangle 5 uses vertex " + std::to_string(m.positions.size()) + " of " +
              std::to_string(m.positions.size()));
    bad = m;
    bad.uvs.resize(3);
    CHECK(message_of([&] { s.add_mesh(bad); }).find("texture coordinates for 3 of 80 triangles") != std::string::npos);
    bad = m;
    bad.material = 4;
    CHECK(message_of([&] { s.add_mesh(bad); }).find("material index 4 does not exist") != std::string::npos);
    CHECK(s.meshes().empty());
    CHECK(s.add_mesh(m) == 0);
}

TEST_CASE("nodes refuse singular and non-finite transforms, missing targets and children of leaves") {
    canopy::scene s;
    auto const m = s.add_mesh(sphere("ball"));
    CHECK(message_of([&] { s.add_transform(s.root(), xf::from_rows({1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0}), "flat"); })
              .find("node 'flat': transform is singular") != std::string::npos);
    CHECK(message_of([&] { s.add_transform(s.root(), translate(NAN, 0, 0), "nan"); }).find("not finite") !=
          std::string::npos);
    CHECK(message_of([&] { s.add_instance(s.root(), 99, xf::identity(), 0, "dangling"); })
              .find("instance target 99 does not exist") != std::string::npos);
    node_id const leaf = s.add_mesh_node(s.root(), m, "leaf");
    CHECK(message_of([&] { s.add_group(leaf, "child"); }).find("a mesh node cannot have children") != std::string::npos);
    CHECK(message_of([&] { s.add_camera(s.root(), {.eye = {1, 1, 1}, .target = {1, 1, 1}}, "cam"); })
              .find("eye and target coincide") != std::string::npos);
}

// ---- compile(): the skip rules --------------------------------------------------------------

TEST_CASE("a single untransformed mesh is traced without a top level") {
    canopy::scene s;
    auto const m = s.add_mesh(sphere("ball", 2));
    s.add_mesh_node(s.add_transform(s.root(), xf::identity(), "identity"), m);
    auto const c = canopy::compile(s);
    CHECK(c.levels == 0);
    CHECK(c.statistics.levels == 0);
    CHECK(c.statistics.identity_transform_nodes == 1);
    CHECK(decided(c, "no top-level BVH"));
    CHECK(c.top_mesh_instances.empty());
    CHECK(c.top_meshes_bvh.empty());
    check_against_brute_force(c, 300, 1);
    // Bit for bit what the mesh BVH gives when traced directly.
    auto const tris = canopy::make_icosphere(2);
    auto const direct = canopy::build_binned_sah(tris);
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
    for (int i = 0; i < 200; ++i) {
        canopy::ray const r{{3 * unit(rng), 3 * unit(rng), 3 * unit(rng)}, 0.0f, {unit(rng), unit(rng), unit(rng)}, INFINITY};
        canopy::default_intersector isect;
        auto const a = c.closest_hit(r, isect);
        auto const b = canopy::closest_hit(r, &direct, &direct + 1);
        REQUIRE(a.hit == b.hit);
        if (a.hit) CHECK((a.t == b.t && a.u == b.u && a.v == b.v && a.prim_id == b.prim_id));
    }
}

TEST_CASE("a transformed single mesh gets a top level, a shared mesh is built once") {
    canopy::scene s;
    auto const m = s.add_mesh(sphere("ball"));
    s.add_mesh_node(s.add_transform(s.root(), translate(3, 0, 0)), m);
    auto const one = canopy::compile(s);
    CHECK(one.levels == 1);
    CHECK(one.statistics.placements == 1);
    CHECK(one.statistics.identity_placements == 0);
    check_against_brute_force(one, 200, 2);

    s.add_mesh_node(s.add_transform(s.root(), scale_rotate_z(0.5f, 30.0f, {-2, 1, 0})), m);
    s.add_mesh_node(s.root(), m); // placed as it is
    auto const three = canopy::compile(s);
    CHECK(three.levels == 1);
    CHECK(three.meshes.size() == 1);
    CHECK(three.statistics.meshes_built == 1);
    CHECK(three.statistics.placements == 3);
    CHECK(three.statistics.identity_placements == 1);
    CHECK(three.statistics.triangles_stored == 80);
    CHECK(three.statistics.triangles_placed == 240);
    CHECK(decided(three, "1 of 3 placements have the identity transform: not applied"));
    CHECK(three.top_mesh_instances[2].identity);
    CHECK(!three.top_mesh_instances[0].identity);
    check_against_brute_force(three, 400, 3);
}

TEST_CASE("instances of a multi-mesh subtree become a group at level 2, single-mesh subtrees are placed directly") {
    canopy::scene s;
    auto const ball = s.add_mesh(sphere("ball"));
    auto const stone = s.add_mesh(sphere("stone", 0));
    node_id const tree = s.add_group(canopy::no_node, "tree"); // a prototype outside the tree
    s.add_mesh_node(tree, ball, "crown");
    s.add_mesh_node(s.add_transform(tree, translate(0, -1.5f, 0)), stone, "trunk");
    node_id const pebble = s.add_group(canopy::no_node, "pebble");
    s.add_mesh_node(s.add_transform(pebble, scale_rotate_z(0.3f, 0.0f, {0, 0, 0})), stone);

    for (int i = 0; i < 4; ++i) s.add_instance(s.root(), tree, scale_rotate_z(1.0f + 0.25f * float(i), 20.0f * float(i), {4.0f * float(i), 0, 0}), std::uint32_t(i));
    s.add_instance(s.root(), pebble, translate(0, 0, 5), 10);
    s.add_mesh_node(s.add_transform(s.root(), translate(0, 5, 0)), ball, "loose ball");

    auto const c = canopy::compile(s);
    CHECK(c.levels == 2);
    CHECK(c.meshes.size() == 2);
    CHECK(c.statistics.groups == 2); // the tree, and the extra group of loose placements
    CHECK(c.statistics.group_instances == 4);
    CHECK(c.top_groups.size() == 5);
    CHECK(c.groups[0].placements.size() == 2);
    CHECK(c.groups[1].placements.size() == 2); // the pebble (placed directly) and the loose ball
    CHECK(decided(c, "1 instances of single-mesh subtrees: the mesh is placed directly"));
    CHECK(decided(c, "one extra group, placed with the identity"));
    CHECK(c.top_group_instances.back().identity);
    // User ids of instance nodes come through; mesh nodes have none.
    for (std::uint32_t i = 0; i < 4; ++i) CHECK(c.top_groups[i].id == i);
    CHECK(c.top_groups[4].id == canopy::invalid_id);
    CHECK(c.groups[1].placements[0].id == 10);
    CHECK(c.groups[1].placements[1].id == canopy::invalid_id);
    canopy::default_intersector isect;
    auto const pebble_hit = c.closest_hit(canopy::ray{{0, 0, 20}, 0.0f, {0, 0, -1}, INFINITY}, isect);
    REQUIRE(pebble_hit.hit);
    CHECK(pebble_hit.t == Approx(20.0f - 5.0f - 0.3f).epsilon(0.02));
    CHECK(c.instance_id(pebble_hit) == 10);
    auto const tree_hit = c.closest_hit(canopy::ray{{8, 0, 20}, 0.0f, {0, 0, -1}, INFINITY}, isect);
    REQUIRE(tree_hit.hit);
    CHECK(c.instance_id(tree_hit) == 2);
    check_against_brute_force(c, 600, 4);
}

TEST_CASE("a scene that is one untransformed subtree uses the subtree's placements as its top level") {
    canopy::scene s;
    auto const ball = s.add_mesh(sphere("ball"));
    node_id const pair = s.add_group(canopy::no_node, "pair");
    s.add_mesh_node(pair, ball);
    s.add_mesh_node(s.add_transform(pair, translate(3, 0, 0)), ball);
    s.add_instance(s.root(), pair, xf::identity(), 0);
    auto const c = canopy::compile(s);
    CHECK(c.levels == 1);
    CHECK(c.groups.empty());
    CHECK(c.top_meshes.size() == 2);
    CHECK(decided(c, "its placements form the top level"));
    check_against_brute_force(c, 200, 5);
}

TEST_CASE("nesting deeper than two levels is flattened into the group, transforms composed") {
    canopy::scene s;
    auto const ball = s.add_mesh(sphere("ball"));
    auto const stone = s.add_mesh(sphere("stone", 0));
    node_id const leaf = s.add_group(canopy::no_node, "leaf");
    s.add_mesh_node(leaf, ball);
    s.add_mesh_node(s.add_transform(leaf, translate(0, 2, 0)), stone);
    node_id const branch = s.add_group(canopy::no_node, "branch");
    s.add_instance(branch, leaf, scale_rotate_z(0.5f, 45.0f, {1, 0, 0}), 0);
    s.add_instance(branch, leaf, scale_rotate_z(0.5f, -45.0f, {-1, 0, 0}), 1);
    s.add_instance(s.root(), branch, translate(0, 0, 0.5f), 0);
    s.add_instance(s.root(), branch, scale_rotate_z(2.0f, 90.0f, {0, 0, 8}), 1);
    auto const c = canopy::compile(s);
    CHECK(c.levels == 2);
    CHECK(c.groups.size() == 1);
    CHECK(c.groups[0].placements.size() == 4);
    CHECK(c.statistics.flattened_placements == 4);
    CHECK(decided(c, "flattened into their group"));
    check_against_brute_force(c, 500, 6);
}

TEST_CASE("empty meshes and subtrees are dropped, unplaced meshes and unused images are skipped") {
    canopy::scene s;
    auto const ball = s.add_mesh(sphere("ball"));
    auto const unused = s.add_mesh(sphere("unused"));
    canopy::mesh_data nothing;
    nothing.name = "nothing";
    auto const empty = s.add_mesh(nothing);
    (void)unused;
    int const image = s.add_image({"leaf.png", 1, 1, {canopy::vec4<float>{1, 1, 1, 0}}});
    canopy::material_data masked;
    masked.name = "leaf";
    masked.image = image;
    masked.alpha = canopy::alpha_mode::mask;
    s.add_material(masked); // no placed mesh uses it
    s.add_mesh_node(s.root(), ball);
    s.add_mesh_node(s.add_transform(s.root(), translate(2, 0, 0)), empty);
    node_id const hollow = s.add_group(canopy::no_node, "hollow");
    s.add_group(hollow);
    s.add_instance(s.root(), hollow, translate(5, 0, 0), 0);
    auto const c = canopy::compile(s);
    CHECK(c.levels == 0); // what remains is one untransformed mesh
    CHECK(c.statistics.meshes_empty == 1);
    CHECK(c.statistics.subtrees_empty == 1);
    CHECK(c.statistics.meshes_unreferenced == 1);
    CHECK(c.statistics.meshes_built == 1);
    CHECK(c.statistics.images_unused == 1);
    CHECK(c.textures.empty());
    CHECK(!c.statistics.alpha_mask_needed);
    CHECK(decided(c, "no material in use has an alpha mask"));
    CHECK(decided(c, "meshes without triangles: dropped"));
    CHECK(decided(c, "instances of subtrees without meshes: dropped"));
}

TEST_CASE("the alpha-mask intersector is needed only when a placed mesh has a masked, textured material") {
    canopy::scene s;
    int const image = s.add_image({"leaf.png", 2, 1, {canopy::vec4<float>{1, 1, 1, 0}, canopy::vec4<float>{1, 1, 1, 1}}});
    canopy::material_data leaf;
    leaf.name = "leaf";
    leaf.image = image;
    leaf.alpha = canopy::alpha_mode::mask;
    leaf.alpha_cutoff = 0.5f;
    int const mat = s.add_material(leaf);
    auto m = sphere("crown");
    m.material = mat;
    s.add_mesh_node(s.root(), s.add_mesh(m));
    auto const c = canopy::compile(s);
    CHECK(c.statistics.alpha_mask_needed);
    CHECK(c.statistics.masked_materials_used == 1);
    REQUIRE(c.textures.size() == 1);
    CHECK(c.materials[std::size_t(mat) + 1].alpha == canopy::alpha_mode::mask);
    CHECK(c.materials[std::size_t(mat) + 1].texture == 0);
    CHECK(c.meshes[0].material == mat + 1);
}

TEST_CASE("colour textures stored sRGB-encoded are decoded to linear once, alpha as it is") {
    canopy::scene s;
    canopy::image_data encoded{"leaf.png", 2, 1, {canopy::vec4<float>{0.5f, 0.04f, 1.0f, 0.5f}, canopy::vec4<float>{0, 0.2f, 0.8f, 1}}, true};
    canopy::image_data linear{"leaf.exr", 1, 1, {canopy::vec4<float>{0.5f, 0.04f, 1.0f, 0.5f}}, false};
    int const a = s.add_material({"encoded", {1, 1, 1}, s.add_image(encoded), canopy::alpha_mode::opaque, 0.5f});
    int const b = s.add_material({"linear", {1, 1, 1}, s.add_image(linear), canopy::alpha_mode::opaque, 0.5f});
    auto ma = sphere("a");
    ma.material = a;
    auto mb = sphere("b");
    mb.material = b;
    s.add_mesh_node(s.root(), s.add_mesh(ma));
    s.add_mesh_node(s.add_transform(s.root(), translate(3, 0, 0)), s.add_mesh(mb));
    auto const c = canopy::compile(s);
    REQUIRE(c.textures.size() == 2);
    // IEC 61966-2-1: ((0.5 + 0.055) / 1.055)^2.4 = 0.21404114; 0.04 / 12.92 = 0.0030959752.
    auto const t = c.textures[0].texel(0, 0);
    CHECK(t.x == Approx(0.21404114).epsilon(1e-6));
    CHECK(t.y == Approx(0.0030959752).epsilon(1e-6));
    CHECK(t.z == 1.0f);
    CHECK(t.w == 0.5f);
    CHECK(c.textures[0].texel(1, 0).y == Approx(0.033104767).epsilon(1e-6)); // ((0.2 + 0.055) / 1.055)^2.4
    auto const u = c.textures[1].texel(0, 0);
    CHECK((u.x == 0.5f && u.y == 0.04f && u.z == 1.0f && u.w == 0.5f));
}

TEST_CASE("instance cycles are errors naming the nodes on the cycle") {
    canopy::scene s;
    auto const ball = s.add_mesh(sphere("ball"));
    node_id const a = s.add_group(canopy::no_node, "a");
    node_id const b = s.add_group(canopy::no_node, "b");
    s.add_mesh_node(a, ball);
    s.add_instance(a, b, translate(1, 0, 0), 0, "a→b");
    s.add_instance(b, a, translate(0, 1, 0), 0, "b→a");
    s.add_instance(s.root(), a, xf::identity(), 0);
    std::string const msg = message_of([&] { canopy::compile(s, {.name = "loop.json"}); });
    CHECK(msg.find("loop.json: instance cycle: ") == 0);
    CHECK(msg.find("group 'a'") != std::string::npos);
    CHECK(msg.find("group 'b'") != std::string::npos);
    CHECK(msg.find("instance 'a→b'") != std::string::npos);

    canopy::scene t; // a cycle through children alone
    node_id const g = t.add_group(t.root(), "g");
    t.attach(g, t.root());
    CHECK(message_of([&] { canopy::compile(t); }).find("instance cycle: group 'root' → group 'g' → group 'root'") != std::string::npos);
}

TEST_CASE("a scene with nothing to trace is an error") {
    canopy::scene s;
    s.add_group(s.root(), "empty");
    CHECK(message_of([&] { canopy::compile(s, {.name = "empty.json"}); }) ==
          "empty.json: the scene has nothing to trace (no mesh with triangles is placed in it)");
}

TEST_CASE("cameras and lights are placed by the transforms above them") {
    canopy::scene s;
    s.add_mesh_node(s.root(), s.add_mesh(sphere("ball")));
    node_id const rig = s.add_transform(s.root(), scale_rotate_z(2.0f, 90.0f, {1, 2, 3}), "rig");
    s.add_camera(rig, {.eye = {1, 0, 0}, .target = {0, 0, 0}, .up = {0, 1, 0}, .fovy_degrees = 40.0f}, "cam");
    canopy::light_data sun;
    sun.direction = {1, 0, 0};
    s.add_light(rig, sun, "sun");
    auto const c = canopy::compile(s);
    REQUIRE(c.camera.has_value());
    // (1,0,0) scaled by 2, turned 90° about z → (0,2,0), then moved by (1,2,3).
    CHECK(c.camera->eye.x == Approx(1.0f).margin(1e-6));
    CHECK(c.camera->eye.y == Approx(4.0f));
    CHECK(c.camera->eye.z == Approx(3.0f));
    CHECK(c.camera->target.x == Approx(1.0f));
    CHECK(c.camera->up.x == Approx(-2.0f));
    REQUIRE(c.lights.size() == 1);
    CHECK(c.lights[0].direction.y == Approx(1.0f));
    CHECK(c.lights[0].direction.x == Approx(0.0f).margin(1e-6));
}

// ---- the registry ---------------------------------------------------------------------------

TEST_CASE("the registry loads by extension, names what it knows, and rolls back failed loads") {
    canopy::registry r;
    int calls = 0;
    r.add_loader(".tri", "test", "one triangle per line", [&](canopy::scene& s, std::filesystem::path const& file, node_id parent, canopy::registry const&) {
        ++calls;
        std::ifstream in(file);
        canopy::mesh_data m;
        m.name = file.stem().string();
        float x;
        while (in >> x) m.positions.push_back({x, 0, 0});
        node_id const g = s.add_group(parent, m.name);
        for (std::uint32_t i = 0; i + 2 < m.positions.size(); i += 3) m.triangles.push_back({i, i + 1, i + 2});
        m.triangles.push_back({0, 1, 99}); // always bad: the load must leave nothing behind
        s.add_mesh_node(g, s.add_mesh(m));
        return g;
    });
    test_support::temp_folder const tmp("canopy_scene_test");
    auto const& dir = tmp.path;
    std::ofstream(dir / "bad.TRI") << "1 2 3\n";
    canopy::scene s;
    std::string const msg = message_of([&] { r.load(s, dir / "bad.TRI"); });
    CHECK(calls == 1);
    CHECK(msg == (dir / "bad.TRI").string() + ": mesh 'bad': triangle 1 uses vertex 99 of 3");
    CHECK(s.nodes().size() == 1);
    CHECK(s.at(s.root()).children.empty());
    CHECK(s.meshes().empty());

    CHECK(message_of([&] { r.load(s, dir / "missing.tri"); }) == (dir / "missing.tri").string() + ": file not found");
    std::ofstream(dir / "scene.xyz") << "1 2 3\n";
    CHECK(message_of([&] { r.load(s, dir / "scene.xyz"); }) ==
          (dir / "scene.xyz").string() + ": unknown extension '.xyz' (known: .tri)");
    CHECK(message_of([&] { r.load(s, dir / "bad.TRI", s.root(), "other"); }) ==
          (dir / "bad.TRI").string() + ": plugin 'other' does not load '.tri' files (test do)");
    CHECK(message_of([&] { r.generate(s, "forest", {}); }).find("generator 'forest': is not registered") !=
          std::string::npos);
    CHECK(message_of([&] { r.load_plugin(dir / "bad.TRI"); }).find("cannot load plugin") != std::string::npos);
}

TEST_CASE("an extension's default loader is the one of highest rank, whatever the order of registration") {
    // Each loader makes a group named after its plugin. Ranked: preferred "omega"; standard
    // "beta", "zeta" (equal: "beta" sorts first); alternative "alpha", "gamma".
    struct loader {
        std::string plugin;
        canopy::loader_rank rank;
    };
    std::vector<loader> loaders{{"zeta", canopy::loader_rank::standard},
                                {"alpha", canopy::loader_rank::alternative},
                                {"beta", canopy::loader_rank::standard},
                                {"gamma", canopy::loader_rank::alternative}};
    auto const by_plugin = [](loader const& a, loader const& b) { return a.plugin < b.plugin; };
    std::sort(loaders.begin(), loaders.end(), by_plugin);
    test_support::temp_folder const tmp("canopy_scene_test");
    std::filesystem::path const file = tmp.write("mesh.tri", "1 2 3\n");
    auto const group_named_after = [](std::string name) {
        return [name](canopy::scene& s, std::filesystem::path const&, node_id parent, canopy::registry const&) {
            return s.add_group(parent, name);
        };
    };
    auto const default_of = [&](canopy::registry const& r) {
        canopy::scene s;
        return s.at(r.load(s, file)).name;
    };
    auto const order_of = [](canopy::registry const& r) {
        std::string order;
        for (auto const& l : r.loaders()) order += (order.empty() ? "" : " ") + l.plugin;
        return order;
    };
    int orders = 0;
    do {
        canopy::registry r;
        for (auto const& l : loaders) r.add_loader(".tri", l.plugin, "a group named after its plugin", group_named_after(l.plugin), l.rank);
        INFO("registered in the order " << loaders[0].plugin << " " << loaders[1].plugin << " " << loaders[2].plugin << " "
                                        << loaders[3].plugin);
        CHECK(default_of(r) == "beta");
        CHECK(order_of(r) == "beta zeta alpha gamma");
        canopy::scene s;
        CHECK(s.at(r.load(s, file, s.root(), "gamma")).name == "gamma");
        CHECK(message_of([&] { r.load(s, file, s.root(), "delta"); }) ==
              file.string() + ": plugin 'delta' does not load '.tri' files (beta zeta alpha gamma do)");
        // Registering again replaces a plugin's loader, rank included.
        r.add_loader(".tri", "beta", "now an alternative", group_named_after("beta"), canopy::loader_rank::alternative);
        CHECK(default_of(r) == "zeta");
        CHECK(order_of(r) == "zeta alpha beta gamma");
        r.add_loader(".tri", "omega", "preferred", group_named_after("omega"), canopy::loader_rank::preferred);
        CHECK(default_of(r) == "omega");
        ++orders;
    } while (std::next_permutation(loaders.begin(), loaders.end(), by_plugin));
    CHECK(orders == 24);
}

TEST_CASE("custom nodes are expanded by their registered type, and refused without one") {
    canopy::registry r;
    r.add_node_type("ball", "test", "a sphere of the given subdivisions", [](canopy::scene& s, node_id self, canopy::parameters const& p) {
        auto const n = p.get_integer("subdivisions", 1, 0, 4, "ball");
        s.add_mesh_node(self, s.add_mesh(sphere("ball", int(n))));
        return self;
    });
    canopy::scene s;
    s.add_custom(s.add_transform(s.root(), translate(1, 0, 0)), "ball", {{"subdivisions", "2"}}, "b");
    CHECK(message_of([&] { canopy::compile(s); }).find("custom node of type 'ball' was not expanded") != std::string::npos);
    auto const c = canopy::compile(s, {.plugins = &r});
    CHECK(c.statistics.custom_nodes_expanded == 1);
    CHECK(c.statistics.triangles_stored == 320);
    CHECK(c.levels == 1);
    check_against_brute_force(c, 100, 7);

    canopy::scene t;
    t.add_custom(t.root(), "ball", {{"subdivisions", "2.5"}}, "b");
    CHECK(message_of([&] { canopy::compile(t, {.plugins = &r}); }) ==
          "ball: parameter 'subdivisions': '2.5' is not an integer in [0, 4]");
    canopy::scene u;
    u.add_custom(u.root(), "tree", {}, "t");
    CHECK(message_of([&] { canopy::compile(u, {.plugins = &r}); }).find("node type 'tree' is not registered") !=
          std::string::npos);
}

TEST_CASE("the registry checks the file before its extension: folders, devices and FIFOs are named, never opened") {
    canopy::registry r;
    int calls = 0;
    r.add_loader(".tri", "test", "counts its calls", [&](canopy::scene& s, std::filesystem::path const&, node_id parent,
                                                      canopy::registry const&) {
        ++calls;
        return s.add_group(parent);
    });
    r.add_image_loader(".png", "test", [&](std::filesystem::path const&, std::uint64_t) {
        ++calls;
        return canopy::image_data{};
    });
    test_support::temp_folder const tmp("canopy_scene_test");
    auto const& dir = tmp.path;
    REQUIRE(test_support::make_special_files(dir, {"", ".tri", ".png"}));
    std::filesystem::create_symlink("zero.tri", dir / "link_to_link.tri");
    canopy::scene s;
    auto const p = [&](char const* name) { return (dir / name).string(); };
    CHECK(message_of([&] { r.load(s, dir / "folder"); }) == p("folder") + ": is a folder, not a regular file");
    CHECK(message_of([&] { r.load(s, dir / "folder.tri"); }) == p("folder.tri") + ": is a folder, not a regular file");
    CHECK(message_of([&] { r.load(s, dir / "zero"); }) == p("zero") + ": is a character device, not a regular file");
    CHECK(message_of([&] { r.load(s, dir / "zero.tri"); }) == p("zero.tri") + ": is a character device, not a regular file");
    CHECK(message_of([&] { r.load(s, dir / "link_to_link.tri"); }) ==
          p("link_to_link.tri") + ": is a character device, not a regular file");
    CHECK(message_of([&] { r.load(s, dir / "fifo.tri"); }) == p("fifo.tri") + ": is a FIFO, not a regular file");
    CHECK(message_of([&] { r.load(s, dir / "fifo.tri", s.root(), "other"); }) == p("fifo.tri") + ": is a FIFO, not a regular file");
    CHECK(message_of([&] { r.load_image(dir / "folder.png"); }) == p("folder.png") + ": is a folder, not a regular file (texture)");
    CHECK(message_of([&] { r.load_image(dir / "fifo.png"); }) == p("fifo.png") + ": is a FIFO, not a regular file (texture)");
    CHECK(message_of([&] { r.load_plugin(dir / "zero"); }) == p("zero") + ": is a character device, not a regular file");
    CHECK(calls == 0);
    CHECK(s.nodes().size() == 1);

    // Bytes per file: the limit is checked before the file is opened.
    std::ofstream(dir / "six.tri") << "12345\n";
    auto const saved = canopy::default_limits();
    canopy::default_limits().max_file_bytes = 5;
    CHECK(message_of([&] { r.load(s, dir / "six.tri"); }) ==
          p("six.tri") + ": is 6 bytes, over the limit of 5 bytes per file (--max-file-bytes)");
    canopy::default_limits().max_file_bytes = 6;
    CHECK_NOTHROW(r.load(s, dir / "six.tri"));
    CHECK(calls == 1);
    canopy::default_limits() = saved;
}

TEST_CASE("scene_error shows a file name of more than 160 bytes by its ends, and keeps it whole in file()") {
    std::string const short_name = std::string(160, 'a');
    CHECK(std::string(canopy::scene_error(short_name, "3", "bad").what()) == short_name + ":3: bad");
    // 200 bytes: the first 60 and the last 99 around "…"; a 3-byte character is never split.
    std::string const long_name = "/tmp/" + std::string(55, 'b') + "\xE2\x82\xAC" + std::string(134, 'c') + ".obj";
    REQUIRE(long_name.size() == 201);
    canopy::scene_error const e(long_name, "", "file not found");
    CHECK(e.file() == long_name);
    CHECK(std::string(e.what()) == "/tmp/" + std::string(55, 'b') + "…" + std::string(95, 'c') + ".obj: file not found");
    std::string const split = std::string(59, 'd') + "\xE2\x82\xAC" + std::string(200, 'e');
    CHECK(std::string(canopy::scene_error(split, "", "x").what()) == std::string(59, 'd') + "…" + std::string(99, 'e') + ": x");
    // A nested error (a loader quoting another file's message) stays short too.
    std::string const huge(10 << 20, 'f');
    canopy::scene_error const inner(huge + ".bin", "", "file not found (buffer)");
    canopy::scene_error const outer("scene.gltf", "buffers[0]", inner.what());
    CHECK(std::string(outer.what()).size() < 300);
}

TEST_CASE("read_regular_file reads a file whole or names why not, require_text refuses binary data by offset") {
    test_support::temp_folder const tmp("canopy_scene_test");
    std::string bytes(70000, 'a');
    bytes[12345] = '\0';
    auto const file = tmp.path / "bytes.bin";
    std::ofstream(file, std::ios::binary) << bytes;
    CHECK(canopy::read_regular_file(file) == bytes);
    CHECK(canopy::read_regular_file(file, 70000, "mesh") == bytes);
    CHECK(message_of([&] { canopy::read_regular_file(file, 69999, "mesh"); }) ==
          file.string() + ": is 70000 bytes, over the limit of 69999 bytes per file (--max-file-bytes) (mesh)");
    CHECK(message_of([&] { canopy::read_regular_file(tmp.path / "none"); }) == (tmp.path / "none").string() + ": file not found");
    CHECK(message_of([&] { canopy::read_regular_file("/dev/zero"); }) == "/dev/zero: is a character device, not a regular file");

    CHECK_NOTHROW(canopy::require_text("v 1 2 3\r\n\tf\v\f \xC3\xA9\xFF\n", "a.obj", "OBJ"));
    CHECK(message_of([&] { canopy::require_text(bytes, "b.bin", "PLY"); }) == "b.bin:1: not a text PLY file: NUL byte at offset 12345");
    CHECK(message_of([&] { canopy::require_text("a\nb\n\x7F", "c", "OFF"); }) == "c:3: not a text OFF file: control byte 0x7F at offset 4");
    CHECK(message_of([&] { canopy::require_text("\xFE\xFF\0a", "d", "OBJ"); }) ==
          "d: not a text OBJ file: UTF-16 byte-order mark (only ASCII or UTF-8 text is read)");

    // A message quotes at most 40 bytes of input, cut between UTF-8 characters, control bytes as '?'.
    CHECK(canopy::excerpt(std::string(10000000, 'z')) == std::string(40, 'z') + "…");
    CHECK(canopy::excerpt("short\ttext") == "short?text");
    CHECK(canopy::excerpt(std::string(39, 'e') + "\xC3\xA9" + "tail") == std::string(39, 'e') + "…");
    CHECK(canopy::excerpt(std::string(38, 'e') + "\xC3\xA9" + "tail") == std::string(38, 'e') + "\xC3\xA9…");
    CHECK(canopy::excerpt("exactly", 7) == "exactly");
}

TEST_CASE("compile() reports the polygon faces a loader had to fan, naming the first") {
    canopy::scene s;
    canopy::mesh_data m = sphere("bad polygons");
    m.source = "model.ply";
    m.fanned_faces = 3;
    m.first_fanned = "face 17";
    s.add_mesh_node(s.root(), s.add_mesh(m));
    canopy::mesh_data n = sphere("fine");
    s.add_mesh_node(s.root(), s.add_mesh(n));
    canopy::mesh_data unplaced = sphere("unplaced");
    unplaced.fanned_faces = 5;
    s.add_mesh(unplaced); // not built: not reported
    auto const c = canopy::compile(s);
    CHECK(c.statistics.faces_fanned == 3);
    CHECK(std::count(c.statistics.decisions.begin(), c.statistics.decisions.end(),
                     "3 polygon faces fanned, not ear-clipped (self-intersecting, collinear, or non-convex with more than "
                     "256 corners): their triangles may cover more than the face; the first in mesh 'bad polygons' "
                     "(model.ply: face 17)") == 1);
}

TEST_CASE("compile() builds the mesh BVHs at the quality of its options, automatic by default, and reports it") {
    // A mesh of long thin triangles (a fan of needles), placed twice.
    canopy::mesh_data fan;
    fan.name = "fan";
    fan.positions.push_back({0, 0, 0});
    for (int i = 0; i <= 200; ++i) {
        double const a = 0.002 * double(i);
        fan.positions.push_back({float(10.0 * std::cos(a)), float(10.0 * std::sin(a)), 0.0f});
    }
    for (std::uint32_t i = 1; i <= 200; ++i) fan.triangles.push_back({0, i, i + 1});
    canopy::scene s;
    auto const m = s.add_mesh(fan);
    s.add_mesh_node(s.root(), m);
    s.add_mesh_node(s.add_transform(s.root(), translate(0, 0, 2)), m);

    // By default (automatic) the needles are split; a mesh of well-shaped triangles is not.
    auto const automatic = canopy::compile(s);
    CHECK(automatic.statistics.quality == canopy::build_quality::automatic);
    REQUIRE(automatic.meshes.size() == 1);
    CHECK(automatic.meshes[0].accel.quality == canopy::build_quality::high);
    CHECK(decided(automatic, "mesh BVHs built at quality automatic (the default): 1 of 1 with spatial splits"));
    canopy::mesh_data quad;
    quad.name = "quad";
    quad.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
    quad.triangles = {{0, 1, 2}, {0, 2, 3}};
    canopy::scene q;
    q.add_mesh_node(q.root(), q.add_mesh(quad));
    auto const plain = canopy::compile(q);
    REQUIRE(plain.meshes.size() == 1);
    CHECK(plain.meshes[0].accel.quality == canopy::build_quality::fast);
    CHECK(decided(plain, "mesh BVHs built at quality automatic (the default): 0 of 1 with spatial splits"));

    auto const fast = canopy::compile(s, {.bvh = {.quality = canopy::build_quality::fast}});
    CHECK(fast.statistics.quality == canopy::build_quality::fast);
    CHECK(decided(fast, "mesh BVHs built at quality fast: object splits only"));
    auto const high = canopy::compile(s, {.bvh = {.quality = canopy::build_quality::high}});
    CHECK(high.statistics.quality == canopy::build_quality::high);
    CHECK(decided(high, "mesh BVHs built at quality high: object and spatial splits"));
    for (auto const* c : {&fast, &high}) {
        REQUIRE(c->meshes.size() == 1);
        CHECK(c->meshes[0].build_seconds > 0.0);
        CHECK(c->statistics.mesh_build_seconds == c->meshes[0].build_seconds);
        CHECK(c->statistics.mesh_build_seconds <= c->statistics.build_seconds);
    }
    // The builds themselves: the fast one as build_binned_sah gives it, the high one with split
    // references (more leaf slots than triangles) and a lower SAH cost.
    std::vector<canopy::triangle> tris;
    for (auto const& t : fast.meshes[0].triangles) tris.push_back(t);
    CHECK(canopy::compute_stats(fast.meshes[0].accel).sah_cost ==
          canopy::compute_stats(canopy::build_binned_sah(tris, {.quality = canopy::build_quality::fast})).sah_cost);
    CHECK(canopy::compute_stats(automatic.meshes[0].accel).sah_cost == canopy::compute_stats(canopy::build_binned_sah(tris)).sah_cost);
    std::size_t references = 0;
    canopy::for_each_primitive(high.meshes[0].accel, [&](canopy::triangle const&) { ++references; });
    CHECK(references > tris.size());
    CHECK(canopy::compute_stats(high.meshes[0].accel).sah_cost < canopy::compute_stats(fast.meshes[0].accel).sah_cost);
    check_against_brute_force(high, 300, 7);
}

// ---- compiled_scene: the root, the camera and the lights --------------------------------------

TEST_CASE("visit_root hands queries the BVH of the scene's level: the mesh, mesh instances or group instances") {
    // Levels 0: one untransformed mesh; 1: the mesh moved; 2: instances of a two-mesh subtree.
    canopy::scene one;
    one.add_mesh_node(one.root(), one.add_mesh(sphere("ball")));
    canopy::scene moved;
    moved.add_mesh_node(moved.add_transform(moved.root(), translate(3, 0, 0)), moved.add_mesh(sphere("ball")));
    canopy::scene grouped;
    auto const ball = grouped.add_mesh(sphere("ball"));
    node_id const pair = grouped.add_group(canopy::no_node, "pair");
    grouped.add_mesh_node(pair, ball);
    grouped.add_mesh_node(grouped.add_transform(pair, translate(0, 3, 0)), ball);
    grouped.add_instance(grouped.root(), pair, translate(3, 0, 0), 0);
    grouped.add_instance(grouped.root(), pair, translate(-3, 0, 0), 1);

    struct expected_root {
        canopy::scene const* graph;
        int level;
        float centre_x; // of the root's bounds, placed by hand above
    };
    for (auto const& [graph, level, centre_x] :
         {expected_root{&one, 0, 0.0f}, expected_root{&moved, 1, 3.0f}, expected_root{&grouped, 2, 0.0f}}) {
        INFO("level " << level);
        auto const c = canopy::compile(*graph);
        REQUIRE(c.levels == level);
        // Which object, and of which type, the root is.
        auto const [root, kind] = c.visit_root([](auto const& bvh) {
            using type = std::decay_t<decltype(bvh)>;
            int const k = std::is_same_v<type, canopy::bvh<canopy::triangle>>    ? 0
                          : std::is_same_v<type, canopy::bvh<canopy::mesh_instance>> ? 1
                          : std::is_same_v<type, canopy::bvh<canopy::group_instance>> ? 2
                                                                                     : -1;
            return std::pair{static_cast<void const*>(&bvh), k};
        });
        CHECK(kind == level);
        void const* const expected = level == 0   ? static_cast<void const*>(&c.meshes[0].accel)
                                     : level == 1 ? static_cast<void const*>(&c.top_meshes_bvh)
                                                  : static_cast<void const*>(&c.top_groups_bvh);
        CHECK(root == expected);
        // bounds() and the queries go through it: the centre of the placed spheres, and a ray down
        // onto the sphere placed at x = centre_x + 3 (levels 1, 2) or at the origin (level 0).
        CHECK(canopy::center(c.bounds()).x == Approx(centre_x).margin(1e-5));
        float const x = level == 0 ? 0.0f : 3.0f;
        canopy::default_intersector isect;
        auto const hit = c.closest_hit(canopy::ray{{x, 10, 0}, 0.0f, {0, -1, 0}, INFINITY}, isect);
        REQUIRE(hit.hit);
        CHECK(hit.t == Approx(level == 2 ? 10.0 - 4.0 : 9.0).margin(0.1));
        CHECK(hit.inst_id == (level == 0 ? canopy::invalid_id : 0u));
        CHECK(c.any_hit(canopy::ray{{x, 10, 0}, 0.0f, {0, -1, 0}, INFINITY}, isect).hit);
    }
}

TEST_CASE("render_camera: the scene's camera as placed, else one from above and in front of the bounds") {
    float const half_height = float(std::tan(22.5 * 3.14159265358979323846 / 180.0)); // fovy 45°
    canopy::scene s;
    // One triangle spanning the box (-1, -2, -3) .. (1, 2, 3): centre 0, diagonal √56.
    canopy::mesh_data m;
    m.positions = {{-1, -2, -3}, {1, 2, 3}, {1, -2, 3}};
    m.triangles = {{0, 1, 2}};
    s.add_mesh_node(s.root(), s.add_mesh(std::move(m)));

    auto const automatic = canopy::compile(s, {.name = "box.json"}).render_camera(1.0f, "box.json");
    double const diagonal = std::sqrt(56.0);
    CHECK(automatic.eye.x == Approx(0.35 * diagonal).epsilon(1e-6));
    CHECK(automatic.eye.y == Approx(0.45 * diagonal).epsilon(1e-6));
    CHECK(automatic.eye.z == Approx(1.0 * diagonal).epsilon(1e-6));
    double const to_centre = std::sqrt(0.35 * 0.35 + 0.45 * 0.45 + 1.0);
    CHECK(automatic.forward.x == Approx(-0.35 / to_centre).epsilon(1e-5));
    CHECK(automatic.forward.y == Approx(-0.45 / to_centre).epsilon(1e-5));
    CHECK(automatic.forward.z == Approx(-1.0 / to_centre).epsilon(1e-5));
    CHECK(canopy::length(automatic.up) == Approx(half_height).epsilon(1e-5));

    // The scene's camera, 5 up a transform: looking down -z from (0, 5, 5), aspect 2.
    s.add_camera(s.add_transform(s.root(), translate(0, 5, 0)), {.eye = {0, 0, 5}, .target = {0, 0, 0}}, "cam");
    auto const c = canopy::compile(s, {.name = "view.json"});
    auto const camera = c.render_camera(2.0f, "other name");
    CHECK(camera.eye.x == 0.0f);
    CHECK(camera.eye.y == 5.0f);
    CHECK(camera.eye.z == 5.0f);
    CHECK(camera.forward.z == -1.0f);
    CHECK(camera.right.x == Approx(2.0f * half_height).epsilon(1e-6));
    CHECK(camera.right.y == 0.0f);
    CHECK(camera.up.y == Approx(half_height).epsilon(1e-6));
    CHECK(camera.up.x == 0.0f);
    // Values that give no camera are named by the camera's file and node.
    CHECK(message_of([&] { c.render_camera(0.0f, "other name"); }) ==
          "view.json: camera 'cam': aspect ratio 0 is not a positive number");

    // Bounds beyond float range give no automatic camera.
    canopy::scene huge;
    canopy::mesh_data far;
    far.positions = {{-3e38f, 0, -3e38f}, {3e38f, 0, -3e38f}, {3e38f, 0, 3e38f}};
    far.triangles = {{0, 1, 2}};
    huge.add_mesh_node(huge.root(), huge.add_mesh(std::move(far)));
    CHECK(message_of([&] { canopy::compile(huge).render_camera(1.0f, "huge.json"); }) ==
          "huge.json: automatic camera: the scene's bounds (-3e+38, 0, -3e+38) .. (3e+38, 0, 3e+38) are empty or beyond "
          "float range: give the scene a camera");
}

TEST_CASE("render_lights: the scene's first sun and point light, else a point light above the middle of the bounds") {
    canopy::scene s;
    canopy::mesh_data m;
    m.positions = {{-1, -2, -3}, {1, 2, 3}, {1, -2, 3}};
    m.triangles = {{0, 1, 2}};
    s.add_mesh_node(s.root(), s.add_mesh(std::move(m)));

    // Without lights: the default sun, and a point light 0.35 · √56 above the centre (the origin),
    // of intensity (1, 0.8, 0.6) · 0.05 · 56.
    canopy::light_options const defaults;
    auto const lit = canopy::compile(s).render_lights("box.json");
    CHECK(lit.point_light);
    CHECK(lit.point_position.x == 0.0f);
    CHECK(lit.point_position.y == Approx(0.35 * std::sqrt(56.0)).epsilon(1e-6));
    CHECK(lit.point_position.z == 0.0f);
    CHECK(lit.point_intensity.x == Approx(2.8).epsilon(1e-5));
    CHECK(lit.point_intensity.y == Approx(2.24).epsilon(1e-5));
    CHECK(lit.point_intensity.z == Approx(1.68).epsilon(1e-5));
    CHECK(lit.sun_direction.y == defaults.sun_direction.y);
    CHECK(lit.sun_colour.x == defaults.sun_colour.x);

    // The first directional light is the sun (its direction made unit), the first point light the
    // point light; the second of each is not used.
    using light = canopy::light_data;
    s.add_light(s.root(), {.kind = light::directional, .direction = {0, 2, 0}, .colour = {1, 0.5f, 0.25f}});
    s.add_light(s.root(), {.kind = light::point, .position = {1, 2, 3}, .colour = {4, 5, 6}});
    s.add_light(s.root(), {.kind = light::directional, .direction = {1, 0, 0}, .colour = {9, 9, 9}});
    s.add_light(s.root(), {.kind = light::point, .position = {7, 7, 7}, .colour = {9, 9, 9}});
    auto const own = canopy::compile(s).render_lights("box.json");
    CHECK(own.sun_direction.x == 0.0f);
    CHECK(own.sun_direction.y == 1.0f);
    CHECK(own.sun_direction.z == 0.0f);
    CHECK(own.sun_colour.y == 0.5f);
    CHECK(own.point_light);
    CHECK(own.point_position.z == 3.0f);
    CHECK(own.point_intensity.x == 4.0f);
    CHECK(own.point_intensity.z == 6.0f);
}
