// zero_cost_embree — Embree's side of bench/zero_cost.sh: the same rays against the same
// icosphere through rtcIntersect1, without a filter and with an intersection filter function
// that accepts every candidate, so the instruction counts show what Embree's run-time callback
// costs where Canopy's compile-time intersectors cost nothing.
//
//   canopy_bench_zero_cost_embree none|noop_filter [RAYS]
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>
#include <embree3/rtcore.h>
#include "embree_support.hpp"
import canopy;
import canopy.procedural;

namespace {

void accept_all(RTCFilterFunctionNArguments const*) {}

[[gnu::noinline]] unsigned trace_all(RTCScene scene, std::vector<canopy::ray> const& rays) {
    unsigned hits = 0;
    for (auto const& r : rays) {
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        RTCRayHit rh = canopy_bench::embree_ray_hit(r);
        rtcIntersect1(scene, &context, &rh);
        hits += rh.hit.geomID != RTC_INVALID_GEOMETRY_ID ? 1u : 0u;
    }
    return hits;
}

} // namespace

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s none|noop_filter [RAYS]\n", argv[0]);
        return 2;
    }
    std::string const mode = argv[1];
    if (mode != "none" && mode != "noop_filter") {
        std::fprintf(stderr, "unknown mode '%s'\n", mode.c_str());
        return 2;
    }
    int const n = argc > 2 ? std::atoi(argv[2]) : 20000;
    auto const tris = canopy::make_icosphere(4);
    // The same rays as canopy_bench_zero_cost.
    std::mt19937 rng(1);
    std::normal_distribution<float> g(0.0f, 1.0f);
    std::vector<canopy::ray> rays;
    for (int i = 0; i < n; ++i)
        rays.push_back({{0.1f * g(rng), 0.1f * g(rng), 0.1f * g(rng)}, 0.0f, {g(rng), g(rng), g(rng)}, 1e30f});

    RTCDevice device = rtcNewDevice("threads=1");
    RTCScene scene = rtcNewScene(device);
    RTCGeometry geom = canopy_bench::embree_triangles(device, tris);
    if (mode == "noop_filter") rtcSetGeometryIntersectFilterFunction(geom, accept_all);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);
    unsigned const hits = trace_all(scene, rays);
    std::printf("embree %s: %d rays, %u hits\n", mode.c_str(), n, hits);
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    return 0;
}
