// Refit against rebuild on a moving mesh: a closed icosphere (8 subdivisions: 1,310,720
// triangles) waving and twisting a little more each frame. Each frame times canopy::refit of the
// BVH built for frame 0 and a fresh build_binned_sah of the moved mesh, and prints both with the
// SAH costs of the refitted and the fresh tree over the cost of the tree as first built (the
// drift canopy::needs_rebuild compares with its threshold).
//
//   canopy_bench_refit [--subdivisions S] [--frames N] [--quality fast|high]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string_view>
#include <vector>

import canopy;
import canopy.procedural;

namespace {

using clock_type = std::chrono::steady_clock;

double seconds_since(clock_type::time_point start) {
    return std::chrono::duration<double>(clock_type::now() - start).count();
}

// Frame f of the animation: a wave along x and a twist about the y axis, both growing with f.
std::vector<canopy::triangle> frame(std::vector<canopy::triangle> mesh, int f) {
    double const phase = 0.7 * f, twist = 0.25 * f;
    auto const move = [&](canopy::vec3<float> p) {
        double const y = double(p.y) + 0.05 * f * std::sin(6.0 * double(p.x) + phase);
        double const a = twist * y, c = std::cos(a), s = std::sin(a);
        return canopy::vec3<float>(float(c * double(p.x) - s * double(p.z)), float(y), float(s * double(p.x) + c * double(p.z)));
    };
    for (auto& t : mesh) {
        t.v0 = move(t.v0);
        t.v1 = move(t.v1);
        t.v2 = move(t.v2);
    }
    return mesh;
}

int usage() {
    std::fputs("usage: canopy_bench_refit [--subdivisions S (1-9, default 8)] [--frames N (1-100, default 5)] "
               "[--quality fast|high]\n", stderr);
    return 2;
}

} // namespace

int main(int argc, char** argv) {
    int subdivisions = 8, frames = 5;
    canopy::bvh_build_options options;
    for (int i = 1; i < argc; ++i) {
        std::string_view const a = argv[i];
        if (i + 1 >= argc) return usage();
        std::string_view const v = argv[++i];
        if (a == "--subdivisions") {
            subdivisions = std::atoi(v.data());
            if (subdivisions < 1 || subdivisions > 9) return usage();
        } else if (a == "--frames") {
            frames = std::atoi(v.data());
            if (frames < 1 || frames > 100) return usage();
        } else if (a == "--quality" && (v == "fast" || v == "high")) {
            options.quality = v == "high" ? canopy::build_quality::high : canopy::build_quality::fast;
        } else {
            return usage();
        }
    }
    auto const mesh = canopy::make_icosphere(subdivisions);
    auto start = clock_type::now();
    canopy::bvh<canopy::triangle> b = canopy::build_binned_sah(mesh, options);
    double const build_seconds = seconds_since(start);
    double const built_cost = canopy::compute_stats(b).sah_cost;
    std::printf("%zu triangles, quality %s: built in %.1f ms, SAH cost %.2f\n", mesh.size(),
                options.quality == canopy::build_quality::high ? "high" : "fast", build_seconds * 1e3, built_cost);
    std::printf("frame  refit ms  rebuild ms  refit/rebuild  SAH drift refitted  fresh  rebuild advised\n");
    for (int f = 1; f <= frames; ++f) {
        auto const moved = frame(mesh, f);
        start = clock_type::now();
        canopy::refit(b, moved);
        double const refit_seconds = seconds_since(start);
        start = clock_type::now();
        auto const fresh = canopy::build_binned_sah(moved, options);
        double const rebuild_seconds = seconds_since(start);
        std::printf("%5d  %8.2f  %10.2f  %13.3f  %18.3f  %5.3f  %s\n", f, refit_seconds * 1e3, rebuild_seconds * 1e3,
                    refit_seconds / rebuild_seconds, canopy::sah_drift(b, built_cost),
                    canopy::compute_stats(fresh).sah_cost / built_cost, canopy::needs_rebuild(b, built_cost) ? "yes" : "no");
    }
    return 0;
}
