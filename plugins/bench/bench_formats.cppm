// canopy.plugins.bench:formats — the benchmark file formats (bench/FORMATS.md of the project's shared
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
// Only regular files are read (canopy.scene's require_regular_file: a folder, a device, a FIFO is
// refused before it is opened), each whole and within the limit of bytes per file; counts are
// checked against canopy::default_limits() as they grow (vertices and triangles: max_triangles,
// instances: max_placements).
//
// Text is read by canopy.scene:text's rules (tokens, numbers, OBJ indices; a UTF-8 byte-order mark
// is skipped).
//
// Errors (canopy::scene_error) name the file, the line where there is one, and the problem: text
// files that are not text (a NUL or other control byte, a UTF-16/32 byte-order mark: "not a text OBJ
// file: NUL byte at offset 12"), faces with more or fewer than 3 vertices, bad or non-finite
// numbers, numbers that overflow a float ("value 1e300 overflows a float"), zero or out-of-range
// indices, files with nothing to trace (a mesh without faces, an .inst without instance lines), an
// .inst naming itself as its mesh, a ray file whose size is not a multiple of 32, unreadable files
// and files over a limit. Input quoted in a message is cut to a short prefix.
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
#include <new>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>
export module canopy.plugins.bench:formats;
import canopy.intersector;
import canopy.scene;

export namespace canopy {

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
// For scalar rays and for packets (lane by lane), so that batch queries can trace packets.
struct bench_alpha_intersector : basic_intersector<bench_alpha_intersector> {
    template <typename Ray, typename T>
    simd::mask_type_t<T> filter(Ray const&, basic_hit_record<T> const& hr) const {
        if constexpr (simd::simd_width_v<T> == 1) {
            return !rejects(hr.u, hr.v);
        } else {
            simd::mask_type_t<T> keep;
            for (int k = 0; k < simd::simd_width_v<T>; ++k) keep.set(k, !rejects(hr.u[k], hr.v[k]));
            return keep;
        }
    }

    static inline bool rejects(float u, float v) {
        int const cu = int(std::floor(8.0f * std::clamp(u, 0.0f, 1.0f)));
        int const cv = int(std::floor(8.0f * std::clamp(v, 0.0f, 1.0f)));
        return ((cu + cv) & 1) != 0;
    }
};

// The same rule written as the paper writes intersectors: a triangle hook, which the library
// calls once per triangle (leaves are then tested one triangle at a time). Same hits. For scalar
// rays and packets.
struct bench_alpha_hook_intersector : basic_intersector<bench_alpha_hook_intersector> {
    using basic_intersector<bench_alpha_hook_intersector>::operator();

    template <typename Ray>
    auto operator()(Ray const& ray, triangle const& tri) {
        auto hr = intersect(ray, tri);
        if constexpr (simd::simd_width_v<ray_value_t<Ray>> == 1) {
            if (hr.hit) hr.hit = !bench_alpha_intersector::rejects(hr.u, hr.v);
        } else {
            for (int k = 0; k < simd::simd_width_v<ray_value_t<Ray>>; ++k)
                if (hr.hit[k] && bench_alpha_intersector::rejects(hr.u[k], hr.v[k])) hr.hit.set(k, false);
        }
        return hr;
    }
};

// prim value of an any-hit result that does not say which primitive occluded.
inline constexpr std::uint32_t occluded_unreported = 0xfffffffeu;

} // namespace canopy

namespace canopy::detail {

[[noreturn]] inline void fail(std::filesystem::path const& file, std::size_t line, std::string const& what) {
    throw scene_error(file.string(), line_where(line), what);
}

// Runs f; running out of memory is an error naming the file.
template <typename F>
auto checked(std::filesystem::path const& file, F&& f) {
    try {
        return f();
    } catch (std::bad_alloc const&) {
        fail(file, 0, "out of memory while reading");
    }
}

inline std::string read_file(std::filesystem::path const& file, std::string const& role = {}) {
    return checked(file, [&] { return read_regular_file(file, role); });
}

} // namespace canopy::detail

export namespace canopy {

// The OBJ subset from text (no file is read; `file` names it in errors, also for fuzzing).
inline bench_mesh parse_bench_obj(std::string_view content, std::filesystem::path const& file) {
    std::string const name = file.string();
    require_text(content, name, "OBJ");
    std::uint64_t const max_triangles = default_limits().max_triangles;
    std::vector<vec3<float>> vertices;
    bench_mesh mesh;
    std::vector<std::string_view> tok;
    line_reader lines(skip_utf8_bom(content));
    while (lines.next(tok)) {
        std::size_t const line = lines.number();
        if (tok[0] == "v") {
            if (tok.size() < 4) detail::fail(file, line, "vertex needs 3 coordinates");
            check_limit(name, lines.where(), vertices.size() + 1, max_triangles, "vertices", "--max-triangles");
            vertices.emplace_back(parse_float(tok[1], name, line), parse_float(tok[2], name, line),
                                  parse_float(tok[3], name, line));
        } else if (tok[0] == "f") {
            if (tok.size() != 4)
                detail::fail(file, line, "face has " + std::to_string(tok.size() - 1) + " vertices; only triangles are supported");
            check_limit(name, lines.where(), mesh.triangles.size() + 1, max_triangles, "triangles", "--max-triangles");
            std::array<vec3<float>, 3> v;
            for (std::size_t k = 0; k < 3; ++k) {
                // Only the vertex index of a corner counts (the subset has no texture coordinates or normals).
                std::string_view const corner = tok[k + 1];
                v[k] = vertices[resolve_obj_index(corner.substr(0, corner.find('/')), corner, vertices.size(), "vertex",
                                                  "vertices", name, line)];
            }
            auto const id = std::uint32_t(mesh.triangles.size());
            mesh.triangles.push_back(triangle{v[0], v[1], v[2], id, 0});
        }
    }
    if (mesh.triangles.empty())
        detail::fail(file, 0, vertices.empty() ? "no faces ('f' lines) and no vertices: nothing to trace"
                                               : "no faces ('f' lines): nothing to trace");
    return mesh;
}

inline bench_mesh read_bench_obj(std::filesystem::path const& file) {
    std::string const content = detail::read_file(file);
    return detail::checked(file, [&] { return parse_bench_obj(content, file); });
}

// An .inst from text: its instances and its mesh's path (resolved against `file`'s folder); the
// mesh is not read (mesh stays empty). Also for fuzzing.
inline bench_instanced_scene parse_bench_inst(std::string_view content, std::filesystem::path const& file) {
    std::string const name = file.string();
    require_text(content, name, ".inst");
    std::uint64_t const max_instances = default_limits().max_placements;
    bench_instanced_scene out;
    std::vector<std::string_view> tok;
    line_reader lines(skip_utf8_bom(content));
    while (lines.next(tok)) {
        std::size_t const line = lines.number();
        if (tok[0] == "mesh") {
            if (tok.size() != 2) detail::fail(file, line, "expected 'mesh PATH'");
            if (!out.mesh_path.empty()) detail::fail(file, line, "a second 'mesh' line (one shared mesh only)");
            check_path_length(tok[1], name, line, "mesh path");
            std::filesystem::path p(tok[1]);
            out.mesh_path = p.is_absolute() ? p : file.parent_path() / p;
            continue;
        }
        if (tok.size() != 12)
            detail::fail(file, line, "instance line needs 12 numbers (3x4 row-major matrix), found " +
                                         std::to_string(tok.size()));
        check_limit(name, lines.where(), out.instances.size() + 1, max_instances, "instances", "--max-placements");
        std::array<float, 12> rows;
        for (std::size_t k = 0; k < 12; ++k) rows[k] = parse_float(tok[k], name, line);
        auto const m = affine_transform<float>::from_rows(rows);
        if (determinant(m.linear) == 0.0f) detail::fail(file, line, "singular instance transform");
        out.instances.push_back(m);
    }
    if (out.mesh_path.empty()) detail::fail(file, 0, "no 'mesh' line");
    if (out.instances.empty()) detail::fail(file, 0, "no instance lines (12 numbers each): nothing to trace");
    return out;
}

inline bench_instanced_scene read_bench_inst(std::filesystem::path const& file) {
    std::string const content = detail::read_file(file);
    auto out = detail::checked(file, [&] { return parse_bench_inst(content, file); });
    std::error_code ec;
    if (std::filesystem::equivalent(out.mesh_path, file, ec))
        detail::fail(file, 0, "names itself as its mesh ('mesh " + excerpt(out.mesh_path.filename().string()) +
                                  "'); the mesh is an .obj file");
    std::string const mesh_text = detail::read_file(out.mesh_path, "mesh of " + file.filename().string());
    out.mesh = detail::checked(out.mesh_path, [&] { return parse_bench_obj(mesh_text, out.mesh_path); });
    return out;
}

// Rays from the bytes of a ray file (`file` names it in errors).
inline std::vector<ray> parse_bench_rays(std::string_view content, std::filesystem::path const& file) {
    if (content.size() % 32 != 0)
        detail::fail(file, 0, "size " + std::to_string(content.size()) + " bytes is not a multiple of 32 (one ray = 32 bytes)");
    return detail::checked(file, [&] {
        std::vector<ray> rays(content.size() / 32);
        for (std::size_t i = 0; i < rays.size(); ++i) {
            float f[8];
            std::memcpy(f, content.data() + 32 * i, sizeof f);
            rays[i] = ray{vec3<float>(f[0], f[1], f[2]), f[3], vec3<float>(f[4], f[5], f[6]), f[7]};
        }
        return rays;
    });
}

// The number of rays of a ray file (a regular file within the limit of bytes; its size a
// multiple of 32).
inline std::uint64_t count_bench_rays(std::filesystem::path const& file) {
    std::uint64_t const size = require_regular_file(file, "ray file");
    if (size % 32 != 0)
        detail::fail(file, 0, "size " + std::to_string(size) + " bytes is not a multiple of 32 (one ray = 32 bytes)");
    return size / 32;
}

} // namespace canopy

namespace canopy::detail {

// Rays [first, first + count) of `in`, read in pieces straight into the rays (no second copy of
// the file in memory); `size` is the file's, for messages.
inline std::vector<ray> read_rays(std::ifstream& in, std::filesystem::path const& file, std::uint64_t first,
                                  std::uint64_t count, std::uint64_t size) {
    std::vector<ray> rays;
    std::vector<char> piece;
    checked(file, [&] {
        rays.resize(std::size_t(count));
        piece.resize(32 * 4096);
    });
    if (first > 0) in.seekg(std::streamoff(32 * first));
    for (std::size_t done = 0; done < rays.size();) {
        std::size_t const n = std::min<std::size_t>(4096, rays.size() - done);
        in.read(piece.data(), std::streamsize(32 * n));
        if (in.bad() || std::size_t(in.gcount()) != 32 * n)
            fail(file, 0, "read error after " + std::to_string(32 * (first + done) + std::size_t(in.gcount())) + " of " +
                              std::to_string(size) + " bytes");
        for (std::size_t i = 0; i < n; ++i) {
            float f[8];
            std::memcpy(f, piece.data() + 32 * i, sizeof f);
            rays[done + i] = ray{vec3<float>(f[0], f[1], f[2]), f[3], vec3<float>(f[4], f[5], f[6]), f[7]};
        }
        done += n;
    }
    return rays;
}

inline std::ifstream open_rays(std::filesystem::path const& file) {
    std::ifstream in(file, std::ios::binary);
    if (!in) fail(file, 0, std::string("cannot be opened: ") + std::strerror(errno));
    return in;
}

} // namespace canopy::detail

export namespace canopy {

// A ray file, read in pieces straight into the rays (no second copy of the file in memory).
inline std::vector<ray> read_bench_rays(std::filesystem::path const& file) {
    std::uint64_t const count = count_bench_rays(file);
    std::ifstream in = detail::open_rays(file);
    std::vector<ray> rays = detail::read_rays(in, file, 0, count, 32 * count);
    if (in.peek() != std::ifstream::traits_type::eof()) detail::fail(file, 0, "grew while it was being read");
    return rays;
}

// Rays [first, first + count) of a ray file of `total` rays (count_bench_rays), read at their
// offset: each process of a distributed trace reads only its own.
inline std::vector<ray> read_bench_rays(std::filesystem::path const& file, std::uint64_t first, std::uint64_t count,
                                        std::uint64_t total) {
    if (first > total || count > total - first)
        detail::fail(file, 0, "rays " + std::to_string(first) + " to " + std::to_string(first + count) +
                                  " are beyond its " + std::to_string(total) + " rays");
    std::ifstream in = detail::open_rays(file);
    return detail::read_rays(in, file, first, count, 32 * total);
}

} // namespace canopy

namespace canopy::detail {

// Writes `bytes` as the whole of `file`; a file that cannot be opened or written (a folder, a full
// disk) is an error naming it.
// Checked after closing: a full disk (or /dev/full) is an error with the system's reason.
inline void write_file(std::filesystem::path const& file, std::string const& bytes) {
    auto const reason = [] { return std::string(errno != 0 ? std::strerror(errno) : "unknown error"); };
    errno = 0;
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    if (!out) fail(file, 0, "cannot open file for writing: " + reason());
    out.write(bytes.data(), std::streamsize(bytes.size()));
    out.close();
    if (!out) fail(file, 0, "cannot write: " + reason());
}

} // namespace canopy::detail

export namespace canopy {

// The bytes of hits as a hit file holds them (20 per hit).
inline std::string encode_bench_hits(std::span<bench_hit const> hits) {
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
    return buffer;
}

inline void write_bench_hits(std::filesystem::path const& file, std::vector<bench_hit> const& hits) {
    detail::write_file(file, encode_bench_hits(hits));
}

// Hits from the bytes of a hit file (`file` names it in errors).
inline std::vector<bench_hit> parse_bench_hits(std::string_view content, std::filesystem::path const& file) {
    if (content.size() % 20 != 0)
        detail::fail(file, 0, "size " + std::to_string(content.size()) + " bytes is not a multiple of 20 (one hit = 20 bytes)");
    return detail::checked(file, [&] {
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
    });
}

inline std::vector<bench_hit> read_bench_hits(std::filesystem::path const& file) {
    return parse_bench_hits(detail::read_file(file, "hit file"), file);
}

inline void write_bench_rays(std::filesystem::path const& file, std::vector<ray> const& rays) {
    std::string buffer(rays.size() * 32, '\0');
    for (std::size_t i = 0; i < rays.size(); ++i) {
        float const f[8] = {rays[i].origin.x,    rays[i].origin.y,    rays[i].origin.z,    rays[i].tmin,
                            rays[i].direction.x, rays[i].direction.y, rays[i].direction.z, rays[i].tmax};
        std::memcpy(buffer.data() + 32 * i, f, sizeof f);
    }
    detail::write_file(file, buffer);
}

} // namespace canopy
