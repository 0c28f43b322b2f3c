// Types that break the traversal protocol (canopy.bvh:protocol) must not compile
// (tests/CMakeLists.txt: one compile of this file, whose errors each "protocol mistake" test looks
// for). Each case is refused at the call, by the concept it fails, and the compiler's notes name
// the missing expression and the case's type.
#include <cstdint>
#include <vector>

import canopy.query;

namespace user {

// A primitive without get_bounds: it cannot be built into a BVH.
struct no_bounds_case {
    std::uint32_t prim_id = 0;
};
canopy::basic_hit_record<float> intersect(canopy::ray const&, no_bounds_case const&) { return {}; }

// A primitive without intersect: a BVH of it could never be traced.
struct no_intersect_case {
    std::uint32_t prim_id = 0;
};
canopy::aabb get_bounds(no_intersect_case const&) { return {}; }

// A hit collector without report: traversal could not hand it a candidate.
struct no_report_case : canopy::instance_path {
    static constexpr bool wants_near_first = true;
};

} // namespace user

void calls(std::vector<user::no_bounds_case> const& a, std::vector<user::no_intersect_case> const& b,
           canopy::bvh<canopy::triangle> const& mesh, canopy::ray const& r) {
    (void)canopy::build_binned_sah(a);
    (void)canopy::build_binned_sah(b);
    (void)canopy::closest_hit(r, b.begin(), b.end());
    canopy::ray ray = r;
    canopy::default_intersector isect;
    user::no_report_case collector;
    (void)traverse(ray, mesh, isect, collector);
}
