// Tests of canopy.plugins.procedural: each generator's counts against the numbers worked out by
// hand from its parameters, the icosphere's closedness (every edge in exactly two faces, once in
// each direction), determinism in the seed, errors naming the generator and the parameter, the
// billboard forest (the demo scene) compiled with one BLAS per mesh, its placements laid out as
// its comment says (checked from the transforms alone), its alpha mask cutting rays, and the
// `procedural` node type.
#include <catch2/catch.hpp>

#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

import canopy.scene;
import canopy.plugins.procedural;
import canopy.testing;
import canopy.testing.scene;

namespace {

using test_support::message_of;
using canopy::vec3;

canopy::registry procedural_registry() {
    canopy::registry r;
    canopy::register_procedural_plugin(r);
    return r;
}

// Generates into a new scene; returns the scene.
canopy::scene generated(std::string const& name, canopy::parameters const& params) {
    canopy::scene s;
    procedural_registry().generate(s, name, params);
    return s;
}

std::vector<std::uint32_t> bits_of(canopy::mesh_data const& m) {
    std::vector<std::uint32_t> out;
    for (auto const& p : m.positions)
        for (float f : {p.x, p.y, p.z}) out.push_back(std::bit_cast<std::uint32_t>(f));
    return out;
}

long long power_of_4(int n) { return 1LL << (2 * n); }

} // namespace

TEST_CASE("sphere has 20·4^s triangles and 10·4^s + 2 vertices, every edge shared by two faces") {
    for (int sub = 0; sub <= 4; ++sub) {
        CAPTURE(sub);
        auto const s = generated("sphere", {{"subdivisions", std::to_string(sub)}, {"radius", "2.5"}, {"centre", "1, -2, 3"}});
        REQUIRE(s.meshes().size() == 1);
        auto const& m = s.meshes()[0];
        CHECK(static_cast<long long>(m.triangles.size()) == 20 * power_of_4(sub));
        CHECK(static_cast<long long>(m.positions.size()) == 10 * power_of_4(sub) + 2);

        // Closed and consistently oriented: each directed edge once, and its reverse once.
        std::map<std::pair<std::uint32_t, std::uint32_t>, int> directed;
        for (auto const& t : m.triangles)
            for (int k = 0; k < 3; ++k) ++directed[{t[std::size_t(k)], t[std::size_t((k + 1) % 3)]}];
        bool closed = true;
        for (auto const& [edge, count] : directed) {
            auto const reverse = directed.find({edge.second, edge.first});
            closed &= count == 1 && reverse != directed.end() && reverse->second == 1;
        }
        CHECK(closed);
        CHECK(directed.size() == 3 * m.triangles.size());

        double worst = 0.0;
        for (auto const& p : m.positions) {
            double const r = std::sqrt((p.x - 1.0) * (p.x - 1.0) + (p.y + 2.0) * (p.y + 2.0) + (p.z - 3.0) * (p.z - 3.0));
            worst = std::max(worst, std::abs(r - 2.5));
        }
        CHECK(worst < 1e-5);
    }
}

TEST_CASE("sphere defaults: 3 subdivisions, radius 1, centred at the origin") {
    auto const s = generated("sphere", {});
    auto const& m = s.meshes()[0];
    CHECK(m.triangles.size() == 20 * 64);
    for (auto const& p : m.positions) CHECK(std::sqrt(double(p.x) * p.x + double(p.y) * p.y + double(p.z) * p.z) == Approx(1.0).epsilon(1e-6));
}

TEST_CASE("terrain has 2·n² triangles over (n + 1)² vertices, spans the square and stays within the amplitude") {
    auto const s = generated("terrain", {{"size", "8"}, {"resolution", "12"}, {"amplitude", "0.75"}, {"seed", "7"}});
    auto const& m = s.meshes()[0];
    CHECK(m.triangles.size() == 2 * 12 * 12);
    REQUIRE(m.positions.size() == 13 * 13);
    float lo_x = 1e9f, hi_x = -1e9f, lo_z = 1e9f, hi_z = -1e9f, lo_y = 1e9f, hi_y = -1e9f;
    for (auto const& p : m.positions) {
        lo_x = std::min(lo_x, p.x), hi_x = std::max(hi_x, p.x);
        lo_y = std::min(lo_y, p.y), hi_y = std::max(hi_y, p.y);
        lo_z = std::min(lo_z, p.z), hi_z = std::max(hi_z, p.z);
    }
    CHECK(lo_x == -4.0f);
    CHECK(hi_x == 4.0f);
    CHECK(lo_z == -4.0f);
    CHECK(hi_z == 4.0f);
    CHECK(lo_y >= -0.75f);
    CHECK(hi_y <= 0.75f);
    CHECK(hi_y - lo_y > 0.1f); // not flat

    // Every triangle faces up (+y).
    int facing_up = 0;
    for (auto const& t : m.triangles) {
        auto const a = m.positions[t[0]], b = m.positions[t[1]], c = m.positions[t[2]];
        facing_up += canopy::cross(b - a, c - a).y > 0.0f;
    }
    CHECK(facing_up == int(m.triangles.size()));

    auto const flat = generated("terrain", {{"resolution", "3"}, {"amplitude", "0"}});
    for (auto const& p : flat.meshes()[0].positions) CHECK(p.y == 0.0f);
}

TEST_CASE("triangle_soup has count triangles of 3 vertices each, inside the box widened by size") {
    auto const s = generated("triangle_soup", {{"count", "250"}, {"size", "0.5"}, {"extent", "2"}, {"seed", "3"}});
    auto const& m = s.meshes()[0];
    CHECK(m.triangles.size() == 250);
    CHECK(m.positions.size() == 750);
    bool inside = true;
    for (auto const& p : m.positions)
        for (float c : {p.x, p.y, p.z}) inside &= std::abs(c) <= 2.5f;
    CHECK(inside);
    bool first_corner_in_box = true;
    for (auto const& t : m.triangles)
        for (float c : {m.positions[t[0]].x, m.positions[t[0]].y, m.positions[t[0]].z}) first_corner_in_box &= std::abs(c) <= 2.0f;
    CHECK(first_corner_in_box);
}

TEST_CASE("generators are deterministic: same parameters, same bits, another seed, other data") {
    for (std::string const name : {"terrain", "triangle_soup", "billboard_forest"}) {
        CAPTURE(name);
        canopy::parameters const small = name == "terrain"         ? canopy::parameters{{"resolution", "16"}}
                                         : name == "triangle_soup" ? canopy::parameters{{"count", "50"}}
                                                                   : canopy::parameters{{"billboards", "20"}};
        auto with_seed = [&](char const* seed) {
            canopy::parameters p = small;
            p.set("seed", seed);
            return generated(name, p);
        };
        auto const a = with_seed("11"), b = with_seed("11"), c = with_seed("12");
        REQUIRE(a.meshes().size() == c.meshes().size());
        std::vector<std::uint32_t> all_a, all_b, all_c;
        for (std::size_t i = 0; i < a.meshes().size(); ++i) {
            auto const x = bits_of(a.meshes()[i]), y = bits_of(b.meshes()[i]), z = bits_of(c.meshes()[i]);
            all_a.insert(all_a.end(), x.begin(), x.end());
            all_b.insert(all_b.end(), y.begin(), y.end());
            all_c.insert(all_c.end(), z.begin(), z.end());
        }
        // The forest's randomness is in its placements.
        std::vector<float> place_a, place_b, place_c;
        auto placements = [](canopy::scene const& s, std::vector<float>& out) {
            for (auto const& n : s.nodes())
                if (n.kind == canopy::node_kind::instance)
                    for (auto v : {n.transform.linear.col0, n.transform.linear.col1, n.transform.linear.col2, n.transform.translation})
                        out.insert(out.end(), {v.x, v.y, v.z});
        };
        placements(a, place_a), placements(b, place_b), placements(c, place_c);
        CHECK(all_a == all_b);
        CHECK(place_a == place_b);
        CHECK((all_a != all_c || place_a != place_c));
    }
    auto const s1 = generated("sphere", {{"subdivisions", "2"}}), s2 = generated("sphere", {{"subdivisions", "2"}});
    CHECK(bits_of(s1.meshes()[0]) == bits_of(s2.meshes()[0]));
}

TEST_CASE("bad parameters are scene errors naming the generator and the parameter, the scene is unchanged") {
    struct bad {
        char const* generator;
        char const* key;
        char const* value;
    };
    for (auto const& [generator, key, value] : {
             bad{"sphere", "subdivisions", "9"},     bad{"sphere", "subdivisions", "1.5"}, bad{"sphere", "radius", "0"},
             bad{"sphere", "radius", "-1"},          bad{"sphere", "radius", "abc"},      bad{"sphere", "radius", "nan"},
             bad{"sphere", "centre", "1 2"},         bad{"sphere", "centre", "1 2 x"},    bad{"sphere", "centre", "1 2 3 4"},
             bad{"sphere", "centre", "0 0 1e7"},     bad{"sphere", "radus", "1"},         bad{"terrain", "resolution", "0"},
             bad{"terrain", "resolution", "5000"},   bad{"terrain", "amplitude", "-1"},   bad{"terrain", "size", "inf"},
             bad{"terrain", "octaves", "9"},         bad{"terrain", "seed", "-1"},        bad{"terrain", "seed", "4294967296"},
             bad{"triangle_soup", "count", "0"},     bad{"triangle_soup", "size", "-0.5"}, bad{"triangle_soup", "extent", ""},
             bad{"billboard_forest", "billboards", "-3"}, bad{"billboard_forest", "texture_size", "4"},
             bad{"billboard_forest", "trees", "10"},
         }) {
        CAPTURE(generator, key, value);
        canopy::scene s;
        auto const r = procedural_registry();
        r.generate(s, "sphere", {{"subdivisions", "0"}}); // something to keep
        std::size_t const nodes = s.nodes().size(), meshes = s.meshes().size();
        std::string const message = message_of([&] { r.generate(s, generator, {{key, value}}); });
        CHECK(message.find("generator '" + std::string(generator) + "'") != std::string::npos);
        CHECK(message.find("parameter '" + std::string(key) + "'") != std::string::npos);
        CHECK(s.nodes().size() == nodes);
        CHECK(s.meshes().size() == meshes);
    }
}

TEST_CASE("billboard_forest compiles to one top level with one BLAS per mesh and needs the alpha mask") {
    auto const r = procedural_registry();
    canopy::scene s;
    r.generate(s, "billboard_forest", {{"billboards", "40"}, {"spheres", "5"}, {"texture_size", "64"}});
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r});
    CHECK(c.levels == 1);
    REQUIRE(c.meshes.size() == 3); // ground, sphere, billboard: each built once
    CHECK(c.statistics.meshes_built == 3);
    CHECK(c.meshes[0].triangles.size() == 2 * 40 * 40);
    CHECK(c.meshes[1].triangles.size() == 20 * 64);
    CHECK(c.meshes[2].triangles.size() == 2);
    CHECK(c.statistics.placements == 1 + 5 + 40);
    CHECK(c.statistics.triangles_placed == 3200 + 5 * 1280 + 40 * 2);
    CHECK(c.statistics.alpha_mask_needed);
    CHECK(c.statistics.masked_materials_used == 1);
    REQUIRE(c.camera.has_value());
    CHECK(c.camera->eye.z == 17.0f);
}

TEST_CASE("billboard_forest places the ground, then the spheres on it, then billboards facing the camera") {
    auto const r = procedural_registry();
    canopy::scene s;
    r.generate(s, "billboard_forest", {{"seed", "5"}});
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r});
    REQUIRE(c.camera.has_value());
    vec3<float> const eye = c.camera->eye;
    REQUIRE(c.top_meshes.size() == 1 + 7 + 160);
    CHECK(c.meshes[0].name == "ground");
    CHECK(c.meshes[1].name == "sphere");
    CHECK(c.meshes[2].name == "billboard");
    CHECK(c.top_meshes[0].index == 0);
    CHECK(c.top_meshes[0].transform.is_identity());
    std::size_t spheres_on_ground = 0, billboards_facing = 0;
    for (std::size_t k = 1; k < c.top_meshes.size(); ++k) {
        auto const& p = c.top_meshes[k];
        auto const& m = p.transform.linear;
        vec3<float> const at = p.transform.translation;
        if (k <= 7) {
            // A uniform scale r in [0.6, 1.6], the unit sphere's centre lifted by r: it stands on y = 0.
            float const radius = m.col0.x;
            spheres_on_ground += p.index == 1 && radius >= 0.6f && radius <= 1.6f && m.col1.y == radius &&
                                 m.col2.z == radius && at.y == radius && at.x >= -9.0f && at.x <= 9.0f &&
                                 at.z >= -14.0f && at.z <= 2.0f;
            continue;
        }
        // The quad's normal (+z of the prototype) turned about y towards the eye; height in [1.8, 3.6].
        double const nx = m.col2.x, nz = m.col2.z;
        double const ex = double(eye.x) - at.x, ez = double(eye.z) - at.z;
        double const cosine = (nx * ex + nz * ez) / (std::hypot(nx, nz) * std::hypot(ex, ez));
        billboards_facing += p.index == 2 && cosine > 1.0 - 1e-6 && m.col2.y == 0.0f && m.col1.y >= 1.8f &&
                             m.col1.y <= 3.6f && at.y == 0.0f && at.x >= -16.0f && at.x <= 16.0f;
    }
    CHECK(spheres_on_ground == 7);
    CHECK(billboards_facing == 160);
}

TEST_CASE("the billboards' alpha mask lets rays through transparent texels only") {
    auto const r = procedural_registry();
    canopy::scene s;
    r.generate(s, "billboard_forest", {{"billboards", "12"}, {"spheres", "0"}});
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r});
    canopy::texture_alpha_mask masked;
    masked.scene = &c;
    canopy::default_intersector plain;
    // Each billboard: a ray just in front of its quad, at texture coordinates (u, v).
    int opaque_hits = 0, transparent_passes = 0, plain_hits = 0, billboards = 0;
    for (std::uint32_t k = 0; k < c.top_meshes.size(); ++k) {
        if (c.meshes[c.top_meshes[k].index].name != "billboard") continue;
        ++billboards;
        auto const& xf = c.top_meshes[k].transform;
        vec3<float> const normal = canopy::normalize(xf.linear.col2);
        auto const ray_at = [&](float u, float v) {
            vec3<float> const p = xf.transform_point(vec3<float>(u - 0.5f, 1.0f - v, 0.0f));
            return canopy::ray{p + normal * 0.01f, 0.0f, -normal, 1e30f};
        };
        auto const solid = c.closest_hit(ray_at(0.5f, 0.6f), masked);    // inside the lowest tier
        auto const hole = c.closest_hit(ray_at(0.05f, 0.05f), masked);   // top-left corner: transparent
        auto const unmasked = c.closest_hit(ray_at(0.05f, 0.05f), plain);
        opaque_hits += solid.hit && solid.inst_id == k && solid.t < 0.02f;
        transparent_passes += !(hole.hit && hole.inst_id == k && hole.t < 0.02f);
        plain_hits += unmasked.hit && unmasked.inst_id == k && unmasked.t < 0.02f;
    }
    CHECK(billboards == 12);
    CHECK(opaque_hits == 12);
    CHECK(transparent_passes == 12);
    CHECK(plain_hits == 12);
}

TEST_CASE("the tree texture is opaque on the trunk and the tiers, transparent around them") {
    canopy::image_data const img = canopy::make_tree_texture(100);
    REQUIRE(img.width == 100);
    REQUIRE(img.height == 100);
    auto const alpha = [&](int x, int y) { return img.texels[std::size_t(y) * 100 + std::size_t(x)].w; };
    CHECK(alpha(50, 90) == 1.0f); // trunk
    CHECK(alpha(50, 30) == 1.0f); // first tier
    CHECK(alpha(2, 2) == 0.0f);   // corners
    CHECK(alpha(97, 97) == 0.0f);
    CHECK(alpha(50, 0) == 0.0f);  // above the apex
    bool binary = true;
    for (auto const& t : img.texels) binary &= t.w == 0.0f || t.w == 1.0f;
    CHECK(binary);
}

TEST_CASE("a procedural node expands into its generator's content") {
    auto const r = procedural_registry();
    canopy::scene s;
    canopy::node_id const n = s.add_custom(s.root(), "procedural", {{"generator", "sphere"}, {"subdivisions", "1"}}, "ball");
    canopy::node_id const t =
        s.add_transform(s.root(), canopy::affine_transform<float>::from_rows({1, 0, 0, 5, 0, 1, 0, 0, 0, 0, 1, 0}));
    s.add_custom(t, "procedural", {{"generator", "triangle_soup"}, {"count", "30"}}, "soup");
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r});
    CHECK(c.statistics.custom_nodes_expanded == 2);
    CHECK(c.statistics.triangles_stored == 80 + 30);
    CHECK(c.levels == 1);

    canopy::scene expanded = s;
    r.expand_custom_nodes(expanded);
    REQUIRE(expanded.at(n).children.size() == 1);
    CHECK(expanded.at(expanded.at(n).children[0]).name == "sphere");
}

TEST_CASE("a procedural node runs a generator of another plugin through the registry") {
    auto r = procedural_registry();
    // A generator of another plugin: one triangle of the size given.
    r.add_generator("unit_triangle", "test", "one triangle", [](canopy::scene& s, canopy::node_id parent,
                                                               canopy::parameters const& p) {
        float const size = float(p.get_number("size", 1.0, "unit_triangle"));
        canopy::mesh_data m;
        m.name = "triangle";
        m.positions = {{0, 0, 0}, {size, 0, 0}, {0, size, 0}};
        m.triangles = {{0, 1, 2}};
        return s.add_mesh_node(parent, s.add_mesh(std::move(m)));
    });
    canopy::scene s;
    s.add_custom(s.root(), "procedural", {{"generator", "unit_triangle"}, {"size", "2"}}, "tri");
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r});
    REQUIRE(c.meshes.size() == 1);
    REQUIRE(c.meshes[0].triangles.size() == 1);
    CHECK(c.meshes[0].triangles[0].v1.x == 2.0f);
    canopy::default_intersector isect;
    auto const hit = c.closest_hit(canopy::ray{{0.5f, 0.5f, 1.0f}, 0.0f, {0, 0, -1}, INFINITY}, isect);
    CHECK(hit.hit);
    CHECK(hit.t == 1.0f);
}

TEST_CASE("procedural node errors name the node, the generator and the parameter") {
    auto const r = procedural_registry();
    auto const compiled_message = [&](canopy::parameters p) {
        canopy::scene s;
        s.add_custom(s.root(), "procedural", std::move(p), "trees");
        return message_of([&] { (void)canopy::compile(s, {.plugins = &r}); });
    };
    std::string const unknown = compiled_message({{"generator", "cube"}});
    CHECK(unknown.find("node 'trees'") != std::string::npos);
    CHECK(unknown.find("'cube'") != std::string::npos);
    CHECK(unknown.find("sphere") != std::string::npos); // the known ones are listed
    std::string const missing = compiled_message({{"subdivisions", "2"}});
    CHECK(missing.find("node 'trees'") != std::string::npos);
    CHECK(missing.find("'generator'") != std::string::npos);
    std::string const bad = compiled_message({{"generator", "terrain"}, {"resolution", "-4"}});
    CHECK(bad.find("node 'trees'") != std::string::npos);
    CHECK(bad.find("generator 'terrain'") != std::string::npos);
    CHECK(bad.find("parameter 'resolution'") != std::string::npos);
}

TEST_CASE("the procedural plugin registers its generators and node type under its name") {
    auto const r = procedural_registry();
    for (char const* name : {"sphere", "terrain", "triangle_soup", "billboard_forest"}) CHECK(r.has_generator(name));
    CHECK(r.has_node_type("procedural"));
    for (auto const& g : r.generators()) CHECK(g.plugin == "procedural");
}
