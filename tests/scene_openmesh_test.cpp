// Tests of the openmesh plugin (canopy.plugins.openmesh). Real meshes from Debian packages (the
// Stanford bunny of glmark2-data, closed OFF meshes of libcgal-demo) are checked against this
// file's own reading of them: face counts, bounds, closedness; closed meshes are compiled and
// rays from points inside (verified by a parity count) must all hit, at the hit a brute-force
// loop over the triangles finds. Each format (PLY ASCII and binary, OFF, STL ASCII and binary,
// OM written with OpenMesh, OBJ) is written here with known content and read back. Malformed
// files — generated here, and the odd ones of assimp-testmodels — must give a scene_error
// naming the file.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>

import canopy.scene;
import canopy.plugins.openmesh;
import canopy.testing;
import canopy.testing.scene;

namespace {

namespace fs = std::filesystem;
using test_support::temp_folder;
using test_support::limits_guard;
using canopy::vec2;
using canopy::vec3;

std::string read_file(fs::path const& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

canopy::registry const& openmesh_registry() {
    static canopy::registry const r = [] {
        canopy::registry reg;
        canopy::register_openmesh_plugin(reg);
        return reg;
    }();
    return r;
}

// Loads through the registry (plugin "openmesh") and returns the one mesh it made.
canopy::mesh_data load_mesh(fs::path const& file, canopy::scene& s) {
    auto const group = openmesh_registry().load(s, file, s.root(), "openmesh");
    REQUIRE(s.at(group).name == file.filename().string());
    REQUIRE(s.at(group).children.size() == 1);
    REQUIRE(s.meshes().size() == 1);
    return s.meshes()[0];
}

// The loader's error for `file`: a scene_error whose message names the file and says `problem`.
void require_error(fs::path const& file, std::string const& problem) {
    std::string const m = test_support::load_failure(openmesh_registry(), file, "openmesh").message;
    INFO(m);
    CHECK(m.find(file.filename().string()) != std::string::npos);
    CHECK(m.find(problem) != std::string::npos);
}

// --- Independent readings of the real meshes -------------------------------------------------

struct parsed_mesh {
    std::vector<vec3<float>> positions;
    std::vector<std::array<std::uint32_t, 3>> triangles;
    vec3<float> lo{std::numeric_limits<float>::max()}, hi{-std::numeric_limits<float>::max()};
};

void extend(parsed_mesh& m, vec3<float> p) {
    m.positions.push_back(p);
    m.lo = {std::min(m.lo.x, p.x), std::min(m.lo.y, p.y), std::min(m.lo.z, p.z)};
    m.hi = {std::max(m.hi.x, p.x), std::max(m.hi.y, p.y), std::max(m.hi.z, p.z)};
}

// An OBJ of `v x y z` and `f a b c` lines (the bunny's form).
parsed_mesh parse_simple_obj(fs::path const& file) {
    parsed_mesh m;
    std::ifstream in(file);
    std::string line;
    while (std::getline(in, line)) {
        std::istringstream s(line);
        std::string key;
        s >> key;
        if (key == "v") {
            float x, y, z;
            s >> x >> y >> z;
            extend(m, {x, y, z});
        } else if (key == "f") {
            std::array<std::uint32_t, 3> t{};
            for (auto& i : t) {
                s >> i;
                --i;
            }
            m.triangles.push_back(t);
        }
    }
    return m;
}

// A triangle OFF: "OFF", counts, vertices, "3 a b c" faces.
parsed_mesh parse_triangle_off(fs::path const& file) {
    parsed_mesh m;
    std::ifstream in(file);
    std::string keyword;
    std::size_t nv = 0, nf = 0, ne = 0;
    in >> keyword >> nv >> nf >> ne;
    for (std::size_t i = 0; i < nv; ++i) {
        float x, y, z;
        in >> x >> y >> z;
        extend(m, {x, y, z});
    }
    for (std::size_t i = 0; i < nf; ++i) {
        int n = 0;
        std::array<std::uint32_t, 3> t{};
        in >> n >> t[0] >> t[1] >> t[2];
        REQUIRE(n == 3);
        m.triangles.push_back(t);
    }
    REQUIRE(in);
    return m;
}

std::size_t count_face_lines(fs::path const& file) {
    std::ifstream in(file);
    std::string line;
    std::size_t n = 0;
    while (std::getline(in, line)) n += line.rfind("f ", 0) == 0;
    return n;
}

// Every undirected edge is shared by exactly two triangles.
bool is_closed(std::vector<std::array<std::uint32_t, 3>> const& triangles) {
    std::map<std::pair<std::uint32_t, std::uint32_t>, int> edges;
    for (auto const& t : triangles)
        for (int k = 0; k < 3; ++k) {
            auto a = t[std::size_t(k)], b = t[std::size_t((k + 1) % 3)];
            ++edges[{std::min(a, b), std::max(a, b)}];
        }
    return std::all_of(edges.begin(), edges.end(), [](auto const& e) { return e.second == 2; });
}

// Crossings of the ray o + t d (t > 0) with the triangles, in double (Möller–Trumbore).
int crossings(parsed_mesh const& m, std::array<double, 3> o, std::array<double, 3> d) {
    auto const sub = [](std::array<double, 3> a, std::array<double, 3> b) {
        return std::array<double, 3>{a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    };
    auto const cross = [](std::array<double, 3> a, std::array<double, 3> b) {
        return std::array<double, 3>{a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    };
    auto const dot = [](std::array<double, 3> a, std::array<double, 3> b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; };
    auto const at = [&](std::uint32_t i) {
        return std::array<double, 3>{m.positions[i].x, m.positions[i].y, m.positions[i].z};
    };
    int n = 0;
    for (auto const& t : m.triangles) {
        auto const v0 = at(t[0]), e1 = sub(at(t[1]), v0), e2 = sub(at(t[2]), v0);
        auto const p = cross(d, e2);
        double const det = dot(e1, p);
        if (det == 0.0) continue;
        auto const s = sub(o, v0);
        double const u = dot(s, p) / det;
        auto const q = cross(s, e1);
        double const v = dot(d, q) / det;
        double const tt = dot(e2, q) / det;
        n += u >= 0.0 && v >= 0.0 && u + v <= 1.0 && tt > 0.0;
    }
    return n;
}

// Points strictly inside a closed mesh: just off the centroids of random faces, on the side
// where three random rays all cross the surface an odd number of times.
std::vector<vec3<float>> inside_points(parsed_mesh const& m, std::size_t wanted, std::mt19937& rng) {
    std::normal_distribution<double> gauss;
    std::uniform_int_distribution<std::size_t> pick(0, m.triangles.size() - 1);
    std::vector<vec3<float>> out;
    for (int attempt = 0; attempt < 200 && out.size() < wanted; ++attempt) {
        auto const& t = m.triangles[pick(rng)];
        vec3<float> const a = m.positions[t[0]], b = m.positions[t[1]], c = m.positions[t[2]];
        vec3<float> const centroid = (a + b + c) / 3.0f;
        vec3<float> const n = cross(b - a, c - a);
        float const size = std::sqrt(length(n));
        if (!(size > 0.0f)) continue;
        for (float side : {-0.05f, 0.05f}) {
            vec3<float> const p = centroid + (side * size / length(n)) * n;
            bool odd = true;
            for (int k = 0; k < 3; ++k)
                odd = odd && crossings(m, {p.x, p.y, p.z}, {gauss(rng), gauss(rng), gauss(rng)}) % 2 == 1;
            if (odd) out.push_back(p);
        }
    }
    return out;
}

struct ray_agreement {
    int rays = 0, misses = 0, mismatches = 0;
};

// Rays in random directions from each point: closest_hit of the compiled scene against a loop
// over every triangle with the same triangle test.
ray_agreement shoot_from_inside(canopy::compiled_scene const& compiled, parsed_mesh const& m,
                                std::vector<vec3<float>> const& points, int per_point, std::mt19937& rng) {
    std::vector<canopy::triangle> triangles;
    for (std::size_t i = 0; i < m.triangles.size(); ++i) {
        auto const& t = m.triangles[i];
        canopy::triangle tri{m.positions[t[0]], m.positions[t[1]], m.positions[t[2]]};
        tri.prim_id = std::uint32_t(i);
        triangles.push_back(tri);
    }
    std::normal_distribution<float> gauss;
    ray_agreement a;
    for (auto const& p : points)
        for (int k = 0; k < per_point; ++k) {
            vec3<float> const d = normalize(vec3<float>(gauss(rng), gauss(rng), gauss(rng)));
            canopy::ray const r{p, 0.0f, d, std::numeric_limits<float>::infinity()};
            canopy::default_intersector isect;
            auto const got = compiled.closest_hit(r, isect);
            ++a.rays;
            if (!got.hit) {
                ++a.misses;
                continue;
            }
            float best = std::numeric_limits<float>::infinity();
            std::uint32_t best_prim = 0;
            for (auto const& tri : triangles) {
                auto const h = canopy::intersect(r, tri);
                if (h.hit && (h.t < best || (h.t == best && tri.prim_id < best_prim))) {
                    best = h.t;
                    best_prim = tri.prim_id;
                }
            }
            a.mismatches += !(got.t == best && got.prim_id == best_prim);
        }
    return a;
}

void check_loaded_like_parsed(canopy::mesh_data const& mesh, parsed_mesh const& parsed) {
    REQUIRE(mesh.triangles.size() == parsed.triangles.size());
    REQUIRE(mesh.positions.size() == parsed.positions.size());
    CHECK(mesh.triangles == parsed.triangles);
    vec3<float> lo{std::numeric_limits<float>::max()}, hi{-std::numeric_limits<float>::max()};
    for (auto p : mesh.positions) {
        lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
        hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
    }
    CHECK(lo.x == parsed.lo.x);
    CHECK(lo.y == parsed.lo.y);
    CHECK(lo.z == parsed.lo.z);
    CHECK(hi.x == parsed.hi.x);
    CHECK(hi.y == parsed.hi.y);
    CHECK(hi.z == parsed.hi.z);
}

void check_closed_mesh_traces(fs::path const& file, parsed_mesh const& parsed, int points, int rays_per_point) {
    INFO(file);
    REQUIRE(is_closed(parsed.triangles));
    canopy::scene s;
    check_loaded_like_parsed(load_mesh(file, s), parsed);
    auto const compiled = canopy::compile(s, {.plugins = &openmesh_registry(), .name = file.string()});
    std::mt19937 rng(20240611);
    auto const inside = inside_points(parsed, std::size_t(points), rng);
    REQUIRE(inside.size() >= std::size_t(points) / 2);
    auto const a = shoot_from_inside(compiled, parsed, inside, rays_per_point, rng);
    INFO(a.rays << " rays from " << inside.size() << " points inside");
    CHECK(a.rays >= rays_per_point * points / 2);
    CHECK(a.misses == 0);
    CHECK(a.mismatches == 0);
}

// libcgal-demo ships its meshes in data.tar.gz: the few used here are unpacked into `folder`.
std::vector<fs::path> cgal_meshes(fs::path const& folder, std::vector<std::string> const& names) {
    std::string command = "tar -xzf /usr/share/doc/libcgal-dev/data.tar.gz -C '" + folder.string() + "'";
    for (auto const& n : names) command += " data/meshes/" + n;
    REQUIRE(std::system(command.c_str()) == 0);
    std::vector<fs::path> out;
    for (auto const& n : names) out.push_back(folder / "data" / "meshes" / n);
    return out;
}

} // namespace

TEST_CASE("the Stanford bunny of glmark2-data loads with every face of its file, closed, and traces from inside") {
    fs::path const bunny = "/usr/share/glmark2/models/bunny.obj";
    REQUIRE(fs::exists(bunny));
    parsed_mesh const parsed = parse_simple_obj(bunny);
    std::size_t const faces = count_face_lines(bunny);
    REQUIRE(faces == parsed.triangles.size());
    auto const result = canopy::read_openmesh(bunny);
    CHECK(result.faces == faces);
    CHECK(result.mesh.triangles.size() == faces);
    CHECK(result.polygons == 0);
    CHECK(result.mesh.name == "bunny");
    CHECK(result.mesh.source == bunny.string());
    check_closed_mesh_traces(bunny, parsed, 6, 40);
}

TEST_CASE("closed OFF meshes of libcgal-demo load exactly and no ray from inside escapes") {
    temp_folder const tmp("canopy_openmesh_test");
    auto const files = cgal_meshes(tmp.path, {"elephant.off", "eight.off", "sphere.off"});
    for (auto const& f : files) check_closed_mesh_traces(f, parse_triangle_off(f), 12, 60);
}

// A square pyramid: apex 4 over the quad 0 1 2 3, four triangle sides; per-vertex uv and normal.
namespace pyramid {
std::array<vec3<float>, 5> const positions{{{0, 0, 0}, {2, 0, 0}, {2, 2, 0}, {0, 2, 0}, {1, 1, 1.5f}}};
std::array<vec2<float>, 5> const uvs{{{0, 0}, {1, 0}, {1, 1}, {0, 1}, {0.5f, 0.5f}}};
std::array<vec3<float>, 5> const normals{{{0, 0, -1}, {1, 0, 0}, {0, 1, 0}, {-1, 0, 0}, {0, 0, 1}}};
std::vector<std::vector<std::uint32_t>> const faces{{0, 3, 2, 1}, {0, 1, 4}, {1, 2, 4}, {2, 3, 4}, {3, 0, 4}};
// The quad fanned from its first corner, then the sides.
std::vector<std::array<std::uint32_t, 3>> const triangles{{0, 3, 2}, {0, 2, 1}, {0, 1, 4}, {1, 2, 4}, {2, 3, 4}, {3, 0, 4}};

void check(canopy::mesh_data const& m, bool with_uv, bool with_normals) {
    REQUIRE(m.positions.size() == positions.size());
    for (std::size_t i = 0; i < positions.size(); ++i) {
        CHECK(m.positions[i].x == positions[i].x);
        CHECK(m.positions[i].y == positions[i].y);
        CHECK(m.positions[i].z == positions[i].z);
    }
    CHECK(m.triangles == triangles);
    REQUIRE(m.uvs.size() == (with_uv ? triangles.size() : 0));
    REQUIRE(m.normals.size() == (with_normals ? triangles.size() : 0));
    for (std::size_t t = 0; t < m.uvs.size(); ++t)
        for (std::size_t k = 0; k < 3; ++k) {
            CHECK(m.uvs[t][k].x == uvs[triangles[t][k]].x);
            CHECK(m.uvs[t][k].y == uvs[triangles[t][k]].y);
        }
    for (std::size_t t = 0; t < m.normals.size(); ++t)
        for (std::size_t k = 0; k < 3; ++k) {
            CHECK(m.normals[t][k].x == normals[triangles[t][k]].x);
            CHECK(m.normals[t][k].y == normals[triangles[t][k]].y);
            CHECK(m.normals[t][k].z == normals[triangles[t][k]].z);
        }
}

std::string ply_header(char const* format) {
    return std::string("ply\nformat ") + format +
           " 1.0\ncomment written by scene_openmesh_test\nelement vertex 5\nproperty float x\nproperty float y\n"
           "property float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float u\n"
           "property float v\nelement face 5\nproperty list uchar int vertex_indices\nend_header\n";
}

std::string ply_ascii() {
    std::ostringstream s;
    s << ply_header("ascii");
    for (std::size_t i = 0; i < 5; ++i)
        s << positions[i].x << ' ' << positions[i].y << ' ' << positions[i].z << ' ' << normals[i].x << ' ' << normals[i].y
          << ' ' << normals[i].z << ' ' << uvs[i].x << ' ' << uvs[i].y << '\n';
    for (auto const& f : faces) {
        s << f.size();
        for (auto v : f) s << ' ' << v;
        s << '\n';
    }
    return s.str();
}

template <typename T>
void put(std::string& out, T value, bool big_endian) {
    std::array<char, sizeof(T)> b;
    std::memcpy(b.data(), &value, sizeof(T));
    if (big_endian) std::reverse(b.begin(), b.end());
    out.append(b.data(), b.size());
}

std::string ply_binary(bool big_endian) {
    std::string s = ply_header(big_endian ? "binary_big_endian" : "binary_little_endian");
    for (std::size_t i = 0; i < 5; ++i)
        for (float v : {positions[i].x, positions[i].y, positions[i].z, normals[i].x, normals[i].y, normals[i].z, uvs[i].x,
                        uvs[i].y})
            put(s, v, big_endian);
    for (auto const& f : faces) {
        put(s, std::uint8_t(f.size()), big_endian);
        for (auto v : f) put(s, std::int32_t(v), big_endian);
    }
    return s;
}

std::string off() {
    std::ostringstream s;
    s << "OFF\n# a square pyramid\n5 5 0\n";
    for (auto const& p : positions) s << p.x << ' ' << p.y << ' ' << p.z << '\n';
    for (auto const& f : faces) {
        s << f.size();
        for (auto v : f) s << ' ' << v;
        s << '\n';
    }
    return s.str();
}
} // namespace pyramid

TEST_CASE("PLY ASCII and binary (both byte orders) load positions, per-vertex normals and uvs, quads fanned") {
    temp_folder const tmp("canopy_openmesh_test");
    std::vector<std::pair<std::string, std::string>> const files{{"ascii.ply", pyramid::ply_ascii()},
                                                                 {"little.ply", pyramid::ply_binary(false)},
                                                                 {"big.ply", pyramid::ply_binary(true)}};
    for (auto const& [name, content] : files) {
        INFO(name);
        tmp.write(name, content);
        canopy::scene s;
        pyramid::check(load_mesh(tmp.path / name, s), true, true);
        auto const r = canopy::read_openmesh(tmp.path / name);
        CHECK(r.faces == 5);
        CHECK(r.polygons == 1);
        CHECK(r.texcoords);
        CHECK(r.vertex_normals);
    }
}

TEST_CASE("OFF loads positions and fans polygons, faces OpenMesh cannot connect are kept on their vertices") {
    temp_folder const tmp("canopy_openmesh_test");
    tmp.write("pyramid.off", pyramid::off());
    canopy::scene s;
    pyramid::check(load_mesh(tmp.path / "pyramid.off", s), false, false);

    // Three triangles on one edge (0, 1) and a face repeating a vertex: OpenMesh's importer
    // re-adds the non-manifold one on copied vertices and drops the degenerate one.
    tmp.write("fin.off", "OFF\n5 4 0\n0 0 0\n1 0 0\n0 1 0\n0 -1 0\n0 0 1\n"
                                     "3 0 1 2\n3 1 0 3\n3 0 1 4\n3 2 2 4\n");
    auto const r = canopy::read_openmesh(tmp.path / "fin.off");
    CHECK(r.faces == 4);
    CHECK(r.nonmanifold_faces == 1);
    CHECK(r.degenerate_faces == 1);
    CHECK(r.mesh.positions.size() == 5);
    std::vector<std::array<std::uint32_t, 3>> const expected{{0, 1, 2}, {1, 0, 3}, {0, 1, 4}, {2, 2, 4}};
    CHECK(r.mesh.triangles == expected);
}

TEST_CASE("a non-convex OFF face is ear-clipped, a convex one fanned, both counted") {
    // The arrowhead (2 2)(1 1)(0 2)(1 0.25): its fan from corner 0 would start with the notch
    // (0 1 2). A convex quad follows.
    temp_folder const tmp("canopy_openmesh_test");
    tmp.write("arrow.off", "OFF\n8 2 0\n2 2 0\n1 1 0\n0 2 0\n1 0.25 0\n5 0 0\n6 0 0\n6 1 0\n5 1 0\n"
                           "4 0 1 2 3\n4 4 5 6 7\n");
    auto const r = canopy::read_openmesh(tmp.path / "arrow.off");
    CHECK(r.faces == 2);
    CHECK(r.polygons == 2);
    CHECK(r.concave_polygons == 1);
    REQUIRE(r.mesh.triangles.size() == 4);
    using tri = std::array<std::uint32_t, 3>;
    // Ear clipping starts at corner 0: (3 0 1) is an ear, then the corners left, in face order.
    CHECK(r.mesh.triangles[0] == tri{3, 0, 1});
    CHECK(r.mesh.triangles[1] == tri{1, 2, 3});
    CHECK(r.mesh.triangles[2] == tri{4, 5, 6});
    CHECK(r.mesh.triangles[3] == tri{4, 6, 7});
}

TEST_CASE("STL ASCII and binary load every facet with its corners") {
    temp_folder const tmp("canopy_openmesh_test");
    std::array<std::array<vec3<float>, 3>, 3> const facets{{{{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}},
                                                           {{{1, 0, 0}, {1, 1, 0.5f}, {0, 1, 0}}},
                                                           {{{-2, 3, 4}, {-2.5f, 3, 4}, {-2, 3.25f, 4.75f}}}}};
    std::ostringstream ascii;
    ascii << "solid test\n";
    for (auto const& f : facets) {
        ascii << "  facet normal 0 0 1\n    outer loop\n";
        for (auto const& p : f) ascii << "      vertex " << p.x << ' ' << p.y << ' ' << p.z << '\n';
        ascii << "    endloop\n  endfacet\n";
    }
    ascii << "endsolid test\n";
    std::string binary(80, ' ');
    binary.replace(0, 11, "solid test ");
    pyramid::put(binary, std::uint32_t(facets.size()), false);
    for (auto const& f : facets) {
        for (float v : {0.0f, 0.0f, 1.0f}) pyramid::put(binary, v, false);
        for (auto const& p : f)
            for (float v : {p.x, p.y, p.z}) pyramid::put(binary, v, false);
        pyramid::put(binary, std::uint16_t(0), false);
    }
    tmp.write("ascii.stl", ascii.str());
    tmp.write("binary.stl", binary);
    for (char const* name : {"ascii.stl", "binary.stl"}) {
        INFO(name);
        canopy::scene s;
        auto const m = load_mesh(tmp.path / name, s);
        REQUIRE(m.triangles.size() == facets.size());
        CHECK(m.positions.size() == 7); // corners shared by facets 0 and 1 are merged by OpenMesh
        for (std::size_t t = 0; t < facets.size(); ++t)
            for (std::size_t k = 0; k < 3; ++k) {
                auto const p = m.positions[m.triangles[t][k]];
                CHECK(p.x == facets[t][k].x);
                CHECK(p.y == facets[t][k].y);
                CHECK(p.z == facets[t][k].z);
            }
        CHECK(m.uvs.empty());
        CHECK(m.normals.empty());
    }
    // assimp's spider, ASCII and binary: every facet of the file, except those with two equal
    // corners (OpenMesh's STL reader skips them; they have no area), counted here.
    auto const degenerate = [](std::vector<float> const& corners) {
        std::size_t n = 0;
        auto const same = [&](std::size_t f, std::size_t a, std::size_t b) {
            return std::equal(&corners[9 * f + 3 * a], &corners[9 * f + 3 * a + 3], &corners[9 * f + 3 * b]);
        };
        for (std::size_t f = 0; f < corners.size() / 9; ++f) n += same(f, 0, 1) || same(f, 0, 2) || same(f, 1, 2);
        return n;
    };
    std::vector<float> ascii_corners, binary_corners;
    std::istringstream text(read_file("/usr/share/assimp/models/STL/Spider_ascii.stl"));
    for (std::string word; text >> word;)
        if (word == "vertex")
            for (int k = 0; k < 3; ++k) {
                text >> word;
                ascii_corners.push_back(std::strtof(word.c_str(), nullptr));
            }
    std::string const bin = read_file("/usr/share/assimp/models/STL/Spider_binary.stl");
    std::uint32_t facets_in_binary = 0;
    std::memcpy(&facets_in_binary, bin.data() + 80, 4);
    for (std::size_t f = 0; f < facets_in_binary; ++f)
        for (std::size_t c = 0; c < 9; ++c) {
            float v;
            std::memcpy(&v, bin.data() + 84 + 50 * f + 12 + 4 * c, 4);
            binary_corners.push_back(v);
        }
    REQUIRE(ascii_corners.size() == 9 * std::size_t(facets_in_binary));
    auto const from_ascii = canopy::read_openmesh("/usr/share/assimp/models/STL/Spider_ascii.stl");
    auto const from_binary = canopy::read_openmesh("/usr/share/assimp/models/STL/Spider_binary.stl");
    CHECK(degenerate(ascii_corners) > 0);
    CHECK(from_ascii.mesh.triangles.size() == facets_in_binary - degenerate(ascii_corners));
    CHECK(from_ascii.degenerate_faces == degenerate(ascii_corners));
    CHECK(from_binary.mesh.triangles.size() == facets_in_binary - degenerate(binary_corners));
    CHECK(from_binary.degenerate_faces == degenerate(binary_corners));
    CHECK(canopy::read_openmesh("/usr/share/assimp/models/STL/triangle_with_two_solids.stl").mesh.triangles.size() == 2);
    CHECK(canopy::read_openmesh("/usr/share/assimp/models/STL/triangle_with_empty_solid.stl").mesh.triangles.size() == 1);
}

TEST_CASE("OM files written by OpenMesh load with their normals and texture coordinates") {
    temp_folder const tmp("canopy_openmesh_test");
    using om_mesh = OpenMesh::PolyMesh_ArrayKernelT<>;
    om_mesh m;
    m.request_vertex_normals();
    m.request_vertex_texcoords2D();
    std::vector<om_mesh::VertexHandle> v;
    for (std::size_t i = 0; i < 5; ++i) {
        auto const& p = pyramid::positions[i];
        v.push_back(m.add_vertex({p.x, p.y, p.z}));
        m.set_normal(v.back(), {pyramid::normals[i].x, pyramid::normals[i].y, pyramid::normals[i].z});
        m.set_texcoord2D(v.back(), {pyramid::uvs[i].x, pyramid::uvs[i].y});
    }
    for (auto const& f : pyramid::faces) {
        std::vector<om_mesh::VertexHandle> corners;
        for (auto i : f) corners.push_back(v[i]);
        REQUIRE(m.add_face(corners).is_valid());
    }
    OpenMesh::IO::Options const options = OpenMesh::IO::Options::Binary | OpenMesh::IO::Options::VertexNormal |
                                          OpenMesh::IO::Options::VertexTexCoord;
    REQUIRE(OpenMesh::IO::write_mesh(m, (tmp.path / "pyramid.om").string(), options));

    auto const r = canopy::read_openmesh(tmp.path / "pyramid.om");
    CHECK(r.faces == 5);
    CHECK(r.polygons == 1);
    // OM stores faces by halfedges: each face may start at another corner. Compare corner sets
    // with their attributes, triangle by triangle, against the written pyramid.
    REQUIRE(r.mesh.triangles.size() == 6);
    REQUIRE(r.mesh.positions.size() == 5);
    REQUIRE(r.mesh.uvs.size() == 6);
    REQUIRE(r.mesh.normals.size() == 6);
    double area = 0.0;
    for (std::size_t t = 0; t < 6; ++t)
        for (std::size_t k = 0; k < 3; ++k) {
            auto const i = r.mesh.triangles[t][k];
            CHECK(r.mesh.positions[i].x == pyramid::positions[i].x);
            CHECK(r.mesh.positions[i].y == pyramid::positions[i].y);
            CHECK(r.mesh.positions[i].z == pyramid::positions[i].z);
            CHECK(r.mesh.uvs[t][k].x == pyramid::uvs[i].x);
            CHECK(r.mesh.uvs[t][k].y == pyramid::uvs[i].y);
            CHECK(r.mesh.normals[t][k].z == pyramid::normals[i].z);
            if (k == 0) {
                auto const& tri = r.mesh.triangles[t];
                auto const& p = r.mesh.positions;
                area += 0.5 * double(length(cross(p[tri[1]] - p[tri[0]], p[tri[2]] - p[tri[0]])));
            }
        }
    // The base (area 4) and four sides (each ½ · 2 · √(1.5² + 1)).
    CHECK(area == Approx(4.0 + 4.0 * std::sqrt(1.5 * 1.5 + 1.0)));

    // Cut short after its header: OpenMesh's reader fails, or reads fewer faces than declared.
    std::string const om = read_file(tmp.path / "pyramid.om");
    require_error(tmp.write("cut.om", om.substr(0, 40)),
                  "the header declares 5 vertices, 5 faces and 8 edges, more than the file's 40 bytes hold");
    require_error(tmp.write("cut.om", om.substr(0, om.size() - 20)), "5 of 5 faces were dropped");
}

TEST_CASE("OBJ through the openmesh plugin keeps per-corner texture coordinates and normals") {
    temp_folder const tmp("canopy_openmesh_test");
    // Vertex 0 carries different vt and vn in the two faces.
    tmp.write("corners.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\n"
                                         "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.25 0.75\n"
                                         "vn 0 0 1\nvn 0 1 0\n"
                                         "f 1/1/1 2/2/1 3/3/1 4/4/1\nf 1/5/2 5/2/2 2/3/2\n");
    auto const r = canopy::read_openmesh(tmp.path / "corners.obj");
    std::vector<std::array<std::uint32_t, 3>> const expected{{0, 1, 2}, {0, 2, 3}, {0, 4, 1}};
    REQUIRE(r.mesh.triangles == expected);
    REQUIRE(r.mesh.uvs.size() == 3);
    REQUIRE(r.mesh.normals.size() == 3);
    std::array<std::array<vec2<float>, 3>, 3> const uv{{{{{0, 0}, {1, 0}, {1, 1}}},
                                                       {{{0, 0}, {1, 1}, {0, 1}}},
                                                       {{{0.25f, 0.75f}, {1, 0}, {1, 1}}}}};
    for (std::size_t t = 0; t < 3; ++t)
        for (std::size_t k = 0; k < 3; ++k) {
            CHECK(r.mesh.uvs[t][k].x == uv[t][k].x);
            CHECK(r.mesh.uvs[t][k].y == uv[t][k].y);
            CHECK(r.mesh.normals[t][k].z == (t < 2 ? 1.0f : 0.0f));
            CHECK(r.mesh.normals[t][k].y == (t < 2 ? 0.0f : 1.0f));
        }
}

TEST_CASE("missing, empty and truncated files are errors naming the file") {
    temp_folder const tmp("canopy_openmesh_test");
    require_error(tmp.path / "missing.ply", "not found");
    CHECK_THROWS_AS(canopy::read_openmesh(tmp.path / "missing.off"), canopy::scene_error);
    for (char const* name : {"empty.ply", "empty.off", "empty.stl", "empty.om", "empty.obj"}) {
        tmp.write(name, "");
        require_error(tmp.path / name, "empty");
    }
    require_error(tmp.write("blank.off", "  \n\n"), "empty");

    std::string const ply = pyramid::ply_binary(false);
    require_error(tmp.write("cut.ply", ply.substr(0, ply.size() - 7)),
                  "element 'face' declares 5 entries of at least 13 bytes");
    require_error(tmp.write("cut_vertices.ply", ply.substr(0, ply.find("end_header") + 11 + 40)),
                  "element 'vertex' declares 5 entries of at least 32 bytes");
    tmp.write("cut_list.ply", ply.substr(0, ply.size() - 2)); // within the last face's indices
    require_error(tmp.path / "cut_list.ply", "file ends in face 4 of 5");

    std::string const stl = read_file("/usr/share/assimp/models/STL/Spider_binary.stl");
    require_error(tmp.write("cut.stl", stl.substr(0, stl.size() - 30)), "truncated");
    require_error(tmp.write("short.stl", stl.substr(0, 40)), "too short");

    std::string const off = pyramid::off();
    require_error(tmp.write("cut.off", off.substr(0, off.rfind("3 3 0 4"))), "file ends after 4 of 5 faces");
    require_error(tmp.write("cut.om", "OM"), "header");
}

TEST_CASE("NaN and infinite coordinates are errors naming the file and the place") {
    temp_folder const tmp("canopy_openmesh_test");
    require_error(tmp.write("nan.off", "OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"),
                  "nan.off:4: vertex 1: coordinate 'nan' is not a finite number");
    require_error(tmp.write("inf.obj", "v 0 0 0\nv 1 0 0\nv 0 1 inf\nf 1 2 3\n"),
                  "inf.obj:3: vertex coordinate 'inf' is not a finite number");
    require_error(tmp.write("huge.obj", "v 0 0 0\nv 1 0 0\nv 0 1 1e999\nf 1 2 3\n"),
                  "huge.obj:3: vertex coordinate '1e999' overflows a float");
    std::string ascii = pyramid::ply_ascii();
    ascii.replace(ascii.find("end_header\n") + 11, 1, "-inf");
    require_error(tmp.write("inf.ply", ascii), "vertex 0: coordinate x = '-inf' is not finite");

    std::string binary = pyramid::ply_binary(false);
    float const nan = std::numeric_limits<float>::quiet_NaN();
    std::memcpy(binary.data() + binary.find("end_header\n") + 11 + 32 + 8, &nan, 4); // vertex 1, z
    require_error(tmp.write("nan.ply", binary), "vertex 1: coordinate z");

    require_error(tmp.write("nan.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 NaN\n"
                                       "vertex 0 1 0\nendloop\nendfacet\nendsolid x\n"),
                  "nan.stl:5: coordinate 'NaN' is not a finite number");
    std::string stl(80, ' ');
    pyramid::put(stl, std::uint32_t(1), false);
    for (float v : {0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, std::numeric_limits<float>::infinity(), 0.0f})
        pyramid::put(stl, v, false);
    pyramid::put(stl, std::uint16_t(0), false);
    require_error(tmp.write("inf.stl", stl), "triangle 0: corner 2 has a coordinate that is not finite");
}

TEST_CASE("vertex indices out of range and faces of fewer than three corners are errors") {
    temp_folder const tmp("canopy_openmesh_test");
    require_error(tmp.write("range.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n"),
                  "range.off:6: face 0: vertex index 3 is out of range (3 vertices)");
    require_error(tmp.write("negative.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"),
                  "vertex index -1 is out of range");
    require_error(tmp.write("two.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n"), "face 0 has 2 corners");
    require_error(tmp.write("counts.off", "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"), "counts from the next line");

    std::string ascii = pyramid::ply_ascii();
    ascii.replace(ascii.rfind("3 3 0 4"), 7, "3 3 0 5");
    require_error(tmp.write("range.ply", ascii), "face 4: vertex index '5' is out of range (5 vertices)");
    std::string binary = pyramid::ply_binary(true);
    binary.replace(binary.size() - 4, 4, std::string("\0\0\0\7", 4)); // the last index, big-endian 7
    require_error(tmp.write("range_big.ply", binary), "face 4: vertex index 7 is out of range (5 vertices)");

    require_error(tmp.write("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n"),
                  "range.obj:5: vertex index 4 is out of range");
    require_error(tmp.write("uv_range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n"),
                  "texture coordinate index 2 is out of range");
    require_error(tmp.write("line.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n"), "line.obj:3: face has 2 corners");
}

TEST_CASE("odd files of assimp-testmodels: invalid OFF is an error, a point cloud is a mesh without triangles") {
    require_error("/usr/share/assimp/models/OFF/invalid.off", "the OFF counts line must hold three numbers");

    // points.ply: four vertices, no face element. It loads as a mesh without triangles, which
    // compile() drops: a scene of nothing else has nothing to trace.
    fs::path const points = "/usr/share/assimp/models/PLY/points.ply";
    canopy::scene s;
    auto const mesh = load_mesh(points, s);
    CHECK(mesh.positions.size() == 4);
    CHECK(mesh.triangles.empty());
    try {
        (void)canopy::compile(s, {.plugins = &openmesh_registry(), .name = points.string()});
        FAIL("compile accepted a scene with nothing to trace");
    } catch (canopy::scene_error const& e) {
        CHECK(std::string(e.what()).find("nothing to trace") != std::string::npos);
    }

    // cube_binary.ply (binary, 12 triangles) and cube_uv.ply (6 quads with u, v): counts from
    // their headers.
    CHECK(canopy::read_openmesh("/usr/share/assimp/models/PLY/cube_binary.ply").mesh.triangles.size() == 12);
    auto const uv = canopy::read_openmesh("/usr/share/assimp/models/PLY/cube_uv.ply");
    CHECK(uv.faces == 6);
    CHECK(uv.polygons == 6);
    CHECK(uv.mesh.triangles.size() == 12);
    CHECK(uv.texcoords);
}

TEST_CASE("the openmesh plugin registers its extensions and keeps OpenMesh's messages off the console") {
    auto const& r = openmesh_registry();
    for (char const* ext : {".ply", ".off", ".stl", ".om", ".obj", ".PLY"}) CHECK(r.has_loader(ext));
    // A face OpenMesh complains about ("complex edge") while reading: nothing may reach std::cerr.
    temp_folder const tmp("canopy_openmesh_test");
    tmp.write("fin.off", "OFF\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n0 -1 0\n3 0 1 2\n3 0 1 3\n3 1 0 3\n");
    std::ostringstream captured;
    auto* const old = std::cerr.rdbuf(captured.rdbuf());
    auto const result = canopy::read_openmesh(tmp.path / "fin.off");
    std::cerr.rdbuf(old);
    CHECK(result.faces == 3);
    CHECK(captured.str().empty());
}

// ---- Hostile files: what OpenMesh's readers would loop on, allocate for or misread ---------------

namespace {

std::string triangle_ply(std::string const& format, std::string const& x_type, std::string const& body) {
    return "ply\nformat " + format + " 1.0\nelement vertex 3\nproperty " + x_type + " x\nproperty " + x_type +
           " y\nproperty " + x_type + " z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n" + body;
}

// OFF BINARY (OpenMesh's layout): the header line, u32 counts, float positions [and normals], faces.
std::string off_binary(std::string const& header, std::uint32_t vertices, std::uint32_t faces,
                       std::vector<float> const& values, std::vector<std::uint32_t> const& face_data) {
    std::string s = header + "\n";
    for (std::uint32_t v : {vertices, faces, 0u}) pyramid::put(s, v, false);
    for (float v : values) pyramid::put(s, v, false);
    for (std::uint32_t v : face_data) pyramid::put(s, v, false);
    return s;
}

} // namespace

TEST_CASE("PLY values OpenMesh's stream cannot read are refused with the value, not looped on") {
    temp_folder const tmp("canopy_openmesh_test");
    // A double that overflows a float: OpenMesh reads coordinates as floats, its stream fails and
    // every later read fails while its loops go on (the face loop then grows a vector without end).
    require_error(tmp.write("double.ply", triangle_ply("ascii", "double", "1e300 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")),
                  "double.ply:10: vertex 0: coordinate x = '1e300' overflows a float");
    require_error(tmp.write("normal.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                                          "property float nx\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
                                          "0 0 0 1\n1 0 0 -3.5e38\n0 1 0 0\n"),
                  "normal.ply:12: vertex 1: nx = '-3.5e38' overflows a float");
    require_error(tmp.write("nan.ply", triangle_ply("ascii", "float", "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n")),
                  "nan.ply:11: vertex 1: coordinate y = 'nan' is not finite");
    require_error(tmp.write("index.ply", triangle_ply("ascii", "float", "0 0 0\n1 0 0\n0 1 0\n3 0 1.0 2\n")),
                  "index.ply:13: face 0: vertex_indices = '1.0' is not an integer");
    std::string binary = triangle_ply("binary_little_endian", "double", "");
    for (double v : {1e300, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0}) pyramid::put(binary, v, false);
    binary += '\3';
    for (std::int32_t i : {0, 1, 2}) pyramid::put(binary, i, false);
    require_error(tmp.write("double_binary.ply", binary),
                  "double_binary.ply: vertex 0: coordinate x = 1e+300 overflows a float");

    // Too small for a float is no error: the stream reads 0, as here.
    tmp.write("tiny.ply", triangle_ply("ascii", "float", "1e-50 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"));
    auto const tiny = canopy::read_openmesh(tmp.path / "tiny.ply");
    REQUIRE(tiny.mesh.positions.size() == 3);
    CHECK(tiny.mesh.positions[0].x == 0.0f);
    CHECK(tiny.mesh.triangles.size() == 1);
}

TEST_CASE("PLY counts are checked against OpenMesh's integers, the file's size and --max-triangles") {
    temp_folder const tmp("canopy_openmesh_test");
    std::string const header = "ply\nformat binary_little_endian 1.0\nelement vertex ";
    std::string const rest = "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    // A count OpenMesh's header reader (an unsigned int from a stream) cannot hold: it would loop
    // on its header for ever.
    require_error(tmp.write("wide.ply", header + "4294967296" + rest),
                  "wide.ply:3: element 'vertex': count 4294967296 is more than OpenMesh reads (2^32 - 1)");
    // More vertices than the file holds: refused before OpenMesh reserves for them.
    require_error(tmp.write("short.ply", header + "100000000" + rest + std::string(36, '\0')),
                  "short.ply: element 'vertex' declares 100000000 entries of at least 12 bytes, "
                  "more than the 36 bytes after the header hold");
    require_error(tmp.write("text.ply", "ply\nformat ascii 1.0\nelement vertex 2000000\nproperty float x\nproperty float y\n"
                                        "property float z\nend_header\n0 0 0\n"),
                  "element 'vertex' declares 2000000 entries of at least 3 values");
    limits_guard const guard;
    canopy::default_limits().max_triangles = 4;
    require_error(tmp.write("many.ply", header + "5" + rest + std::string(60, '\0')),
                  "many.ply: 5 vertices exceed the limit of 4 (--max-triangles)");
}

TEST_CASE("PLY layouts OpenMesh misreads are refused, naming what it would do") {
    temp_folder const tmp("canopy_openmesh_test");
    std::string body;
    for (float v : {0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f}) pyramid::put(body, v, false);
    body += '\3';
    for (std::int32_t i : {0, 1, 2}) pyramid::put(body, i, false);
    std::string const good = triangle_ply("binary_little_endian", "float", body);
    tmp.write("good.ply", good);
    CHECK(canopy::read_openmesh(tmp.path / "good.ply").mesh.triangles.size() == 1);

    // A comment right before end_header: OpenMesh seeks one byte into the data.
    std::string commented = good;
    commented.insert(commented.find("end_header"), "comment last\n");
    tmp.write("comment.ply", commented);
    std::size_t const data = commented.find("end_header\n") + 11;
    require_error(tmp.path / "comment.ply", "comment.ply: OpenMesh would read the binary data from byte " +
                                                std::to_string(data + 1) + ", not from byte " + std::to_string(data));
    // Lists other than the face's vertex_indices: OpenMesh reads one value of them.
    std::string listed = triangle_ply("ascii", "float", "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 6 0 0 1 0 0 1\n");
    listed.insert(listed.find("end_header"), "property list uchar float texcoord\n");
    tmp.write("texcoord.ply", listed);
    require_error(tmp.path / "texcoord.ply",
                  "texcoord.ply: face property 'texcoord': OpenMesh reads no list property other than the face's vertex_indices");
    // Binary coordinates of an integer type: OpenMesh reads none of their bytes.
    require_error(tmp.write("int.ply", triangle_ply("binary_little_endian", "int", std::string(49, '\0'))),
                  "vertex property 'x' of type 'int' is not read by OpenMesh from binary files");
    std::string uint_count = triangle_ply("ascii", "float", "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    uint_count.replace(uint_count.find("list uchar"), 10, "list uint");
    require_error(tmp.write("count.ply", uint_count),
                  "count.ply:8: list 'vertex_indices': count type 'uint' is not one OpenMesh reads");
    require_error(tmp.write("format.ply", "ply\ncomment first\nformat ascii 1.0\nelement vertex 0\nproperty float x\nend_header\n"),
                  "format.ply:2: the line after 'ply' must be 'format <type> <version>'");
    require_error(tmp.write("no_end.ply", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\ncomment end_header\n"),
                  "no_end.ply: PLY header has no end_header line");
}

TEST_CASE("OFF BINARY is checked like ASCII OFF: counts against the file and the limit, values, indices") {
    temp_folder const tmp("canopy_openmesh_test");
    std::vector<float> const triangle{0, 0, 0, 1, 0, 0, 0, 1, 0};
    // Counts of 2·10^9: OpenMesh would reserve for them and loop reading past the end.
    require_error(tmp.write("huge.off", off_binary("OFF BINARY", 2000000000u, 2000000000u, triangle, {3, 0, 1, 2})),
                  "huge.off: 2000000000 vertices exceed the limit of 268435456 (--max-triangles)");
    require_error(tmp.write("short.off", off_binary("OFF BINARY", 1000, 1, triangle, {3, 0, 1, 2})),
                  "short.off: the header declares 1000 vertices of 12 bytes, more than the 52 bytes after it hold");
    require_error(tmp.write("faces.off", off_binary("OFF BINARY", 3, 1000, triangle, {3, 0, 1, 2})),
                  "faces.off: the header declares 1000 faces of at least 16 bytes, more than the 16 bytes");
    require_error(tmp.write("range.off", off_binary("OFF BINARY", 3, 1, triangle, {3, 0, 7, 2})),
                  "range.off: face 0: vertex index 7 is out of range (3 vertices)");
    require_error(tmp.write("corners.off", off_binary("OFF BINARY", 3, 1, triangle, {2, 0, 1, 2})),
                  "corners.off: face 0: has 2 corners (at least 3 needed)");
    std::vector<float> with_nan = triangle;
    with_nan[4] = std::numeric_limits<float>::quiet_NaN();
    require_error(tmp.write("nan.off", off_binary("OFF BINARY", 3, 1, with_nan, {3, 0, 1, 2})),
                  "nan.off: vertex 1: position has a value that is not finite");

    // A good one, with normals: positions, normals and the face as written.
    std::vector<float> values;
    for (std::size_t v = 0; v < 3; ++v) values.insert(values.end(), {triangle[3 * v], triangle[3 * v + 1], triangle[3 * v + 2], 0, 0, 1});
    tmp.write("good.off", off_binary("NOFF BINARY", 3, 1, values, {3, 0, 1, 2}));
    auto const r = canopy::read_openmesh(tmp.path / "good.off");
    REQUIRE(r.mesh.positions.size() == 3);
    CHECK(r.mesh.positions[1].x == 1.0f);
    CHECK(r.mesh.positions[2].y == 1.0f);
    REQUIRE(r.mesh.triangles.size() == 1);
    CHECK(r.mesh.triangles[0] == std::array<std::uint32_t, 3>{0, 1, 2});
    REQUIRE(r.mesh.normals.size() == 1);
    CHECK(r.mesh.normals[0][2].z == 1.0f);
}

TEST_CASE("ASCII OFF: values beyond a float and counts beyond OpenMesh's are refused, normals, uvs and colours read") {
    temp_folder const tmp("canopy_openmesh_test");
    require_error(tmp.write("huge.off", "OFF\n3 1 0\n0 0 0\n1 1e300 0\n0 1 0\n3 0 1 2\n"),
                  "huge.off:4: vertex 1: coordinate '1e300' overflows a float");
    require_error(tmp.write("wide.off", "OFF\n4294967296 1 0\n"),
                  "wide.off:2: OFF count 4294967296 is more than OpenMesh reads (2^32 - 1)");
    require_error(tmp.write("uv.off", "STOFF\n3 1 0\n0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1e39\n3 0 1 2\n"),
                  "uv.off:5: vertex 2: texture coordinate '1e39' overflows a float");
    {
        limits_guard const guard;
        canopy::default_limits().max_triangles = 2;
        require_error(tmp.write("many.off", "OFF\n3 3 0\n"),
                      "many.off:2: 3 vertices exceed the limit of 2 (--max-triangles)");
    }

    // NOFF after a binary NOFF (OpenMesh's reader keeps a file's flags), STOFF with a COFF colour,
    // and a face line with a colour but no C in its header (the colour is not read as a face).
    std::vector<float> values;
    for (float v : {0.f, 0.f, 0.f, 0.f, 0.f, 1.f, 1.f, 0.f, 0.f, 0.f, 0.f, 1.f, 0.f, 1.f, 0.f, 0.f, 0.f, 1.f}) values.push_back(v);
    tmp.write("first.off", off_binary("NOFF BINARY", 3, 1, values, {3, 0, 1, 2}));
    CHECK(canopy::read_openmesh(tmp.path / "first.off").vertex_normals);
    tmp.write("plain.off", "OFF\n# comment\n3 2 0\n0 0 0\n2 0 0\n0 3 0\n3 0 1 2 255 0 0\n3 2 1 0\n");
    auto const plain = canopy::read_openmesh(tmp.path / "plain.off");
    CHECK_FALSE(plain.vertex_normals);
    REQUIRE(plain.mesh.positions.size() == 3);
    CHECK(plain.mesh.positions[1].x == 2.0f);
    CHECK(plain.mesh.positions[2].y == 3.0f);
    using tri = std::array<std::uint32_t, 3>;
    REQUIRE(plain.mesh.triangles.size() == 2);
    CHECK(plain.mesh.triangles[1] == tri{2, 1, 0});
    tmp.write("normals.off", "NOFF\n3 1 0\n0 0 0 0 0 1\n1 0 0 0 1 0\n0 1 0 1 0 0\n3 0 1 2\n");
    auto const n = canopy::read_openmesh(tmp.path / "normals.off");
    REQUIRE(n.mesh.normals.size() == 1);
    CHECK(n.mesh.normals[0][0].z == 1.0f);
    CHECK(n.mesh.normals[0][1].y == 1.0f);
    CHECK(n.mesh.normals[0][2].x == 1.0f);
    tmp.write("uvs.off", "STCOFF\n3 1 0\n0 0 0 255 0 0 0.25 0.5\n1 0 0 0.5 0.5 0.5 1 0.75\n0 1 0 0 1\n3 0 1 2\n");
    auto const uv = canopy::read_openmesh(tmp.path / "uvs.off");
    REQUIRE(uv.mesh.uvs.size() == 1);
    CHECK(uv.mesh.uvs[0][0].x == 0.25f);
    CHECK(uv.mesh.uvs[0][0].y == 0.5f);
    CHECK(uv.mesh.uvs[0][1].x == 1.0f);
    CHECK(uv.mesh.uvs[0][1].y == 0.75f);
    CHECK(uv.mesh.uvs[0][2].y == 1.0f);
}

TEST_CASE("an ASCII STL cut after a complete facet, before its 'endsolid' line, is a truncated file") {
    temp_folder const tmp("canopy_openmesh_test");
    std::string const facet =
        "facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 0 1 0\n endloop\nendfacet\n";
    std::string const whole = "solid t\n" + facet + facet + "endsolid t\n";
    tmp.write("whole.stl", whole);
    canopy::scene s;
    CHECK(load_mesh(tmp.path / "whole.stl", s).triangles.size() == 2);
    tmp.write("spaces.stl", "solid t\n" + facet + "  endsolid\r\n\n  \n");
    canopy::scene s2;
    CHECK(load_mesh(tmp.path / "spaces.stl", s2).triangles.size() == 1);
    // Cut after the second facet, inside 'endsolid', after 'endloop': each names the last line read.
    for (auto const& [text, line] : std::vector<std::pair<std::string, int>>{
             {"solid t\n" + facet + facet, 15}, {"solid t\n" + facet + "endsol", 9},
             {"solid t\n" + facet + facet.substr(0, facet.find("endfacet")), 14}}) {
        INFO(text);
        tmp.write("cut.stl", text);
        require_error(tmp.path / "cut.stl",
                      "cut.stl:" + std::to_string(line) + ": ASCII STL ends before its 'endsolid' line (truncated?)");
    }
}

TEST_CASE("ASCII PLY: a value left over on an entry's line is named, not read as the next entry's") {
    temp_folder const tmp("canopy_openmesh_test");
    std::string const header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                               "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
    require_error(tmp.write("extra_vertex.ply", header + "0 0 0 9\n1 0 0\n0 1 0\n3 0 1 2\n"),
                  "extra_vertex.ply:10: vertex 0: more values on its line than its properties take (next: '9')");
    require_error(tmp.write("extra_face.ply", header + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 7 \r\n"),
                  "extra_face.ply:13: face 0: more values on its line than its properties take (next: '7')");
    // Trailing blanks and CRLF line ends are fine.
    tmp.write("crlf.ply", header + "0 0 0 \r\n1 0 0\t\r\n0 1 0\r\n3 0 1 2\r\n");
    canopy::scene s;
    CHECK(load_mesh(tmp.path / "crlf.ply", s).triangles.size() == 1);
}

TEST_CASE("STL, OBJ and OM: values beyond a float, the lines OpenMesh reads, counts against the limit and the file") {
    temp_folder const tmp("canopy_openmesh_test");
    require_error(tmp.write("huge.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 1e39\nvertex 0 1 0\n"
                                        "endloop\nendfacet\nendsolid x\n"),
                  "huge.stl:5: coordinate '1e39' overflows a float");
    require_error(tmp.write("loop.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\nendsolid x\n"),
                  "loop.stl:6: facet 0: expected 'vertex x y z'");
    require_error(tmp.write("uv.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 1e39\nf 1/1 2/1 3/1\n"),
                  "uv.obj:4: texture coordinate value '1e39' overflows a float");
    {
        limits_guard const guard;
        canopy::default_limits().max_triangles = 1;
        std::string stl(80, ' ');
        pyramid::put(stl, std::uint32_t(2), false);
        stl += std::string(100, '\0');
        require_error(tmp.write("two.stl", stl), "two.stl: 6 vertices exceed the limit of 1 (--max-triangles)");
    }
    std::string om = "OM";
    om += 'T';
    om += char(2);
    for (std::uint32_t v : {100000000u, 1u, 3u}) pyramid::put(om, v, false);
    om += std::string(64, '\0');
    require_error(tmp.write("big.om", om),
                  "big.om: the header declares 100000000 vertices, 1 faces and 3 edges, more than the file's 80 bytes hold");
}

TEST_CASE("a mesh file that is a device or a folder is refused before it is opened") {
    temp_folder const tmp("canopy_openmesh_test");
    fs::create_symlink("/dev/zero", tmp.path / "zero.ply");
    fs::create_directory(tmp.path / "folder.off");
    require_error(tmp.path / "zero.ply", "zero.ply: is a character device, not a regular file");
    CHECK_THROWS_WITH(canopy::read_openmesh(tmp.path / "zero.ply"),
                      Catch::Contains("zero.ply: is a character device, not a regular file"));
    CHECK_THROWS_WITH(canopy::read_openmesh(tmp.path / "folder.off"), Catch::Contains("folder.off: is a folder, not a regular file"));
}

TEST_CASE("OBJ and PLY text is read by canopy.scene:text's rules, as the OBJ and benchmark readers read it") {
    temp_folder const tmp("canopy_openmesh_test");
    std::string const tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    // A byte-order mark would be read by OpenMesh as part of the first statement (dropping a vertex).
    require_error(tmp.write("bom.obj", "\xEF\xBB\xBF" + tri + "f 1 2 3\n"),
                  "bom.obj:1: the file begins with a UTF-8 byte-order mark, which OpenMesh's OBJ reader does not skip");
    require_error(tmp.write("parts.obj", tri + "f 1/1/1/1 2 3\n"), "parts.obj:4: corner '1/1/1/1' has more than three parts");
    require_error(tmp.write("zero.obj", tri + "f 0 2 3\n"), "zero.obj:4: vertex index 0 is not valid (OBJ indices start at 1)");
    require_error(tmp.write("hex.obj", "v 0 0 0\nv 0x1 0 0\nv 0 1 0\nf 1 2 3\n"),
                  "hex.obj:2: vertex coordinate '0x1' is not a number");
    // An index beyond 64 bits is refused as such, not clamped.
    require_error(tmp.write("big.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 99999999999999999999\n"),
                  "big.off:6: face 0: vertex index '99999999999999999999' is beyond the 64-bit integer range");
    // A value PLY reads and drops: a decimal number, an integer for an integer type.
    std::string ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                      "property uchar quality\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                      "0 0 0 1\n1 0 0 2\n0 1 0 Q\n3 0 1 2\n";
    require_error(tmp.write("quality.ply", ply), "quality.ply:13: vertex 2: quality = 'Q' is not an integer");
    ply.replace(ply.find(" Q\n"), 3, " 3\n");
    CHECK(canopy::read_openmesh(tmp.write("quality_ok.ply", ply)).mesh.triangles.size() == 1);
}
