// zero_cost — the workloads whose instruction counts (valgrind --tool=callgrind) prove that
// unused features cost nothing. bench/zero_cost.sh runs each mode under callgrind, counting only
// inside trace_all, and prints the table.
//
//   canopy_bench_zero_cost MODE [RAYS]
//   MODE: default      closest_hit(r, first, last)
//         explicit     closest_hit(r, first, last, default_intersector{})
//         forwarding   a paper-style intersector whose hooks only forward to intersect()
//         forwarding_tri  the same with the triangle hook only (boxes keep the SIMD test; the
//                      hook is called once per triangle, so leaves are tested one at a time)
//         filter_all   a filter that accepts every candidate (no hooks: SIMD leaves)
//         single       the mesh BVH traced directly (one level)
//         instanced    the same mesh as the only instance of a top-level BVH (identity)
//         instanced_rt the same, with a rotation + translation (transform applied)
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>
import canopy;
import canopy.procedural;

namespace {

// Paper-style hooks that only forward: they must cost nothing either.
struct forwarding : canopy::basic_intersector<forwarding> {
    using canopy::basic_intersector<forwarding>::operator();
    template <typename Ray, typename... Args>
    auto operator()(Ray const& ray, canopy::aabb const& box, Args&&... args) {
        return intersect(ray, box, std::forward<Args>(args)...);
    }
    template <typename Ray>
    auto operator()(Ray const& ray, canopy::triangle const& tri) {
        return intersect(ray, tri);
    }
};

struct forwarding_triangles : canopy::basic_intersector<forwarding_triangles> {
    using canopy::basic_intersector<forwarding_triangles>::operator();
    template <typename Ray>
    auto operator()(Ray const& ray, canopy::triangle const& tri) {
        return intersect(ray, tri);
    }
};

// A filter that accepts everything: it must leave the default path as it is.
struct accept_all : canopy::basic_intersector<accept_all> {
    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const&) {
        return true;
    }
};

template <typename Structure, typename... Isect>
[[gnu::noinline]] unsigned trace_all(std::vector<canopy::ray> const& rays, Structure const& s, Isect&&... isect) {
    unsigned hits = 0;
    for (auto const& r : rays) hits += canopy::closest_hit(r, &s, &s + 1, isect...).hit ? 1u : 0u;
    return hits;
}

} // namespace

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s default|explicit|forwarding|forwarding_tri|filter_all|single|instanced|instanced_rt [RAYS]\n", argv[0]);
        return 2;
    }
    std::string const mode = argv[1];
    int const n = argc > 2 ? std::atoi(argv[2]) : 20000;
    auto const mesh = canopy::build_binned_sah(canopy::make_icosphere(4));
    std::mt19937 rng(1);
    std::normal_distribution<float> g(0.0f, 1.0f);
    std::vector<canopy::ray> rays;
    for (int i = 0; i < n; ++i)
        rays.push_back({{0.1f * g(rng), 0.1f * g(rng), 0.1f * g(rng)}, 0.0f, {g(rng), g(rng), g(rng)}, 1e30f});

    using inst_t = canopy::instance<canopy::bvh<canopy::triangle>>;
    std::vector<inst_t> one{inst_t(mesh, canopy::affine_transform<float>::identity(), 0)};
    auto const top = canopy::build_binned_sah(one);
    std::vector<inst_t> moved{inst_t(mesh, canopy::affine_transform<float>::from_rows({0, -1, 0, 0.5f, 1, 0, 0, 0, 0, 0, 1, 0}), 0)};
    auto const top_moved = canopy::build_binned_sah(moved);

    unsigned hits = 0;
    if (mode == "default" || mode == "single") hits = trace_all(rays, mesh);
    else if (mode == "explicit") hits = trace_all(rays, mesh, canopy::default_intersector{});
    else if (mode == "forwarding") hits = trace_all(rays, mesh, forwarding{});
    else if (mode == "forwarding_tri") hits = trace_all(rays, mesh, forwarding_triangles{});
    else if (mode == "filter_all") hits = trace_all(rays, mesh, accept_all{});
    else if (mode == "instanced") hits = trace_all(rays, top);
    else if (mode == "instanced_rt") hits = trace_all(rays, top_moved);
    else {
        std::fprintf(stderr, "unknown mode '%s'\n", mode.c_str());
        return 2;
    }
    std::printf("%s: %d rays, %u hits\n", mode.c_str(), n, hits);
    return 0;
}
