// canopy.procedural — deterministic procedural geometry: closed icospheres, height-field
// terrain grids and random triangle soups. Same seed, same triangles, on every machine.
//
//   make_icosphere(subdivisions, center, radius)   20·4^s triangles, closed, shared vertices
//                                                  bit-identical between neighbours
//   make_grid(nx, ny, height)                      2·nx·ny triangles over [0,nx]×[0,ny]
//   make_triangle_soup(count, seed, bounds, size)  independent random triangles
//
// prim_id of triangle i is i; geom_id is 0.
module;
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <map>
#include <random>
#include <utility>
#include <vector>
export module canopy.procedural;
import canopy.geometry;

export namespace canopy {

// Indexed triangles → triangle list; every use of a vertex copies the same bits.
inline std::vector<triangle> expand_indexed(std::vector<vec3<float>> const& vertices,
                                            std::vector<std::array<std::uint32_t, 3>> const& faces) {
    std::vector<triangle> out;
    out.reserve(faces.size());
    for (auto const& f : faces)
        out.push_back(triangle{vertices[f[0]], vertices[f[1]], vertices[f[2]], std::uint32_t(out.size()), 0});
    return out;
}

inline std::vector<triangle> make_icosphere(int subdivisions, vec3<float> center = {}, float radius = 1.0f) {
    double const t = (1.0 + std::sqrt(5.0)) / 2.0;
    std::vector<vec3<double>> unit{{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                                   {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    for (auto& v : unit) v = normalize(v);
    std::vector<std::array<std::uint32_t, 3>> faces{
        {0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
        {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
        {3, 8, 9},  {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
    for (int s = 0; s < subdivisions; ++s) {
        std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> midpoints;
        auto midpoint = [&](std::uint32_t a, std::uint32_t b) {
            auto const key = std::minmax(a, b);
            auto const [it, inserted] = midpoints.try_emplace({key.first, key.second}, std::uint32_t(unit.size()));
            if (inserted) unit.push_back(normalize((unit[a] + unit[b]) * 0.5));
            return it->second;
        };
        std::vector<std::array<std::uint32_t, 3>> next;
        next.reserve(faces.size() * 4);
        for (auto const& f : faces) {
            std::uint32_t const ab = midpoint(f[0], f[1]), bc = midpoint(f[1], f[2]), ca = midpoint(f[2], f[0]);
            next.push_back({f[0], ab, ca});
            next.push_back({f[1], bc, ab});
            next.push_back({f[2], ca, bc});
            next.push_back({ab, bc, ca});
        }
        faces = std::move(next);
    }
    std::vector<vec3<float>> vertices;
    vertices.reserve(unit.size());
    vec3<double> const c(center);
    for (auto const& u : unit) vertices.emplace_back(c + u * double(radius));
    return expand_indexed(vertices, faces);
}

// A height field z = height(x, y) sampled on the integer grid [0, nx] × [0, ny].
inline std::vector<triangle> make_grid(int nx, int ny, std::function<float(float, float)> const& height = {}) {
    std::vector<vec3<float>> vertices;
    for (int j = 0; j <= ny; ++j)
        for (int i = 0; i <= nx; ++i)
            vertices.emplace_back(float(i), float(j), height ? height(float(i), float(j)) : 0.0f);
    std::vector<std::array<std::uint32_t, 3>> faces;
    auto const at = [&](int i, int j) { return std::uint32_t(j * (nx + 1) + i); };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            faces.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
            faces.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
        }
    return expand_indexed(vertices, faces);
}

// count random triangles: a random corner in `bounds`, the other two within ±size of it.
inline std::vector<triangle> make_triangle_soup(std::size_t count, std::uint32_t seed, aabb const& bounds,
                                                float size) {
    std::mt19937 rng(seed);
    auto uniform = [&](float lo, float hi) {
        return lo + (hi - lo) * float(double(rng()) / double(std::mt19937::max()));
    };
    std::vector<triangle> out;
    out.reserve(count);
    for (std::size_t i = 0; i < count; ++i) {
        vec3<float> const a(uniform(bounds.min.x, bounds.max.x), uniform(bounds.min.y, bounds.max.y),
                            uniform(bounds.min.z, bounds.max.z));
        auto corner = [&] { return a + vec3<float>(uniform(-size, size), uniform(-size, size), uniform(-size, size)); };
        vec3<float> const b = corner();
        vec3<float> const c = corner();
        out.push_back(triangle{a, b, c, std::uint32_t(i), 0});
    }
    return out;
}

} // namespace canopy
