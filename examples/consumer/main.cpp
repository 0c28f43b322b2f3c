// Uses the installed Canopy package: one BVH, one instance, a counting intersector, an icosphere of
// canopy.procedural; and checks that it was compiled for the ISA the package records.
#include <algorithm>
#include <iterator>
#include <cstdio>
#include <string_view>
#include <vector>
import canopy;
import canopy.procedural;

// The vector features this translation unit was compiled for must be exactly those of the
// package's ISA among them (the package's flags reach importers through canopy::canopy_isa).
constexpr std::string_view checked[] = {"sse4.2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512bw"};
constexpr std::string_view compiled[] = {
#if defined(__SSE4_2__)
    "sse4.2",
#endif
#if defined(__AVX__)
    "avx",
#endif
#if defined(__AVX2__)
    "avx2",
#endif
#if defined(__FMA__)
    "fma",
#endif
#if defined(__AVX512F__)
    "avx512f",
#endif
#if defined(__AVX512VL__)
    "avx512vl",
#endif
#if defined(__AVX512BW__)
    "avx512bw",
#endif
    ""};

bool compiled_for_package_isa() {
    auto const recorded = canopy::simd::build_isa_features();
    bool same = true;
    for (std::string_view name : checked) {
        bool const in_package = std::find(recorded.begin(), recorded.end(), name) != recorded.end();
        bool const in_consumer = std::find(std::begin(compiled), std::end(compiled), name) != std::end(compiled);
        if (in_package != in_consumer) {
            std::printf("consumer compiled %s %.*s, the package's ISA %s it\n", in_consumer ? "with" : "without",
                        int(name.size()), name.data(), in_package ? "has" : "lacks");
            same = false;
        }
    }
    return same;
}

struct count_triangles : canopy::basic_intersector<count_triangles> {
    using canopy::basic_intersector<count_triangles>::operator();
    template <typename Ray>
    auto operator()(Ray const& ray, canopy::triangle const& tri) {
        ++tests;
        return intersect(ray, tri);
    }
    int tests = 0;
};

int main() {
    std::string_view const isa = canopy::simd::build_isa();
    std::printf("package ISA %.*s, this CPU runs it: %s\n", int(isa.size()), isa.data(),
                canopy::simd::cpu_supports_build_isa() ? "yes" : "no");
    if (!compiled_for_package_isa()) return 1;

    std::vector<canopy::triangle> const tris{{{-1, -1, 0}, {1, -1, 0}, {0, 1, 0}, 0, 0}};
    auto const mesh = canopy::build_binned_sah(tris);
    using inst_t = canopy::instance<canopy::bvh<canopy::triangle>>;
    std::vector<inst_t> const placed{inst_t(mesh, canopy::affine_transform<float>::from_rows({1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 5}), 7)};
    auto const top = canopy::build_binned_sah(placed);
    count_triangles isect;
    canopy::ray const r{{0, 0, 10}, 0, {0, 0, -1}, 100};
    auto const hr = canopy::closest_hit(r, &top, &top + 1, isect);
    std::printf("hit=%d t=%g inst=%u tests=%d\n", int(hr.hit), double(hr.t), hr.inst_id, isect.tests);
    if (!(hr.hit && hr.t == 5.0f && hr.inst_id == 7 && isect.tests == 1)) return 1;

    // A closed icosphere of radius 2 about z = -10 (20·4² triangles): the ray down z meets the
    // sphere at t = 18 and the inscribed polyhedron a little further.
    auto const ball = canopy::build_binned_sah(canopy::make_icosphere(2, {0, 0, -10}, 2.0f));
    auto const on_ball = canopy::closest_hit(r, &ball, &ball + 1);
    std::printf("icosphere: %zu triangles, hit t=%g\n", ball.size, double(on_ball.t));
    return ball.size == 320 && on_ball.hit && on_ball.t >= 18.0f && on_ball.t < 18.5f ? 0 : 1;
}
