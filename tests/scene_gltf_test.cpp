// Tests of the glTF plugin (canopy.plugins.gltf). Every file is written here: JSON text plus a
// binary buffer (an external .bin, a base64 data: URI, or a hand-assembled .glb), and a PNG
// written through canopy.image. Expected values are worked out by hand from the numbers put in
// the file: world positions from the node transforms, triangles from the glTF rules for strips
// and fans, texels from the sRGB formula, and hits from rays aimed at chosen texture quadrants.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

import canopy.scene;
import canopy.image;
import canopy.plugins.oiio;
import canopy.plugins.gltf;
import canopy.plugins;
import canopy.testing;
import canopy.testing.scene;

namespace {

namespace fs = std::filesystem;
using test_support::temp_folder;
using test_support::limits_guard;
using canopy::vec3;

constexpr float inf = std::numeric_limits<float>::infinity();

canopy::registry const& plugins() {
    static canopy::registry const r = [] {
        canopy::registry reg;
        canopy::register_oiio_plugin(reg);
        canopy::register_gltf_plugin(reg);
        return reg;
    }();
    return r;
}

void write_text(fs::path const& file, std::string const& text) {
    std::ofstream out(file, std::ios::binary);
    out << text;
}

std::vector<unsigned char> read_bytes(fs::path const& file) {
    std::ifstream in(file, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::string base64(std::vector<unsigned char> const& data) {
    static char const digits[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    for (std::size_t i = 0; i < data.size(); i += 3) {
        std::uint32_t v = std::uint32_t(data[i]) << 16;
        if (i + 1 < data.size()) v |= std::uint32_t(data[i + 1]) << 8;
        if (i + 2 < data.size()) v |= data[i + 2];
        out += digits[(v >> 18) & 63];
        out += digits[(v >> 12) & 63];
        out += i + 1 < data.size() ? digits[(v >> 6) & 63] : '=';
        out += i + 2 < data.size() ? digits[v & 63] : '=';
    }
    return out;
}

// Binary data and the bufferViews / accessors that describe it (all in buffer 0).
struct gltf_builder {
    std::vector<unsigned char> bin;
    std::vector<std::string> views, accessors;

    int add_view(void const* data, std::size_t bytes) {
        while (bin.size() % 4 != 0) bin.push_back(0);
        std::size_t const offset = bin.size();
        auto const* p = static_cast<unsigned char const*>(data);
        bin.insert(bin.end(), p, p + bytes);
        views.push_back("{\"buffer\": 0, \"byteOffset\": " + std::to_string(offset) +
                        ", \"byteLength\": " + std::to_string(bytes) + "}");
        return int(views.size() - 1);
    }
    template <typename T>
    int add(std::vector<T> const& values, int component_type, char const* type, std::size_t components,
            bool normalized = false) {
        int const view = add_view(values.data(), values.size() * sizeof(T));
        accessors.push_back("{\"bufferView\": " + std::to_string(view) + ", \"componentType\": " +
                            std::to_string(component_type) + ", \"count\": " +
                            std::to_string(values.size() / components) + ", \"type\": \"" + type + "\"" +
                            (normalized ? ", \"normalized\": true" : "") + "}");
        return int(accessors.size() - 1);
    }
    int vec3s(std::vector<float> const& v) { return add(v, 5126, "VEC3", 3); }
    int vec2s(std::vector<float> const& v) { return add(v, 5126, "VEC2", 2); }

    // The whole document; `buffer` is the buffers entry, `rest` the other top-level members.
    std::string document(std::string const& buffer, std::string const& rest) const {
        auto const join = [](std::vector<std::string> const& items) {
            std::string s;
            for (auto const& i : items) s += (s.empty() ? "" : ", ") + i;
            return s;
        };
        return "{\"asset\": {\"version\": \"2.0\"}, \"buffers\": [" + buffer + "], \"bufferViews\": [" + join(views) +
               "], \"accessors\": [" + join(accessors) + "], " + rest + "}";
    }
    std::string external_buffer(fs::path const& bin_file) const {
        std::ofstream(bin_file, std::ios::binary).write(reinterpret_cast<char const*>(bin.data()), std::streamsize(bin.size()));
        return "{\"uri\": \"" + bin_file.filename().string() + "\", \"byteLength\": " + std::to_string(bin.size()) + "}";
    }
    std::string embedded_buffer() const {
        return "{\"uri\": \"data:application/octet-stream;base64," + base64(bin) +
               "\", \"byteLength\": " + std::to_string(bin.size()) + "}";
    }
};

// .glb: 12-byte header, a JSON chunk (space-padded), a BIN chunk (zero-padded).
void write_glb(fs::path const& file, std::string json, std::vector<unsigned char> bin) {
    while (json.size() % 4 != 0) json += ' ';
    while (bin.size() % 4 != 0) bin.push_back(0);
    auto const u32 = [](std::vector<unsigned char>& out, std::uint32_t v) {
        for (int k = 0; k < 4; ++k) out.push_back(static_cast<unsigned char>(v >> (8 * k)));
    };
    std::vector<unsigned char> out{'g', 'l', 'T', 'F'};
    u32(out, 2);
    u32(out, std::uint32_t(12 + 8 + json.size() + 8 + bin.size()));
    u32(out, std::uint32_t(json.size()));
    out.insert(out.end(), {'J', 'S', 'O', 'N'});
    out.insert(out.end(), json.begin(), json.end());
    u32(out, std::uint32_t(bin.size()));
    out.insert(out.end(), {'B', 'I', 'N', 0});
    out.insert(out.end(), bin.begin(), bin.end());
    std::ofstream(file, std::ios::binary).write(reinterpret_cast<char const*>(out.data()), std::streamsize(out.size()));
}

// The mask texture: 4×4, the top-left 2×2 quadrant opaque with colour (1, 0.2, 0) (sRGB-encoded),
// the rest fully transparent.
void write_mask_png(fs::path const& file) {
    canopy::rgba_image img;
    img.width = img.height = 4;
    img.pixels.assign(4 * 16, 0.0f);
    for (int y = 0; y < 2; ++y)
        for (int x = 0; x < 2; ++x) {
            float* p = img.at(x, y);
            p[0] = 1.0f, p[1] = 0.2f, p[2] = 0.0f, p[3] = 1.0f;
        }
    canopy::write_image(file, img);
}

double srgb_to_linear(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }

// ---- the instancing scene ---------------------------------------------------------------------
//
// meshes[0] "backdrop_quad": the square [-1, 1]² at z = 0, six unindexed vertices, normals +Z,
//           opaque red material 0; used by nodes 1, 4 and 5.
// meshes[1] "masked_quad": the same square, u16 indices, uv (0, 0) at the top-left corner
//           (-1, 1); masked material 1 with the mask texture; used by nodes 0 and 3.
// meshes[2] "two_parts": a TRIANGLE_STRIP with u8 indices and a TRIANGLE_FAN without indices,
//           normalized u16 texture coordinates; used by node 6.
// Nodes (scene 0 = [0, 1, 2, 6, 7]):
//   0 masked_1   T(0, 0, -5)
//   1 backdrop   T(0, 0, -10) S(4, 4, 1)
//   2 group      T(10, 0, 0) R(90° about +Y: (x, y, z) → (z, y, -x)), children 3, 4
//   3 masked_2   T(0, 0, -5)                            → world (x, y) ↦ (5, y, -x)
//   4 nested     matrix T(0, 0, -8), child 5            → world (x, y) ↦ (2, y, -x)
//   5 deep       T(0, 0, -1) S(0.5)                     → world (x, y) ↦ (1, y/2, -x/2)
//   6 parts      T(0, -20, 0)
//   7 rig        T(0, 10, 0), child 8
//   8 eye        camera 0 (yfov 0.8), T(1, 2, 3) R(90° about +Y) → eye (1, 12, 3) looking along -X
struct instancing_scene {
    gltf_builder b;
    std::string rest;

    instancing_scene() {
        std::vector<float> const square{-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, -1, 0, 1, 1, 0, -1, 1, 0};
        std::vector<float> normals;
        for (int k = 0; k < 6; ++k) normals.insert(normals.end(), {0, 0, 1});
        int const a_pos = b.vec3s(square);
        int const a_nrm = b.vec3s(normals);
        int const b_pos = b.vec3s({-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0});
        int const b_uv = b.vec2s({0, 1, 1, 1, 1, 0, 0, 0});
        int const b_idx = b.add(std::vector<std::uint16_t>{0, 1, 2, 0, 2, 3}, 5123, "SCALAR", 1);
        int const c_pos = b.vec3s({0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0});
        int const c_idx = b.add(std::vector<std::uint8_t>{0, 1, 2, 3}, 5121, "SCALAR", 1);
        int const c_fan = b.vec3s({0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1});
        int const c_uv = b.add(std::vector<std::uint16_t>{0, 0, 65535, 0, 65535, 32768, 0, 65535}, 5123, "VEC2", 2, true);
        auto const s = [](int i) { return std::to_string(i); };
        double const h = std::sqrt(0.5);
        std::string const ry = "\"rotation\": [0, " + std::to_string(h) + ", 0, " + std::to_string(h) + "]";
        rest = "\"meshes\": ["
               "{\"name\": \"backdrop_quad\", \"primitives\": [{\"attributes\": {\"POSITION\": " + s(a_pos) +
               ", \"NORMAL\": " + s(a_nrm) + "}, \"material\": 0}]},"
               "{\"name\": \"masked_quad\", \"primitives\": [{\"attributes\": {\"POSITION\": " + s(b_pos) +
               ", \"TEXCOORD_0\": " + s(b_uv) + "}, \"indices\": " + s(b_idx) + ", \"material\": 1}]},"
               "{\"name\": \"two_parts\", \"primitives\": ["
               "{\"attributes\": {\"POSITION\": " + s(c_pos) + "}, \"indices\": " + s(c_idx) + ", \"mode\": 5},"
               "{\"attributes\": {\"POSITION\": " + s(c_fan) + ", \"TEXCOORD_0\": " + s(c_uv) + "}, \"mode\": 6}]}],"
               "\"materials\": ["
               "{\"name\": \"red\", \"pbrMetallicRoughness\": {\"baseColorFactor\": [0.8, 0.2, 0.1, 1]}},"
               "{\"name\": \"leaves\", \"alphaMode\": \"MASK\", \"pbrMetallicRoughness\": {\"baseColorTexture\": {\"index\": 0}}}],"
               "\"textures\": [{\"source\": 0}],"
               "\"cameras\": [{\"type\": \"perspective\", \"perspective\": {\"yfov\": 0.8, \"znear\": 0.1}}],"
               "\"nodes\": ["
               "{\"name\": \"masked_1\", \"mesh\": 1, \"translation\": [0, 0, -5]},"
               "{\"name\": \"backdrop\", \"mesh\": 0, \"translation\": [0, 0, -10], \"scale\": [4, 4, 1]},"
               "{\"name\": \"group\", \"translation\": [10, 0, 0], " + ry + ", \"children\": [3, 4]},"
               "{\"name\": \"masked_2\", \"mesh\": 1, \"translation\": [0, 0, -5]},"
               "{\"name\": \"nested\", \"mesh\": 0, \"matrix\": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,-8,1], \"children\": [5]},"
               "{\"name\": \"deep\", \"mesh\": 0, \"translation\": [0, 0, -1], \"scale\": [0.5, 0.5, 0.5]},"
               "{\"name\": \"parts\", \"mesh\": 2, \"translation\": [0, -20, 0]},"
               "{\"name\": \"rig\", \"translation\": [0, 10, 0], \"children\": [8]},"
               "{\"name\": \"eye\", \"camera\": 0, \"translation\": [1, 2, 3], " + ry + "}],"
               "\"scenes\": [{\"nodes\": [0, 1, 2, 6, 7]}], \"scene\": 0";
    }

    // The .gltf with an external .bin and an external mask.png beside it.
    fs::path write_external(fs::path const& dir) const {
        write_mask_png(dir / "mask.png");
        fs::path const file = dir / "forest.gltf";
        write_text(file, b.document(b.external_buffer(dir / "forest.bin"), rest + ", \"images\": [{\"uri\": \"mask.png\"}]"));
        return file;
    }
};

canopy::mesh_data const& mesh_named(canopy::scene const& s, std::string const& name) {
    for (auto const& m : s.meshes())
        if (m.name == name) return m;
    FAIL("no mesh named " << name);
    return s.meshes().front();
}

canopy::ray ray_from(vec3<float> origin, vec3<float> direction) { return {origin, 0.0f, direction, inf}; }

struct traced {
    bool hit = false;
    float t = inf;
    std::string mesh;
};

template <typename I>
traced trace(canopy::compiled_scene const& c, canopy::ray const& r, I& isect) {
    auto const hr = c.closest_hit(r, isect);
    traced out;
    out.hit = bool(hr.hit);
    if (out.hit) {
        out.t = hr.t;
        out.mesh = c.meshes[hr.geom_id].name;
    }
    return out;
}

// The checks shared by the external, embedded and .glb versions of the scene.
void check_instancing_scene(canopy::scene const& s) {
    canopy::compiled_scene const c = canopy::compile(s, {.plugins = &plugins()});

    // One mesh per primitive, built once; one placement per mesh node.
    CHECK(s.meshes().size() == 4);
    REQUIRE(c.meshes.size() == 4);
    CHECK(c.statistics.meshes_built == 4);
    CHECK(c.levels == 1);
    REQUIRE(c.top_meshes.size() == 7);
    std::map<std::string, int> placed;
    for (auto const& p : c.top_meshes) ++placed[c.meshes[p.index].name];
    CHECK(placed["backdrop_quad"] == 3);
    CHECK(placed["masked_quad"] == 2);
    CHECK(placed["two_parts.primitives[0]"] == 1);
    CHECK(placed["two_parts.primitives[1]"] == 1);
    CHECK(c.statistics.alpha_mask_needed);
    CHECK(c.statistics.masked_materials_used == 1);

    // Placements of the backdrop quad: its corner (1, 1, 0) lands where the hierarchy puts it.
    std::vector<vec3<float>> corners;
    for (auto const& p : c.top_meshes)
        if (c.meshes[p.index].name == "backdrop_quad") corners.push_back(p.transform.transform_point(vec3<float>(1, 1, 0)));
    std::vector<vec3<float>> const expected{{4, 4, -10}, {2, 1, -1}, {1, 0.5f, -0.5f}};
    for (auto const& e : expected) {
        bool found = false;
        for (auto const& q : corners)
            found |= std::abs(q.x - e.x) < 1e-5f && std::abs(q.y - e.y) < 1e-5f && std::abs(q.z - e.z) < 1e-5f;
        CHECK(found);
    }

    // Strip and fan, triangulated by the glTF rules; normalized u16 texture coordinates.
    auto const& strip = mesh_named(s, "two_parts.primitives[0]");
    REQUIRE(strip.triangles.size() == 2);
    CHECK(strip.triangles[0] == std::array<std::uint32_t, 3>{0, 1, 2});
    CHECK(strip.triangles[1] == std::array<std::uint32_t, 3>{1, 3, 2});
    auto const& fan = mesh_named(s, "two_parts.primitives[1]");
    REQUIRE(fan.triangles.size() == 2);
    CHECK(fan.triangles[0] == std::array<std::uint32_t, 3>{1, 2, 0});
    CHECK(fan.triangles[1] == std::array<std::uint32_t, 3>{2, 3, 0});
    REQUIRE(fan.uvs.size() == 2);
    CHECK(fan.uvs[0][0].x == 1.0f);
    CHECK(fan.uvs[0][1].y == float(32768.0 / 65535.0));
    CHECK(fan.uvs[0][2].x == 0.0f);
    auto const& backdrop = mesh_named(s, "backdrop_quad");
    REQUIRE(backdrop.normals.size() == 2);
    CHECK(backdrop.normals[1][2].z == 1.0f);
    CHECK(backdrop.uvs.empty());

    // Materials: the factor as linear colour; the texture's RGB decoded from sRGB, alpha kept.
    bool saw_red = false, saw_mask = false;
    for (auto const& m : c.meshes) {
        auto const& mat = c.materials[std::size_t(m.material)];
        if (m.name == "backdrop_quad") {
            saw_red = true;
            CHECK(mat.colour.x == 0.8f);
            CHECK(mat.colour.y == 0.2f);
            CHECK(mat.colour.z == 0.1f);
            CHECK(mat.alpha == canopy::alpha_mode::opaque);
            CHECK(mat.texture < 0);
        }
        if (m.name == "masked_quad") {
            saw_mask = true;
            CHECK(mat.alpha == canopy::alpha_mode::mask);
            CHECK(mat.alpha_cutoff == 0.5f);
            REQUIRE(mat.texture >= 0);
            auto const& tex = c.textures[std::size_t(mat.texture)];
            REQUIRE(tex.width() == 4);
            REQUIRE(tex.height() == 4);
            auto const opaque = tex.texel(1, 1);
            CHECK(opaque.x == Approx(1.0).margin(1e-6));
            CHECK(opaque.y == Approx(srgb_to_linear(51.0 / 255.0)).margin(1e-6));
            CHECK(opaque.z == Approx(0.0).margin(1e-6));
            CHECK(opaque.w == 1.0f);
            CHECK(tex.texel(2, 1).w == 0.0f);
            CHECK(tex.texel(1, 2).w == 0.0f);
        }
    }
    CHECK(saw_red);
    CHECK(saw_mask);

    // Rays. masked_1 spans [-1, 1]² at z = -5 with uv (0, 0) at (-1, 1): the opaque quadrant
    // is x < 0, y > 0. The backdrop lies behind it at z = -10.
    canopy::texture_alpha_mask mask;
    mask.scene = &c;
    canopy::default_intersector plain;
    vec3<float> const down_z{0, 0, -1};
    auto const opaque = trace(c, ray_from({-0.5f, 0.5f, 5}, down_z), mask);
    CHECK(opaque.mesh == "masked_quad");
    CHECK(opaque.t == Approx(10.0f));
    for (auto const origin : {vec3<float>(0.5f, 0.5f, 5), vec3<float>(-0.5f, -0.5f, 5), vec3<float>(0.5f, -0.5f, 5)}) {
        auto const through = trace(c, ray_from(origin, down_z), mask);
        CHECK(through.mesh == "backdrop_quad");
        CHECK(through.t == Approx(15.0f));
        auto const ignored = trace(c, ray_from(origin, down_z), plain);
        CHECK(ignored.mesh == "masked_quad");
        CHECK(ignored.t == Approx(10.0f));
    }
    // masked_2 maps local (x, y) to world (5, y, -x): its opaque quadrant is z > 0, y > 0.
    // Behind it (seen from +X) lies nested at x = 2.
    vec3<float> const down_x{-1, 0, 0};
    auto const opaque2 = trace(c, ray_from({20, 0.5f, 0.5f}, down_x), mask);
    CHECK(opaque2.mesh == "masked_quad");
    CHECK(opaque2.t == Approx(15.0f));
    auto const through2 = trace(c, ray_from({20, 0.5f, -0.5f}, down_x), mask);
    CHECK(through2.mesh == "backdrop_quad");
    CHECK(through2.t == Approx(18.0f));
    auto const ignored2 = trace(c, ray_from({20, 0.5f, -0.5f}, down_x), plain);
    CHECK(ignored2.t == Approx(15.0f));
    // From between nested (x = 2) and deep (x = 1): deep, half the size, is hit.
    CHECK(trace(c, ray_from({1.5f, 0.25f, 0.25f}, down_x), plain).t == Approx(0.5f));

    // The camera where its node puts it.
    REQUIRE(c.camera.has_value());
    CHECK(c.camera->eye.x == Approx(1.0f));
    CHECK(c.camera->eye.y == Approx(12.0f));
    CHECK(c.camera->eye.z == Approx(3.0f));
    CHECK(c.camera->target.x == Approx(0.0f));
    CHECK(c.camera->target.y == Approx(12.0f));
    CHECK(c.camera->target.z == Approx(3.0f).margin(1e-6));
    CHECK(c.camera->up.x == Approx(0.0f).margin(1e-6));
    CHECK(c.camera->up.y == Approx(1.0f));
    CHECK(c.camera->fovy_degrees == Approx(0.8 * 180.0 / 3.14159265358979));
}

// Loads `file` expecting a scene_error (see test_support::load_failure); returns its message.
std::string load_error(fs::path const& file) { return test_support::load_failure(plugins(), file).message; }

// A one-primitive file for the error cases: a quad with u16 indices; parts replaceable.
struct small_file {
    std::vector<float> positions{-1, -1, 0, 1, -1, 0, 1, 1, 0, -1, 1, 0};
    std::vector<std::uint16_t> indices{0, 1, 2, 0, 2, 3};
    std::string primitive_extra;                        // appended inside the primitive
    std::string nodes = "[{\"mesh\": 0}]";
    std::string extra;                                  // appended top-level members
    std::string index_count;                            // overrides the indices accessor's count

    fs::path write(fs::path const& file) const {
        gltf_builder b;
        int const pos = b.vec3s(positions);
        int const idx = b.add(indices, 5123, "SCALAR", 1);
        if (!index_count.empty()) {
            auto& a = b.accessors[std::size_t(idx)];
            auto const at = a.find("\"count\": ") + 9;
            a.replace(at, a.find(',', at) - at, index_count);
        }
        write_text(file, b.document(b.embedded_buffer(),
                                    "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": " + std::to_string(pos) +
                                        "}, \"indices\": " + std::to_string(idx) + primitive_extra + "}]}], \"nodes\": " +
                                        nodes + ", \"scenes\": [{\"nodes\": [0]}]" + extra));
        return file;
    }
};

} // namespace

TEST_CASE("a glTF mesh used by several nodes is built once and placed once per node") {
    temp_folder const dir("canopy_gltf_test");
    instancing_scene const scene_file;
    canopy::scene s;
    plugins().load(s, scene_file.write_external(dir.path));
    std::size_t mesh_nodes = 0, cameras = 0;
    for (auto const& n : s.nodes()) {
        mesh_nodes += n.kind == canopy::node_kind::mesh;
        cameras += n.kind == canopy::node_kind::camera;
    }
    CHECK(mesh_nodes == 7);
    CHECK(cameras == 1);
    check_instancing_scene(s);
}

TEST_CASE("embedded buffers and images (data: URIs) load like external ones") {
    temp_folder const dir("canopy_gltf_test");
    instancing_scene const scene_file;
    write_mask_png(dir.path / "mask.png");
    std::string const image = "\"images\": [{\"uri\": \"data:image/png;base64," + base64(read_bytes(dir.path / "mask.png")) + "\"}]";
    fs::remove(dir.path / "mask.png");
    fs::path const file = dir.path / "embedded.gltf";
    write_text(file, scene_file.b.document(scene_file.b.embedded_buffer(), scene_file.rest + ", " + image));
    canopy::scene s;
    plugins().load(s, file);
    check_instancing_scene(s);
}

TEST_CASE(".glb files load, with the image in a buffer view") {
    temp_folder const dir("canopy_gltf_test");
    instancing_scene scene_file;
    write_mask_png(dir.path / "mask.png");
    auto const png = read_bytes(dir.path / "mask.png");
    fs::remove(dir.path / "mask.png");
    int const view = scene_file.b.add_view(png.data(), png.size());
    std::string const json = scene_file.b.document(
        "{\"byteLength\": " + std::to_string(scene_file.b.bin.size()) + "}",
        scene_file.rest + ", \"images\": [{\"bufferView\": " + std::to_string(view) + ", \"mimeType\": \"image/png\"}]");
    fs::path const file = dir.path / "forest.glb";
    write_glb(file, json, scene_file.b.bin);
    canopy::scene s;
    plugins().load(s, file);
    check_instancing_scene(s);
}

TEST_CASE("a node with a multi-primitive mesh holds a group of one mesh node per primitive") {
    temp_folder const dir("canopy_gltf_test");
    instancing_scene const scene_file;
    canopy::scene s;
    plugins().load(s, scene_file.write_external(dir.path));
    bool found = false;
    for (auto const& n : s.nodes()) {
        if (n.kind != canopy::node_kind::transform || n.name != "parts") continue;
        found = true;
        REQUIRE(n.children.size() == 1);
        auto const& g = s.at(n.children[0]);
        CHECK(g.kind == canopy::node_kind::group);
        REQUIRE(g.children.size() == 2);
        CHECK(s.meshes()[s.at(g.children[0]).mesh].name == "two_parts.primitives[0]");
        CHECK(s.meshes()[s.at(g.children[1]).mesh].name == "two_parts.primitives[1]");
    }
    CHECK(found);
}

namespace {

// A .gltf document of one triangle, (-1, -1, 0), (1, -1, 0), (1, 1, 0), whose positions accessor
// has a sparse part replacing element `index` with (3, 4, 5).
std::string sparse_triangle(std::uint8_t index) {
    gltf_builder b;
    int const pos = b.vec3s({-1, -1, 0, 1, -1, 0, 1, 1, 0});
    int const sparse_index = b.add_view(std::vector<std::uint8_t>{index}.data(), 1);
    std::vector<float> const moved{3, 4, 5};
    int const sparse_value = b.add_view(moved.data(), 12);
    b.accessors[std::size_t(pos)].insert(b.accessors[std::size_t(pos)].size() - 1,
                                         ", \"sparse\": {\"count\": 1, \"indices\": {\"bufferView\": " +
                                             std::to_string(sparse_index) + ", \"componentType\": 5121}, "
                                             "\"values\": {\"bufferView\": " + std::to_string(sparse_value) + "}}");
    return b.document(b.embedded_buffer(), "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": " +
                                               std::to_string(pos) + "}}]}], \"nodes\": [{\"mesh\": 0}], \"scenes\": [{\"nodes\": [0]}]");
}

} // namespace

TEST_CASE("sparse accessors replace the listed elements") {
    temp_folder const dir("canopy_gltf_test");
    fs::path const file = dir.path / "sparse.gltf";
    write_text(file, sparse_triangle(2));
    canopy::scene s;
    plugins().load(s, file);
    REQUIRE(s.meshes().size() == 1);
    auto const& p = s.meshes()[0].positions;
    REQUIRE(p.size() == 3);
    CHECK(p[0].x == -1.0f);
    CHECK(p[1].x == 1.0f);
    CHECK(p[2].x == 3.0f);
    CHECK(p[2].y == 4.0f);
    CHECK(p[2].z == 5.0f);
}

TEST_CASE("the builtin registry loads .gltf and .glb with the gltf plugin") {
    canopy::registry const& builtin = canopy::builtin_registry();
    for (canopy::registry const* registry : {&plugins(), &builtin}) {
        CHECK(registry->has_loader(".gltf"));
        CHECK(registry->has_loader(".glb"));
        int named = 0;
        for (auto const& l : registry->loaders()) named += (l.name == ".gltf" || l.name == ".glb") && l.plugin == "gltf";
        CHECK(named == 2);
    }
    temp_folder const dir("canopy_gltf_test");
    instancing_scene const scene_file;
    canopy::scene s = canopy::load_scene(scene_file.write_external(dir.path), canopy::builtin_registry());
    CHECK(s.meshes().size() == 4);
}

TEST_CASE("bad glTF files give errors naming the file and the element") {
    temp_folder const dir("canopy_gltf_test");
    auto const expect = [&](fs::path const& file, std::vector<std::string> const& parts) {
        std::string const message = load_error(file);
        INFO(message);
        REQUIRE_FALSE(message.empty());
        CHECK(message.find(file.filename().string()) != std::string::npos);
        for (auto const& p : parts) CHECK(message.find(p) != std::string::npos);
    };

    SECTION("missing file") {
        expect(dir.path / "absent.gltf", {"absent.gltf"});
        canopy::scene s;
        CHECK_THROWS_WITH(canopy::load_gltf(s, dir.path / "absent.gltf", s.root(), plugins()),
                          Catch::Contains("absent.gltf") && Catch::Contains("file not found"));
    }
    SECTION("malformed JSON") {
        write_text(dir.path / "broken.gltf", "{\"asset\": {\"version\": \"2.0\"}, \"nodes\": [{\"mesh\": ");
        expect(dir.path / "broken.gltf", {"parse error at line 1"});
    }
    SECTION("missing external buffer") {
        gltf_builder b;
        b.vec3s({0, 0, 0, 1, 0, 0, 0, 1, 0});
        write_text(dir.path / "nobin.gltf",
                   b.document("{\"uri\": \"absent.bin\", \"byteLength\": 36}",
                              "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": 0}}]}], "
                              "\"nodes\": [{\"mesh\": 0}], \"scenes\": [{\"nodes\": [0]}]"));
        expect(dir.path / "nobin.gltf", {"nobin.gltf: buffers[0]: " + (dir.path / "absent.bin").string() + ": file not found (buffer)"});
        b.external_buffer(dir.path / "short.bin");
        write_text(dir.path / "short.gltf",
                   b.document("{\"uri\": \"short.bin\", \"byteLength\": 40}",
                              "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": 0}}]}], "
                              "\"nodes\": [{\"mesh\": 0}], \"scenes\": [{\"nodes\": [0]}]"));
        expect(dir.path / "short.gltf", {"short.gltf: buffers[0]: " + (dir.path / "short.bin").string() +
                                         ": has 36 bytes, its byteLength says 40"});
    }
    SECTION("accessor reaching past its buffer view") {
        small_file f;
        f.index_count = "7";
        expect(f.write(dir.path / "long.gltf"),
               {"long.gltf: accessors[1]: 7 elements of 2 bytes, 2 apart from byte 0, do not fit in bufferViews[1] (12 bytes)"});
    }
    SECTION("index out of range") {
        small_file f;
        f.indices = {0, 1, 2, 0, 2, 7};
        expect(f.write(dir.path / "index.gltf"),
               {"meshes[0].primitives[0]", "index 7 at position 5 is out of range (4 vertices)"});
    }
    SECTION("NaN position") {
        small_file f;
        f.positions[4] = std::numeric_limits<float>::quiet_NaN();
        expect(f.write(dir.path / "nan.gltf"), {"meshes[0].primitives[0]", "POSITION", "vertex 1", "not finite"});
    }
    SECTION("lines are not triangles") {
        small_file f;
        f.primitive_extra = ", \"mode\": 1";
        expect(f.write(dir.path / "lines.gltf"), {"meshes[0].primitives[0]", "LINES"});
    }
    SECTION("triangle list not a multiple of 3") {
        small_file f;
        f.indices = {0, 1, 2, 0};
        expect(f.write(dir.path / "four.gltf"), {"meshes[0].primitives[0]", "not a multiple of 3"});
    }
    SECTION("node referring to a missing mesh") {
        small_file f;
        f.nodes = "[{\"mesh\": 9}]";
        expect(f.write(dir.path / "nomesh.gltf"), {"nomesh.gltf: nodes[0].mesh: index 9 is out of range (1 meshes)"});
    }
    SECTION("node hierarchy with a cycle") {
        small_file f;
        f.nodes = "[{\"children\": [1]}, {\"mesh\": 0, \"children\": [0]}]";
        expect(f.write(dir.path / "cycle.gltf"), {"cycle.gltf: nodes[0]: is its own descendant (nodes[0] → nodes[1] → nodes[0])"});
    }
    SECTION("zero scale") {
        small_file f;
        f.nodes = "[{\"mesh\": 0, \"scale\": [1, 0, 1]}]";
        expect(f.write(dir.path / "flat.gltf"), {"nodes[0]", "scale"});
    }
    SECTION("missing texture image") {
        small_file f;
        f.primitive_extra = ", \"material\": 0";
        f.extra = ", \"materials\": [{\"alphaMode\": \"MASK\", \"pbrMetallicRoughness\": {\"baseColorTexture\": "
                  "{\"index\": 0}}}], \"textures\": [{\"source\": 0}], \"images\": [{\"uri\": \"absent.png\"}]";
        // The texture needs texture coordinates: first their absence, then the missing image.
        expect(f.write(dir.path / "nouv.gltf"), {"meshes[0].primitives[0]", "TEXCOORD_0"});
        f.primitive_extra = ", \"material\": 0";
        f.extra = ", \"materials\": [{\"pbrMetallicRoughness\": {\"baseColorTexture\": {\"index\": 0}}}], "
                  "\"textures\": [{\"source\": 0}], \"images\": [{\"uri\": \"absent.png\"}]";
        gltf_builder b;
        int const pos = b.vec3s(f.positions);
        int const uv = b.vec2s({0, 1, 1, 1, 1, 0, 0, 0});
        write_text(dir.path / "noimage.gltf",
                   b.document(b.embedded_buffer(), "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": " +
                                                       std::to_string(pos) + ", \"TEXCOORD_0\": " + std::to_string(uv) +
                                                       "}, \"mode\": 6, \"material\": 0}]}], \"nodes\": [{\"mesh\": 0}], "
                                                       "\"scenes\": [{\"nodes\": [0]}]" + f.extra));
        expect(dir.path / "noimage.gltf", {"images[0]", "absent.png"});
    }
    SECTION("bad sparse index") {
        write_text(dir.path / "sparse.gltf", sparse_triangle(3));
        expect(dir.path / "sparse.gltf", {"meshes[0].primitives[0]", "sparse index 3"});
    }
    SECTION("orthographic camera") {
        small_file f;
        f.nodes = "[{\"mesh\": 0, \"camera\": 0}]";
        f.extra = ", \"cameras\": [{\"type\": \"orthographic\", \"orthographic\": {\"xmag\": 1, \"ymag\": 1, "
                  "\"znear\": 0.1, \"zfar\": 10}}]";
        expect(f.write(dir.path / "ortho.gltf"), {"cameras[0]", "orthographic"});
    }
    SECTION("required extension") {
        small_file f;
        f.extra = ", \"extensionsUsed\": [\"KHR_draco_mesh_compression\"], "
                  "\"extensionsRequired\": [\"KHR_draco_mesh_compression\"]";
        expect(f.write(dir.path / "draco.gltf"), {"KHR_draco_mesh_compression"});
    }
}

// ---- Debian's assimp-testmodels (the glTF Asset Generator and deliberately broken files) ----------

namespace {
fs::path const assimp_gltf = "/usr/share/assimp/models/glTF2";
}

TEST_CASE("the Asset Generator's triangle, strip and fan quads load as two front-facing triangles covering the quad") {
    // Each file holds the square [-0.5, 0.5]² at z = 0, counter-clockwise seen from +Z, in one
    // primitive: unindexed (04 strip, 05 fan, 06 list) or indexed (11 strip, 12 fan, 13-15 list
    // with u32, u8 and u16 indices).
    for (char const* n : {"04", "05", "06", "11", "12", "13", "14", "15"}) {
        fs::path const file = assimp_gltf / "glTF-Asset-Generator/Mesh_PrimitiveMode" / ("Mesh_PrimitiveMode_" + std::string(n) + ".gltf");
        INFO(file.string());
        REQUIRE(fs::exists(file));
        canopy::scene s;
        plugins().load(s, file);
        REQUIRE(s.meshes().size() == 1);
        auto const& m = s.meshes()[0];
        REQUIRE(m.triangles.size() == 2);
        for (auto const& t : m.triangles) {
            auto const e1 = m.positions[t[1]] - m.positions[t[0]];
            auto const e2 = m.positions[t[2]] - m.positions[t[0]];
            CHECK(e1.x * e2.y - e1.y * e2.x > 0.0f); // counter-clockwise: the face points along +Z
        }
        canopy::compiled_scene const c = canopy::compile(s, {.plugins = &plugins()});
        canopy::default_intersector plain;
        for (float x : {-0.4f, -0.15f, 0.1f, 0.35f})
            for (float y : {-0.35f, -0.05f, 0.2f, 0.45f}) {
                auto const hit = trace(c, ray_from({x, y, 1}, {0, 0, -1}), plain);
                CHECK(hit.hit);
                CHECK(hit.t == Approx(1.0f));
            }
        CHECK_FALSE(trace(c, ray_from({0.6f, 0.0f, 1}, {0, 0, -1}), plain).hit);
    }
}

TEST_CASE("the Asset Generator's points and lines are refused, naming the primitive and the mode") {
    std::map<std::string, std::string> const modes{{"00", "POINTS"}, {"01", "LINES"}, {"02", "LINE_LOOP"}, {"03", "LINE_STRIP"}};
    for (auto const& [n, mode] : modes) {
        fs::path const file = assimp_gltf / "glTF-Asset-Generator/Mesh_PrimitiveMode" / ("Mesh_PrimitiveMode_" + n + ".gltf");
        REQUIRE(fs::exists(file));
        std::string const message = load_error(file);
        INFO(message);
        CHECK(message.find(file.filename().string()) != std::string::npos);
        CHECK(message.find("meshes[0].primitives[0]: mode " + mode + " is not supported") != std::string::npos);
    }
}

TEST_CASE("assimp's broken glTF files give errors naming the file and the element") {
    struct broken {
        char const* file;
        std::vector<std::string> parts;
    };
    std::vector<broken> const cases{
        {"IndexOutOfRange/IndexOutOfRange.gltf", {"meshes[0].primitives[0]", "is out of range (24 vertices)"}},
        {"IndexOutOfRange/AllIndicesOutOfRange.gltf", {"meshes[0].primitives[0]", "index 65535 at position 0"}},
        {"BoxWithInfinites-glTF-Binary/BoxWithInfinites.glb", {"meshes[0].primitives[0]", "POSITION", "not finite"}},
        {"RecursiveNodes/RecursiveNodes.gltf", {"nodes[0]: is its own descendant (nodes[0] → nodes[1] → nodes[0])"}},
        {"MissingBin/BoxTextured.gltf", {"BoxTextured0.bin"}},
        // Its buffer views reach past its 514-byte buffer (found before its meshes are read).
        {"IncorrectVertexArrays/Cube.gltf", {"bufferViews[2]: bytes 504 + 432 lie outside buffers[0] (514 bytes)"}},
        {"BoxTextured-glTF-techniqueWebGL/BoxTextured.gltf", {"extensionsRequired", "KHR_technique_webgl"}},
        // glTF 1.0 (assimp's glTF/ folder) is refused by version, not read as an empty scene.
        {"../glTF/TwoBoxes/TwoBoxes.gltf", {"asset.version", "glTF '1.0' is not supported"}},
    };
    for (auto const& b : cases) {
        fs::path const file = assimp_gltf / b.file;
        REQUIRE(fs::exists(file));
        std::string const message = load_error(file);
        INFO(message);
        CHECK(message.find(file.filename().string()) != std::string::npos);
        for (auto const& p : b.parts) CHECK(message.find(p) != std::string::npos);
    }
}

TEST_CASE("assimp's textured box loads alike from .gltf, embedded .gltf and .glb") {
    // 12 triangles; the base colour texture (CesiumLogoFlat.png, 211×211 with a palette) in all three forms.
    std::vector<std::vector<canopy::vec4<float>>> texels;
    for (char const* f : {"BoxTextured-glTF/BoxTextured.gltf", "BoxTextured-glTF-Embedded/BoxTextured.gltf",
                          "BoxTextured-glTF-Binary/BoxTextured.glb"}) {
        INFO(f);
        REQUIRE(fs::exists(assimp_gltf / f));
        canopy::scene s;
        plugins().load(s, assimp_gltf / f);
        REQUIRE(s.meshes().size() == 1);
        CHECK(s.meshes()[0].triangles.size() == 12);
        CHECK(s.meshes()[0].uvs.size() == 12);
        REQUIRE(s.images().size() == 1);
        CHECK(s.images()[0].width == 211);
        CHECK(s.images()[0].height == 211);
        texels.push_back(s.images()[0].texels);
    }
    // The file through the registry's image loader (OpenImageIO) and the embedded copies through
    // tinygltf's decoder: the same 8-bit values, so the same linear texels up to float rounding.
    REQUIRE(texels.size() == 3);
    for (std::size_t k = 1; k < 3; ++k) {
        REQUIRE(texels[k].size() == texels[0].size());
        float worst = 0.0f;
        for (std::size_t i = 0; i < texels[0].size(); ++i)
            for (float d : {texels[k][i].x - texels[0][i].x, texels[k][i].y - texels[0][i].y,
                            texels[k][i].z - texels[0][i].z, texels[k][i].w - texels[0][i].w})
                worst = std::max(worst, std::abs(d));
        CHECK(worst < 1e-6f);
    }
}

// ---- Schema violations, hostile hierarchies and files ---------------------------------------------

namespace {

// The small quad file with `replace` substituted for the first `find` in its JSON text.
fs::path small_file_with(fs::path const& file, std::string const& find, std::string const& replace,
                         small_file const& f = {}) {
    f.write(file);
    std::ifstream in(file, std::ios::binary);
    std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    auto const at = text.find(find);
    REQUIRE(at != std::string::npos);
    text.replace(at, find.size(), replace);
    write_text(file, text);
    return file;
}

// A document of the quad and `nodes` (a JSON array), every node holding the quad's mesh.
fs::path with_nodes(fs::path const& file, std::string const& nodes, std::string const& scene_nodes = "[0]") {
    small_file f;
    f.nodes = nodes;
    return small_file_with(file, "\"scenes\": [{\"nodes\": [0]}]", "\"scenes\": [{\"nodes\": " + scene_nodes + "}]", f);
}

// A PNG header claiming width × height (RGBA 8-bit), with CRCs, a token image data chunk and IEND.
std::vector<unsigned char> png_claiming(std::uint32_t width, std::uint32_t height) {
    auto const crc = [](std::string const& bytes) {
        std::uint32_t c = 0xFFFFFFFFu;
        for (unsigned char b : bytes) {
            c ^= b;
            for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
        }
        return ~c;
    };
    auto const be32 = [](std::string& out, std::uint32_t v) {
        for (int k = 3; k >= 0; --k) out += char((v >> (8 * k)) & 0xFF);
    };
    std::string png = "\x89PNG\r\n\x1a\n";
    auto const chunk = [&](std::string const& type, std::string const& data) {
        be32(png, std::uint32_t(data.size()));
        png += type + data;
        be32(png, crc(type + data));
    };
    std::string ihdr;
    be32(ihdr, width);
    be32(ihdr, height);
    ihdr += std::string("\x08\x06\x00\x00\x00", 5);
    chunk("IHDR", ihdr);
    chunk("IDAT", std::string("\x78\x9c\x63\x00\x00", 5));
    chunk("IEND", "");
    return {png.begin(), png.end()};
}

} // namespace

TEST_CASE("glTF schema violations are refused with their JSON path, not dropped") {
    temp_folder const dir("canopy_gltf_test");
    auto const expect = [&](fs::path const& file, std::string const& message) {
        std::string const m = load_error(file);
        INFO(m);
        CHECK(m.find(file.filename().string() + ": " + message) != std::string::npos);
        CHECK(m.size() < 400);
    };
    small_file textured;
    textured.primitive_extra = ", \"material\": 0";
    textured.extra = ", \"materials\": [{\"pbrMetallicRoughness\": {\"baseColorTexture\": {\"index\": -1}}}]";
    expect(textured.write(dir.path / "minus_one.gltf"),
           "materials[0].pbrMetallicRoughness.baseColorTexture.index: index -1 is out of range (0 textures)");
    textured.extra = ", \"materials\": [{\"pbrMetallicRoughness\": [\"not an object\"]}]";
    expect(textured.write(dir.path / "array.gltf"), "materials[0].pbrMetallicRoughness: expected an object, got an array");
    textured.extra = ", \"materials\": [{\"normalTexture\": {\"index\": 0, \"scale\": \"big\"}}], \"textures\": [{}]";
    expect(textured.write(dir.path / "scale.gltf"), "materials[0].normalTexture.scale: expected a number, got a string ('big')");
    textured.extra = ", \"materials\": [{\"pbrMetallicRoughness\": {\"baseColorFactor\": [1, 0.5, 1.5, 1]}}]";
    expect(textured.write(dir.path / "factor.gltf"), "materials[0].pbrMetallicRoughness.baseColorFactor[2]: 1.5 is out of range [0, 1]");
    textured.extra = ", \"materials\": [{\"alphaMode\": \"CLIP\"}]";
    expect(textured.write(dir.path / "mode.gltf"), "materials[0].alphaMode: 'CLIP' is not one of OPAQUE, MASK, BLEND");
    textured.extra = ", \"materials\": [{\"extensions\": {\"KHR_materials_unlit\": \"yes\"}}]";
    expect(textured.write(dir.path / "extension.gltf"),
           "materials[0].extensions.KHR_materials_unlit: expected an object, got a string ('yes')");

    expect(small_file_with(dir.path / "primitives.gltf", "\"primitives\": [", "\"primitives\": [[], "),
           "meshes[0].primitives[0]: expected an object, got an array");
    expect(small_file_with(dir.path / "mesh.gltf", "\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": 0.0}]"),
           "nodes[0].mesh: expected an integer index, got the number 0");
    expect(small_file_with(dir.path / "scene.gltf", "\"scenes\": [{\"nodes\": [0]}]", "\"scenes\": [{\"nodes\": [0]}], \"scene\": \"main\""),
           "scene: expected an integer index, got a string ('main')");
    expect(small_file_with(dir.path / "name.gltf", "\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": 0, \"name\": 42}]"),
           "nodes[0].name: expected a string, got the number 42");
    expect(small_file_with(dir.path / "count.gltf", "\"count\": 6", "\"count\": -6"),
           "accessors[1].count: -6 is out of range [1, 9007199254740992]");
    expect(small_file_with(dir.path / "component.gltf", "\"componentType\": 5123", "\"componentType\": 5124"),
           "accessors[1].componentType: 5124 is not one of 5120, 5121, 5122, 5123, 5125, 5126");
    expect(small_file_with(dir.path / "type.gltf", "\"type\": \"SCALAR\"", "\"type\": \"VEC5\""),
           "accessors[1].type: 'VEC5' is not one of SCALAR, VEC2, VEC3, VEC4, MAT2, MAT3, MAT4");
    expect(small_file_with(dir.path / "stride.gltf", "\"byteOffset\": 0,", "\"byteOffset\": 0, \"byteStride\": 6,"),
           "bufferViews[0].byteStride: 6 is not a multiple of 4");
    expect(small_file_with(dir.path / "stride_small.gltf", "\"byteOffset\": 0,", "\"byteOffset\": 0, \"byteStride\": 8,"),
           "accessors[0]: byteStride 8 of bufferViews[0] is smaller than an element (12 bytes)");
    // Offsets that would overflow a 64-bit sum are out of range, not wrapped.
    expect(small_file_with(dir.path / "offset.gltf", "\"byteOffset\": 0,", "\"byteOffset\": 9007199254740000,"),
           "bufferViews[0]: bytes 9007199254740000 + 48 lie outside buffers[0] (60 bytes)");
    expect(small_file_with(dir.path / "accessor_offset.gltf", "\"componentType\": 5126", "\"byteOffset\": 9007199254740000, \"componentType\": 5126"),
           "accessors[0]: 4 elements of 12 bytes, 12 apart from byte 9007199254740000, do not fit in bufferViews[0] (48 bytes)");
    expect(small_file_with(dir.path / "matrix.gltf", "\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": 0, \"matrix\": [1, 0, 0]}]"),
           "nodes[0].matrix: has 3 values (16 needed)");
    expect(small_file_with(dir.path / "rotation.gltf", "\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": 0, \"rotation\": [0, 0, 2, 1]}]"),
           "nodes[0].rotation[2]: 2 is out of range [-1, 1]");
    expect(small_file_with(dir.path / "children.gltf", "\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": 0, \"children\": [1, 1]}, {}]"),
           "nodes[0].children[1]: index 1 is listed twice");
    expect(small_file_with(dir.path / "sparse.gltf", "\"componentType\": 5126", "\"componentType\": 5126, \"sparse\": {\"count\": 0}"),
           "accessors[0].sparse.count: 0 is out of range [1, 4]");
    // Finite in JSON, beyond a float in the scene.
    expect(small_file_with(dir.path / "far.gltf", "\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": 0, \"translation\": [1e300, 0, 0]}]"),
           "nodes[0]: transform has a value beyond the range of a float");
    expect(small_file_with(dir.path / "version.gltf", "\"version\": \"2.0\"", "\"version\": 2"),
           "asset.version: expected a string, got the number 2");
    // A long token is quoted by a short prefix.
    expect(small_file_with(dir.path / "long.gltf", "\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": \"" + std::string(100000, 'x') + "\"}]"),
           "nodes[0].mesh: expected an integer index, got a string ('xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx…')");
    write_text(dir.path / "broken.gltf", "{\"asset\": {\"version\": \"2.0\"}, \"nodes\": [\"" + std::string(100000, 'y'));
    expect(dir.path / "broken.gltf", "malformed JSON: parse error at line 1");
}

TEST_CASE("glTF node hierarchies: no recursion, a limit on depth, cycles and second parents named") {
    temp_folder const dir("canopy_gltf_test");
    // A chain of 100,000 nodes: refused at the node past --max-depth (4096), quickly.
    std::string chain = "[";
    for (int i = 0; i < 100000; ++i)
        chain += (i ? ", " : "") + std::string("{\"children\": [") + std::to_string(i + 1) + "]}";
    chain += ", {\"mesh\": 0}]";
    CHECK_THAT(load_error(with_nodes(dir.path / "chain.gltf", chain)),
               Catch::Contains("chain.gltf: nodes[4096]: is 4097 levels deep in the node hierarchy, over the limit of 4096 (--max-depth)"));
    {
        // At the limit a chain loads (the limit also bounds the JSON's nesting, 6 levels here).
        limits_guard const guard;
        canopy::default_limits().max_depth = 8;
        auto const chain_of = [](int n) {
            std::string nodes = "[";
            for (int i = 0; i + 1 < n; ++i) nodes += "{\"children\": [" + std::to_string(i + 1) + "]}, ";
            return nodes + "{\"mesh\": 0}]";
        };
        canopy::scene s;
        plugins().load(s, with_nodes(dir.path / "eight.gltf", chain_of(8)));
        CHECK(s.meshes().size() == 1);
        CHECK_THAT(load_error(with_nodes(dir.path / "nine.gltf", chain_of(9))),
                   Catch::Contains("nine.gltf: nodes[8]: is 9 levels deep in the node hierarchy, over the limit of 8 (--max-depth)"));
    }
    CHECK_THAT(load_error(with_nodes(dir.path / "self.gltf", "[{\"mesh\": 0, \"children\": [0]}]")),
               Catch::Contains("self.gltf: nodes[0]: is its own descendant (nodes[0] → nodes[0])"));
    CHECK_THAT(load_error(with_nodes(dir.path / "ring.gltf", "[{\"mesh\": 0}, {\"children\": [2]}, {\"children\": [1]}]")),
               Catch::Contains("ring.gltf: nodes[1]: is its own descendant (nodes[1] → nodes[2] → nodes[1])"));
    CHECK_THAT(load_error(with_nodes(dir.path / "two.gltf", "[{\"children\": [2]}, {\"children\": [2]}, {\"mesh\": 0}]", "[0, 1]")),
               Catch::Contains("two.gltf: nodes[2]: is a child of both nodes[0] and nodes[1] (a glTF node has at most one parent)"));
    CHECK_THAT(load_error(with_nodes(dir.path / "root.gltf", "[{\"children\": [1]}, {\"mesh\": 0}]", "[0, 1]")),
               Catch::Contains("root.gltf: scenes[0].nodes: nodes[1] is a child of nodes[0], not a root node"));
    // JSON nested without end (in extras, which tinygltf copies recursively).
    CHECK_THAT(load_error(small_file_with(dir.path / "deep.gltf", "\"nodes\": [{\"mesh\": 0}]",
                                          "\"nodes\": [{\"mesh\": 0, \"extras\": " + std::string(100000, '[') +
                                              std::string(100000, ']') + "}]")),
               Catch::Contains("deep.gltf: JSON arrays and objects nest deeper than 512 levels") &&
                   Catch::Contains("over the limit of the glTF loader"));
}

TEST_CASE("glTF buffers and images that are devices, huge or not images are refused by name") {
    temp_folder const dir("canopy_gltf_test");
    // An external buffer and a texture that are /dev/zero.
    gltf_builder b;
    b.vec3s({0, 0, 0, 1, 0, 0, 0, 1, 0});
    fs::create_symlink("/dev/zero", dir.path / "zero.bin");
    write_text(dir.path / "zero_buffer.gltf",
               b.document("{\"uri\": \"zero.bin\", \"byteLength\": 36}",
                          "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": 0}}]}], \"nodes\": [{\"mesh\": 0}], "
                          "\"scenes\": [{\"nodes\": [0]}]"));
    CHECK_THAT(load_error(dir.path / "zero_buffer.gltf"),
               Catch::Contains("zero_buffer.gltf: buffers[0]: " + (dir.path / "zero.bin").string() +
                               ": is a character device, not a regular file (buffer)"));
    fs::create_symlink("/dev/zero", dir.path / "zero.png");
    gltf_builder t;
    int const pos = t.vec3s({-1, -1, 0, 1, -1, 0, 1, 1, 0});
    int const uv = t.vec2s({0, 1, 1, 1, 1, 0});
    std::string const mesh = "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": " + std::to_string(pos) +
                             ", \"TEXCOORD_0\": " + std::to_string(uv) + "}, \"material\": 0}]}], \"nodes\": [{\"mesh\": 0}], "
                             "\"scenes\": [{\"nodes\": [0]}], \"materials\": [{\"pbrMetallicRoughness\": "
                             "{\"baseColorTexture\": {\"index\": 0}}}], \"textures\": [{\"source\": 0}], ";
    write_text(dir.path / "zero_texture.gltf", t.document(t.embedded_buffer(), mesh + "\"images\": [{\"uri\": \"zero.png\"}]"));
    CHECK_THAT(load_error(dir.path / "zero_texture.gltf"),
               Catch::Contains("zero_texture.gltf: images[0]: 'zero.png': " + (dir.path / "zero.png").string() +
                               ": is a character device, not a regular file (texture)"));

    // An embedded PNG whose header claims 16384 × 16384: refused before stb_image decodes it.
    gltf_builder g = t;
    auto const png = png_claiming(16384, 16384);
    int const view = g.add_view(png.data(), png.size());
    std::string const json = g.document("{\"byteLength\": " + std::to_string(g.bin.size()) + "}",
                                        mesh + "\"images\": [{\"bufferView\": " + std::to_string(view) + ", \"mimeType\": \"image/png\"}]");
    write_glb(dir.path / "big.glb", json, g.bin);
    CHECK_THAT(load_error(dir.path / "big.glb"),
               Catch::Contains("big.glb: images[0]: embedded image is 16384 × 16384 (268435456 texels), over the limit of "
                               "67108864 texels (--max-texels)"));
    std::vector<unsigned char> const gif{'G', 'I', 'F', '8', '9', 'a', 1, 0, 1, 0, 0, 0, 0};
    write_text(dir.path / "gif.gltf", t.document(t.embedded_buffer(), mesh + "\"images\": [{\"uri\": \"data:image/gif;base64," +
                                                                         base64(gif) + "\"}]"));
    CHECK_THAT(load_error(dir.path / "gif.gltf"), Catch::Contains("gif.gltf: images[0]: embedded image is neither PNG nor JPEG"));
    // A data: URI tinygltf does not decode: quoted by a short prefix, not in full.
    write_text(dir.path / "webp.gltf", t.document(t.embedded_buffer(), mesh + "\"images\": [{\"uri\": \"data:image/webp;base64," +
                                                                          std::string(200000, 'A') + "\"}]"));
    std::string const webp = load_error(dir.path / "webp.gltf");
    CHECK_THAT(webp, Catch::Contains("webp.gltf: images[0]: data: URI 'data:image/webp;base64,AAAAAAAAAAAAAAAAA…' is not one tinygltf decodes"));
    CHECK(webp.size() < 400);

}

TEST_CASE("a .glb's layout is checked before it is read: the header, each chunk, the BIN chunk buffers[0] needs") {
    temp_folder const dir("canopy_gltf_test");
    // A valid .glb: one triangle, its buffer the BIN chunk.
    gltf_builder b;
    b.vec3s({0, 0, 0, 1, 0, 0, 0, 1, 0});
    std::string const rest =
        "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": 0}}]}], \"nodes\": [{\"mesh\": 0}], \"scenes\": [{\"nodes\": [0]}]";
    std::string const document = b.document("{\"byteLength\": " + std::to_string(b.bin.size()) + "}", rest);
    write_glb(dir.path / "good.glb", document, b.bin);
    std::string good;
    for (unsigned char c : read_bytes(dir.path / "good.glb")) good += char(c);
    REQUIRE(good.size() > 40);
    auto const set_u32 = [](std::string bytes, std::size_t at, std::uint32_t v) {
        for (std::size_t k = 0; k < 4; ++k) bytes[at + k] = char((v >> (8 * k)) & 0xFF);
        return bytes;
    };
    std::size_t const json_chunk = 12 + 8 + std::size_t(std::uint8_t(good[12])) + 256 * std::size_t(std::uint8_t(good[13]));
    std::string const size = std::to_string(good.size());
    // A chunk of a type this loader does not know, after BIN: skipped, as glTF asks.
    std::string extra = good + set_u32(std::string(4, '\0'), 0, 4) + "XTRA" + "abcd";
    extra = set_u32(extra, 8, std::uint32_t(extra.size()));
    {
        write_text(dir.path / "extra.glb", extra);
        canopy::scene s;
        plugins().load(s, dir.path / "extra.glb");
        REQUIRE(s.meshes().size() == 1);
        CHECK(s.meshes()[0].triangles.size() == 1);
    }
    std::string trailing = good + "abcd";
    trailing = set_u32(trailing, 8, std::uint32_t(trailing.size()));
    std::string const no_bin = good.substr(0, json_chunk);
    std::string short_bin = no_bin + set_u32(std::string(4, '\0'), 0, 4) + std::string("BIN\0", 4) + good.substr(json_chunk + 8, 4);
    short_bin = set_u32(short_bin, 8, std::uint32_t(short_bin.size()));
    struct bad_case {
        std::string name, bytes, message;
    };
    std::vector<bad_case> const cases = {
        {"magic", "abcd" + good.substr(4), "GLB header: magic is 'abcd', expected 'glTF'"},
        {"binary_magic", std::string("\x01\0'x", 4) + good.substr(4), "GLB header: magic is '\\x01\\x00\\x27x', expected 'glTF'"},
        {"text", document, "GLB header: magic is '{\"as', expected 'glTF'"},
        {"short", good.substr(0, 8), "GLB header: the file has 8 bytes, fewer than the header's 12"},
        {"version", set_u32(good, 4, 1), "GLB header: version is 1, expected 2"},
        {"long", set_u32(good, 8, 99999), "GLB header: length 99999 runs past the end of the file (" + size + " bytes)"},
        {"longer_file", good + "abcd", "GLB header: length " + size + " ends before the end of the file (" +
                                           std::to_string(good.size() + 4) + " bytes)"},
        {"header_only", set_u32(good.substr(0, 12), 8, 12), "GLB header: no chunk follows the header (the JSON chunk is required)"},
        {"json_length", set_u32(good, 12, 99999), "chunk 0: length 99999 runs past the end of the file (" + size + " bytes)"},
        {"json_type", good.substr(0, 16) + "BIN" + good.substr(19),
         "chunk 0: type is 'BINN', expected 'JSON' (the JSON chunk comes first)"},
        {"json_unpadded", set_u32(good, 12, std::uint32_t(json_chunk - 20 - 1)),
         "chunk 0: length " + std::to_string(json_chunk - 21) + " is not a multiple of 4 (chunks are padded)"},
        {"bin_length", set_u32(good, json_chunk, 99999), "chunk 1: length 99999 runs past the end of the file (" + size + " bytes)"},
        {"two_json", good.substr(0, json_chunk + 4) + "JSON" + good.substr(json_chunk + 8),
         "chunk 1: a second JSON chunk (there is one, the first)"},
        {"trailing", trailing, "chunk 2: its 8-byte header at byte " + size + " runs past the end of the file (" +
                                   std::to_string(trailing.size()) + " bytes)"},
        {"no_bin", set_u32(no_bin, 8, std::uint32_t(no_bin.size())), "buffers[0]: has no uri and the file has no BIN chunk"},
        {"short_bin", short_bin, "buffers[0]: byteLength 36 is more than the 4 bytes of the BIN chunk"},
    };
    for (auto const& c : cases) {
        INFO(c.name);
        fs::path const file = dir.path / (c.name + ".glb");
        write_text(file, c.bytes);
        CHECK(load_error(file) == file.string() + ": " + c.message);
    }
    // Only a .glb's first buffer may go without a uri.
    write_text(dir.path / "no_uri.gltf", document);
    CHECK(load_error(dir.path / "no_uri.gltf") ==
          (dir.path / "no_uri.gltf").string() +
              ": buffers[0]: has no uri (only the first buffer of a .glb file, its BIN chunk, may go without)");
}

TEST_CASE("glTF images of the same bytes or file are decoded once, and alpha factors move the cutoff, not the texels") {
    temp_folder const dir("canopy_gltf_test");
    write_mask_png(dir.path / "mask.png");
    auto const png = read_bytes(dir.path / "mask.png");
    gltf_builder b;
    int const pos = b.vec3s({-1, -1, 0, 1, -1, 0, 1, 1, 0});
    int const uv = b.vec2s({0, 1, 1, 1, 1, 0});
    int const view = b.add_view(png.data(), png.size());
    b.views.push_back(b.views[std::size_t(view)]); // a second view of the same bytes
    std::string primitives;
    for (int m = 0; m < 5; ++m)
        primitives += std::string(m ? ", " : "") + "{\"attributes\": {\"POSITION\": " + std::to_string(pos) +
                      ", \"TEXCOORD_0\": " + std::to_string(uv) + "}, \"material\": " + std::to_string(m) + "}";
    auto const material = [](int texture, double alpha) {
        return "{\"alphaMode\": \"MASK\", \"alphaCutoff\": 0.5, \"pbrMetallicRoughness\": {\"baseColorFactor\": [1, 1, 1, " +
               std::to_string(alpha) + "], \"baseColorTexture\": {\"index\": " + std::to_string(texture) + "}}}";
    };
    std::string const rest =
        "\"meshes\": [{\"primitives\": [" + primitives + "]}], \"nodes\": [{\"mesh\": 0}], \"scenes\": [{\"nodes\": [0]}], "
        "\"materials\": [" + material(0, 1.0) + ", " + material(1, 0.5) + ", " + material(2, 0.25) + ", " + material(3, 1.0) +
        ", " + material(4, 0.8) + "], \"textures\": [{\"source\": 0}, {\"source\": 1}, {\"source\": 2}, {\"source\": 3}, {\"source\": 4}], "
        "\"images\": [{\"bufferView\": " + std::to_string(view) + ", \"mimeType\": \"image/png\"}, {\"bufferView\": " +
        std::to_string(view + 1) + ", \"mimeType\": \"image/png\"}, {\"bufferView\": " + std::to_string(view) +
        ", \"mimeType\": \"image/png\"}, {\"uri\": \"mask.png\"}, {\"uri\": \"mask.png\"}]";
    write_glb(dir.path / "shared.glb", b.document("{\"byteLength\": " + std::to_string(b.bin.size()) + "}", rest), b.bin);
    canopy::scene s;
    plugins().load(s, dir.path / "shared.glb");
    // Images 0-2 (one buffer range) are one image, 3-4 (one file) another; factor 0.25 < cutoff 0.5
    // leaves only holes (a texel of alpha 0).
    REQUIRE(s.materials().size() == 5);
    REQUIRE(s.images().size() == 3);
    auto const& m = s.materials();
    CHECK(m[0].image == m[1].image);
    CHECK(m[3].image == m[4].image);
    CHECK(m[0].image != m[3].image);
    CHECK(m[0].alpha_cutoff == 0.5f);
    CHECK(m[1].alpha_cutoff == 1.0f);
    CHECK(m[4].alpha_cutoff == float(0.5 / 0.8));
    auto const& hole = s.images()[std::size_t(m[2].image)];
    REQUIRE(hole.texels.size() == 1);
    CHECK(hole.texels[0].w == 0.0f);
    // The texels as stored in the file: the opaque quadrant keeps alpha 1.
    auto const& shared = s.images()[std::size_t(m[0].image)];
    REQUIRE(shared.width == 4);
    CHECK(shared.texels[5].w == 1.0f);
    CHECK(shared.texels[10].w == 0.0f);
}

TEST_CASE("glTF images count against --max-total-texels: embedded ones from when they are decoded") {
    temp_folder const dir("canopy_gltf_test");
    limits_guard const guard;
    write_mask_png(dir.path / "mask.png"); // 4 × 4
    auto const png = read_bytes(dir.path / "mask.png");
    gltf_builder b;
    int const pos = b.vec3s({-1, -1, 0, 1, -1, 0, 1, 1, 0});
    int const uv = b.vec2s({0, 1, 1, 1, 1, 0});
    int const view = b.add_view(png.data(), png.size());
    std::string primitives;
    for (int m = 0; m < 2; ++m)
        primitives += std::string(m ? ", " : "") + "{\"attributes\": {\"POSITION\": " + std::to_string(pos) +
                      ", \"TEXCOORD_0\": " + std::to_string(uv) + "}, \"material\": " + std::to_string(m) + "}";
    // Material 0 uses the file (read after the embedded image is decoded, before the scene holds
    // it), material 1 the embedded image.
    std::string const rest =
        "\"meshes\": [{\"primitives\": [" + primitives + "]}], \"nodes\": [{\"mesh\": 0}], \"scenes\": [{\"nodes\": [0]}], "
        "\"materials\": [{\"pbrMetallicRoughness\": {\"baseColorTexture\": {\"index\": 0}}}, "
        "{\"pbrMetallicRoughness\": {\"baseColorTexture\": {\"index\": 1}}}], "
        "\"textures\": [{\"source\": 0}, {\"source\": 1}], "
        "\"images\": [{\"uri\": \"mask.png\"}, {\"bufferView\": " + std::to_string(view) + ", \"mimeType\": \"image/png\"}]";
    fs::path const file = dir.path / "two.glb";
    write_glb(file, b.document("{\"byteLength\": " + std::to_string(b.bin.size()) + "}", rest), b.bin);
    auto const over = [](std::uint64_t held, std::uint64_t limit) {
        return "image is 4 × 4 (16 texels): with the " + std::to_string(held) + " texels of the images loaded before it, " +
               std::to_string(held + 16) + " texels in all exceed the limit of " + std::to_string(limit) +
               " (--max-total-texels)";
    };
    canopy::default_limits().max_total_texels = 32;
    {
        canopy::scene s;
        plugins().load(s, file);
        CHECK(s.images().size() == 2);
        CHECK(s.texels() == 32);
        // Loaded again into the same scene: the embedded image is refused as it is decoded.
        CHECK(test_support::message_of([&] { plugins().load(s, file); }) ==
              file.string() + ": images[1]: embedded " + over(32, 32));
        CHECK(s.texels() == 32);
    }
    canopy::default_limits().max_total_texels = 31;
    CHECK(load_error(file) ==
          file.string() + ": images[0]: 'mask.png': " + (dir.path / "mask.png").string() + ": " + over(16, 31));
    canopy::default_limits().max_total_texels = 15;
    CHECK(load_error(file) == file.string() + ": images[1]: embedded " + over(0, 15));
}

TEST_CASE("glTF meshes are held to --max-triangles together, before their accessors are read") {
    temp_folder const dir("canopy_gltf_test");
    // Four meshes of one primitive each, all on the quad's accessors: 16 vertices, 8 triangles.
    small_file f;
    f.write(dir.path / "quads.gltf");
    std::ifstream in(dir.path / "quads.gltf", std::ios::binary);
    std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    std::string const meshes_key = "\"meshes\": [";
    auto const start = text.find(meshes_key) + meshes_key.size();
    auto const end = text.find("]}], \"nodes\"") + 2;
    std::string const one = text.substr(start, end - start);
    text.replace(start, end - start, one + ", " + one + ", " + one + ", " + one);
    text.replace(text.find("\"nodes\": [{\"mesh\": 0}]"), 22,
                 "\"nodes\": [{\"mesh\": 0, \"children\": [1, 2, 3]}, {\"mesh\": 1}, {\"mesh\": 2}, {\"mesh\": 3}]");
    write_text(dir.path / "quads.gltf", text);
    limits_guard const guard;
    canopy::default_limits().max_triangles = 16;
    canopy::scene s;
    plugins().load(s, dir.path / "quads.gltf");
    CHECK(s.meshes().size() == 4);
    canopy::default_limits().max_triangles = 7;
    CHECK_THAT(load_error(dir.path / "quads.gltf"),
               Catch::Contains("quads.gltf: meshes[1].primitives[0]: 8 vertices in the scene's meshes exceed the limit of 7 (--max-triangles)"));
    canopy::default_limits().max_triangles = 15;
    CHECK_THAT(load_error(dir.path / "quads.gltf"),
               Catch::Contains("quads.gltf: meshes[3].primitives[0]: 16 vertices in the scene's meshes exceed the limit of 15 (--max-triangles)"));
}

TEST_CASE("glTF mesh placements are held to --max-placements as the nodes are made") {
    temp_folder const dir("canopy_gltf_test");
    std::string nodes = "[{\"children\": [1, 2, 3, 4]}";
    for (int i = 0; i < 4; ++i) nodes += ", {\"mesh\": 0}";
    nodes += "]";
    fs::path const file = with_nodes(dir.path / "many.gltf", nodes);
    limits_guard const guard;
    canopy::default_limits().max_placements = 4;
    canopy::scene s;
    plugins().load(s, file);
    CHECK(s.meshes().size() == 1);
    canopy::default_limits().max_placements = 3;
    CHECK_THAT(load_error(file), Catch::Contains("many.gltf: nodes[4]: 4 mesh placements exceed the limit of 3 (--max-placements)"));
}
