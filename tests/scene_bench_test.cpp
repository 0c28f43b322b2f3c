// Tests of canopy.plugins.bench: .inst files written here load into one shared mesh and one
// instance node per matrix line (counts and transforms as written), and compile() traces them
// exactly as a reference built by hand from the reader's output (the mesh BVH, instances with id
// = matrix line, a top-level BVH over them): same t, u, v, prim_id and inst_id, ray by ray. With
// keep_single_instance (what `canopy trace` compiles with), hits report `inst` as the formats say:
// the matrix line, also for a single identity instance, and none for an .obj, which costs the
// same tests per ray as its mesh BVH traced alone. The strict .obj subset loads under the plugin
// name "bench". Malformed files (written here, and broken
// models from Debian's assimp-testmodels) give scene errors naming the file at fault and the line.
#include <catch2/catch.hpp>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <string>
#include <vector>

import canopy.scene;
import canopy.procedural;
import canopy.plugins.bench;
import canopy.testing;
import canopy.testing.scene;

namespace {

namespace fs = std::filesystem;
using test_support::error_of;
using test_support::temp_folder;
using canopy::vec3;
using xf = canopy::affine_transform<float>;

void write(fs::path const& file, std::string const& text) {
    std::ofstream out(file, std::ios::binary);
    out << text;
}

std::string number(float v) {
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, "%.9g", double(v));
    return buffer;
}

// The icosphere (1 subdivision, 80 triangles) as OBJ text with shared vertices: `v` lines,
// then `f` lines in three spellings (plain, a/b/c, negative) that all mean the same.
std::string sphere_obj(std::size_t& triangles) {
    auto const tris = canopy::make_icosphere(1, {0.0f, 0.0f, 0.0f}, 1.0f);
    std::string text = "# icosphere\n";
    for (auto const& t : tris)
        for (auto const& v : {t.v0, t.v1, t.v2}) text += "v " + number(v.x) + " " + number(v.y) + " " + number(v.z) + "\n";
    for (std::size_t i = 0; i < tris.size(); ++i) {
        std::size_t const a = 3 * i + 1;
        if (i % 3 == 0) text += "f " + std::to_string(a) + " " + std::to_string(a + 1) + " " + std::to_string(a + 2) + "\n";
        else if (i % 3 == 1)
            text += "f " + std::to_string(a) + "/1/1 " + std::to_string(a + 1) + "/2/2 " + std::to_string(a + 2) + "//3\n";
        else {
            long const n = long(3 * tris.size()); // vertices so far
            text += "f " + std::to_string(long(a) - 1 - n) + " " + std::to_string(long(a) - n) + " " +
                    std::to_string(long(a) + 1 - n) + "\n";
        }
    }
    triangles = tris.size();
    return text;
}

// Row-major 3×4 matrices of the instances written to the test's .inst file.
std::vector<std::array<float, 12>> instance_rows() {
    return {
        {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0},               // identity
        {1, 0, 0, 3, 0, 1, 0, 0, 0, 0, 1, 0},               // translation
        {0.5f, 0, 0, -3, 0, 0.5f, 0, 1, 0, 0, 0.5f, 0.25f}, // scale
        {0, -2, 0, 0, 2, 0, 0, 3, 0, 0, 2, -1},             // rotation about z by 90°, scale 2
        {0.8f, -0.6f, 0, 1.5f, 0.6f, 0.8f, 0, -2.5f, 0, 0, 1, 0.5f},
    };
}

// A temporary folder holding sphere.obj, the icosphere of sphere_obj (`triangles` of them).
struct sphere_folder {
    temp_folder tmp{"canopy_scene_bench_test"};
    fs::path const& folder = tmp.path;
    std::size_t triangles = 0;
    sphere_folder() { write(folder / "sphere.obj", sphere_obj(triangles)); }
};

// spheres.inst, next to the fixture's sphere.obj: one instance per row of instance_rows().
fs::path write_inst(fs::path const& folder) {
    std::string text = "# five spheres\nmesh sphere.obj\n";
    for (auto const& rows : instance_rows()) {
        for (float v : rows) text += number(v) + " ";
        text += "\n";
    }
    write(folder / "spheres.inst", text);
    return folder / "spheres.inst";
}

canopy::registry bench_registry() {
    canopy::registry r;
    canopy::register_bench_plugin(r);
    return r;
}

std::vector<canopy::ray> random_rays(std::uint32_t seed, std::size_t count) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> box(-6.0f, 6.0f), target(-3.5f, 3.5f);
    std::vector<canopy::ray> rays;
    for (std::size_t i = 0; i < count; ++i) {
        vec3<float> const o(box(rng), box(rng), 10.0f);
        vec3<float> const t(target(rng), target(rng) + 0.5f, target(rng));
        rays.push_back(canopy::ray{o, 0.0f, t - o, 1e30f});
    }
    return rays;
}

} // namespace

TEST_CASE(".inst loads one shared mesh and one instance node per matrix line, in file order") {
    sphere_folder const sphere;
    auto const file = write_inst(sphere.folder);
    auto const r = bench_registry();
    canopy::scene s;
    canopy::node_id const group = r.load(s, file);
    CHECK(s.at(group).name == "spheres.inst");
    REQUIRE(s.meshes().size() == 1);
    CHECK(s.meshes()[0].triangles.size() == sphere.triangles);
    auto const rows = instance_rows();
    REQUIRE(s.at(group).children.size() == rows.size());
    canopy::node_id prototype = canopy::no_node;
    for (std::size_t k = 0; k < rows.size(); ++k) {
        auto const& n = s.at(s.at(group).children[k]);
        REQUIRE(n.kind == canopy::node_kind::instance);
        CHECK(n.instance_id == k);
        if (k == 0) prototype = n.target;
        CHECK(n.target == prototype);
        auto const expected = xf::from_rows(rows[k]);
        for (int c = 0; c < 3; ++c) {
            CHECK(n.transform.linear.col0[c] == expected.linear.col0[c]);
            CHECK(n.transform.linear.col1[c] == expected.linear.col1[c]);
            CHECK(n.transform.linear.col2[c] == expected.linear.col2[c]);
            CHECK(n.transform.translation[c] == expected.translation[c]);
        }
    }
    CHECK(s.at(prototype).kind == canopy::node_kind::mesh);

    canopy::compiled_scene const c = canopy::compile(s);
    CHECK(c.levels == 1);
    CHECK(c.statistics.meshes_built == 1);
    CHECK(c.statistics.placements == rows.size());
    CHECK(c.statistics.identity_placements == 1);
}

TEST_CASE(".inst through compile() gives the direct bench path's closest hits, ray by ray") {
    sphere_folder const sphere;
    auto const file = write_inst(sphere.folder);
    auto const r = bench_registry();
    canopy::compiled_scene const c = canopy::compile(canopy::load_scene(file, r));

    // The reference: mesh BVH, instances with id = line index, top BVH, built by hand.
    auto const inst = canopy::read_bench_inst(file);
    auto const mesh = canopy::build_binned_sah(inst.mesh.triangles);
    std::vector<canopy::instance<canopy::bvh<canopy::triangle>>> instances;
    for (std::size_t k = 0; k < inst.instances.size(); ++k) instances.emplace_back(mesh, inst.instances[k], std::uint32_t(k));
    auto const top = canopy::build_binned_sah(instances);

    canopy::default_intersector isect;
    std::size_t same = 0, hits = 0;
    std::vector<int> per_instance(instances.size(), 0);
    auto const rays = random_rays(1, 3000);
    for (auto const& ray : rays) {
        auto const a = c.closest_hit(ray, isect);
        auto const b = canopy::closest_hit(ray, &top, &top + 1);
        bool const equal = a.hit == b.hit && (!a.hit || (a.t == b.t && a.u == b.u && a.v == b.v && a.prim_id == b.prim_id &&
                                                         a.inst_id == b.inst_id && c.instance_id(a) == b.inst_id));
        same += equal;
        if (b.hit) {
            ++hits;
            ++per_instance.at(b.inst_id);
        }
    }
    CHECK(same == rays.size());
    CHECK(hits > rays.size() / 4);
    for (int n : per_instance) CHECK(n > 0); // every instance is seen, so inst ids are compared

    // With other content in the scene (a mesh placed before the file, far from the rays),
    // placement indices shift but compiled_scene::instance_id still gives the line index.
    canopy::scene combined;
    canopy::mesh_data far;
    far.name = "far away";
    far.positions = {{100, 0, 0}, {101, 0, 0}, {100, 1, 0}};
    far.triangles = {{0, 1, 2}};
    combined.add_mesh_node(combined.root(), combined.add_mesh(std::move(far)));
    r.load(combined, file);
    canopy::compiled_scene const cc = canopy::compile(combined);
    std::size_t same_id = 0, shifted = 0;
    for (auto const& ray : rays) {
        auto const a = cc.closest_hit(ray, isect);
        auto const b = canopy::closest_hit(ray, &top, &top + 1);
        same_id += a.hit == b.hit && (!a.hit || (cc.instance_id(a) == b.inst_id && a.prim_id == b.prim_id && a.t == b.t));
        shifted += a.hit && a.inst_id != b.inst_id;
    }
    CHECK(same_id == rays.size());
    CHECK(shifted > 0);
}

TEST_CASE("keep_single_instance: hits report inst as the bench formats say, with no extra level for an .obj") {
    sphere_folder const sphere;
    fs::path const& folder = sphere.folder;
    write(folder / "one.inst", "mesh sphere.obj\n1 0 0 0  0 1 0 0  0 0 1 0\n");
    write(folder / "moved.inst", "mesh sphere.obj\n1 0 0 0  0 1 0 0  0 0 1 0\n1 0 0 0  0 1 0 0  0 0 1 -5\n");
    auto const r = bench_registry();
    auto const compiled = [&](fs::path const& file, bool keep) {
        canopy::scene s;
        r.load(s, file, s.root(), "bench");
        return canopy::compile(s, {.name = file.string(), .keep_single_instance = keep});
    };
    canopy::ray const down_z{{0.1f, 0.2f, 10.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, 1e30f};      // hits the sphere at the origin
    canopy::ray const behind{{0.1f, 0.2f, -2.5f}, 0.0f, {0.0f, 0.0f, -1.0f}, 1e30f};      // only the one at z = -5
    canopy::default_intersector isect;

    // One identity instance: inst 0 (its matrix line) with the option, none without it (levels 0).
    canopy::compiled_scene const kept = compiled(folder / "one.inst", true);
    canopy::compiled_scene const plain = compiled(folder / "one.inst", false);
    CHECK(kept.levels == 1);
    CHECK(plain.levels == 0);
    std::size_t kept_decisions = 0;
    for (auto const& d : kept.statistics.decisions) kept_decisions += d.find("keep_single_instance") != std::string::npos;
    CHECK(kept_decisions == 1);
    auto const a = kept.closest_hit(down_z, isect);
    auto const b = plain.closest_hit(down_z, isect);
    REQUIRE(a.hit);
    REQUIRE(b.hit);
    CHECK(a.inst_id == 0);
    CHECK(b.inst_id == canopy::invalid_id);
    CHECK((a.t == b.t && a.u == b.u && a.v == b.v && a.prim_id == b.prim_id)); // the identity reuses the ray
    CHECK(a.t == Approx(9.0).margin(0.25));

    // Two instances: each hit names its matrix line, with or without the option.
    canopy::compiled_scene const two = compiled(folder / "moved.inst", true);
    CHECK(two.levels == 1);
    CHECK(two.closest_hit(down_z, isect).inst_id == 0);
    auto const far = two.closest_hit(behind, isect);
    REQUIRE(far.hit);
    CHECK(far.inst_id == 1);
    CHECK(far.t == Approx(1.5).margin(0.25)); // the sphere at z = -5 has its top at z = -4

    // An .obj has no instances: no top level, inst none, and the very tests of its mesh BVH alone.
    canopy::compiled_scene const mesh = compiled(folder / "sphere.obj", true);
    CHECK(mesh.levels == 0);
    auto const direct = canopy::build_binned_sah(canopy::read_bench_obj(folder / "sphere.obj").triangles);
    std::size_t same_costs = 0, hits = 0;
    auto const rays = random_rays(3, 500);
    for (auto const& ray : rays) {
        canopy::cost_counter compiled_costs, direct_costs;
        auto const hit = mesh.closest_hit(ray, compiled_costs);
        canopy::closest_hit(ray, &direct, &direct + 1, direct_costs);
        same_costs += compiled_costs.num_boxes == direct_costs.num_boxes && compiled_costs.num_tris == direct_costs.num_tris;
        if (hit.hit) {
            ++hits;
            CHECK(hit.inst_id == canopy::invalid_id);
        }
    }
    CHECK(same_costs == rays.size());
    CHECK(hits > 20);
}

TEST_CASE("bench .obj loads the strict subset: prim_id is the f line order") {
    sphere_folder const sphere;
    fs::path const& folder = sphere.folder;
    auto r = bench_registry();
    // A general OBJ loader (of standard rank) is the default over bench's, an alternative; "bench"
    // still picks this one.
    r.add_loader(".obj", "other", "a stand-in general loader", [](canopy::scene&, fs::path const&, canopy::node_id, canopy::registry const&) -> canopy::node_id {
        throw canopy::scene_error("", "", "the other loader");
    });
    canopy::scene s;
    CHECK(std::string(error_of([&] { r.load(s, folder / "sphere.obj"); }).what()).find("the other loader") != std::string::npos);
    r.load(s, folder / "sphere.obj", s.root(), "bench");
    REQUIRE(s.meshes().size() == 1);
    CHECK(s.meshes()[0].triangles.size() == sphere.triangles);

    canopy::compiled_scene const c = canopy::compile(s);
    CHECK(c.levels == 0);
    auto const direct = canopy::build_binned_sah(canopy::read_bench_obj(folder / "sphere.obj").triangles);
    auto const reference = canopy::make_icosphere(1, {0.0f, 0.0f, 0.0f}, 1.0f);
    canopy::default_intersector isect;
    std::size_t same = 0, hits = 0, same_triangle = 0;
    auto const rays = random_rays(2, 1000);
    for (auto const& ray : rays) {
        auto const a = c.closest_hit(ray, isect);
        auto const b = canopy::closest_hit(ray, &direct, &direct + 1);
        same += a.hit == b.hit && (!a.hit || (a.t == b.t && a.prim_id == b.prim_id && a.u == b.u && a.v == b.v));
        if (a.hit) {
            ++hits;
            // The f line order is the icosphere's triangle order (the file was written from it).
            auto const& t = reference.at(a.prim_id);
            auto const& m = c.meshes[0].triangles[a.prim_id];
            same_triangle += t.v0.x == m.v0.x && t.v1.y == m.v1.y && t.v2.z == m.v2.z;
        }
    }
    CHECK(same == rays.size());
    CHECK(hits > 0);
    CHECK(same_triangle == hits);
}

TEST_CASE("malformed bench files are scene errors naming the file at fault and the line") {
    sphere_folder const sphere;
    fs::path const& folder = sphere.folder;
    write(folder / "quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
    write(folder / "index.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\nf 1 2 7\n");
    write(folder / "empty.obj", "# nothing\nv 0 0 0\n");
    write(folder / "short_row.inst", "mesh sphere.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n");
    write(folder / "no_mesh.inst", "1 0 0 0 0 1 0 0 0 0 1 0\n");
    write(folder / "two_meshes.inst", "mesh sphere.obj\nmesh sphere.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n");
    write(folder / "missing_mesh.inst", "mesh nowhere.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n");
    write(folder / "bad_mesh.inst", "mesh quad.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n");
    write(folder / "nan.inst", "mesh sphere.obj\n# comment\n1 0 0 0 0 1 0 nan 0 0 1 0\n");
    write(folder / "singular.inst", "mesh sphere.obj\n1 0 0 0 0 1 0 0 0 0 0 0\n");
    write(folder / "no_instances.inst", "mesh sphere.obj\n# none\n");

    struct expectation {
        char const* load;
        char const* file; // the file the error names
        char const* where;
        char const* problem;
    };
    auto const r = bench_registry();
    for (auto const& [load, file, where, problem] : {
             expectation{"quad.obj", "quad.obj", "5", "only triangles"},
             expectation{"index.obj", "index.obj", "5", "out of range"},
             expectation{"empty.obj", "empty.obj", "", "no faces ('f' lines): nothing to trace"},
             expectation{"short_row.inst", "short_row.inst", "3", "12 numbers"},
             expectation{"no_mesh.inst", "no_mesh.inst", "", "no 'mesh' line"},
             expectation{"two_meshes.inst", "two_meshes.inst", "2", "second 'mesh'"},
             expectation{"missing_mesh.inst", "nowhere.obj", "", "file not found (mesh of missing_mesh.inst)"},
             expectation{"bad_mesh.inst", "quad.obj", "5", "only triangles"},
             expectation{"nan.inst", "nan.inst", "3", "number 'nan' is not finite"},
             expectation{"singular.inst", "singular.inst", "2", "singular"},
             expectation{"no_instances.inst", "no_instances.inst", "", "no instance lines (12 numbers each): nothing to trace"},
             expectation{"absent.inst", "absent.inst", "", "not found"},
         }) {
        CAPTURE(load);
        canopy::scene s;
        std::size_t const nodes = s.nodes().size();
        auto const e = error_of([&] { r.load(s, folder / load, s.root(), "bench"); });
        CHECK(fs::path(e.file()).filename() == file);
        CHECK(e.where() == where);
        CHECK(e.problem().find(problem) != std::string::npos);
        CHECK(s.nodes().size() == nodes);
        CHECK(s.meshes().empty());
    }
}

TEST_CASE("broken and odd OBJ files of assimp-testmodels: errors with lines, or the triangles they hold") {
    fs::path const models = "/usr/share/assimp/models/OBJ";
    REQUIRE(fs::exists(models / "box.obj"));
    auto const r = bench_registry();
    auto const load = [&](char const* name) {
        canopy::scene s;
        return error_of([&] { r.load(s, models / name, s.root(), "bench"); });
    };
    // Quads (the first `f` line is line 23 of box.obj).
    auto const box = load("box.obj");
    CHECK(box.file() == (models / "box.obj").string());
    CHECK(box.where() == "23");
    CHECK(box.problem().find("only triangles") != std::string::npos);
    // "3.1+e2" on line 11 is not a number.
    auto const numbers = load("number_formats.obj");
    CHECK(numbers.where() == "11");
    CHECK(numbers.problem().find("'3.1+e2'") != std::string::npos);
    // UTF-16 text is not read; a point cloud has no `f` line.
    CHECK(load("box_UTF16BE.obj").problem() == "not a text OBJ file: UTF-16 byte-order mark (only ASCII or UTF-8 text is read)");
    CHECK(load("testpoints.obj").problem() == "no faces ('f' lines): nothing to trace");

    // Extra spaces everywhere: one triangle, (1,2,3) (2,3,1) (3,1,2).
    canopy::scene s;
    r.load(s, models / "multiple_spaces.obj", s.root(), "bench");
    REQUIRE(s.meshes().size() == 1);
    auto const& m = s.meshes()[0];
    REQUIRE(m.triangles.size() == 1);
    auto const& t = m.triangles[0];
    CHECK(m.positions[t[0]].x == 1.0f);
    CHECK(m.positions[t[1]].x == 2.0f);
    CHECK(m.positions[t[2]].x == 3.0f);
    CHECK(m.positions[t[2]].y == 1.0f);
    // A cube of 12 triangles among usemtl and mtllib lines.
    canopy::scene cube;
    r.load(cube, models / "cube_usemtl.obj", cube.root(), "bench");
    CHECK(cube.meshes().at(0).triangles.size() == 12);
}

TEST_CASE("bench readers: counts grow within the limits, byte sizes of rays and hits are checked, messages stay short") {
    temp_folder const tmp("canopy_scene_bench_test");
    fs::path const& folder = tmp.path;
    auto const message = [](auto&& f) { return test_support::what_of<canopy::scene_error>(f); };
    write(folder / "three.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3\nf 1 2 3\n");
    write(folder / "two.inst", "mesh three.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 5 0 1 0 0 0 0 1 0\n");
    auto const saved = canopy::default_limits();
    canopy::default_limits().max_triangles = 2;
    CHECK(message([&] { canopy::read_bench_obj(folder / "three.obj"); }) ==
          (folder / "three.obj").string() + ":3: 3 vertices exceed the limit of 2 (--max-triangles)");
    canopy::default_limits().max_triangles = 3;
    CHECK(canopy::read_bench_obj(folder / "three.obj").triangles.size() == 3);
    canopy::default_limits().max_placements = 1;
    CHECK(message([&] { canopy::read_bench_inst(folder / "two.inst"); }) ==
          (folder / "two.inst").string() + ":3: 2 instances exceed the limit of 1 (--max-placements)");
    canopy::default_limits() = saved;
    CHECK(canopy::read_bench_inst(folder / "two.inst").instances.size() == 2);

    // Rays and hits from bytes (what the fuzzer feeds): sizes that are not whole records are errors.
    CHECK(message([&] { canopy::parse_bench_rays(std::string(31, '\0'), "r.rays"); }) ==
          "r.rays: size 31 bytes is not a multiple of 32 (one ray = 32 bytes)");
    CHECK(message([&] { canopy::parse_bench_hits(std::string(21, '\0'), "h.hits"); }) ==
          "h.hits: size 21 bytes is not a multiple of 20 (one hit = 20 bytes)");
    float const f[8] = {1, 2, 3, 0.5f, 0, 0, -1, 9};
    std::string bytes(64, '\0');
    std::memcpy(bytes.data() + 32, f, 32);
    auto const rays = canopy::parse_bench_rays(bytes, "r.rays");
    REQUIRE(rays.size() == 2);
    CHECK((rays[1].origin.x == 1 && rays[1].origin.y == 2 && rays[1].origin.z == 3 && rays[1].tmin == 0.5f));
    CHECK((rays[1].direction.z == -1 && rays[1].tmax == 9));
    write(folder / "two.rays", bytes);
    auto const read = canopy::read_bench_rays(folder / "two.rays");
    REQUIRE(read.size() == 2);
    CHECK((read[1].origin.y == 2 && read[1].tmax == 9 && read[0].tmax == 0));

    // Numbers: 1e300 overflows a float, an over-long token is quoted by its prefix only.
    CHECK(message([&] { canopy::parse_bench_obj("v 0 1e300 0\n", "o.obj"); }) == "o.obj:1: value 1e300 overflows a float");
    CHECK(message([&] { canopy::parse_bench_obj("v 0 1e-300 0\nv 1 0 0\nv nan 0 0\n", "o.obj"); }) ==
          "o.obj:3: number 'nan' is not finite");
    CHECK(message([&] { canopy::parse_bench_inst("mesh m.obj\n1 0 0 0 0 1 0 0 0 0 1 " + std::string(100000, '9') + "\n", "i.inst"); }) ==
          "i.inst:2: value " + std::string(40, '9') + "… overflows a float");
    CHECK(message([&] { canopy::parse_bench_inst("mesh " + std::string(5000, 'm') + "\n", "i.inst"); }) ==
          "i.inst:1: mesh path of 5000 bytes is too long ('" + std::string(40, 'm') + "…')");
}

TEST_CASE("bench readers read text by canopy.scene:text's rules: hexadecimal refused, a byte-order mark skipped") {
    auto const message = [](auto&& f) { return test_support::what_of<canopy::scene_error>(f); };
    // strtod read "0x1p3" as 8; the formats' numbers are decimal.
    CHECK(message([&] { canopy::parse_bench_obj("v 0 0 0\nv 0x1p3 0 0\nv 0 1 0\nf 1 2 3\n", "h.obj"); }) ==
          "h.obj:2: bad number '0x1p3'");
    CHECK(message([&] { canopy::parse_bench_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 2 3\n", "z.obj"); }) ==
          "z.obj:4: vertex index 0 is not valid (OBJ indices start at 1)");
    // A byte-order mark before the first `v` line: that line is a vertex like the others.
    auto const mesh = canopy::parse_bench_obj("\xEF\xBB\xBFv 7 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "b.obj");
    REQUIRE(mesh.triangles.size() == 1);
    CHECK(mesh.triangles[0].v0.x == 7.0f);
    // Numbers are read straight to the nearest float: just above the midpoint between 1 and the
    // next float up (through double they would round to the midpoint, then to 1).
    auto const rounded = canopy::parse_bench_obj("v 1.0000000596046448 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "r.obj");
    CHECK(rounded.triangles[0].v0.x == 1.0f + 0x1p-23f);
}
