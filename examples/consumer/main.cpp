// Uses the installed Canopy package: one BVH, one instance, a counting intersector.
#include <cstdio>
#include <vector>
import canopy;

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
    std::vector<canopy::triangle> const tris{{{-1, -1, 0}, {1, -1, 0}, {0, 1, 0}, 0, 0}};
    auto const mesh = canopy::build_binned_sah(tris);
    using inst_t = canopy::instance<canopy::bvh<canopy::triangle>>;
    std::vector<inst_t> const placed{inst_t(mesh, canopy::affine_transform<float>::from_rows({1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 5}), 7)};
    auto const top = canopy::build_binned_sah(placed);
    count_triangles isect;
    canopy::ray const r{{0, 0, 10}, 0, {0, 0, -1}, 100};
    auto const hr = canopy::closest_hit(r, &top, &top + 1, isect);
    std::printf("hit=%d t=%g inst=%u tests=%d\n", int(hr.hit), double(hr.t), hr.inst_id, isect.tests);
    return hr.hit && hr.t == 5.0f && hr.inst_id == 7 && isect.tests == 1 ? 0 : 1;
}
