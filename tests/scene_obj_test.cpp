// Tests of canopy.plugins.obj, Canopy's OBJ + MTL reader. Files are written here (values and
// counts known to the test) and read back through a registry; every error the reader reports is
// provoked by a malformed file and checked for the file, the line and the problem. The OBJ files
// of Debian's assimp-testmodels must all load or fail with a scene_error; a few are checked in
// detail against counts taken from the files by hand.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <vector>
#include <sys/stat.h>

import canopy.scene;
import canopy.plugins.obj;
import canopy.plugins.oiio;
import canopy.image;
import canopy.testing;
import canopy.testing.scene;

namespace {

namespace fs = std::filesystem;
using test_support::load_failure;
using test_support::temp_folder;
using test_support::limits_guard;
using namespace std::string_literals;
using canopy::vec2;
using canopy::vec3;

canopy::registry obj_registry() {
    canopy::registry r;
    canopy::register_oiio_plugin(r);
    canopy::register_obj_plugin(r);
    return r;
}

// The world-space corners of triangle t of mesh m.
std::array<vec3<float>, 3> corners(canopy::mesh_data const& m, std::size_t t) {
    auto const& tri = m.triangles.at(t);
    return {m.positions.at(tri[0]), m.positions.at(tri[1]), m.positions.at(tri[2])};
}

bool same(vec3<float> a, vec3<float> b) { return a.x == b.x && a.y == b.y && a.z == b.z; }

// Meshes under the group a load made, in child order.
std::vector<canopy::mesh_data const*> meshes_of(canopy::scene const& s, canopy::node_id group) {
    std::vector<canopy::mesh_data const*> out;
    for (auto child : s.at(group).children) {
        REQUIRE(s.at(child).kind == canopy::node_kind::mesh);
        out.push_back(&s.meshes().at(s.at(child).mesh));
    }
    return out;
}

void write_png(fs::path const& p, int w, int h, std::vector<std::array<float, 4>> const& texels) {
    canopy::rgba_image img;
    img.width = w;
    img.height = h;
    for (auto const& t : texels) img.pixels.insert(img.pixels.end(), t.begin(), t.end());
    canopy::write_image(p, img);
}

} // namespace

TEST_CASE("obj: polygons are fanned, in file order, with negative indices relative to the count so far") {
    temp_folder const tmp("canopy_obj_test");
    auto const file = tmp.write("fans.obj", "# five vertices\n"
                                            "v 0 0 0\n"
                                            "v 1 0 0\n"
                                            "v 1 1 0\n"
                                            "v 0 1 0\n"
                                            "v 0.5 2 0.25\n"
                                            "f 1 2 3\n"
                                            "f 1 2 3 4\n"
                                            "o ignored_object\n"
                                            "g ignored_group\n"
                                            "s 1\n"
                                            "f -5 -4 -3 -1 -2   # pentagon\n");
    auto const r = obj_registry();
    canopy::scene s;
    auto const group = r.load(s, file);
    CHECK(s.at(group).name == "fans");
    auto const meshes = meshes_of(s, group);
    REQUIRE(meshes.size() == 1);
    auto const& m = *meshes[0];
    CHECK(m.name == "fans");
    CHECK(m.material == -1);
    CHECK(m.uvs.empty());
    CHECK(m.normals.empty());
    vec3<float> const v[5] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0.5f, 2, 0.25f}};
    // 1 + 2 + 3 triangles: (0 1 2) | (0 1 2) (0 2 3) | (0 1 2) (0 2 4) (0 4 3)
    int const expected[6][3] = {{0, 1, 2}, {0, 1, 2}, {0, 2, 3}, {0, 1, 2}, {0, 2, 4}, {0, 4, 3}};
    REQUIRE(m.triangles.size() == 6);
    for (std::size_t t = 0; t < 6; ++t) {
        auto const c = corners(m, t);
        for (std::size_t k = 0; k < 3; ++k) CHECK(same(c[k], v[expected[t][k]]));
    }
}

TEST_CASE("obj: a non-convex face is ear-clipped: rays through its notch miss, rays through it hit") {
    // An arrowhead whose fan from corner 1 would be (1 2 3) = the notch itself, then a square
    // elsewhere (convex: fanned as always).
    temp_folder const tmp("canopy_obj_test");
    auto const file = tmp.write("arrow.obj", "v 2 2 0\nv 1 1 0\nv 0 2 0\nv 1 0.25 0\n"
                                             "v 5 0 0\nv 6 0 0\nv 6 1 0\nv 5 1 0\n"
                                             "f 1 2 3 4\nf 5 6 7 8\n");
    auto const r = obj_registry();
    canopy::scene s;
    auto const meshes = meshes_of(s, r.load(s, file));
    REQUIRE(meshes.size() == 1);
    REQUIRE(meshes[0]->triangles.size() == 4);
    auto const c = canopy::compile(s, {.plugins = &r});
    canopy::default_intersector isect;
    auto const hits = [&](float x, float y) {
        canopy::ray const ray{{x, y, -1.0f}, 0.0f, {0.0f, 0.0f, 1.0f}, 10.0f};
        return bool(c.closest_hit(ray, isect).hit);
    };
    CHECK_FALSE(hits(1.0f, 1.5f));  // the notch
    CHECK_FALSE(hits(1.5f, 1.9f));
    CHECK_FALSE(hits(0.5f, 1.9f));
    CHECK(hits(1.0f, 0.5f));        // the arrow's body
    CHECK(hits(1.8f, 1.75f));       // its right barb
    CHECK(hits(0.2f, 1.75f));       // its left barb
    CHECK(hits(5.5f, 0.5f));        // the square
    // The square keeps the fan's triangles (v5 v6 v7) (v5 v7 v8).
    auto const sq0 = corners(*meshes[0], 2), sq1 = corners(*meshes[0], 3);
    CHECK((same(sq0[0], {5, 0, 0}) && same(sq0[1], {6, 0, 0}) && same(sq0[2], {6, 1, 0})));
    CHECK((same(sq1[0], {5, 0, 0}) && same(sq1[1], {6, 1, 0}) && same(sq1[2], {5, 1, 0})));
}

TEST_CASE("obj: a polygon of 50000 corners is fanned into 49998 triangles") {
    temp_folder const tmp("canopy_obj_test");
    constexpr int n = 50000;
    std::string text;
    for (int i = 0; i < n; ++i) text += "v " + std::to_string(i) + " " + std::to_string(i % 7) + " 0\n";
    text += "f";
    for (int i = 1; i <= n; ++i) text += " " + std::to_string(i);
    text += "\n";
    auto const r = obj_registry();
    canopy::scene s;
    auto const meshes = meshes_of(s, r.load(s, tmp.write("big.obj", text)));
    REQUIRE(meshes.size() == 1);
    REQUIRE(meshes[0]->triangles.size() == std::size_t(n - 2));
    CHECK(meshes[0]->fanned_faces == 1); // non-convex and over max_ear_clipped_corners: reported
    CHECK(meshes[0]->first_fanned == std::to_string(n + 1));
    auto const last = corners(*meshes[0], n - 3); // (v0, v[n-2], v[n-1])
    CHECK(same(last[0], {0, 0, 0}));
    CHECK(same(last[1], {float(n - 2), float((n - 2) % 7), 0}));
    CHECK(same(last[2], {float(n - 1), float((n - 1) % 7), 0}));
}

TEST_CASE("obj: corners v/vt, v//vn and v/vt/vn give per-corner uvs (v flipped) and normals") {
    temp_folder const tmp("canopy_obj_test");
    auto const file = tmp.write("forms.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
                                             "vt 0.25 0.125\nvt 0.5\nvt 1 1 0\n"
                                             "vn 0 0 1\nvn 0 0.6 0.8\n"
                                             "f 1/1 2/2 3/3\n"
                                             "f 1//2 2//1 3//2\n"
                                             "f 3/3/1 2/1/2 1/2/2\n"
                                             "f 1 2 3\n");
    auto const r = obj_registry();
    canopy::scene s;
    auto const meshes = meshes_of(s, r.load(s, file));
    REQUIRE(meshes.size() == 1);
    auto const& m = *meshes[0];
    REQUIRE(m.triangles.size() == 4);
    REQUIRE(m.uvs.size() == 4);
    REQUIRE(m.normals.size() == 4);
    // (u, 1 - v) for vt (0.25, 0.125), (0.5, 0), (1, 1).
    vec2<float> const uv[3] = {{0.25f, 0.875f}, {0.5f, 1.0f}, {1.0f, 0.0f}};
    auto const same2 = [](vec2<float> a, vec2<float> b) { return a.x == b.x && a.y == b.y; };
    for (std::size_t k = 0; k < 3; ++k) CHECK(same2(m.uvs[0][k], uv[k]));
    CHECK(same2(m.uvs[2][0], uv[2]));
    CHECK(same2(m.uvs[2][1], uv[0]));
    CHECK(same2(m.uvs[2][2], uv[1]));
    // Faces without vt in a textured mesh get (0, 0).
    for (std::size_t k = 0; k < 3; ++k) CHECK(same2(m.uvs[1][k], {0.0f, 0.0f}));
    CHECK(same(m.normals[1][0], {0, 0.6f, 0.8f}));
    CHECK(same(m.normals[1][1], {0, 0, 1}));
    CHECK(same(m.normals[2][0], {0, 0, 1}));
    // Faces without vn get their geometric normal: (0,0,0) (1,0,0) (0,1,0) faces +z.
    for (std::size_t k = 0; k < 3; ++k) CHECK(same(m.normals[3][k], {0, 0, 1}));
    CHECK(same(corners(m, 2)[0], {0, 1, 0}));
}

TEST_CASE("obj: the benchmark OBJ subset reads identically: triangle i is the i-th f line") {
    temp_folder const tmp("canopy_obj_test");
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> coordinate(-10.0f, 10.0f);
    std::vector<vec3<float>> vertices;
    std::vector<std::array<std::size_t, 3>> faces;
    std::ostringstream text;
    text.precision(9);
    text << "vn 0 0 1\n";
    for (int i = 0; i < 200; ++i) {
        vec3<float> const p{coordinate(rng), coordinate(rng), coordinate(rng)};
        vertices.push_back(p);
        text << "v " << p.x << ' ' << p.y << ' ' << p.z << "\n";
        if (i < 2) continue;
        // Index forms of the subset: plain, a/b/c (only a counts), negative.
        std::array<std::size_t, 3> f{};
        std::uniform_int_distribution<std::size_t> pick(0, vertices.size() - 1);
        for (auto& x : f) x = pick(rng);
        faces.push_back(f);
        std::size_t const n = vertices.size();
        switch (i % 3) {
        case 0: text << "f " << f[0] + 1 << ' ' << f[1] + 1 << ' ' << f[2] + 1 << "\n"; break;
        case 1: text << "f " << f[0] + 1 << "//1 " << f[1] + 1 << "//1 " << f[2] + 1 << "//1\n"; break;
        default:
            text << "f -" << n - f[0] << " -" << n - f[1] << " -" << n - f[2] << "  # relative\n";
        }
    }
    auto const file = tmp.write("bench.obj", text.str());
    auto const r = obj_registry();
    canopy::scene s;
    auto const meshes = meshes_of(s, r.load(s, file));
    REQUIRE(meshes.size() == 1);
    REQUIRE(meshes[0]->triangles.size() == faces.size());
    for (std::size_t t = 0; t < faces.size(); ++t) {
        auto const c = corners(*meshes[0], t);
        for (std::size_t k = 0; k < 3; ++k) REQUIRE(same(c[k], vertices[faces[t][k]]));
    }
}

TEST_CASE("obj: one mesh per material in order of first use, MTL colours, undefined names use the default") {
    temp_folder const tmp("canopy_obj_test");
    tmp.write("colours.mtl", "# two materials\n"
                             "newmtl red\n"
                             "Kd 1 0 0\n"
                             "Ns 10\n"
                             "newmtl Leaf Green\n"
                             "kd 0.25\n");
    auto const file = tmp.write("materials.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                                 "f 1 2 3\n"
                                                 "usemtl red\n"
                                                 "f 1 2 4\n"
                                                 "usemtl Leaf Green  \n"
                                                 "f 1 3 4\n"
                                                 "usemtl red\n"
                                                 "f 2 3 4 1\n"
                                                 "usemtl nowhere\n"
                                                 "f 4 3 2\n"
                                                 "mtllib colours.mtl\n");
    auto const r = obj_registry();
    canopy::scene s;
    auto const meshes = meshes_of(s, r.load(s, file));
    REQUIRE(meshes.size() == 4);
    CHECK(meshes[0]->name.empty());
    CHECK(meshes[0]->material == -1);
    CHECK(meshes[0]->triangles.size() == 1);
    CHECK(meshes[1]->name == "red");
    CHECK(meshes[1]->triangles.size() == 3);
    CHECK(meshes[2]->name == "Leaf Green");
    CHECK(meshes[2]->triangles.size() == 1);
    CHECK(meshes[3]->name == "nowhere");
    CHECK(meshes[3]->material == -1);
    // Only the materials used are added, in order of first use.
    REQUIRE(s.materials().size() == 2);
    auto const& red = s.materials().at(std::size_t(meshes[1]->material));
    CHECK(red.name == "red");
    CHECK(same(red.colour, {1, 0, 0}));
    CHECK(red.image == -1);
    CHECK(red.alpha == canopy::alpha_mode::opaque);
    auto const& green = s.materials().at(std::size_t(meshes[2]->material));
    CHECK(same(green.colour, {0.25f, 0.25f, 0.25f}));
    // Mesh "red": f 1 2 4, then the quad 2 3 4 1 as (2 3 4) (2 4 1); only its vertices are kept.
    CHECK(meshes[1]->positions.size() == 4);
    CHECK(same(corners(*meshes[1], 2)[2], {0, 0, 0}));
    CHECK(meshes[2]->positions.size() == 3);
}

TEST_CASE("obj: map_Kd loads through the registry, map_d or texture alpha makes an alpha mask with cutoff 0.5") {
    temp_folder const tmp("canopy_obj_test");
    fs::create_directories(tmp.path / "maps");
    // 2x1 colour image: red opaque, green opaque; 1x1 grey alpha map 0.4 (102/255).
    write_png(tmp.path / "maps" / "colour.png", 2, 1, {{1, 0, 0, 1}, {0, 1, 0, 1}});
    write_png(tmp.path / "maps" / "alpha.png", 1, 1, {{0.4f, 0.4f, 0.4f, 1}});
    write_png(tmp.path / "maps" / "cutout.png", 2, 2, {{1, 1, 1, 1}, {1, 1, 1, 0}, {1, 1, 1, 1}, {1, 1, 1, 1}});
    fs::create_directories(tmp.path / "mtl");
    tmp.write("mtl/lib.mtl", "newmtl opaque\n"
                             "map_Kd -bm 1 ../maps/colour.png\n"
                             "newmtl masked\n"
                             "Kd 0.5 0.5 0.5\n"
                             "map_Kd ..\\maps\\colour.png\n"
                             "map_d ../maps/alpha.png\n"
                             "newmtl alpha_only\n"
                             "map_d ../maps/alpha.png\n"
                             "newmtl cutout\n"
                             "map_Kd ../maps/cutout.png\n");
    auto const file = tmp.write("textured.obj", "mtllib mtl/lib.mtl\n"
                                                "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                                                "usemtl opaque\nf 1/1 2/2 3/3\n"
                                                "usemtl masked\nf 1/1 2/2 3/3\n"
                                                "usemtl alpha_only\nf 1/1 2/2 3/3\n"
                                                "usemtl cutout\nf 1/1 2/2 3/3\n");
    auto const r = obj_registry();
    canopy::scene s;
    auto const meshes = meshes_of(s, r.load(s, file));
    REQUIRE(meshes.size() == 4);
    auto const& opaque = s.materials().at(std::size_t(meshes[0]->material));
    CHECK(same(opaque.colour, {1, 1, 1})); // no Kd with map_Kd: white
    CHECK(opaque.alpha == canopy::alpha_mode::opaque);
    REQUIRE(opaque.image >= 0);
    auto const& colour = s.images().at(std::size_t(opaque.image));
    REQUIRE(colour.width == 2);
    REQUIRE(colour.height == 1);
    CHECK(colour.texels[0].x == 1.0f);
    CHECK(colour.texels[1].y == 1.0f);

    auto const& masked = s.materials().at(std::size_t(meshes[1]->material));
    CHECK(masked.alpha == canopy::alpha_mode::mask);
    CHECK(masked.alpha_cutoff == 0.5f);
    CHECK(same(masked.colour, {0.5f, 0.5f, 0.5f}));
    auto const& combined = s.images().at(std::size_t(masked.image));
    REQUIRE(combined.texels.size() == 2);
    CHECK(combined.texels[0].x == 1.0f);
    CHECK(combined.texels[0].w == Approx(102.0 / 255.0));
    CHECK(combined.texels[1].w == Approx(102.0 / 255.0));

    auto const& alpha_only = s.materials().at(std::size_t(meshes[2]->material));
    CHECK(alpha_only.alpha == canopy::alpha_mode::mask);
    auto const& alpha_image = s.images().at(std::size_t(alpha_only.image));
    REQUIRE(alpha_image.texels.size() == 1);
    CHECK(alpha_image.texels[0].x == 1.0f);
    CHECK(alpha_image.texels[0].w == Approx(102.0 / 255.0));

    auto const& cutout = s.materials().at(std::size_t(meshes[3]->material));
    CHECK(cutout.alpha == canopy::alpha_mode::mask);
    CHECK(cutout.alpha_cutoff == 0.5f);

    // The masked materials need the mask intersector once compiled.
    auto const c = canopy::compile(s, {.plugins = &r});
    CHECK(c.statistics.masked_materials_used == 3);
    CHECK(c.statistics.alpha_mask_needed);
}

TEST_CASE("obj: bad input names the file, the line and the problem, the scene is left as it was") {
    temp_folder const tmp("canopy_obj_test");
    auto const r = obj_registry();
    std::string const tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    struct bad_case {
        std::string text, where, problem;
    };
    std::vector<bad_case> const cases = {
        {"v 0 0 0\nv 1 0x 0\n", "2", "bad number '0x'"},
        {"v 0 0 0\nv 1 2\n", "2", "'v' needs 3 to 7 numbers"},
        {"v 0 nan 0\n", "1", "number 'nan' is not finite"},
        {"v 0 0 inf\n", "1", "number 'inf' is not finite"},
        {"v 0 0 1e39\n", "1", "value 1e39 overflows a float"},
        {"v 0 0 1e999\n", "1", "value 1e999 overflows a float"},
        {"v 0 0 -1e300\n", "1", "value -1e300 overflows a float"},
        {"vt 0.5 1e300\n", "1", "value 1e300 overflows a float"},
        {"vn 0 +1e300 0\n", "1", "value +1e300 overflows a float"},
        {"vt 0.5 -nan\n", "1", "not finite"},
        {"vn 0 0\n", "1", "'vn' needs 3 numbers"},
        {tri + "f 1 2 0\n", "4", "vertex index 0 is not valid"},
        {tri + "f 1 2 4\n", "4", "vertex index 4 is out of range (3 vertices so far)"},
        {tri + "f 1 2 -4\n", "4", "vertex index -4 is out of range"},
        {tri + "f 1 2 4000000000\n", "4", "vertex index 4000000000 is out of range"},
        {tri + "f 1 2 99999999999999999999999\n", "4", "bad vertex index '99999999999999999999999'"},
        {tri + "f 1 2 x\n", "4", "bad vertex index 'x'"},
        {tri + "vt 0 0\nf 1/2 2/1 3/1\n", "5", "texture coordinate index 2 is out of range"},
        {tri + "vn 0 0 1\nf 1//1 2//1 3//2\n", "5", "normal index 2 is out of range"},
        {tri + "f 1/ 2/ 3/\n", "4", "empty texture coordinate index"},
        {tri + "f 1/1/1/1 2 3\n", "4", "has more than three parts"},
        {tri + "f 1 2\n", "4", "face has 2 corners; at least 3 are needed"},
        {tri + "f\n", "4", "face has 0 corners"},
        {tri + "vt 0 0\nf 1/1 2 3/1\n", "5", "corner '2' has another form than the face's first corner '1/1'"},
        {tri + "\nmtllib missing.mtl\n", "5", "material library '"},
        {"v 0 0 0\nv 0 \0 0\n"s, "2", "NUL byte"},
        {"\xFE\xFF\0v\0 \0\x31"s, "", "UTF-16"},
    };
    for (std::size_t i = 0; i < cases.size(); ++i) {
        auto const& c = cases[i];
        INFO("case " << i << ": " << c.problem);
        auto const file = tmp.write("bad" + std::to_string(i) + ".obj", c.text);
        auto const f = load_failure(r, file);
        CHECK(f.file == file.string());
        CHECK(f.where == c.where);
        CHECK_THAT(f.problem, Catch::Contains(c.problem));
    }
    // A missing library is named with the .obj line asking for it.
    auto const f = load_failure(r, tmp.write("nolib.obj", tri + "mtllib lib/none.mtl\n"));
    CHECK(f.where == "4");
    CHECK(f.problem == "material library 'lib/none.mtl': file not found");
}

TEST_CASE("obj: bad material libraries and missing textures name the .mtl line") {
    temp_folder const tmp("canopy_obj_test");
    auto const r = obj_registry();
    write_png(tmp.path / "ok.png", 1, 1, {{1, 1, 1, 1}});
    tmp.write("ok.txt", "not an image\n");
    fs::create_directory(tmp.path / "sub");
    struct bad_case {
        std::string mtl, where, problem;
    };
    std::vector<bad_case> const cases = {
        {"newmtl a\nmap_Kd missing.png\n", "2", "texture 'missing.png':"},
        {"newmtl a\nmap_Kd ok.png\nmap_d gone.png\n", "3", "texture 'gone.png':"},
        {"newmtl a\n\nmap_Kd\n", "3", "'map_Kd' needs a file name"},
        {"newmtl a\nmap_Kd -s 2 2 ok.png\n", "2", "texture option -s is not supported"},
        {"newmtl a\nmap_Kd -zz ok.png\n", "2", "unknown texture option -zz"},
        {"newmtl a\nmap_Kd -bm\n", "2", "texture option -bm needs 1 value and a file name"},
        {"Kd 1 1 1\n", "1", "'Kd' before any 'newmtl'"},
        {"newmtl a\nKd 1 x 1\n", "2", "bad number 'x'"},
        {"newmtl a\nKd 1 1\n", "2", "'Kd' needs 1 or 3 numbers"},
        {"newmtl a\nKd 1 -1 1\n", "2", "negative"},
        {"newmtl a\nKd spectral file.rfl\n", "2", "not supported"},
        {"newmtl a\nKd 1 nan 1\n", "2", "not finite"},
        {"newmtl a\nmap_Kd ok.txt\n", "2", "no image loader for extension '.txt'"},
        {"newmtl a\nmap_Kd none.png\n", "2", "none.png: file not found (texture)"},
        {"newmtl a\nmap_Kd sub\n", "2", "sub: is a folder, not a regular file (texture)"},
    };
    for (std::size_t i = 0; i < cases.size(); ++i) {
        auto const& c = cases[i];
        INFO("case " << i << ": " << c.problem);
        auto const mtl = tmp.write("lib" + std::to_string(i) + ".mtl", c.mtl);
        auto const obj = tmp.write("m" + std::to_string(i) + ".obj",
                                   "mtllib lib" + std::to_string(i) + ".mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n");
        auto const f = load_failure(r, obj);
        CHECK(f.file == mtl.string());
        CHECK(f.where == c.where);
        CHECK_THAT(f.problem, Catch::Contains(c.problem));
    }
}

TEST_CASE("obj: parse_obj reads a buffer without files, textures are checked, not loaded, without a registry") {
    canopy::scene s;
    auto const group = canopy::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n", "buffer.obj", nullptr, s, s.root());
    REQUIRE(s.at(group).children.size() == 1);
    CHECK(s.meshes().at(0).triangles.size() == 2);
    CHECK(s.meshes().at(0).source == "buffer.obj");
    auto const lib = canopy::parse_mtl("newmtl a b\nKd 0.5 0.25 1\nmap_Kd -blendu on tex ture.png\nmap_d alpha.png\n", "x.mtl");
    REQUIRE(lib.size() == 1);
    CHECK(lib[0].name == "a b");
    CHECK(same(*lib[0].colour, {0.5f, 0.25f, 1.0f}));
    CHECK(lib[0].colour_texture == "tex ture.png");
    CHECK(lib[0].colour_texture_line == 3);
    CHECK(lib[0].alpha_texture == "alpha.png");
    CHECK(lib[0].alpha_texture_line == 4);
}

TEST_CASE("obj: every OBJ of assimp-testmodels loads or fails with a scene_error") {
    fs::path const folder = "/usr/share/assimp/models/OBJ";
    REQUIRE(fs::is_directory(folder));
    auto const r = obj_registry();
    std::size_t loaded = 0, refused = 0;
    for (auto const& entry : fs::directory_iterator(folder)) {
        if (entry.path().extension() != ".obj") continue;
        INFO(entry.path());
        canopy::scene s;
        try {
            r.load(s, entry.path());
            ++loaded;
        } catch (canopy::scene_error const& e) {
            CHECK(e.file() == entry.path().string());
            ++refused;
        }
    }
    CHECK(loaded + refused == 22);
    // box_UTF16BE.obj, number_formats.obj, cube_mtllib_after_g.obj; point_cloud.obj, testpoints.obj and
    // testline.obj hold no faces.
    CHECK(refused == 6);
}

TEST_CASE("obj: assimp-testmodels files in detail") {
    fs::path const folder = "/usr/share/assimp/models/OBJ";
    auto const r = obj_registry();
    auto const triangles = [](canopy::scene const& s) {
        std::size_t n = 0;
        for (auto const& m : s.meshes()) n += m.triangles.size();
        return n;
    };
    SECTION("box.obj: 8 vertices, 6 quads = 12 triangles, usemtl Default without a library") {
        canopy::scene s;
        auto const meshes = meshes_of(s, r.load(s, folder / "box.obj"));
        REQUIRE(meshes.size() == 1);
        CHECK(meshes[0]->name == "Default");
        CHECK(meshes[0]->material == -1);
        CHECK(meshes[0]->positions.size() == 8);
        CHECK(meshes[0]->triangles.size() == 12);
        auto const c = canopy::compile(s, {.plugins = &r});
        CHECK(c.statistics.levels == 0);
        CHECK(c.statistics.triangles_stored == 12);
    }
    SECTION("box_longline.obj: a 936-corner face and 5 quads = 934 + 10 triangles") {
        canopy::scene s;
        r.load(s, folder / "box_longline.obj");
        CHECK(triangles(s) == 944);
    }
    SECTION("cube_usemtl.obj: 12 triangles in mtl3 (2, undefined), mtl (6), mtl2 (4)") {
        canopy::scene s;
        auto const meshes = meshes_of(s, r.load(s, folder / "cube_usemtl.obj"));
        REQUIRE(meshes.size() == 3);
        CHECK(meshes[0]->name == "mtl3");
        CHECK(meshes[0]->triangles.size() == 2);
        CHECK(meshes[0]->material == -1);
        CHECK(meshes[1]->name == "mtl");
        CHECK(meshes[1]->triangles.size() == 6);
        CHECK(meshes[2]->name == "mtl2");
        CHECK(meshes[2]->triangles.size() == 4);
        CHECK(s.materials().size() == 2);
        REQUIRE(meshes[1]->normals.size() == 6);
        CHECK(same(meshes[1]->normals[0][0], {-1, 0, 0})); // f 1//6 4//6 3//6; vn 6 = -1 0 0
    }
    SECTION("cube_mtllib_after_g.obj: CRLF lines; its library (a .mat file) does not exist: line 2 says so") {
        auto const f = load_failure(r, folder / "cube_mtllib_after_g.obj");
        CHECK(f.where == "2");
        CHECK(f.problem == "material library 'cube_mtllib_after_g.mat': file not found");
    }
    SECTION("spider.obj: 762 vertices, 1368 triangles, JPEG textures with Windows paths") {
        canopy::scene s;
        r.load(s, folder / "spider.obj");
        CHECK(triangles(s) == 1368);
        // Four materials used (HLeibTex Skin BeinTex Augentex), each with its own map_Kd JPEG.
        CHECK(s.materials().size() == 4);
        CHECK(s.images().size() == 4);
        CHECK(s.meshes().size() == 4);
        for (auto const& m : s.materials()) CHECK(m.alpha == canopy::alpha_mode::opaque);
    }
    SECTION("testmixed.obj: lines and points are ignored, 6 quads = 12 triangles") {
        canopy::scene s;
        r.load(s, folder / "testmixed.obj");
        CHECK(triangles(s) == 12);
    }
    SECTION("point_cloud.obj, testpoints.obj, testline.obj: no faces, nothing to trace: refused") {
        CHECK(load_failure(r, folder / "point_cloud.obj").problem == "no faces ('f' lines): nothing to trace");
        CHECK(load_failure(r, folder / "testpoints.obj").problem ==
              "no faces ('f' lines), only points or lines: nothing to trace");
        CHECK(load_failure(r, folder / "testline.obj").problem ==
              "no faces ('f' lines), only points or lines: nothing to trace");
    }
    SECTION("number_formats.obj: '3.1+e2' on line 11 is a bad number") {
        auto const f = load_failure(r, folder / "number_formats.obj");
        CHECK(f.where == "11");
        CHECK_THAT(f.problem, Catch::Contains("bad number '3.1+e2'"));
    }
    SECTION("box_UTF16BE.obj: UTF-16 is refused") {
        auto const f = load_failure(r, folder / "box_UTF16BE.obj");
        CHECK(f.problem == "not a text OBJ file: UTF-16 byte-order mark (only ASCII or UTF-8 text is read)");
    }
}

TEST_CASE("obj: a non-convex face of more than 256 corners is fanned and reported, one of 256 is ear-clipped") {
    temp_folder const tmp("canopy_obj_test");
    // A simple comb: a zigzag top edge (heights 1 and 2: non-convex) and two base corners.
    auto const comb = [&](std::string const& name, int corners_count) {
        std::string text;
        for (int k = 0; k < corners_count - 2; ++k) text += "v " + std::to_string(k) + " " + (k % 2 ? "1" : "2") + " 0\n";
        text += "v " + std::to_string(corners_count - 3) + " 0 0\nv 0 0 0\n";
        text += "f";
        for (int k = 1; k <= corners_count; ++k) text += " " + std::to_string(k);
        return tmp.write(name, text + "\n");
    };
    auto const r = obj_registry();
    canopy::scene big;
    auto const file = comb("comb300.obj", 300);
    auto const meshes = meshes_of(big, r.load(big, file));
    REQUIRE(meshes.size() == 1);
    CHECK(meshes[0]->triangles.size() == 298);
    CHECK(meshes[0]->fanned_faces == 1);
    CHECK(meshes[0]->first_fanned == "301"); // the f line
    auto const c = canopy::compile(big, {.plugins = &r});
    CHECK(c.statistics.faces_fanned == 1);
    CHECK(std::count(c.statistics.decisions.begin(), c.statistics.decisions.end(),
                     "1 polygon faces fanned, not ear-clipped (self-intersecting, collinear, or non-convex with more than "
                     "256 corners): their triangles may cover more than the face; the first in mesh 'comb300' (" +
                         file.string() + ":301)") == 1);

    canopy::scene small;
    auto const clipped = meshes_of(small, r.load(small, comb("comb256.obj", 256)));
    REQUIRE(clipped.size() == 1);
    CHECK(clipped[0]->triangles.size() == 254);
    CHECK(clipped[0]->fanned_faces == 0);
    auto const cs = canopy::compile(small, {.plugins = &r});
    CHECK(cs.statistics.faces_fanned == 0);
    for (auto const& d : cs.statistics.decisions) CHECK_THAT(d, !Catch::Contains("fanned"));
}

TEST_CASE("obj: only regular files are read: the OBJ, its material libraries and their textures") {
    temp_folder const tmp("canopy_obj_test");
    auto const& dir = tmp.path;
    auto const r = obj_registry();
    std::string const tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n";
    REQUIRE(test_support::make_special_files(dir, {".obj", ".mtl", ".png"}));
    for (auto const& [name, kind] : test_support::special_files()) {
        INFO(name);
        // The .obj itself (the registry checks it before its extension).
        auto const obj = load_failure(r, dir / (name + ".obj"));
        CHECK(obj.file == (dir / (name + ".obj")).string());
        CHECK(obj.where == "");
        CHECK(obj.problem == "is " + kind + ", not a regular file");
        // A material library: named with the .obj line asking for it.
        auto const lib = load_failure(r, tmp.write("lib_" + name + ".obj", "mtllib " + name + ".mtl\n" + tri));
        CHECK(lib.file == (dir / ("lib_" + name + ".obj")).string());
        CHECK(lib.where == "1");
        CHECK(lib.problem == "material library '" + name + ".mtl': is " + kind + ", not a regular file");
        // A texture: named with the .mtl line asking for it.
        auto const mtl = tmp.write("tex_" + name + ".mtl", "newmtl a\nmap_Kd " + name + ".png\n");
        auto const tex = load_failure(r, tmp.write("tex_" + name + ".obj", "mtllib tex_" + name + ".mtl\n" + tri));
        CHECK(tex.file == mtl.string());
        CHECK(tex.where == "2");
        CHECK(tex.problem == "texture '" + name + ".png': " + (dir / (name + ".png")).string() + ": is " + kind +
                                 ", not a regular file (texture)");
    }
}

TEST_CASE("obj: files that are not text or hold no faces are refused, naming the byte, its offset and line") {
    temp_folder const tmp("canopy_obj_test");
    auto const r = obj_registry();
    std::string random(3000, '\0');
    std::mt19937 rng(7);
    for (char& c : random) c = char(std::uniform_int_distribution<int>(0x20, 0xFE)(rng));
    std::replace(random.begin(), random.end(), '\x7F', '\xFF'); // DEL is a control byte too
    random[1700] = '\n';
    random[2100] = '\x1B';
    struct bad_case {
        std::string text, where, problem;
    };
    std::vector<bad_case> const cases = {
        {random, "2", "not a text OBJ file: control byte 0x1B at offset 2100"},
        {"v 0 0 0\nv 1 0 0\n\0\0\0"s, "3", "not a text OBJ file: NUL byte at offset 16"},
        {"\xFF\xFEv\0 \0"s, "", "not a text OBJ file: UTF-16 byte-order mark (only ASCII or UTF-8 text is read)"},
        {"\xFE\xFF\0v\0 "s, "", "not a text OBJ file: UTF-16 byte-order mark (only ASCII or UTF-8 text is read)"},
        {"\xFF\xFE\0\0v\0\0\0"s, "", "not a text OBJ file: UTF-32 byte-order mark (only ASCII or UTF-8 text is read)"},
        {"v\0 \0\x30\0"s, "1", "not a text OBJ file: NUL byte at offset 1"},
        {"", "", "is empty: nothing to trace"},
        {" \n\t\r\n", "", "is empty: nothing to trace"},
        {"\xC3\xA9t\xC3\xA9 words\nno statement\n", "", "not an OBJ file: no OBJ statement (v, f, ...) in it, nothing to trace"},
        {"# only a comment\n", "", "not an OBJ file: no OBJ statement (v, f, ...) in it, nothing to trace"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\no name\nusemtl a\n", "", "no faces ('f' lines): nothing to trace"},
        {"v 0 0 0\nv 1 0 0\nl 1 2\n", "", "no faces ('f' lines), only points or lines: nothing to trace"},
    };
    for (std::size_t i = 0; i < cases.size(); ++i) {
        auto const& c = cases[i];
        INFO("case " << i << ": " << c.problem);
        auto const file = tmp.write("notext" + std::to_string(i) + ".obj", c.text);
        auto const f = load_failure(r, file);
        CHECK(f.file == file.string());
        CHECK(f.where == c.where);
        CHECK(f.problem == c.problem);
    }
    // An MTL file is held to the same rule.
    tmp.write("binary.mtl", "newmtl a\nKd 1 1 1\n\x02\n");
    auto const f = load_failure(r, tmp.write("uses_binary.obj", "mtllib binary.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"));
    CHECK(f.file == (tmp.path / "binary.mtl").string());
    CHECK(f.where == "3");
    CHECK(f.problem == "not a text MTL file: control byte 0x02 at offset 18");
}

TEST_CASE("obj: messages quote at most a short prefix of the offending input") {
    temp_folder const tmp("canopy_obj_test");
    auto const r = obj_registry();
    std::string const big(1 << 20, 'x'); // 1 MiB without a space
    std::string const prefix(40, 'x');
    std::string const tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    struct bad_case {
        std::string text, where, problem;
    };
    std::vector<bad_case> const cases = {
        {"v 0 0 " + big + "\n", "1", "bad number '" + prefix + "…'"},
        {tri + "f 1 2 " + big + "\n", "4", "bad vertex index '" + prefix + "…' in corner '" + prefix + "…'"},
        {tri + "f 1 2 3/" + big + "\n", "4", "bad texture coordinate index '" + prefix + "…' in corner '3/" +
                                                   std::string(38, 'x') + "…'"},
        {"mtllib " + big + "\n" + tri + "f 1 2 3\n", "1",
         "material library name of 1048576 bytes is too long ('" + prefix + "…')"},
    };
    for (std::size_t i = 0; i < cases.size(); ++i) {
        auto const& c = cases[i];
        INFO("case " << i);
        auto const f = load_failure(r, tmp.write("long" + std::to_string(i) + ".obj", c.text));
        CHECK(f.where == c.where);
        CHECK(f.problem == c.problem);
        CHECK(f.message.size() < 400);
    }
}

TEST_CASE("obj: vertices and triangles are limited by --max-triangles as they grow") {
    temp_folder const tmp("canopy_obj_test");
    auto const r = obj_registry();
    auto const saved = canopy::default_limits();
    canopy::default_limits().max_triangles = 4;
    struct bad_case {
        std::string text, where, problem;
    };
    std::vector<bad_case> const cases = {
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 2 2 0\n", "5", "5 vertices exceed the limit of 4 (--max-triangles)"},
        {"vt 0 0\nvt 0 0\nvt 0 0\nvt 0 0\nvt 0 0\n", "5", "5 texture coordinates exceed the limit of 4 (--max-triangles)"},
        {"vn 0 0 1\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\n", "5", "5 normals exceed the limit of 4 (--max-triangles)"},
        {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3\nf 1 2 3\nf 1 2 3\nf 1 2 3\n", "8",
         "5 triangles exceed the limit of 4 (--max-triangles)"},
        {"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 2 3 4 1 2\n", "6",
         "5 triangles exceed the limit of 4 (--max-triangles)"},
    };
    for (std::size_t i = 0; i < cases.size(); ++i) {
        auto const& c = cases[i];
        INFO("case " << i);
        auto const f = load_failure(r, tmp.write("limit" + std::to_string(i) + ".obj", c.text));
        CHECK(f.where == c.where);
        CHECK(f.problem == c.problem);
    }
    canopy::scene s;
    CHECK_NOTHROW(r.load(s, tmp.write("four.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nf 1 2 3\nf 4 3 2\n")));
    canopy::default_limits() = saved;
}

TEST_CASE("obj: a library named again and again is read once, materials naming the same texture share its image") {
    temp_folder const tmp("canopy_obj_test");
    auto const r = obj_registry();
    write_png(tmp.path / "leaf.png", 1, 1, {{1, 1, 1, 0.25f}});
    constexpr int n = 5000;
    std::string lib, obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    for (int i = 0; i < n; ++i) {
        lib += "newmtl m" + std::to_string(i) + "\nKd 0.5 0.5 0.5\n" + (i % 2 ? "" : "map_Kd leaf.png\n");
        obj += "mtllib lib.mtl\nusemtl m" + std::to_string(i) + "\nf 1 2 3\n";
    }
    tmp.write("lib.mtl", lib);
    auto const file = tmp.write("many.obj", obj);
    canopy::scene s;
    auto const start = std::chrono::steady_clock::now();
    auto const meshes = meshes_of(s, r.load(s, file));
    double const seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    CHECK(seconds < 5.0); // read n times, the library would take minutes: n × n materials parsed
    CHECK(meshes.size() == std::size_t(n));
    CHECK(s.materials().size() == std::size_t(n));
    REQUIRE(s.images().size() == 1);
    for (int i = 0; i < n; i += 997) {
        CHECK(s.materials()[std::size_t(i)].image == (i % 2 ? -1 : 0));
        CHECK(s.materials()[std::size_t(i)].alpha == (i % 2 ? canopy::alpha_mode::opaque : canopy::alpha_mode::mask));
    }
}

TEST_CASE("obj: textures count against --max-total-texels, a material's colour and alpha images together") {
    temp_folder const tmp("canopy_obj_test");
    limits_guard const guard;
    auto const r = obj_registry();
    std::vector<std::array<float, 4>> const texels(4, {1, 1, 1, 1});
    write_png(tmp.path / "colour.png", 2, 2, texels);
    write_png(tmp.path / "alpha.png", 2, 2, texels);
    write_png(tmp.path / "other.png", 2, 2, texels);
    tmp.write("lib.mtl", "newmtl a\nmap_Kd colour.png\nmap_d alpha.png\nnewmtl b\nmap_Kd other.png\n");
    auto const file = tmp.write("two.obj", "mtllib lib.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\nusemtl b\nf 1 2 3\n");
    // a holds one image of 4 texels (its alpha merged in), but both were decoded: 8 at the most,
    // then b's 4.
    canopy::default_limits().max_total_texels = 8;
    canopy::scene s;
    r.load(s, file);
    CHECK(s.images().size() == 2);
    CHECK(s.texels() == 8);
    canopy::default_limits().max_total_texels = 7;
    auto const f = load_failure(r, file);
    CHECK(f.where == "3");
    CHECK(f.problem == "texture 'alpha.png': " + (tmp.path / "alpha.png").string() +
                           ": image is 2 × 2 (4 texels): with the 4 texels of the images loaded before it, 8 texels in "
                           "all exceed the limit of 7 (--max-total-texels)");
    CHECK(f.file == (tmp.path / "lib.mtl").string());
}
