// Tests of run-time plugins (registry::load_plugin, load_plugin_path, CANOPY_PLUGIN_PATH) with the
// example plugin plugins/runtime_example (canopy_plugin_spiral, a shared library): it loads,
// registers its generator and node type, the staircase it generates has the triangle count and
// the volume worked out by hand from the parameters (so it is closed and wound outwards), and
// compiled rays hit it as a brute-force double-precision loop over the generated triangles does.
// Failures are scene errors naming the file: a file that is not a shared library, a shared library
// without the entry point, a missing path; a plugin called with another ABI version refuses.
// The built-in .obj loaders give the same default (obj; bench and openmesh by name) registered in
// any order.
#include <catch2/catch.hpp>

#include <dlfcn.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>
#include <optional>
#include <random>
#include <string>
#include <utility>
#include <vector>

import canopy.scene;
import canopy.plugins;
import canopy.plugins.bench;
import canopy.plugins.obj;
import canopy.plugins.openmesh;
import canopy.testing;
import canopy.testing.scene;

namespace {

namespace fs = std::filesystem;
using test_support::error_of;
using test_support::temp_folder;
using canopy::vec3;
using dvec3 = vec3<double>;

fs::path const spiral_plugin = CANOPY_SPIRAL_PLUGIN;
fs::path const not_a_plugin = CANOPY_NOT_A_PLUGIN;

canopy::registry with_spiral() {
    canopy::registry r;
    r.load_plugin(spiral_plugin);
    return r;
}

// Closest hit of a brute-force loop in double (Möller–Trumbore); `ambiguous` when a triangle at
// about the closest distance is hit within rounding of one of its edges.
struct reference_hit {
    double t = std::numeric_limits<double>::infinity();
    std::uint32_t prim = canopy::invalid_id;
    bool ambiguous = false;
};

reference_hit brute_force(canopy::mesh_data const& m, canopy::ray const& r) {
    dvec3 const o(r.origin), d(r.direction);
    struct candidate {
        double t;
        std::uint32_t prim;
        bool near_edge;
    };
    std::vector<candidate> found;
    for (std::uint32_t i = 0; i < m.triangles.size(); ++i) {
        dvec3 const a(m.positions[m.triangles[i][0]]), b(m.positions[m.triangles[i][1]]), c(m.positions[m.triangles[i][2]]);
        dvec3 const e1 = b - a, e2 = c - a, p = canopy::cross(d, e2);
        double const det = canopy::dot(e1, p);
        if (det == 0.0) continue;
        dvec3 const s = o - a, q = canopy::cross(s, e1);
        double const u = canopy::dot(s, p) / det, v = canopy::dot(d, q) / det, t = canopy::dot(e2, q) / det;
        double const margin = 1e-6;
        if (u < -margin || v < -margin || u + v > 1.0 + margin || t < double(r.tmin) || t > double(r.tmax)) continue;
        bool const near_edge = u < margin || v < margin || u + v > 1.0 - margin;
        found.push_back({t, i, near_edge});
    }
    reference_hit best;
    for (auto const& f : found)
        if (!f.near_edge && f.t < best.t) best = {f.t, f.prim, false};
    for (auto const& f : found)
        if (f.near_edge && f.t <= best.t * (1.0 + 1e-6)) best.ambiguous = true;
    return best;
}

} // namespace

TEST_CASE("the example plugin loads through load_plugin and registers its generator and node type") {
    canopy::registry r;
    CHECK_FALSE(r.has_generator("spiral_staircase"));
    r.load_plugin(spiral_plugin);
    CHECK(r.has_generator("spiral_staircase"));
    CHECK(r.has_node_type("spiral_staircase"));
    REQUIRE(r.plugins().size() == 1);
    CHECK(fs::path(r.plugins()[0]).filename() == spiral_plugin.filename());
    for (auto const& g : r.generators()) CHECK(g.plugin == "spiral");
    r.load_plugin(spiral_plugin); // the same file again: nothing changes
    CHECK(r.plugins().size() == 1);
}

TEST_CASE("the spiral staircase has 12 triangles per step and each step the volume of its slab") {
    auto const r = with_spiral();
    canopy::scene s;
    r.generate(s, "spiral_staircase",
               {{"steps", "9"}, {"step_angle", "30"}, {"rise", "0.25"}, {"thickness", "0.1"}, {"inner_radius", "0.5"},
                {"outer_radius", "2"}});
    REQUIRE(s.meshes().size() == 1);
    auto const& m = s.meshes()[0];
    REQUIRE(m.triangles.size() == 9 * 12);
    CHECK(m.positions.size() == 9 * 8);
    // Divergence theorem: Σ v0·(v1×v2)/6 over a closed, outward-wound slab is its volume. The slab
    // is a prism over the quadrilateral between the radii: area ½·sin 30°·(2² − 0.5²).
    double const expected = 0.5 * std::sin(std::numbers::pi / 6.0) * (4.0 - 0.25) * 0.1;
    for (std::size_t step = 0; step < 9; ++step) {
        CAPTURE(step);
        double volume = 0.0;
        for (std::size_t i = 12 * step; i < 12 * (step + 1); ++i) {
            dvec3 const a(m.positions[m.triangles[i][0]]), b(m.positions[m.triangles[i][1]]), c(m.positions[m.triangles[i][2]]);
            volume += canopy::dot(a, canopy::cross(b, c)) / 6.0;
        }
        CHECK(volume == Approx(expected).epsilon(1e-5));
        // Top of step k at (k + 1)·rise.
        float top = -1e9f;
        for (std::size_t i = 12 * step; i < 12 * (step + 1); ++i)
            for (auto v : m.triangles[i]) top = std::max(top, m.positions[v].y);
        CHECK(top == Approx(0.25 * double(step + 1)).epsilon(1e-6));
    }
}

TEST_CASE("rays hit the compiled staircase where a brute-force loop over its triangles does") {
    auto const r = with_spiral();
    canopy::scene s;
    r.generate(s, "spiral_staircase", {{"steps", "24"}});
    auto const& m = s.meshes()[0];
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r});
    CHECK(c.levels == 0);

    std::mt19937 rng(4);
    std::uniform_real_distribution<float> around(-4.0f, 4.0f);
    std::uniform_int_distribution<std::size_t> which(0, m.triangles.size() - 1);
    canopy::default_intersector isect;
    std::size_t agree = 0, ambiguous = 0, hits = 0, total = 0;
    for (int i = 0; i < 2000; ++i) {
        // Half the rays aim at a triangle's centroid, half anywhere.
        vec3<float> const o(around(rng), around(rng) + 3.0f, around(rng));
        vec3<float> target(around(rng), around(rng) + 3.0f, around(rng));
        if (i % 2 == 0) {
            auto const& t = m.triangles[which(rng)];
            target = (m.positions[t[0]] + m.positions[t[1]] + m.positions[t[2]]) * (1.0f / 3.0f);
        }
        canopy::ray const ray{o, 0.0f, target - o, 1e30f};
        auto const ref = brute_force(m, ray);
        ++total;
        if (ref.ambiguous) {
            ++ambiguous;
            continue;
        }
        auto const hr = c.closest_hit(ray, isect);
        // t is known to float rounding of the vertices, amplified at grazing incidence by 1/|cos|.
        double tolerance = 0.0;
        if (ref.prim != canopy::invalid_id) {
            auto const& t = m.triangles[ref.prim];
            dvec3 const a(m.positions[t[0]]), b(m.positions[t[1]]), c3(m.positions[t[2]]);
            double const cosine = std::abs(canopy::dot(canopy::normalize(canopy::cross(b - a, c3 - a)),
                                                       canopy::normalize(dvec3(ray.direction))));
            tolerance = 1e-5 * ref.t / std::max(cosine, 1e-6);
        }
        bool const same = hr.hit == (ref.prim != canopy::invalid_id) &&
                          (!hr.hit || (hr.prim_id == ref.prim && std::abs(double(hr.t) - ref.t) <= tolerance));
        agree += same;
        hits += hr.hit;
    }
    CHECK(agree + ambiguous == total);
    CHECK(ambiguous < total / 100);
    CHECK(hits > total / 3);
}

TEST_CASE("the plugin's node type expands in compile(), its errors cross the library boundary as scene errors") {
    auto const r = with_spiral();
    canopy::scene s;
    s.add_custom(s.root(), "spiral_staircase", {{"steps", "5"}}, "stairs");
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r});
    CHECK(c.statistics.custom_nodes_expanded == 1);
    CHECK(c.statistics.triangles_stored == 5 * 12);

    canopy::scene t;
    std::size_t const nodes = t.nodes().size();
    for (auto const& [key, value] : std::vector<std::pair<std::string, std::string>>{
             {"steps", "0"}, {"rise", "-1"}, {"outer_radius", "0.1"}, {"step_angle", "x"}, {"stairs", "3"}}) {
        CAPTURE(key, value);
        auto const e = error_of([&] { r.generate(t, "spiral_staircase", {{key, value}}); });
        CHECK(std::string(e.what()).find("generator 'spiral_staircase'") != std::string::npos);
        CHECK(e.where() == "parameter '" + key + "'");
        CHECK(t.nodes().size() == nodes);
    }
}

TEST_CASE("load_plugin_path loads every shared library of a folder and the files of a list") {
    canopy::registry from_folder;
    from_folder.load_plugin_path(spiral_plugin.parent_path().string());
    CHECK(from_folder.has_generator("spiral_staircase"));
    canopy::registry from_list;
    from_list.load_plugin_path("::" + spiral_plugin.string() + ":");
    CHECK(from_list.has_generator("spiral_staircase"));
    canopy::registry missing;
    auto const e = error_of([&] { missing.load_plugin_path(spiral_plugin.string() + ":/no/such/plugin.so"); });
    CHECK(e.file() == "/no/such/plugin.so");
}

TEST_CASE("CANOPY_PLUGIN_PATH is loaded by builtin_registry()") {
    // This is the only test of this program that calls builtin_registry(): the variable is read
    // on its first call.
    REQUIRE(setenv("CANOPY_PLUGIN_PATH", spiral_plugin.parent_path().string().c_str(), 1) == 0);
    canopy::registry const& r = canopy::builtin_registry();
    CHECK(r.has_generator("spiral_staircase"));
    CHECK(r.has_node_type("spiral_staircase"));
    canopy::scene s;
    r.generate(s, "spiral_staircase", {{"steps", "3"}});
    CHECK(s.meshes().at(0).triangles.size() == 36);
}

TEST_CASE("files that are not plugins are scene errors naming the file, the registry is unchanged") {
    temp_folder const tmp("canopy_scene_plugin_test");
    fs::path const& folder = tmp.path;
    fs::path const text = folder / "notes.so";
    std::ofstream(text) << "not a shared library\n";
    struct failure {
        fs::path file;
        char const* problem;
    };
    for (auto const& [file, problem] : {failure{text, "cannot load plugin"},
                                        failure{not_a_plugin, "no canopy_plugin_register entry point"},
                                        failure{folder / "absent.so", "not found"},
                                        failure{folder, "folder"}}) {
        CAPTURE(file);
        canopy::registry r;
        auto const e = error_of([&] { r.load_plugin(file); });
        CHECK(e.file() == file.string());
        CHECK(e.problem().find(problem) != std::string::npos);
        CHECK(r.plugins().empty());
        CHECK(r.generators().empty());
    }
}

TEST_CASE("the entry point refuses another ABI version and leaves the registry untouched") {
    void* handle = dlopen(spiral_plugin.c_str(), RTLD_NOW | RTLD_LOCAL);
    REQUIRE(handle != nullptr);
    using entry_point = int (*)(unsigned, void*);
    auto const entry = reinterpret_cast<entry_point>(dlsym(handle, "canopy_plugin_register"));
    REQUIRE(entry != nullptr);
    canopy::registry r;
    CHECK(entry(canopy::plugin_abi_version + 1, &r) != 0);
    CHECK(entry(canopy::plugin_abi_version - 1, &r) != 0);
    CHECK(r.generators().empty());
    CHECK(r.node_types().empty());
    CHECK(entry(canopy::plugin_abi_version, &r) == 0);
    CHECK(r.has_generator("spiral_staircase"));
    // The registry holds functions of the library: it stays loaded (dlclose only drops this
    // reference once r is gone).
    r = canopy::registry{};
    CHECK(dlclose(handle) == 0);
}

TEST_CASE("the built-in .obj loaders: obj is the default and bench and openmesh are asked for by name, in any order") {
    temp_folder const tmp("canopy_scene_plugin_test");
    // A quad (the bench subset refuses it) with a material (only the obj plugin reads it).
    tmp.write("red.mtl", "newmtl red\nKd 1 0 0\n");
    fs::path const quad = tmp.write("quad.obj", "mtllib red.mtl\nusemtl red\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
    using registration = void (*)(canopy::registry&);
    std::array<std::pair<std::string, registration>, 3> plugins{{{"bench", canopy::register_bench_plugin},
                                                                 {"obj", canopy::register_obj_plugin},
                                                                 {"openmesh", canopy::register_openmesh_plugin}}};
    auto const obj_loaders = [](canopy::registry const& r) {
        std::string order;
        for (auto const& l : r.loaders())
            if (l.name == ".obj") order += (order.empty() ? "" : " ") + l.plugin;
        return order;
    };
    int orders = 0;
    do {
        canopy::registry r;
        for (auto const& p : plugins) p.second(r);
        INFO("registered in the order " << plugins[0].first << " " << plugins[1].first << " " << plugins[2].first);
        CHECK(obj_loaders(r) == "obj bench openmesh");
        canopy::scene s;
        r.load(s, quad);
        CHECK(s.materials().size() == 1);
        CHECK(s.meshes().size() == 1);
        CHECK(error_of([&] { r.load(s, quad, s.root(), "bench"); }).problem().find("only triangles") != std::string::npos);
        canopy::scene t;
        r.load(t, quad, t.root(), "openmesh");
        CHECK(t.materials().empty());
        CHECK(t.meshes().size() == 1);
        ++orders;
    } while (std::next_permutation(plugins.begin(), plugins.end(),
                                   [](auto const& a, auto const& b) { return a.first < b.first; }));
    CHECK(orders == 6);
    CHECK(obj_loaders(canopy::builtin_registry()) == "obj bench openmesh");
}
