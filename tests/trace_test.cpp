// Tests of the `canopy` command line. `canopy trace` is run on scene and ray files generated here
// and its .hits output is compared, byte for byte, with closest_hit / any_hit of the library
// called in this test on the same geometry (with the bench alpha intersector for
// `--intersector alpha`); bad input and bad options must fail with a message; `canopy render`
// must write readable images of the requested size. For scene files and generators, `canopy info`
// must report what compile() decides in this test, `canopy render` must use the scene's camera,
// and plugins named with --plugin or CANOPY_PLUGIN_PATH must be loaded.
#include <catch2/catch.hpp>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <regex>
#include <string>
#include <vector>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

import canopy.query;
import canopy.plugins.bench;
import canopy.procedural;
import canopy.image;
import canopy.plugins;
import canopy.testing;

namespace {

namespace fs = std::filesystem;
using test_support::temp_folder;
using canopy::vec3;

constexpr float inf = std::numeric_limits<float>::infinity();
constexpr float nan = std::numeric_limits<float>::quiet_NaN();

using run_result = test_support::command_result;

// Runs the canopy program with the given arguments (each single-quoted for the shell).
run_result run_canopy(std::vector<std::string> const& args) {
    std::string command = "'" CANOPY_CLI "'";
    for (auto const& a : args) command += " '" + a + "'";
    return test_support::run_command(command);
}

std::string read_bytes(fs::path const& file) {
    std::ifstream in(file, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_bytes(fs::path const& file, std::string const& bytes) {
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), std::streamsize(bytes.size()));
}

// ---- the generated scene --------------------------------------------------------------------

// Two overlapping icospheres in one mesh: prim i is the i-th triangle.
std::vector<canopy::triangle> make_mesh() {
    auto triangles = canopy::make_icosphere(2, {0.0f, 0.0f, 0.0f}, 1.0f);
    for (auto const& t : canopy::make_icosphere(1, {1.1f, 0.4f, 0.2f}, 0.6f)) triangles.push_back(t);
    for (std::size_t i = 0; i < triangles.size(); ++i) triangles[i].prim_id = std::uint32_t(i);
    return triangles;
}

// Instances of the mesh on a 3 × 3 × 2 lattice, each rotated about an axis and scaled, some
// overlapping their neighbours. Rows of the 3 × 4 object→world matrices.
std::vector<std::array<float, 12>> make_instances() {
    std::vector<std::array<float, 12>> rows;
    int k = 0;
    for (int layer = 0; layer < 2; ++layer)
        for (int j = 0; j < 3; ++j)
            for (int i = 0; i < 3; ++i, ++k) {
                float const angle = 0.37f * float(k), s = 0.6f + 0.1f * float(k % 5);
                float const c = std::cos(angle) * s, n = std::sin(angle) * s;
                rows.push_back({c, 0.0f, n, 2.2f * float(i), 0.0f, s, 0.0f, 2.0f * float(j), -n, 0.0f, c,
                                -2.5f * float(layer)});
            }
    return rows;
}

std::string number(float f) {
    char text[32];
    std::snprintf(text, sizeof text, "%.9g", double(f));
    return text;
}

void write_obj(fs::path const& file, std::vector<canopy::triangle> const& triangles) {
    std::string text = "# generated: two icospheres\n";
    for (auto const& t : triangles)
        for (auto const& v : {t.v0, t.v1, t.v2}) text += "v " + number(v.x) + " " + number(v.y) + " " + number(v.z) + "\n";
    // Faces written alternately with absolute, negative (relative) and a/b/c indices.
    for (std::size_t i = 0; i < triangles.size(); ++i) {
        std::size_t const first = 3 * i + 1;
        if (i % 3 == 0)
            text += "f " + std::to_string(first) + " " + std::to_string(first + 1) + " " + std::to_string(first + 2) + "\n";
        else if (i % 3 == 1)
            text += "f " + std::to_string(first) + "/1/1 " + std::to_string(first + 1) + "//2 " +
                    std::to_string(first + 2) + "/3\n";
        else
            text += "f -" + std::to_string(3 * triangles.size() - first + 1) + " -" +
                    std::to_string(3 * triangles.size() - first) + " -" +
                    std::to_string(3 * triangles.size() - first - 1) + "\n";
    }
    write_bytes(file, text);
}

void write_inst(fs::path const& file, std::string const& mesh_name, std::vector<std::array<float, 12>> const& rows) {
    std::string text = "# generated lattice of instances\nmesh " + mesh_name + "\n";
    for (auto const& r : rows) {
        for (float f : r) text += number(f) + " ";
        text += "\n";
    }
    write_bytes(file, text);
}

// Rays from outside aimed into the scene (direction lengths vary), rays from inside the spheres,
// and rays with narrow [tmin, tmax] windows.
std::vector<canopy::ray> make_rays(canopy::aabb const& bounds) {
    std::mt19937 rng(2024);
    auto uniform = [&](float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(rng); };
    auto inside_bounds = [&] {
        return vec3<float>(uniform(bounds.min.x, bounds.max.x), uniform(bounds.min.y, bounds.max.y),
                           uniform(bounds.min.z, bounds.max.z));
    };
    vec3<float> const centre = (bounds.min + bounds.max) * 0.5f;
    float const radius = canopy::length(bounds.max - bounds.min);
    auto outside = [&] {
        return centre + canopy::normalize(vec3<float>(uniform(-1, 1), uniform(-1, 1), uniform(-1, 1))) * radius;
    };
    std::vector<canopy::ray> rays;
    for (int k = 0; k < 1200; ++k) {
        vec3<float> const origin = outside();
        rays.push_back({origin, 0.0f, (inside_bounds() - origin) * uniform(0.1f, 3.0f), inf});
    }
    for (int k = 0; k < 300; ++k)
        rays.push_back({inside_bounds(), 0.0f, vec3<float>(uniform(-1, 1), uniform(-1, 1), uniform(-1, 1)), inf});
    for (int k = 0; k < 300; ++k) {
        vec3<float> const origin = outside();
        float const tmin = uniform(0.0f, 1.0f);
        rays.push_back({origin, tmin, inside_bounds() - origin, tmin + uniform(0.0f, 0.5f)});
    }
    return rays;
}

// Rays that FORMATS.md says must not crash anything and count as misses: NaN and infinite
// origins, directions and extents, zero directions, empty [tmin, tmax].
std::vector<canopy::ray> make_degenerate_rays(canopy::aabb const& bounds) {
    vec3<float> const c = (bounds.min + bounds.max) * 0.5f;
    vec3<float> const front = c + vec3<float>(0.0f, 0.0f, 2.0f * canopy::length(bounds.max - bounds.min));
    return {{{nan, c.y, c.z}, 0.0f, {1.0f, 0.0f, 0.0f}, inf},
            {front, 0.0f, {0.0f, nan, -1.0f}, inf},
            {front, 0.0f, {0.0f, 0.0f, -inf}, inf},
            {{inf, c.y, c.z}, 0.0f, {-1.0f, 0.0f, 0.0f}, inf},
            {{inf, inf, inf}, 0.0f, {-1.0f, -1.0f, -1.0f}, inf},
            {{-inf, -inf, -inf}, 0.0f, {1.0f, 1.0f, 1.0f}, inf},
            {{inf, -inf, inf}, 0.0f, {-1.0f, 1.0f, -1.0f}, inf},
            {front, 0.0f, {0.0f, 0.0f, 0.0f}, inf},
            {c, 0.0f, {0.0f, 0.0f, 0.0f}, inf},
            {front, 0.0f, {0.0f, 0.0f, -1.0f}, nan},
            {front, nan, {0.0f, 0.0f, -1.0f}, inf},
            {front, 5.0f, {0.0f, 0.0f, -1.0f}, 1.0f}};
}

// The .hits record of a library hit record, written here field by field (FORMATS.md).
std::string hit_bytes(canopy::basic_hit_record<float> const& hr) {
    float const t = hr.hit ? hr.t : inf;
    std::uint32_t const prim = hr.hit ? hr.prim_id : canopy::invalid_id;
    std::uint32_t const inst = hr.hit ? hr.inst_id : canopy::invalid_id;
    float const u = hr.hit ? hr.u : 0.0f, v = hr.hit ? hr.v : 0.0f;
    char record[20];
    std::memcpy(record + 0, &t, 4);
    std::memcpy(record + 4, &prim, 4);
    std::memcpy(record + 8, &inst, 4);
    std::memcpy(record + 12, &u, 4);
    std::memcpy(record + 16, &v, 4);
    return {record, sizeof record};
}

struct hit_fields {
    float t;
    std::uint32_t prim, inst;
    float u, v;
};

hit_fields fields_at(std::string const& bytes, std::size_t i) {
    hit_fields h;
    char const* p = bytes.data() + 20 * i;
    std::memcpy(&h.t, p + 0, 4);
    std::memcpy(&h.prim, p + 4, 4);
    std::memcpy(&h.inst, p + 8, 4);
    std::memcpy(&h.u, p + 12, 4);
    std::memcpy(&h.v, p + 16, 4);
    return h;
}

// The generated files and the same geometry built in memory.
struct trace_fixture {
    temp_folder folder{"canopy_cli_test"};
    std::vector<canopy::triangle> triangles = make_mesh();
    std::vector<std::array<float, 12>> rows = make_instances();
    canopy::bvh<canopy::triangle> mesh;
    std::vector<canopy::instance<canopy::bvh<canopy::triangle>>> instances;
    canopy::bvh<canopy::instance<canopy::bvh<canopy::triangle>>> top;
    std::vector<canopy::ray> mesh_rays, lattice_rays;
    fs::path obj, inst, mesh_rays_file, lattice_rays_file;

    trace_fixture() {
        obj = folder.path / "mesh.obj";
        inst = folder.path / "lattice.inst";
        mesh_rays_file = folder.path / "mesh.rays";
        lattice_rays_file = folder.path / "lattice.rays";
        write_obj(obj, triangles);
        write_inst(inst, "mesh.obj", rows);
        mesh = canopy::build_binned_sah(triangles);
        for (std::size_t k = 0; k < rows.size(); ++k)
            instances.emplace_back(mesh, canopy::affine_transform<float>::from_rows(rows[k]), std::uint32_t(k));
        top = canopy::build_binned_sah(instances);
        mesh_rays = make_rays(mesh.bounds());
        lattice_rays = make_rays(top.bounds());
        canopy::write_bench_rays(mesh_rays_file, mesh_rays);
        canopy::write_bench_rays(lattice_rays_file, lattice_rays);
    }

    std::vector<canopy::ray> const& rays(bool instanced) const { return instanced ? lattice_rays : mesh_rays; }
    fs::path const& scene_file(bool instanced) const { return instanced ? inst : obj; }
    fs::path const& rays_file(bool instanced) const { return instanced ? lattice_rays_file : mesh_rays_file; }

    template <typename I>
    canopy::basic_hit_record<float> reference(canopy::ray const& r, bool instanced, bool closest, I isect) const {
        if (instanced)
            return closest ? canopy::closest_hit(r, &top, &top + 1, isect) : canopy::any_hit(r, &top, &top + 1, isect);
        return closest ? canopy::closest_hit(r, &mesh, &mesh + 1, isect) : canopy::any_hit(r, &mesh, &mesh + 1, isect);
    }

    canopy::basic_hit_record<float> reference(canopy::ray const& r, bool instanced, bool closest, bool alpha) const {
        return alpha ? reference(r, instanced, closest, canopy::bench_alpha_intersector{})
                     : reference(r, instanced, closest, canopy::default_intersector{});
    }
};

// The alpha rule of FORMATS.md, written out: rejected when floor(8u) + floor(8v) is odd.
bool alpha_rule_keeps(float u, float v) {
    auto const cell = [](float x) { return int(std::floor(8.0f * std::fmin(std::fmax(x, 0.0f), 1.0f))); };
    return (cell(u) + cell(v)) % 2 == 0;
}

} // namespace

TEST_CASE("canopy trace --query closest equals the library's closest_hit, byte for byte") {
    trace_fixture const f;
    for (bool const instanced : {false, true})
        for (bool const alpha : {false, true})
            for (char const* threads : {"1", "2"}) {
                INFO((instanced ? "instanced .inst scene" : "single-mesh .obj scene")
                     << (alpha ? ", alpha intersector" : ", no intersector") << ", threads " << threads);
                fs::path const out = f.folder.path / "closest.hits";
                std::vector<std::string> args{"trace", "--scene", f.scene_file(instanced).string(), "--rays",
                                              f.rays_file(instanced).string(), "--query", "closest", "--out",
                                              out.string(), "--threads", threads};
                if (alpha) args.insert(args.end(), {"--intersector", "alpha"});
                auto const result = run_canopy(args);
                INFO(result.output);
                REQUIRE(result.exit_code == 0);
                CHECK(result.output.find("Mrays/s") != std::string::npos);

                auto const& rays = f.rays(instanced);
                std::string const got = read_bytes(out);
                REQUIRE(got.size() == 20 * rays.size());
                int mismatches = 0, hits = 0, rule_violations = 0;
                for (std::size_t i = 0; i < rays.size(); ++i) {
                    auto const expected = f.reference(rays[i], instanced, true, alpha);
                    hits += expected.hit;
                    if (got.compare(20 * i, 20, hit_bytes(expected)) != 0) {
                        ++mismatches;
                        auto const h = fields_at(got, i);
                        if (mismatches <= 5)
                            UNSCOPED_INFO("ray " << i << ": got t=" << h.t << " prim=" << h.prim << " inst=" << h.inst
                                                 << " u=" << h.u << " v=" << h.v << "; expected hit=" << expected.hit
                                                 << " t=" << expected.t << " prim=" << expected.prim_id
                                                 << " inst=" << expected.inst_id);
                    }
                    auto const h = fields_at(got, i);
                    if (alpha && h.prim != canopy::invalid_id) rule_violations += !alpha_rule_keeps(h.u, h.v);
                    if (!instanced) CHECK(h.inst == canopy::invalid_id);
                }
                CHECK(mismatches == 0);
                CHECK(rule_violations == 0);
                CHECK(hits > int(rays.size()) / 4);
                fs::remove(out);
            }
}

TEST_CASE("canopy trace --query any agrees with the library's any_hit on hit or miss") {
    trace_fixture const f;
    for (bool const instanced : {false, true})
        for (bool const alpha : {false, true}) {
            INFO((instanced ? "instanced .inst scene" : "single-mesh .obj scene")
                 << (alpha ? ", alpha intersector" : ", no intersector"));
            fs::path const out = f.folder.path / "any.hits";
            std::vector<std::string> args{"trace", "--scene", f.scene_file(instanced).string(), "--rays",
                                          f.rays_file(instanced).string(), "--query", "any", "--out", out.string()};
            if (alpha) args.insert(args.end(), {"--intersector", "alpha"});
            auto const result = run_canopy(args);
            INFO(result.output);
            REQUIRE(result.exit_code == 0);

            auto const& rays = f.rays(instanced);
            std::string const got = read_bytes(out);
            REQUIRE(got.size() == 20 * rays.size());
            int mismatches = 0, malformed = 0, hits = 0;
            for (std::size_t i = 0; i < rays.size(); ++i) {
                bool const expected = f.reference(rays[i], instanced, false, alpha).hit;
                // Any-hit and closest-hit agree on whether something is hit.
                CHECK(expected == f.reference(rays[i], instanced, true, alpha).hit);
                auto const h = fields_at(got, i);
                bool const reported = h.prim != canopy::invalid_id;
                hits += reported;
                mismatches += reported != expected;
                if (reported) {
                    bool const in_window = h.t >= rays[i].tmin && h.t <= rays[i].tmax;
                    malformed += !in_window || (h.prim != canopy::occluded_unreported && h.prim >= f.triangles.size());
                } else {
                    malformed += !(h.t == inf) || h.inst != canopy::invalid_id;
                }
            }
            CHECK(mismatches == 0);
            CHECK(malformed == 0);
            CHECK(hits > int(rays.size()) / 4);
        }
}

namespace {

// A pinhole camera outside the box looking at its centre, row by row (coherent rays: the batch
// queries trace them as packets), then the degenerate rays.
std::vector<canopy::ray> make_camera_rays(canopy::aabb const& bounds) {
    vec3<float> const c = (bounds.min + bounds.max) * 0.5f;
    float const extent = canopy::length(bounds.max - bounds.min);
    vec3<float> const eye = c + vec3<float>(0.3f, 0.4f, 1.0f) * extent;
    vec3<float> const forward = canopy::normalize(c - eye);
    vec3<float> const right = canopy::normalize(canopy::cross(forward, vec3<float>(0, 1, 0)));
    vec3<float> const up = canopy::cross(right, forward);
    std::vector<canopy::ray> rays;
    for (int j = 0; j < 30; ++j)
        for (int i = 0; i < 41; ++i) {
            float const x = (float(i) + 0.5f) / 41.0f - 0.5f, y = (float(j) + 0.5f) / 30.0f - 0.5f;
            rays.push_back({eye, 0.0f, forward + right * (0.9f * x) + up * (0.9f * y), inf});
        }
    for (auto const& r : make_degenerate_rays(bounds)) rays.push_back(r);
    return rays;
}

} // namespace

TEST_CASE("canopy trace --mode batch writes the hit file of --mode single, byte for byte, and --reps times passes") {
    trace_fixture const f;
    // Camera rays (packets), then the fixture's random rays (single rays): closest hit with the
    // alpha rule through the instanced scene, any hit without an intersector through the mesh.
    for (bool const instanced : {true, false}) {
        char const* const query = instanced ? "closest" : "any";
        bool const alpha = instanced;
        INFO((instanced ? "instanced .inst scene, closest, alpha" : "single-mesh .obj scene, any, no intersector"));
        auto rays = make_camera_rays(instanced ? f.top.bounds() : f.mesh.bounds());
        rays.insert(rays.end(), f.rays(instanced).begin(), f.rays(instanced).end());
        fs::path const rays_file = f.folder.path / "camera.rays";
        canopy::write_bench_rays(rays_file, rays);
        std::string files[2];
        for (int m = 0; m < 2; ++m) {
            std::string const mode = m == 0 ? "single" : "batch";
            fs::path const out = f.folder.path / (mode + ".hits");
            std::vector<std::string> args{"trace", "--scene", f.scene_file(instanced).string(), "--rays",
                                          rays_file.string(), "--query", query, "--out", out.string(), "--mode", mode,
                                          "--reps", "2", "--threads", "2"};
            if (alpha) args.insert(args.end(), {"--intersector", "alpha"});
            auto const result = run_canopy(args);
            INFO(result.output);
            REQUIRE(result.exit_code == 0);
            // Camera rays as packets: 41 × 30 rays, a few groups straddling a change of octant
            // (the count printed: rays traced in packets).
            if (m == 1) {
                auto const at = result.output.find("rays (batch: ");
                REQUIRE(at != std::string::npos);
                CHECK(std::stoul(result.output.substr(at + 13)) > 8 * 60);
            }
            CHECK_THAT(result.output, Catch::Contains("rays (" + mode) && Catch::Contains(") in ") &&
                                          Catch::Contains("(median of 2 after a warm-up pass)") &&
                                          Catch::Contains("Mrays/s"));
            files[m] = read_bytes(out);
            fs::remove(out);
        }
        REQUIRE(files[0].size() == 20 * rays.size());
        CHECK(files[0] == files[1]);
        // Both are the library's single-ray results.
        int mismatches = 0, hits = 0;
        for (std::size_t i = 0; i < rays.size(); ++i) {
            auto const expected = f.reference(rays[i], instanced, instanced, alpha);
            hits += expected.hit;
            mismatches += files[1].compare(20 * i, 20, hit_bytes(expected)) != 0;
        }
        CHECK(mismatches == 0);
        CHECK(hits > int(rays.size()) / 8);
    }
}

TEST_CASE("canopy trace survives NaN and infinite rays and zero directions: they miss") {
    trace_fixture const f;
    for (bool const instanced : {false, true}) {
        auto const rays = make_degenerate_rays(instanced ? f.top.bounds() : f.mesh.bounds());
        fs::path const rays_file = f.folder.path / "degenerate.rays";
        canopy::write_bench_rays(rays_file, rays);
        for (char const* query : {"closest", "any"})
            for (char const* isect : {"none", "alpha"}) {
                INFO(f.scene_file(instanced).filename().string() << ", " << query << ", intersector " << isect);
                fs::path const out = f.folder.path / "degenerate.hits";
                auto const result = run_canopy({"trace", "--scene", f.scene_file(instanced).string(), "--rays",
                                                rays_file.string(), "--query", query, "--out", out.string(),
                                                "--intersector", isect});
                INFO(result.output);
                CHECK(result.exit_code == 0);
                if (result.exit_code != 0) continue;
                std::string const got = read_bytes(out);
                REQUIRE(got.size() == 20 * rays.size());
                for (std::size_t i = 0; i < rays.size(); ++i) {
                    INFO("ray " << i);
                    CHECK(fields_at(got, i).prim == canopy::invalid_id);
                    CHECK(fields_at(got, i).t == inf);
                }
            }
    }
}

TEST_CASE("canopy trace rejects a ray file whose size is not a multiple of 32, naming the file") {
    trace_fixture const f;
    fs::path const bad = f.folder.path / "truncated.rays";
    write_bytes(bad, read_bytes(f.mesh_rays_file).substr(0, 32 * 3 + 5));
    auto const result = run_canopy({"trace", "--scene", f.obj.string(), "--rays", bad.string(), "--query", "closest",
                                    "--out", (f.folder.path / "bad.hits").string()});
    INFO(result.output);
    CHECK(result.exit_code != 0);
    CHECK(result.output.find(bad.string()) != std::string::npos);
    CHECK(result.output.find("32") != std::string::npos);

    auto const missing = run_canopy({"trace", "--scene", f.obj.string(), "--rays", (f.folder.path / "none.rays").string(),
                                     "--query", "closest", "--out", (f.folder.path / "bad.hits").string()});
    INFO(missing.output);
    CHECK(missing.exit_code != 0);
    CHECK(missing.output.find("none.rays") != std::string::npos);
}

namespace {

struct bad_call {
    std::vector<std::string> args;
    std::string message;
};

// Each call exits with status 2, the message and the usage: the command's, or the program's
// when no command is named.
void check_usage_errors(std::vector<bad_call> const& calls) {
    for (auto const& call : calls) {
        std::string joined;
        for (auto const& a : call.args) joined += a + " ";
        INFO("canopy " << joined);
        auto const result = run_canopy(call.args);
        INFO(result.output);
        CHECK(result.exit_code == 2);
        CHECK_THAT(result.output, Catch::Contains(call.message));
        bool const command = !call.args.empty() && (call.args[0] == "trace" || call.args[0] == "render" || call.args[0] == "info");
        CHECK_THAT(result.output, Catch::Contains(command ? "usage: canopy " + call.args[0] : "usage: canopy"));
    }
}

} // namespace

TEST_CASE("canopy gives a usage message and a non-zero exit for bad arguments") {
    temp_folder const folder("canopy_cli_test");
    std::string const out = (folder.path / "x.hits").string();
    check_usage_errors({
        {{"trace", "--bogus", "1"}, "usage: canopy trace"},
        {{"trace", "--scene", "a.obj", "--rays", "a.rays", "--query", "nearest", "--out", out}, "usage: canopy trace"},
        {{"trace", "--scene", "a.obj", "--rays", "a.rays", "--query", "closest"}, "usage: canopy trace"},
        {{"trace", "--scene", "a.obj", "--rays", "a.rays", "--query", "closest", "--out", out, "--intersector", "cheap"},
         "usage: canopy trace"},
        {{"trace", "--scene"}, "usage: canopy trace"},
        {{"trace", "--scene", "a.obj", "--rays", "a.rays", "--query", "any", "--out", out, "--mode", "packet"},
         "usage: canopy trace"},
        {{"trace", "--scene", "a.obj", "--rays", "a.rays", "--query", "any", "--out", out, "--reps", "0"},
         "usage: canopy trace"},
        {{"render", "--frobnicate", "3"}, "usage: canopy render"},
        {{"render", "--size", "big"}, "usage: canopy render"},
        {{"render", "--kernel", "raster"}, "usage: canopy render"},
        {{"info"}, "usage: canopy info"},
        {{"paint"}, "usage: canopy"},
        {{}, "usage: canopy"},
    });
    for (char const* command : {"trace", "render", "info"}) {
        INFO("canopy " << command << " --help");
        auto const result = run_canopy({command, "--help"});
        CHECK(result.exit_code == 0);
        CHECK(result.output.find(std::string("usage: canopy ") + command) != std::string::npos);
        // Every command's help names the limit options with their defaults: the values of
        // canopy::resource_limits, which the help once misstated (2^24 placements for 2^22).
        canopy::resource_limits const defaults{};
        CHECK(defaults.max_placements == 4194304);
        for (std::string const& text :
             {"--max-file-bytes N  bytes of one input file (default " + std::to_string(defaults.max_file_bytes),
              std::string("--max-texels N"), "(default " + std::to_string(defaults.max_texels),
              std::string("--max-total-texels N"), "(default " + std::to_string(defaults.max_total_texels) + " = 2^28",
              std::string("--max-triangles N"), "(default " + std::to_string(defaults.max_triangles),
              "--max-placements N  mesh placements after instances are flattened (default " +
                  std::to_string(defaults.max_placements) + " = 2^22)",
              std::string("--max-depth N"), "(default " + std::to_string(defaults.max_depth) + ")"})
            CHECK_THAT(result.output, Catch::Contains(text));
    }
}

TEST_CASE("canopy render with no scene writes the four Figure-1 images at the requested size") {
    temp_folder const folder("canopy_cli_test");
    fs::path const out = folder.path / "figures";
    auto const result = run_canopy({"render", "-o", out.string(), "--size", "40x30"});
    INFO(result.output);
    REQUIRE(result.exit_code == 0);
    CHECK(result.output.find("Mrays/s") != std::string::npos);
    for (char const* name : {"1_billboards_alpha_ignored.png", "2_texture_alpha_mask.png",
                             "3_procedural_alpha_mask.png", "4_bvh_cost_heatmap.png"}) {
        INFO(name);
        REQUIRE(fs::exists(out / name));
        auto const image = canopy::read_image(out / name);
        CHECK(image.width == 40);
        CHECK(image.height == 30);
    }
}

TEST_CASE("canopy render SCENE writes one image named after the scene") {
    temp_folder const folder("canopy_cli_test");
    write_obj(folder.path / "mesh.obj", make_mesh());
    write_inst(folder.path / "lattice.inst", "mesh.obj", make_instances());
    auto const result = run_canopy({"render", (folder.path / "lattice.inst").string(), "-o", folder.path.string(),
                                    "--size", "32x24", "--intersector", "alpha"});
    INFO(result.output);
    REQUIRE(result.exit_code == 0);
    REQUIRE(fs::exists(folder.path / "lattice.png"));
    auto const image = canopy::read_image(folder.path / "lattice.png");
    CHECK(image.width == 32);
    CHECK(image.height == 24);
}

// OpenImageIO is loaded (through canopy.image's backend) only when an image is read or written:
// without it, what needs no image works, and what does names the image and the problem.
TEST_CASE("canopy loads its image backend only to read or write images, and without it render names the image and the problem") {
    temp_folder const folder("canopy_cli_test");
    write_obj(folder.path / "mesh.obj", make_mesh());
    write_inst(folder.path / "lattice.inst", "mesh.obj", make_instances());
    auto const with_backend = [&](std::string const& backend, std::vector<std::string> const& args) {
        REQUIRE(::setenv("CANOPY_IMAGE_BACKEND", backend.c_str(), 1) == 0);
        auto const result = run_canopy(args);
        ::unsetenv("CANOPY_IMAGE_BACKEND");
        return result;
    };
    std::string const missing = (folder.path / "no_such_backend.so").string();
    auto const info = with_backend(missing, {"info", (folder.path / "lattice.inst").string()});
    INFO(info.output);
    CHECK(info.exit_code == 0);
    CHECK_THAT(info.output, Catch::Contains("triangles"));

    auto const rendered = with_backend(missing, {"render", (folder.path / "lattice.inst").string(), "-o",
                                                 folder.path.string(), "--size", "8x6"});
    INFO(rendered.output);
    CHECK(rendered.exit_code == 1);
    CHECK_THAT(rendered.output, Catch::Contains("lattice.png") &&
                                    Catch::Contains("image support is unavailable: cannot load its OpenImageIO backend") &&
                                    Catch::Contains("no_such_backend.so"));
    CHECK_FALSE(fs::exists(folder.path / "lattice.png"));

    // A shared library that is not a backend (the example scene plugin) is named as such.
    auto const wrong = with_backend(CANOPY_SPIRAL_PLUGIN, {"render", (folder.path / "lattice.inst").string(), "-o",
                                                           folder.path.string(), "--size", "8x6"});
    INFO(wrong.output);
    CHECK(wrong.exit_code == 1);
    CHECK_THAT(wrong.output, Catch::Contains("is not a canopy image backend of version 1"));

    // And with the backend, the same command writes the image.
    auto const written = run_canopy({"render", (folder.path / "lattice.inst").string(), "-o", folder.path.string(),
                                     "--size", "8x6"});
    INFO(written.output);
    REQUIRE(written.exit_code == 0);
    CHECK(canopy::read_image(folder.path / "lattice.png").width == 8);
}

TEST_CASE("canopy render --mode batch writes the images of --mode single, byte for byte") {
    temp_folder const folder("canopy_cli_test");
    auto const images = [&](std::vector<std::string> args, std::string const& mode,
                            std::vector<std::string> const& names) {
        fs::path const out = folder.path / mode;
        args.insert(args.end(), {"-o", out.string(), "--size", "61x45", "--mode", mode, "--threads", "2"});
        auto const result = run_canopy(args);
        INFO(result.output);
        REQUIRE(result.exit_code == 0);
        std::vector<std::string> bytes;
        for (auto const& name : names) bytes.push_back(read_bytes(out / name));
        fs::remove_all(out);
        return bytes;
    };
    // The demo: figures 1-3 in the mode, the heat map always pixel by pixel.
    std::vector<std::string> const figures{"1_billboards_alpha_ignored.png", "2_texture_alpha_mask.png",
                                           "3_procedural_alpha_mask.png", "4_bvh_cost_heatmap.png"};
    auto const demo_single = images({"render"}, "single", figures);
    auto const demo_batch = images({"render"}, "batch", figures);
    for (std::size_t k = 0; k < figures.size(); ++k) {
        INFO(figures[k]);
        CHECK(!demo_single[k].empty());
        CHECK(demo_single[k] == demo_batch[k]);
    }
    // A scene with the AO and path kernels, jittered samples, through the texture mask and the
    // bench formats' alpha rule.
    write_obj(folder.path / "mesh.obj", make_mesh());
    write_inst(folder.path / "lattice.inst", "mesh.obj", make_instances());
    std::string const scene = (folder.path / "lattice.inst").string();
    for (auto const& [kernel, intersector] : {std::pair{"ao", "alpha"}, std::pair{"path", "bench"},
                                              std::pair{"primary", "none"}}) {
        INFO(kernel << " " << intersector);
        std::vector<std::string> const args{"render", scene, "--kernel", kernel, "--intersector", intersector,
                                            "--spp", "2"};
        CHECK(images(args, "single", {"lattice.png"}) == images(args, "batch", {"lattice.png"}));
    }
}

// ---- scene files, generators and plugins through the command line ---------------------------

namespace {

// Two instances of a two-mesh prototype and one untransformed mesh, with a camera looking at a red
// square that fills the middle of the view (the rest is sky).
std::string const scene_json = R"({
  "materials": [{"name": "red", "colour": [1, 0, 0]}],
  "meshes": [
    {"name": "square", "material": "red", "positions": [-1, -1, 0,  1, -1, 0,  1, 1, 0,  -1, 1, 0], "indices": [0, 1, 2,  0, 2, 3]},
    {"name": "post", "positions": [0, 0, -5,  0.1, 0, -5,  0, 0.1, -5], "indices": [0, 1, 2]}
  ],
  "prototypes": [{"name": "pair", "type": "group", "children": [
    {"type": "mesh", "mesh": "post"},
    {"type": "transform", "translate": [0, 0.5, 0], "children": [{"type": "mesh", "mesh": "post"}]}]}],
  "nodes": [
    {"type": "mesh", "mesh": "square"},
    {"type": "instance", "target": "pair", "translate": [30, 0, 0]},
    {"type": "instance", "target": "pair", "translate": [-30, 0, 0]},
    {"type": "camera", "eye": [0, 0, 4], "target": [0, 0, 0], "fovy": 60}
  ]
})";

} // namespace

TEST_CASE("canopy info SCENE reports the counts and every decision compile() makes") {
    temp_folder const folder("canopy_cli_scene_test");
    auto const file = folder.write("pairs.json", scene_json);
    canopy::registry const& r = canopy::builtin_registry();
    canopy::scene const s = canopy::load_scene(file, r);
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r});
    REQUIRE(c.levels == 2); // the reference below is of a two-level scene
    auto const result = run_canopy({"info", file.string()});
    INFO(result.output);
    REQUIRE(result.exit_code == 0);
    CHECK_THAT(result.output, Catch::Contains(std::to_string(s.nodes().size()) + " nodes, 2 meshes, 1 materials"));
    CHECK_THAT(result.output, Catch::Contains("2 instance levels"));
    CHECK_THAT(result.output, Catch::Contains(std::to_string(c.statistics.triangles_placed) + " triangles placed"));
    for (auto const& decision : c.statistics.decisions) CHECK_THAT(result.output, Catch::Contains("- " + decision));
    CHECK_THAT(result.output, Catch::Contains("top-level BVH: 3 primitives"));
}

TEST_CASE("canopy render SCENE uses the scene's camera") {
    temp_folder const folder("canopy_cli_scene_test");
    auto const file = folder.write("pairs.json", scene_json);
    auto const result = run_canopy({"render", file.string(), "-o", folder.path.string(), "--size", "40x40"});
    INFO(result.output);
    REQUIRE(result.exit_code == 0);
    auto const image = canopy::read_image(folder.path / "pairs.png");
    REQUIRE(image.width == 40);
    // From (0, 0, 4) with a 60° field of view the square covers |x|, |y| < tan(30°)⁻¹ / 4 ≈ 0.43 of
    // the half-width around the centre: the centre is red, a corner is sky (bluish).
    float const* centre = image.at(20, 20);
    float const* corner = image.at(1, 1);
    CHECK(centre[0] > 2.0f * centre[1]);
    CHECK(centre[0] > 2.0f * centre[2]);
    CHECK(corner[2] > corner[0]);
}

TEST_CASE("canopy render and info load shared-library plugins given by --plugin or CANOPY_PLUGIN_PATH") {
    temp_folder const folder("canopy_cli_scene_test");
    auto const without = run_canopy({"info", "gen:spiral_staircase:steps=5"});
    CHECK(without.exit_code == 1);
    CHECK_THAT(without.output, Catch::Contains("generator 'spiral_staircase': is not registered"));

    auto const rendered = run_canopy({"render", "gen:spiral_staircase:steps=5", "--plugin", CANOPY_SPIRAL_PLUGIN, "-o",
                                      folder.path.string(), "--size", "24x24"});
    INFO(rendered.output);
    REQUIRE(rendered.exit_code == 0);
    CHECK(canopy::read_image(folder.path / "spiral_staircase.png").width == 24);

    // 12 triangles per step (the plugin's documented count), through the environment variable.
    std::string const plugin_folder = fs::path(CANOPY_SPIRAL_PLUGIN).parent_path().string();
    REQUIRE(::setenv("CANOPY_PLUGIN_PATH", plugin_folder.c_str(), 1) == 0);
    auto const info = run_canopy({"info", "gen:spiral_staircase:steps=5"});
    ::unsetenv("CANOPY_PLUGIN_PATH");
    INFO(info.output);
    REQUIRE(info.exit_code == 0);
    CHECK_THAT(info.output, Catch::Contains("(60 triangles stored)"));

    auto const listed = run_canopy({"info", "--plugins", "--plugin", CANOPY_SPIRAL_PLUGIN});
    CHECK(listed.exit_code == 0);
    for (char const* name : {".gltf", ".glb", ".json", ".ply", ".off", ".stl", ".om", ".inst", ".png", "sphere",
                             "terrain", "billboard_forest", "spiral_staircase", "canopy_plugin_spiral.so"})
        CHECK_THAT(listed.output, Catch::Contains(name));
}

TEST_CASE("canopy render and info name the file, the line and the problem for a bad scene file") {
    temp_folder const folder("canopy_cli_scene_test");
    auto const obj = folder.write("broken.obj", "v 0 0 0\nv 1 0 0\nv 0 q 0\nf 1 2 3\n");
    for (std::vector<std::string> const& call : {std::vector<std::string>{"info", obj.string()},
                                                 std::vector<std::string>{"render", obj.string(), "-o", folder.path.string()}}) {
        auto const result = run_canopy(call);
        std::string const& command = call[0];
        INFO(command << ": " << result.output);
        CHECK(result.exit_code == 1);
        CHECK_THAT(result.output, Catch::Contains(obj.string() + ":3: bad number 'q'"));
    }
    auto const unknown = run_canopy({"info", folder.write("scene.xyz", "1 2 3\n").string()});
    CHECK(unknown.exit_code == 1);
    CHECK_THAT(unknown.output, Catch::Contains("unknown extension '.xyz'"));
}

// ---- hostile arguments, limits, outputs and cameras through the command line ----------------

namespace {

// A shell command line for the program: each argument single-quoted.
std::string canopy_command(std::vector<std::string> const& args) {
    std::string command = "'" CANOPY_CLI "'";
    for (auto const& a : args) command += " '" + a + "'";
    return command;
}

// sRGB-encoded display value → linear (the inverse of canopy::to_srgb, written out).
double srgb_to_linear(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }

// Mean of the linear R, G and B of every pixel of an 8-bit sRGB image.
double mean_linear(canopy::rgba_image const& image) {
    double sum = 0.0;
    for (int y = 0; y < image.height; ++y)
        for (int x = 0; x < image.width; ++x)
            for (int c = 0; c < 3; ++c) sum += srgb_to_linear(double(image.at(x, y)[c]));
    return sum / (3.0 * double(image.width) * double(image.height));
}

// A JSON scene: inline meshes (name, material, 12 numbers of a quad's corners in order) and extra
// nodes.
struct json_quad {
    std::string name, material;
    std::array<float, 12> corners;
};

std::string scene_with(std::vector<json_quad> const& quads, std::string const& materials, std::string const& nodes) {
    std::string meshes, placed;
    for (auto const& q : quads) {
        std::string positions;
        for (float f : q.corners) positions += (positions.empty() ? "" : ", ") + number(f);
        meshes += std::string(meshes.empty() ? "" : ",\n") + "{\"name\": \"" + q.name + "\", " +
                  (q.material.empty() ? "" : "\"material\": \"" + q.material + "\", ") + "\"positions\": [" +
                  positions + "], \"indices\": [0, 1, 2, 0, 2, 3]}";
        placed += std::string(placed.empty() ? "" : ", ") + "{\"type\": \"mesh\", \"mesh\": \"" + q.name + "\"}";
    }
    return "{\"materials\": [" + materials + "],\n\"meshes\": [" + meshes + "],\n\"nodes\": [" + placed +
           (nodes.empty() ? "" : ", " + nodes) + "]}\n";
}

// A horizontal square [-s, s]² at height y, facing up.
json_quad floor_quad(std::string name, float s, float y, std::string material = {}) {
    return {std::move(name), std::move(material), {-s, y, -s, -s, y, s, s, y, s, s, y, -s}};
}

} // namespace

TEST_CASE("canopy reads every number whole and in range, naming the option and the range (exit 2)") {
    check_usage_errors({
        {{"render", "--size", "64x48junk"},
         "--size must be WxH with W and H whole numbers from 1 to 16384 (e.g. 800x600), not '64x48junk'"},
        {{"render", "--spp", "1e9"}, "--spp must be a whole number from 1 to 65536, not '1e9'"},
        {{"render", "--spp", "4294967297"}, "--spp must be a whole number from 1 to 65536, not '4294967297'"},
        {{"trace", "--threads", "2x"}, "--threads must be a whole number from 1 to 1024, not '2x'"},
        {{"render", "--exposure", "nan"}, "--exposure must be a number of stops from -30 to 30, not 'nan'"},
        {{"render", "--kernel", "ao", "--ao-radius", "-2%"}, "--ao-radius must be a number over 0"},
        {{"info", "x.obj", "--max-texels", "12k"},
         "--max-texels must be a whole number from 1 to 18446744073709551615, not '12k'"},
        {{"render", "--size", "100x100", "--max-texels", "9999"},
         "--size 100x100 is 10000 pixels, over the limit of 9999 (--max-texels)"},
        // A long argument is quoted by its first 40 characters.
        {{"render", "--spp", std::string(300, '9')}, "not '" + std::string(40, '9') + "...'"},
    });
}

TEST_CASE("canopy refuses unknown, repeated and value-less options and stray arguments (exit 2)") {
    check_usage_errors({
        {{"render", "--size=64x48"}, "unknown option '--size=64x48'"},
        {{"render", "--spp"}, "option --spp needs a value"},
        {{"render", "--spp", "2", "--spp", "3"}, "option --spp given more than once"},
        {{"render", "-o", "--size", "3x3"}, "option -o needs a value, not the option '--size'"},
        {{"render", "--max-triangles", ""}, "option --max-triangles has an empty value"},
        {{"trace", "stray", "--scene", "a.obj"}, "unexpected argument 'stray'"},
        {{"info", "a.obj", "b.obj"}, "info takes one scene, not 2"},
        {{"render", ""}, "an empty argument (a file name was expected)"},
    });
}

TEST_CASE("canopy render refuses options that would be ignored (exit 2)") {
    check_usage_errors({
        {{"render", "--intersector", "alpha"}, "--intersector applies to a SCENE"},
        {{"render", "s.obj", "--kernel", "ao", "--intersector", "costs"}, "--intersector costs draws the heat map"},
        {{"render", "s.obj", "--kernel", "heatmap", "--tonemap", "aces"}, "not to the heat map"},
        {{"render", "--ao-radius", "2"}, "--ao-radius applies to --kernel ao"},
        {{"render", "s.obj", "--kernel", "heatmap", "--mode", "batch"},
         "--mode batch does not apply to the heat map"},
        {{"render", "--mode", "packets"}, "--mode must be single or batch, not 'packets'"},
        {{"render", "gen:sphere:subdivisions=2,subdivisions=3"},
         "generator parameter 'subdivisions' given more than once"},
    });
}

TEST_CASE("canopy's limit options are set before anything is loaded") {
    temp_folder const folder("canopy_cli_limits_test");
    auto const scene = folder.write("pairs.json", scene_json);
    std::string const size = std::to_string(fs::file_size(scene));
    std::string const limit = std::to_string(fs::file_size(scene) - 1);
    auto const render = run_canopy({"render", scene.string(), "--max-file-bytes", limit, "-o", folder.path.string()});
    CHECK(render.exit_code == 1);
    CHECK_THAT(render.output, Catch::Contains(scene.string() + ": is " + size + " bytes, over the limit of " + limit +
                                              " bytes per file (--max-file-bytes)"));
    CHECK_FALSE(fs::exists(folder.path / "pairs.png"));
    auto const info = run_canopy({"info", scene.string(), "--max-file-bytes", limit});
    CHECK(info.exit_code == 1);
    CHECK_THAT(info.output, Catch::Contains(scene.string() + ": is " + size + " bytes, over the limit of " + limit));
    CHECK(run_canopy({"info", scene.string(), "--max-file-bytes", size}).exit_code == 0);

    // trace: the ray file and the scene file.
    trace_fixture const f;
    std::string const ray_bytes = std::to_string(fs::file_size(f.mesh_rays_file));
    auto const rays = run_canopy({"trace", "--scene", f.obj.string(), "--rays", f.mesh_rays_file.string(), "--query",
                                  "any", "--out", (f.folder.path / "x.hits").string(), "--max-file-bytes",
                                  std::to_string(fs::file_size(f.obj))});
    CHECK(rays.exit_code == 1);
    CHECK_THAT(rays.output, Catch::Contains(f.mesh_rays_file.string() + ": is " + ray_bytes +
                                            " bytes, over the limit of " + std::to_string(fs::file_size(f.obj)) +
                                            " bytes per file (--max-file-bytes) (ray file)"));
    CHECK_FALSE(fs::exists(f.folder.path / "x.hits"));
}

TEST_CASE("canopy trace refuses inputs that are not regular files or hold nothing to trace") {
    trace_fixture const f;
    fs::path const out = f.folder.path / "x.hits";
    fs::create_directories(f.folder.path / "folder.rays");
    write_bytes(f.folder.path / "empty.rays", "");
    write_bytes(f.folder.path / "points.obj", "v 0 0 0\nv 1 0 0\n# no faces\n");
    write_bytes(f.folder.path / "none.inst", "mesh mesh.obj\n");
    REQUIRE(::mkfifo((f.folder.path / "pipe.rays").c_str(), 0600) == 0);
    struct bad_input {
        std::string scene, rays, message;
    };
    std::vector<bad_input> const inputs{
        {f.obj.string(), (f.folder.path / "folder.rays").string(), "folder.rays: is a folder, not a regular file (ray file)"},
        {f.obj.string(), "/dev/zero", "/dev/zero: is a character device, not a regular file (ray file)"},
        {f.obj.string(), (f.folder.path / "pipe.rays").string(), "pipe.rays: is a FIFO, not a regular file (ray file)"},
        {f.obj.string(), (f.folder.path / "empty.rays").string(), "empty.rays: holds no rays (the file is empty): nothing to trace"},
        {(f.folder.path / "points.obj").string(), f.mesh_rays_file.string(), "points.obj: no faces ('f' lines): nothing to trace"},
        {(f.folder.path / "none.inst").string(), f.mesh_rays_file.string(), "none.inst: no instance lines (12 numbers each): nothing to trace"},
        {(f.folder.path / "folder.rays" / "x.obj").string(), f.mesh_rays_file.string(), "x.obj: file not found"},
    };
    for (auto const& input : inputs) {
        INFO(input.scene << " " << input.rays);
        auto const result = run_canopy({"trace", "--scene", input.scene, "--rays", input.rays, "--query", "closest",
                                        "--out", out.string()});
        INFO(result.output);
        CHECK(result.exit_code == 1);
        CHECK_THAT(result.output, Catch::Contains(input.message));
        CHECK_FALSE(fs::exists(out)); // checked writable, then left as it was: absent
    }
}

TEST_CASE("canopy render checks its output folder and images before loading, and after writing") {
    // The image through a link to /dev/full; an output folder that cannot be made, or whose image
    // is taken by a folder, is found before anything is loaded.
    temp_folder const folder("canopy_cli_output_test");
    fs::create_directories(folder.path / "full");
    fs::create_symlink("/dev/full", folder.path / "full" / "sphere.png");
    auto const render_full = run_canopy({"render", "gen:sphere", "-o", (folder.path / "full").string(), "--size", "16x16"});
    CHECK(render_full.exit_code == 1);
    CHECK_THAT(render_full.output, Catch::Contains("full/sphere.png: cannot write: No space left on device"));
    CHECK_THAT(render_full.output, !Catch::Contains("rendered 1 image"));

    auto const file = folder.write("a_file", "x");
    auto const under_file = run_canopy({"render", "gen:sphere", "-o", (file / "sub").string(), "--size", "16x16"});
    CHECK(under_file.exit_code == 1);
    CHECK_THAT(under_file.output, Catch::Contains((file / "sub").string() + ": cannot create the output folder: Not a directory"));
    CHECK_THAT(under_file.output, !Catch::Contains("loaded in"));
    auto const on_file = run_canopy({"render", "-o", file.string(), "--size", "16x16"});
    CHECK(on_file.exit_code == 1);
    CHECK_THAT(on_file.output, Catch::Contains(file.string() + ": the output folder exists and is not a folder"));
    fs::create_directories(folder.path / "taken" / "3_procedural_alpha_mask.png");
    auto const taken = run_canopy({"render", "-o", (folder.path / "taken").string(), "--size", "16x16"});
    CHECK(taken.exit_code == 1);
    CHECK_THAT(taken.output, Catch::Contains("3_procedural_alpha_mask.png: cannot be written: Is a directory"));
    CHECK_THAT(taken.output, !Catch::Contains("demo scene:"));
    CHECK_FALSE(fs::exists(folder.path / "taken" / "1_billboards_alpha_ignored.png"));
}

TEST_CASE("canopy trace checks its hit file before tracing and after closing it, and standard output at exit") {
    trace_fixture const f;
    auto const trace_to = [&](std::string const& out) {
        return run_canopy({"trace", "--scene", f.obj.string(), "--rays", f.mesh_rays_file.string(), "--query", "any",
                           "--out", out});
    };
    // A full device: the write fails at closing, with the system's reason.
    auto const full = trace_to("/dev/full");
    CHECK(full.exit_code == 1);
    CHECK_THAT(full.output, Catch::Contains("/dev/full: cannot write: No space left on device"));
    // Found before the scene is loaded (no "build" line): a folder, a missing folder, a FIFO
    // without a reader.
    fs::create_directories(f.folder.path / "taken.hits");
    REQUIRE(::mkfifo((f.folder.path / "pipe.hits").c_str(), 0600) == 0);
    for (auto const& [out, reason] : {std::pair<std::string, std::string>{(f.folder.path / "taken.hits").string(), "Is a directory"},
                                      {(f.folder.path / "no/such/x.hits").string(), "No such file or directory"},
                                      {(f.folder.path / "pipe.hits").string(), "a FIFO with no reader"}}) {
        INFO(out);
        auto const result = trace_to(out);
        INFO(result.output);
        CHECK(result.exit_code == 1);
        CHECK_THAT(result.output, Catch::Contains(out + ": cannot be written: " + reason));
        CHECK_THAT(result.output, !Catch::Contains("build"));
    }

    // Standard output: lost output is an error.
    auto const lost = test_support::run_command("(" + canopy_command({"info", "--plugins"}) + " >/dev/full)");
    CHECK(lost.exit_code == 1);
    CHECK_THAT(lost.output, Catch::Contains("canopy: cannot write to standard output: No space left on device"));
}

TEST_CASE("canopy names the step and the file when memory runs out") {
#if defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || __has_feature(memory_sanitizer)
    WARN("not run: an address-space limit cannot apply under a sanitizer's shadow memory");
    return;
#endif
#endif
    temp_folder const folder("canopy_cli_memory_test");
    // A 16384 × 16384 float RGBA framebuffer (4 GiB) under a 1 GB address-space limit; one
    // thread, so that no worker thread needs a stack.
    auto const result = test_support::run_command(
        "ulimit -v 1000000 && " + canopy_command({"render", "gen:sphere", "-o", folder.path.string(), "--size",
                                                  "16384x16384", "--max-texels", "268435456", "--threads", "1"}));
    INFO(result.output);
    CHECK(result.exit_code == 1);
    CHECK_THAT(result.output, Catch::Contains("canopy: out of memory while rendering " +
                                              (folder.path / "sphere.png").string()));
    CHECK_FALSE(fs::exists(folder.path / "sphere.png"));
}

TEST_CASE("canopy render refuses a degenerate camera, naming the file and the camera") {
    temp_folder const folder("canopy_cli_camera_test");
    std::vector<json_quad> const floor{floor_quad("floor", 1.0f, 0.0f)};
    struct bad_camera {
        std::string name, nodes, message;
    };
    std::vector<bad_camera> const cameras{
        {"zero_up", R"({"type": "camera", "name": "main", "eye": [0, 2, 5], "up": [0, 0, 0]})",
         "zero_up.json: camera 'main': up is zero: no orientation"},
        // The camera under a scale of 1e-30: eye and target 5e-30 apart, no direction in float.
        {"collapsed", R"({"type": "transform", "scale": 1e-30, "children": [{"type": "camera", "name": "tiny", "eye": [0, 0, 5]}]})",
         "collapsed.json: camera 'tiny': eye (0, 0, 5e-30) and target (0, 0, 0) are too close to give a view direction in float"},
        // Placed beyond float range: the eye is infinite.
        {"far", R"({"type": "transform", "scale": 1e38, "children": [{"type": "camera", "name": "far", "eye": [0, 0, 50]}]})",
         "far.json: camera 'far': placed by the transforms above it, the camera's eye, target or up is not finite in float"},
        // Without a camera, bounds beyond float range or with no extent in float.
        {"huge", "", "huge.json: automatic camera: the scene's bounds (-3e+38, 0, -3e+38) .. (3e+38, 0, 3e+38) are empty or beyond float range: give the scene a camera"},
        {"speck", "", "speck.json: automatic camera: the scene's bounds"},
    };
    for (auto const& c : cameras) {
        INFO(c.name);
        std::vector<json_quad> quads = floor;
        if (c.name == "huge") quads = {floor_quad("floor", 3e38f, 0.0f)};
        if (c.name == "speck") quads = {floor_quad("floor", 1e-30f, 0.0f)};
        auto const file = folder.write(c.name + ".json", scene_with(quads, "", c.nodes));
        auto const result = run_canopy({"render", file.string(), "-o", folder.path.string(), "--size", "16x16"});
        INFO(result.output);
        CHECK(result.exit_code == 1);
        CHECK_THAT(result.output, Catch::Contains(file.parent_path().string() + "/" + c.message));
        CHECK_FALSE(fs::exists(folder.path / (c.name + ".png")));
    }
}

TEST_CASE("canopy render: an up vector along the view direction falls back to -z (looking down) or +y") {
    temp_folder const folder("canopy_cli_camera_test");
    // The floor in three parts: red at x < 0, z < 0; green at x > 0, z < 0; blue at z > 0.
    std::vector<json_quad> const parts{{"red", "red", {-2, 0, -2, -2, 0, 0, 0, 0, 0, 0, 0, -2}},
                                       {"green", "green", {0, 0, -2, 0, 0, 0, 2, 0, 0, 2, 0, -2}},
                                       {"blue", "blue", {-2, 0, 0, -2, 0, 2, 2, 0, 2, 2, 0, 0}}};
    std::string const materials = R"({"name": "red", "colour": [1, 0, 0]}, {"name": "green", "colour": [0, 1, 0]},
                                     {"name": "blue", "colour": [0, 0, 1]})";
    // Straight down with the default up (0, 1, 0): the fallback up is -z, so the image's top
    // shows z < 0 and its right x > 0.
    auto const down = folder.write("down.json", scene_with(parts, materials,
                                                           R"({"type": "camera", "eye": [0, 5, 0], "target": [0, 0, 0], "fovy": 30})"));
    auto const result = run_canopy({"render", down.string(), "-o", folder.path.string(), "--size", "40x40"});
    INFO(result.output);
    REQUIRE(result.exit_code == 0);
    auto const image = canopy::read_image(folder.path / "down.png");
    auto const dominant = [&](int x, int y) {
        float const* p = image.at(x, y);
        return p[0] > 2.0f * std::max(p[1], p[2]) ? 0 : p[1] > 2.0f * std::max(p[0], p[2]) ? 1
                                                    : p[2] > 2.0f * std::max(p[0], p[1]) ? 2 : -1;
    };
    CHECK(dominant(10, 10) == 0); // top left: red
    CHECK(dominant(30, 10) == 1); // top right: green
    CHECK(dominant(10, 30) == 2); // bottom: blue
    CHECK(dominant(30, 30) == 2);

    // Looking along -z with up (0, 0, 5): the fallback is +y, the same image as with up (0, 1, 0).
    auto const along = [&](std::string const& name, std::string const& up) {
        auto const file = folder.write(name + ".json", scene_with(parts, materials,
                                                                  R"({"type": "camera", "eye": [0, 3, 6], "target": [0, 3, 0], "up": )" +
                                                                      up + "}"));
        auto const r = run_canopy({"render", file.string(), "-o", folder.path.string(), "--size", "24x24"});
        INFO(r.output);
        REQUIRE(r.exit_code == 0);
        return read_bytes(folder.path / (name + ".png"));
    };
    CHECK(along("parallel", "[0, 0, 5]") == along("plain", "[0, 1, 0]"));
}

TEST_CASE("canopy render --kernel ao: the default radius scales with the scene, --ao-radius sets it") {
    temp_folder const folder("canopy_cli_ao_test");
    // A floor of 2 × 2 with 19 fins 0.1 high, 0.1 apart, seen from above at an angle (every pixel
    // on the model), scaled by s.
    auto const scene = [&](float s) {
        auto const q = [&](std::string name, std::array<float, 12> c) {
            for (float& v : c) v *= s;
            return json_quad{std::move(name), "", c};
        };
        std::vector<json_quad> quads{q("floor", {-1, 0, -1, -1, 0, 1, 1, 0, 1, 1, 0, -1})};
        for (int i = -9; i <= 9; ++i) {
            float const x = 0.1f * float(i);
            quads.push_back(q("fin" + std::to_string(i + 9), {x, 0, -1, x, 0.1f, -1, x, 0.1f, 1, x, 0, 1}));
        }
        return scene_with(quads, "",
                          "{\"type\": \"camera\", \"eye\": [0, " + number(1.6f * s) + ", " + number(1.2f * s) +
                              "], \"target\": [0, 0, " + number(-0.1f * s) + "], \"fovy\": 40}");
    };
    auto const render = [&](std::string const& name, float s, std::vector<std::string> extra) {
        auto const file = folder.write(name + ".json", scene(s));
        std::vector<std::string> args{"render", file.string(), "-o", folder.path.string(), "--size", "48x36", "--kernel",
                                      "ao", "--spp", "8"};
        args.insert(args.end(), extra.begin(), extra.end());
        auto const result = run_canopy(args);
        INFO(result.output);
        REQUIRE(result.exit_code == 0);
        return mean_linear(canopy::read_image(folder.path / (name + ".png")));
    };
    double const unit = render("unit", 1.0f, {});
    double const large = render("large", 1000.0f, {});
    double const relative = render("relative", 1000.0f, {"--ao-radius", "5%"});
    double const absolute = render("absolute", 1000.0f, {"--ao-radius", "2"});
    INFO("mean AO: unit " << unit << ", large " << large << ", 5% " << relative << ", absolute 2: " << absolute);
    // The same picture at any scale: the radius is 5% of the bounding-box diagonal (0.14 at unit
    // scale, longer than the gaps between the fins: well occluded).
    CHECK(std::fabs(unit - large) < 0.01);
    CHECK(unit < 0.8);
    CHECK(relative == Approx(large).margin(1e-9));
    // An absolute radius does not scale: 2 units in a model 2800 across sees no occluder.
    CHECK(absolute > 0.95);
}

TEST_CASE("canopy render --kernel ao between two planes matches the analytic open fraction (h/R)²") {
    // Floor y = 0 and ceiling y = h = 1, far wider than R. From a point of either plane a
    // cosine-weighted ray at angle θ to the normal meets the other plane at distance h / cos θ;
    // under cosine weighting cos²θ is uniform in [0, 1], so a fraction (h/R)² of the rays of
    // length R escapes (all of them when R ≤ h). Every pixel sees a plane.
    temp_folder const folder("canopy_cli_ao_test");
    auto const file = folder.write(
        "planes.json",
        scene_with({floor_quad("floor", 1000.0f, 0.0f), floor_quad("ceiling", 1000.0f, 1.0f)}, "",
                   R"({"type": "camera", "eye": [0, 0.5, 0], "target": [0, -0.5, -1], "fovy": 30})"));
    for (double const radius : {0.5, 2.0, 4.0}) {
        INFO("R = " << radius);
        auto const result = run_canopy({"render", file.string(), "-o", folder.path.string(), "--size", "32x32",
                                        "--kernel", "ao", "--ao-radius", number(float(radius))});
        INFO(result.output);
        REQUIRE(result.exit_code == 0);
        double const expected = std::min(1.0, 1.0 / (radius * radius));
        CHECK(mean_linear(canopy::read_image(folder.path / "planes.png")) == Approx(expected).margin(0.015));
    }
}

TEST_CASE("canopy render --exposure and --tonemap follow their formulas, and path defaults to aces") {
    temp_folder const folder("canopy_cli_tone_test");
    // A white floor seen from above at an angle: lit by the sun, radiance above 1.
    auto const file = folder.write("white.json",
                                   scene_with({floor_quad("floor", 50.0f, 0.0f, "white")},
                                              R"({"name": "white", "colour": [1, 1, 1]})",
                                              R"({"type": "camera", "eye": [0, 3, 3], "target": [0, 0, -1], "fovy": 40})"));
    auto const render = [&](std::string const& name, std::vector<std::string> extra) {
        fs::path const out = folder.path / name;
        std::vector<std::string> args{"render", file.string(), "-o", out.string(), "--size", "24x18"};
        args.insert(args.end(), extra.begin(), extra.end());
        auto const result = run_canopy(args);
        INFO(result.output);
        REQUIRE(result.exit_code == 0);
        return canopy::read_image(out / "white.png");
    };
    auto const linear = [](canopy::rgba_image const& image, std::size_t i) { return srgb_to_linear(double(image.pixels[i])); };
    // The written formulas: radiance v from an image at -3 EV (8 × its linear value, unclipped).
    auto const reinhard = [](double v) { return v / (1.0 + v); };
    auto const aces = [](double v) { return std::min(1.0, v * (2.51 * v + 0.03) / (v * (2.43 * v + 0.59) + 0.14)); };

    auto const none_m3 = render("none_m3", {"--exposure", "-3"});
    auto const none_0 = render("none_0", {});
    auto const reinhard_0 = render("reinhard", {"--tonemap", "reinhard"});
    int channels = 0, over_one = 0, exposure_errors = 0, reinhard_errors = 0;
    for (std::size_t i = 0; i < none_0.pixels.size(); ++i) {
        if (i % 4 == 3) continue;
        double const v = 8.0 * linear(none_m3, i);
        ++channels;
        over_one += v > 1.05;
        exposure_errors += std::fabs(linear(none_0, i) - std::min(1.0, v)) > 0.02;
        reinhard_errors += std::fabs(linear(reinhard_0, i) - reinhard(v)) > 0.02;
    }
    CHECK(over_one > channels / 4); // radiance over 1: the plain image clips there
    CHECK(exposure_errors == 0);
    CHECK(reinhard_errors == 0);

    // The path kernel (deterministic samples): its default curve is aces, which does not clip
    // what --tonemap none clips.
    auto const path_m3 = render("path_m3", {"--kernel", "path", "--spp", "4", "--tonemap", "none", "--exposure", "-3"});
    auto const path_default = render("path_default", {"--kernel", "path", "--spp", "4"});
    int path_over_one = 0, aces_errors = 0, aces_clipped = 0;
    for (std::size_t i = 0; i < path_m3.pixels.size(); ++i) {
        if (i % 4 == 3) continue;
        double const v = 8.0 * linear(path_m3, i);
        path_over_one += v > 1.05;
        aces_errors += std::fabs(linear(path_default, i) - aces(v)) > 0.02;
        aces_clipped += path_default.pixels[i] == 1.0f;
    }
    CHECK(path_over_one > 0);
    CHECK(aces_errors == 0);
    CHECK(aces_clipped == 0);
}

TEST_CASE("canopy render: bounds beyond float range give no AO radius and no default point light") {
    temp_folder const folder("canopy_cli_bounds_test");
    auto const file = folder.write("huge.json", scene_with({floor_quad("floor", 3e38f, 0.0f)}, "",
                                                           R"({"type": "camera", "eye": [0, 5, 5]})"));
    auto const ao = run_canopy({"render", file.string(), "-o", folder.path.string(), "--size", "8x8", "--kernel", "ao"});
    CHECK(ao.exit_code == 1);
    CHECK_THAT(ao.output, Catch::Contains(file.string() + ": the AO radius, 5% of the bounding-box diagonal (inf), is "
                                                          "not a positive finite length: give --ao-radius in scene units"));
    auto const path = run_canopy({"render", file.string(), "-o", folder.path.string(), "--size", "8x8", "--kernel", "path"});
    CHECK(path.exit_code == 1);
    CHECK_THAT(path.output, Catch::Contains(file.string() + ": the bounding box (diagonal inf) is beyond float range for "
                                                            "the default point light of the path kernel: give the scene a point light"));
    CHECK_FALSE(fs::exists(folder.path / "huge.png"));
    // With a radius given, the AO image is made.
    CHECK(run_canopy({"render", file.string(), "-o", folder.path.string(), "--size", "8x8", "--kernel", "ao",
                      "--ao-radius", "1"}).exit_code == 0);
}

TEST_CASE("the trace readers refuse what is not a scene or a ray file, naming the file and the problem") {
    temp_folder const folder("canopy_cli_hostile_test");
    auto const& dir = folder.path;
    folder.write("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    REQUIRE(test_support::make_special_files(dir, {".obj", ".inst", ".rays"}));
    // Random bytes (a NUL planted at offset 12 of the first line), UTF-16 with and without its
    // byte-order mark, control bytes.
    std::string random(4096, '\0');
    std::mt19937 rng(15);
    for (char& c : random) c = char(std::uniform_int_distribution<int>(32, 126)(rng));
    random[12] = '\0';
    folder.write("random.obj", random);
    folder.write("utf16.obj", std::string("\xFF\xFE" "v\0 \0" "0\0", 8));
    folder.write("utf16_plain.obj", std::string("v\0 \0" "0\0", 6));
    folder.write("control.obj", "v 0 0 0\nv 1 \x01 0\n");
    folder.write("empty.obj", "");
    folder.write("vertices.obj", "v 0 0 0\nv 1 0 0\n# no faces\n");
    folder.write("huge.obj", "v 0 0 0\nv 1 0 0\nv 0 1e300 0\nf 1 2 3\n");
    folder.write("self.inst", "# a mesh of itself\nmesh self.inst\n1 0 0 0 0 1 0 0 0 0 1 0\n");
    folder.write("no_instances.inst", "mesh tri.obj\n# nothing else\n");
    folder.write("faceless.inst", "mesh vertices.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n");
    folder.write("folder_mesh.inst", "mesh folder.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n");
    folder.write("zero_mesh.inst", "mesh zero.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n");
    folder.write("huge.inst", "mesh tri.obj\n1 0 0 0 0 1 0 0 0 0 1 -1e39\n");
    folder.write("odd.rays", std::string(33, '\0'));
    folder.write("long.obj", "v 0 0 " + std::string(1 << 20, '7') + "x\n");

    auto const p = [&](char const* name) { return (dir / name).string(); };
    auto const message = [](auto&& read) { return test_support::what_of<canopy::scene_error>(read); };
    struct bad_file {
        char const* name;
        std::string message;
    };
    for (auto const& [name, expected] : {
             bad_file{"folder.obj", p("folder.obj") + ": is a folder, not a regular file"},
             bad_file{"zero.obj", p("zero.obj") + ": is a character device, not a regular file"},
             bad_file{"zero.inst", p("zero.inst") + ": is a character device, not a regular file"},
             bad_file{"fifo.obj", p("fifo.obj") + ": is a FIFO, not a regular file"},
             bad_file{"random.obj", p("random.obj") + ":1: not a text OBJ file: NUL byte at offset 12"},
             bad_file{"utf16.obj", p("utf16.obj") + ": not a text OBJ file: UTF-16 byte-order mark (only ASCII or UTF-8 text is read)"},
             bad_file{"utf16_plain.obj", p("utf16_plain.obj") + ":1: not a text OBJ file: NUL byte at offset 1"},
             bad_file{"control.obj", p("control.obj") + ":2: not a text OBJ file: control byte 0x01 at offset 12"},
             bad_file{"empty.obj", p("empty.obj") + ": no faces ('f' lines) and no vertices: nothing to trace"},
             bad_file{"vertices.obj", p("vertices.obj") + ": no faces ('f' lines): nothing to trace"},
             bad_file{"huge.obj", p("huge.obj") + ":3: value 1e300 overflows a float"},
             bad_file{"long.obj", p("long.obj") + ":1: bad number '" + std::string(40, '7') + "…'"},
             bad_file{"self.inst", p("self.inst") + ": names itself as its mesh ('mesh self.inst'); the mesh is an .obj file"},
             bad_file{"no_instances.inst", p("no_instances.inst") + ": no instance lines (12 numbers each): nothing to trace"},
             bad_file{"faceless.inst", p("vertices.obj") + ": no faces ('f' lines): nothing to trace"},
             bad_file{"folder_mesh.inst", p("folder.obj") + ": is a folder, not a regular file (mesh of folder_mesh.inst)"},
             bad_file{"zero_mesh.inst", p("zero.obj") + ": is a character device, not a regular file (mesh of zero_mesh.inst)"},
             bad_file{"huge.inst", p("huge.inst") + ":2: value -1e39 overflows a float"},
         }) {
        INFO(name);
        fs::path const file = dir / name;
        if (file.extension() == ".obj") CHECK(message([&] { canopy::read_bench_obj(file); }) == expected);
        else CHECK(message([&] { canopy::read_bench_inst(file); }) == expected);
    }
    for (auto const& [name, expected] : {
             bad_file{"folder.rays", p("folder.rays") + ": is a folder, not a regular file (ray file)"},
             bad_file{"zero.rays", p("zero.rays") + ": is a character device, not a regular file (ray file)"},
             bad_file{"fifo.rays", p("fifo.rays") + ": is a FIFO, not a regular file (ray file)"},
             bad_file{"odd.rays", p("odd.rays") + ": size 33 bytes is not a multiple of 32 (one ray = 32 bytes)"},
         }) {
        INFO(name);
        CHECK(message([&] { canopy::read_bench_rays(dir / name); }) == expected);
    }
    CHECK(message([&] { canopy::write_bench_hits(dir / "folder.rays", {}); }) ==
          p("folder.rays") + ": cannot open file for writing: Is a directory");
}

TEST_CASE("canopy trace exits 1 with the reader's message for a file that is not a scene or a ray file") {
    temp_folder const folder("canopy_cli_hostile_test");
    auto const& dir = folder.path;
    auto const obj = folder.write("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    canopy::write_bench_rays(dir / "one.rays", {canopy::ray{{0.2f, 0.2f, -1.0f}, 0.0f, {0.0f, 0.0f, 1.0f}, inf}});
    fs::create_directory(dir / "folder");
    REQUIRE(::mkfifo((dir / "fifo.rays").c_str(), 0600) == 0);
    folder.write("self.inst", "mesh self.inst\n1 0 0 0 0 1 0 0 0 0 1 0\n");
    auto const p = [&](char const* name) { return (dir / name).string(); };
    struct bad_call {
        std::string scene, rays, out, message; // message: all the program writes
    };
    for (auto const& call : {
             bad_call{p("folder"), p("one.rays"), p("out.hits"), p("folder") + ": is a folder, not a regular file"},
             bad_call{p("self.inst"), p("one.rays"), p("out.hits"),
                      p("self.inst") + ": names itself as its mesh ('mesh self.inst'); the mesh is an .obj file"},
             bad_call{obj.string(), p("fifo.rays"), p("out.hits"), p("fifo.rays") + ": is a FIFO, not a regular file (ray file)"},
             bad_call{obj.string(), p("one.rays"), p("folder"), p("folder") + ": cannot be written: Is a directory"},
         }) {
        INFO("--scene " << call.scene << " --rays " << call.rays << " --out " << call.out);
        auto const result = run_canopy({"trace", "--scene", call.scene, "--rays", call.rays, "--query", "closest", "--out", call.out});
        CHECK(result.exit_code == 1);
        CHECK(result.output == "canopy: " + call.message + "\n");
    }
}

TEST_CASE("canopy info and render refuse OBJ files that hold nothing to trace or are not text, exit 1") {
    temp_folder const folder("canopy_cli_hostile_test");
    auto const& dir = folder.path;
    std::string random(2048, '\0');
    std::mt19937 rng(1515);
    for (char& c : random) c = char(std::uniform_int_distribution<int>(0, 255)(rng));
    // The first byte that is not text, found here: a control byte other than tab, LF, VT, FF, CR.
    std::size_t offset = 0, line = 1;
    for (; offset < random.size(); ++offset) {
        auto const c = static_cast<unsigned char>(random[offset]);
        if (c == '\n') ++line;
        else if ((c < 0x20 && c != '\t' && c != '\r' && c != '\v' && c != '\f') || c == 0x7F) break;
    }
    REQUIRE(offset < random.size());
    char byte[8];
    std::snprintf(byte, sizeof byte, "0x%02X", unsigned(static_cast<unsigned char>(random[offset])));
    std::string const what = random[offset] == '\0' ? "NUL byte" : std::string("control byte ") + byte;
    auto const garbage = folder.write("garbage.obj", random);
    auto const points = folder.write("points.obj", "v 0 0 0\nv 1 0 0\np 1 2\n");
    fs::create_symlink("/dev/zero", dir / "zero.obj");
    auto const info = run_canopy({"info", garbage.string()});
    CHECK(info.exit_code == 1);
    CHECK(info.output == "canopy: " + garbage.string() + ":" + std::to_string(line) + ": not a text OBJ file: " + what +
                             " at offset " + std::to_string(offset) + "\n");
    auto const render = run_canopy({"render", points.string(), "-o", dir.string(), "--size", "8x8"});
    CHECK(render.exit_code == 1);
    CHECK(render.output == "canopy: " + points.string() + ": no faces ('f' lines), only points or lines: nothing to trace\n");
    auto const zero = run_canopy({"info", (dir / "zero.obj").string()});
    CHECK(zero.exit_code == 1);
    CHECK(zero.output == "canopy: " + (dir / "zero.obj").string() + ": is a character device, not a regular file\n");
}

TEST_CASE("canopy info reports the non-convex polygon of more than 256 corners that had to be fanned") {
    temp_folder const folder("canopy_cli_polygon_test");
    // A simple comb of 300 corners in the plane z = 0: a zigzag top edge of 298 corners (heights
    // 1 and 2, so non-convex) and two base corners; one face, on line 301.
    std::string text;
    for (int k = 0; k < 298; ++k) text += "v " + std::to_string(k) + " " + (k % 2 ? "1" : "2") + " 0\n";
    text += "v 297 0 0\nv 0 0 0\nf";
    for (int k = 1; k <= 300; ++k) text += " " + std::to_string(k);
    text += "\n";
    auto const comb = folder.write("comb.obj", text);
    auto const result = run_canopy({"info", comb.string()});
    INFO(result.output);
    CHECK(result.exit_code == 0);
    CHECK_THAT(result.output, Catch::Contains("(298 triangles stored)"));
    CHECK_THAT(result.output,
               Catch::Contains("  - 1 polygon faces fanned, not ear-clipped (self-intersecting, collinear, or non-convex "
                               "with more than 256 corners): their triangles may cover more than the face; the first in "
                               "mesh 'comb' (" + comb.string() + ":301)\n"));
}

TEST_CASE("canopy trace --quality high gives the hits of the library's fast build, byte for byte, bad values exit 2") {
    // The same hits, byte for byte, as the library's fast build (the triangle test
    // does not depend on the tree).
    trace_fixture const f;
    for (bool const instanced : {false, true}) {
        INFO((instanced ? "instanced .inst scene" : "single-mesh .obj scene"));
        fs::path const out = f.folder.path / "high.hits";
        auto const result = run_canopy({"trace", "--scene", f.scene_file(instanced).string(), "--rays",
                                        f.rays_file(instanced).string(), "--query", "closest", "--out", out.string(),
                                        "--quality", "high"});
        INFO(result.output);
        REQUIRE(result.exit_code == 0);
        CHECK_THAT(result.output, Catch::Contains(" ms at quality high, trace "));
        auto const& rays = f.rays(instanced);
        std::string const got = read_bytes(out);
        REQUIRE(got.size() == 20 * rays.size());
        int mismatches = 0;
        for (std::size_t i = 0; i < rays.size(); ++i)
            mismatches += got.compare(20 * i, 20, hit_bytes(f.reference(rays[i], instanced, true, false))) != 0;
        CHECK(mismatches == 0);
    }

    check_usage_errors({
        {{"trace", "--scene", "a.obj", "--rays", "a.rays", "--query", "closest", "--out", (f.folder.path / "x.hits").string(),
          "--quality", "best"},
         "--quality must be automatic, fast or high, not 'best'"},
        {{"render", "--quality", "high"}, "--quality applies to a SCENE: the demo scene is built at the default quality"},
        {{"info", "--plugins", "--quality", "high"}, "--quality applies to a SCENE, not to --plugins"},
    });
}

TEST_CASE("canopy info and render take --quality automatic|fast|high, info reports the mesh builds") {
    // info: the quality, the mesh builds' SAH cost (mean over triangles) and bytes per triangle
    // of what compile() builds at that quality.
    temp_folder const folder("canopy_cli_quality_test");
    auto const file = folder.write("pairs.json", scene_json);
    canopy::registry const& r = canopy::builtin_registry();
    canopy::scene const s = canopy::load_scene(file, r);
    for (auto const quality : {canopy::build_quality::automatic, canopy::build_quality::fast, canopy::build_quality::high}) {
        bool const high = quality == canopy::build_quality::high;
        bool const automatic = quality == canopy::build_quality::automatic;
        canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r, .bvh = {.quality = quality}});
        double sah = 0.0, bytes = 0.0, triangles = 0.0;
        for (auto const& m : c.meshes) {
            auto const st = canopy::compute_stats(m.accel);
            sah += st.sah_cost * double(st.primitive_count);
            bytes += double(st.bytes);
            triangles += double(st.primitive_count);
        }
        char expected[160];
        std::snprintf(expected, sizeof expected, "SAH cost %.2f (mean over triangles), %.1f bytes/triangle",
                      sah / triangles, bytes / triangles);
        std::vector<std::string> args{"info", file.string()};
        if (!automatic) args.insert(args.end(), {"--quality", high ? "high" : "fast"});
        auto const result = run_canopy(args);
        INFO(result.output);
        REQUIRE(result.exit_code == 0);
        std::size_t split = 0;
        for (auto const& m : c.meshes) split += m.accel.quality == canopy::build_quality::high ? 1 : 0;
        std::string const name = automatic ? "automatic (high for " + std::to_string(split) + " of " +
                                                 std::to_string(c.meshes.size()) + " mesh" +
                                                 (c.meshes.size() == 1 ? "" : "es") + ")"
                                           : (high ? "high" : "fast");
        CHECK_THAT(result.output, Catch::Contains("mesh BVH build: quality " + name + ", "));
        CHECK_THAT(result.output, Catch::Contains(expected));
        CHECK_THAT(result.output, Catch::Contains(std::string("- mesh BVHs built at quality ") +
                                                  (automatic ? "automatic (the default): " + std::to_string(split) + " of "
                                                             : (high ? "high" : "fast"))));
        // The phases: each shown, and together within the mesh builds' time.
        std::smatch total, phases;
        std::regex const total_line("mesh BVH build: quality [^\n]*?, ([0-9.]+) ms, SAH");
        std::regex const phase_line("mesh BVH build phases(?: \\(summed over the meshes\\))?: references ([0-9.]+) ms, "
                                    "binary tree ([0-9.]+) ms, wide nodes ([0-9.]+) ms, leaves ([0-9.]+) ms");
        REQUIRE(std::regex_search(result.output, total, total_line));
        REQUIRE(std::regex_search(result.output, phases, phase_line));
        double sum = 0.0;
        for (int k = 1; k <= 4; ++k) sum += std::stod(phases[k].str());
        CHECK(sum <= std::stod(total[1].str()) + 0.005); // each printed to 0.001 ms
        CHECK(std::stod(phases[2].str()) + std::stod(phases[4].str()) > 0.0);
    }

    // render at high renders the scene and says so.
    auto const rendered = run_canopy({"render", file.string(), "-o", (folder.path / "out").string(), "--size", "32x24",
                                      "--quality", "high"});
    INFO(rendered.output);
    CHECK(rendered.exit_code == 0);
    CHECK_THAT(rendered.output, Catch::Contains("(mesh BVHs at quality high)"));
    CHECK(fs::exists(folder.path / "out" / "pairs.png"));
}
