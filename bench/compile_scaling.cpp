// compile() against the size of one group: one small mesh placed n times by instance nodes in one
// group, and n transformed mesh nodes in one group, for n = 10^4 … 10^6 (--max N). Prints the
// time of compile() (its BVH builds included) per placement, and its ratio to the smallest n's:
// near 1 when compiling scales linearly (the BVH builds add a slowly growing log n).
//
//   canopy_bench_compile_scaling [--max N]
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <initializer_list>
#include <utility>

import canopy.scene;

namespace {

using clock_type = std::chrono::steady_clock;

canopy::mesh_data square() {
    canopy::mesh_data m;
    m.name = "square";
    m.positions = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}};
    return m;
}

canopy::affine_transform<float> grid_cell(std::size_t k) {
    float const x = 3.0f * float(k % 1000), y = 3.0f * float(k / 1000);
    return canopy::affine_transform<float>::from_rows({1, 0, 0, x, 0, 1, 0, y, 0, 0, 1, 0});
}

// Seconds to compile the scene `make` builds with n placements.
template <typename Make>
double seconds_to_compile(std::size_t n, Make&& make) {
    canopy::scene s;
    make(s, n);
    auto const start = clock_type::now();
    auto const c = canopy::compile(s, {.name = "bench"});
    double const seconds = std::chrono::duration<double>(clock_type::now() - start).count();
    if (c.statistics.placements != n) std::fprintf(stderr, "unexpected placement count %zu\n", c.statistics.placements);
    return seconds;
}

} // namespace

int main(int argc, char** argv) {
    std::size_t max = 1000000;
    for (int i = 1; i + 1 < argc; ++i)
        if (std::strcmp(argv[i], "--max") == 0) max = std::strtoull(argv[i + 1], nullptr, 10);
    auto const instances = [](canopy::scene& s, std::size_t n) {
        canopy::node_id const tile = s.add_mesh_node(canopy::no_node, s.add_mesh(square()), "tile");
        canopy::node_id const group = s.add_group(s.root(), "grid");
        for (std::size_t k = 0; k < n; ++k) s.add_instance(group, tile, grid_cell(k), std::uint32_t(k));
    };
    auto const mesh_nodes = [](canopy::scene& s, std::size_t n) {
        auto const mesh = s.add_mesh(square());
        canopy::node_id const group = s.add_group(s.root(), "field");
        for (std::size_t k = 0; k < n; ++k) s.add_mesh_node(s.add_transform(group, grid_cell(k)), mesh);
    };
    std::printf("%-34s %10s %14s %8s\n", "scene", "n", "ns/placement", "ratio");
    for (auto const& [name, make] : {std::pair{"instances of one mesh in a group", +instances},
                                     std::pair{"transformed mesh nodes in a group", +mesh_nodes}}) {
        double base = 0.0;
        for (std::size_t n = 10000; n <= max; n *= 10) {
            double const per = seconds_to_compile(n, make) / double(n) * 1e9;
            if (base == 0.0) base = per;
            std::printf("%-34s %10zu %14.1f %8.2f\n", name, n, per, per / base);
        }
    }
    return 0;
}
