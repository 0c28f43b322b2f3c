// hello — one ray, one triangle, the default (watertight) test, then the same through a BVH.
#include <cstdio>
#include <vector>
import canopy;

int main() {
    canopy::triangle const tri{{0.0f, 0.0f, 0.0f}, {1.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f}};
    canopy::ray const r{{0.25f, 0.25f, -1.0f}, 0.0f, {0.0f, 0.0f, 2.0f}, 10.0f};

    auto const hr = intersect(r, tri);
    std::printf("ray/triangle: hit=%d t=%g u=%g v=%g (expected t=0.5 u=0.25 v=0.25)\n", int(hr.hit), double(hr.t),
                double(hr.u), double(hr.v));

    std::vector<canopy::triangle> const tris{tri};
    auto const bvh = canopy::build_binned_sah(tris);
    auto const through_bvh = canopy::closest_hit(r, &bvh, &bvh + 1);
    std::printf("through a BVH: hit=%d t=%g prim=%u\n", int(through_bvh.hit), double(through_bvh.t),
                through_bvh.prim_id);
    std::printf("SIMD: %s\n", canopy::simd::isa_name().data());
    return hr.hit && through_bvh.hit ? 0 : 1;
}
