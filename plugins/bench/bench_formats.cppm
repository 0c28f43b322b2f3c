// canopy.bench_formats — the benchmark file formats (bench/FORMATS.md of the project's shared
// specification), read and written byte for byte so results compare ray by ray with any other
// tracer fed the same files.
//
//   .obj   subset: `v x y z`, `f a b c` (1-based; negative = relative; in `a/b/c` only the first
//          number counts); everything else ignored. Triangle i is the i-th `f` line (its prim id).
//   .inst  `mesh PATH` (relative to the .inst file) then one 3×4 row-major object→world matrix
//          per line (12 numbers); instance k is the k-th matrix line.
//   .rays  32 bytes per ray: origin xyz, tmin, direction xyz, tmax (float32, little-endian).
//   .hits  20 bytes per ray: t (+inf on miss), prim, inst (0xffffffff: none), u, v.
//
// Errors (format_error) name the file, the line where there is one, and the problem: faces with
// more or fewer than 3 vertices, bad or non-finite numbers, out-of-range indices, a ray file whose
// size is not a multiple of 32, unreadable files.
module;
#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>
export module canopy.bench_formats;
import canopy.intersector;

export namespace canopy {

struct format_error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// A mesh of the OBJ subset: one triangle per `f` line, prim_id = its index.
struct bench_mesh {
    std::vector<triangle> triangles;
};

// A two-level scene: one shared mesh and the object→world transform of each instance.
struct bench_instanced_scene {
    std::filesystem::path mesh_path;
    bench_mesh mesh;
    std::vector<affine_transform<float>> instances;
};

// One hit of the .hits format.
struct bench_hit {
    float t = std::numeric_limits<float>::infinity();
    std::uint32_t prim = invalid_id;
    std::uint32_t inst = invalid_id;
    float u = 0.0f;
    float v = 0.0f;
};

// The alpha rule of the formats (`--intersector alpha`): on every candidate hit, clamp u and v to
// [0, 1] and reject the candidate when floor(8u) + floor(8v) is odd; traversal goes on. A filter
// (canopy.intersector): the library keeps its SIMD leaf test and asks only about candidates.
struct bench_alpha_intersector : basic_intersector<bench_alpha_intersector> {
    template <typename Ray>
    bool filter(Ray const&, basic_hit_record<float> const& hr) const {
        return !rejects(hr.u, hr.v);
    }

    static inline bool rejects(float u, float v) {
        int const cu = int(std::floor(8.0f * std::clamp(u, 0.0f, 1.0f)));
        int const cv = int(std::floor(8.0f * std::clamp(v, 0.0f, 1.0f)));
        return ((cu + cv) & 1) != 0;
    }
};

// The same rule written as the paper writes intersectors: a triangle hook, which the library
// calls once per triangle (leaves are then tested one triangle at a time). Same hits.
struct bench_alpha_hook_intersector : basic_intersector<bench_alpha_hook_intersector> {
    using basic_intersector<bench_alpha_hook_intersector>::operator();

    template <typename Ray>
    auto operator()(Ray const& ray, triangle const& tri) {
        auto hr = intersect(ray, tri);
        if (hr.hit) hr.hit = !bench_alpha_intersector::rejects(hr.u, hr.v);
        return hr;
    }
};

// prim value of an any-hit result that does not say which primitive occluded.
inline constexpr std::uint32_t occluded_unreported = 0xfffffffeu;

namespace detail {

[[noreturn]] inline void fail(std::filesystem::path const& file, std::size_t line, std::string const& what) {
    std::string message = file.string();
    if (line) message += ":" + std::to_string(line);
    throw format_error(message + ": " + what);
}

inline std::string read_file(std::filesystem::path const& file) {
    std::ifstream in(file, std::ios::binary);
    if (!in) detail::fail(file, 0, "cannot open file");
    std::ostringstream content;
    content << in.rdbuf();
    if (in.bad()) detail::fail(file, 0, "read error");
    return std::move(content).str();
}

// Splits s into whitespace-separated tokens.
inline std::vector<std::string_view> tokens(std::string_view s) {
    std::vector<std::string_view> out;
    std::size_t i = 0;
    while (i < s.size()) {
        while (i < s.size() && (s[i] == ' ' || s[i] == '\t' || s[i] == '\r')) ++i;
        std::size_t const start = i;
        while (i < s.size() && s[i] != ' ' && s[i] != '\t' && s[i] != '\r') ++i;
        if (i > start) out.push_back(s.substr(start, i - start));
    }
    return out;
}

inline float parse_float(std::string_view token, std::filesystem::path const& file, std::size_t line) {
    std::string const text(token);
    char* end = nullptr;
    errno = 0;
    float const value = std::strtof(text.c_str(), &end);
    if (end != text.c_str() + text.size() || text.empty())
        fail(file, line, "bad number '" + text + "'");
    if (!std::isfinite(value)) fail(file, line, "non-finite number '" + text + "'");
    return value;
}

inline long parse_index(std::string_view token, std::filesystem::path const& file, std::size_t line) {
    std::string const text(token.substr(0, token.find('/')));
    char* end = nullptr;
    errno = 0;
    long const value = std::strtol(text.c_str(), &end, 10);
    if (text.empty() || end != text.c_str() + text.size() || errno == ERANGE)
        fail(file, line, "bad vertex index '" + std::string(token) + "'");
    return value;
}

template <typename F>
void for_each_line(std::string const& content, F&& f) {
    std::size_t line = 0, pos = 0;
    while (pos <= content.size()) {
        std::size_t const end = std::min(content.find('\n', pos), content.size());
        ++line;
        std::string_view text(content.data() + pos, end - pos);
        if (auto const hash = text.find('#'); hash != std::string_view::npos) text = text.substr(0, hash);
        f(line, text);
        if (end == content.size()) break;
        pos = end + 1;
    }
}

} // namespace detail

inline bench_mesh read_bench_obj(std::filesystem::path const& file) {
    std::string const content = detail::read_file(file);
    std::vector<vec3<float>> vertices;
    bench_mesh mesh;
    detail::for_each_line(content, [&](std::size_t line, std::string_view text) {
        auto const tok = detail::tokens(text);
        if (tok.empty()) return;
        if (tok[0] == "v") {
            if (tok.size() < 4) detail::fail(file, line, "vertex needs 3 coordinates");
            vertices.emplace_back(detail::parse_float(tok[1], file, line), detail::parse_float(tok[2], file, line),
                                  detail::parse_float(tok[3], file, line));
        } else if (tok[0] == "f") {
            if (tok.size() != 4)
                detail::fail(file, line, "face has " + std::to_string(tok.size() - 1) + " vertices; only triangles are supported");
            std::array<vec3<float>, 3> v;
            for (int k = 0; k < 3; ++k) {
                long const index = detail::parse_index(tok[std::size_t(k + 1)], file, line);
                long const n = long(vertices.size());
                long const resolved = index > 0 ? index - 1 : n + index;
                if (index == 0 || resolved < 0 || resolved >= n)
                    detail::fail(file, line, "vertex index " + std::to_string(index) + " out of range (" +
                                                 std::to_string(n) + " vertices so far)");
                v[std::size_t(k)] = vertices[std::size_t(resolved)];
            }
            auto const id = std::uint32_t(mesh.triangles.size());
            mesh.triangles.push_back(triangle{v[0], v[1], v[2], id, 0});
        }
    });
    return mesh;
}

inline bench_instanced_scene read_bench_inst(std::filesystem::path const& file) {
    std::string const content = detail::read_file(file);
    bench_instanced_scene scene;
    detail::for_each_line(content, [&](std::size_t line, std::string_view text) {
        auto const tok = detail::tokens(text);
        if (tok.empty()) return;
        if (tok[0] == "mesh") {
            if (tok.size() != 2) detail::fail(file, line, "expected 'mesh PATH'");
            if (!scene.mesh_path.empty()) detail::fail(file, line, "a second 'mesh' line (one shared mesh only)");
            std::filesystem::path p(tok[1]);
            scene.mesh_path = p.is_absolute() ? p : file.parent_path() / p;
            return;
        }
        if (tok.size() != 12)
            detail::fail(file, line, "instance line needs 12 numbers (3x4 row-major matrix), found " +
                                         std::to_string(tok.size()));
        std::array<float, 12> rows;
        for (std::size_t k = 0; k < 12; ++k) rows[k] = detail::parse_float(tok[k], file, line);
        auto const m = affine_transform<float>::from_rows(rows);
        if (determinant(m.linear) == 0.0f) detail::fail(file, line, "singular instance transform");
        scene.instances.push_back(m);
    });
    if (scene.mesh_path.empty()) detail::fail(file, 0, "no 'mesh' line");
    scene.mesh = read_bench_obj(scene.mesh_path);
    return scene;
}

inline std::vector<ray> read_bench_rays(std::filesystem::path const& file) {
    std::string const content = detail::read_file(file);
    if (content.size() % 32 != 0)
        detail::fail(file, 0, "size " + std::to_string(content.size()) + " bytes is not a multiple of 32 (one ray = 32 bytes)");
    std::vector<ray> rays(content.size() / 32);
    for (std::size_t i = 0; i < rays.size(); ++i) {
        float f[8];
        std::memcpy(f, content.data() + 32 * i, sizeof f);
        rays[i] = ray{vec3<float>(f[0], f[1], f[2]), f[3], vec3<float>(f[4], f[5], f[6]), f[7]};
    }
    return rays;
}

inline void write_bench_hits(std::filesystem::path const& file, std::vector<bench_hit> const& hits) {
    static_assert(std::endian::native == std::endian::little);
    std::string buffer(hits.size() * 20, '\0');
    for (std::size_t i = 0; i < hits.size(); ++i) {
        char* p = buffer.data() + 20 * i;
        std::memcpy(p + 0, &hits[i].t, 4);
        std::memcpy(p + 4, &hits[i].prim, 4);
        std::memcpy(p + 8, &hits[i].inst, 4);
        std::memcpy(p + 12, &hits[i].u, 4);
        std::memcpy(p + 16, &hits[i].v, 4);
    }
    // Checked after closing: a full disk (or /dev/full) is an error with the system's reason.
    auto const reason = [] { return std::string(errno != 0 ? std::strerror(errno) : "unknown error"); };
    errno = 0;
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    if (!out) detail::fail(file, 0, "cannot open file for writing: " + reason());
    out.write(buffer.data(), std::streamsize(buffer.size()));
    out.close();
    if (!out) detail::fail(file, 0, "cannot write: " + reason());
}

inline std::vector<bench_hit> read_bench_hits(std::filesystem::path const& file) {
    std::string const content = detail::read_file(file);
    if (content.size() % 20 != 0) detail::fail(file, 0, "size is not a multiple of 20 (one hit = 20 bytes)");
    std::vector<bench_hit> hits(content.size() / 20);
    for (std::size_t i = 0; i < hits.size(); ++i) {
        char const* p = content.data() + 20 * i;
        std::memcpy(&hits[i].t, p + 0, 4);
        std::memcpy(&hits[i].prim, p + 4, 4);
        std::memcpy(&hits[i].inst, p + 8, 4);
        std::memcpy(&hits[i].u, p + 12, 4);
        std::memcpy(&hits[i].v, p + 16, 4);
    }
    return hits;
}

inline void write_bench_rays(std::filesystem::path const& file, std::vector<ray> const& rays) {
    std::string buffer(rays.size() * 32, '\0');
    for (std::size_t i = 0; i < rays.size(); ++i) {
        float const f[8] = {rays[i].origin.x,    rays[i].origin.y,    rays[i].origin.z,    rays[i].tmin,
                            rays[i].direction.x, rays[i].direction.y, rays[i].direction.z, rays[i].tmax};
        std::memcpy(buffer.data() + 32 * i, f, sizeof f);
    }
    // Checked after closing: a full disk (or /dev/full) is an error with the system's reason.
    auto const reason = [] { return std::string(errno != 0 ? std::strerror(errno) : "unknown error"); };
    errno = 0;
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    if (!out) detail::fail(file, 0, "cannot open file for writing: " + reason());
    out.write(buffer.data(), std::streamsize(buffer.size()));
    out.close();
    if (!out) detail::fail(file, 0, "cannot write: " + reason());
}

} // namespace canopy
