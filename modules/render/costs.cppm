// canopy.render:costs — counting<Inner>: the paper's cost counter (its bvh_costs, §4) over any
// intersector. It counts every ray/box and ray/triangle test, at every level of the scene, and
// hands each test to Inner's hook when Inner has one for it (else to the library's test), and
// each candidate to Inner's filter when Inner has one: counting<texture_alpha_mask> counts the
// tests while the mask decides the hits.
//
// cost_counter = counting<default_intersector> is the paper's bvh_costs, named differently so that
// the paper's own code, which defines bvh_costs, compiles under `using namespace canopy;`. It has
// hooks, hence it is a custom intersector: traversal calls it for every test (the default path,
// without hooks, is untouched).
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <utility>
export module canopy.render:costs;
import canopy.query;

export namespace canopy {

template <typename Inner = default_intersector>
struct counting : basic_intersector<counting<Inner>> {
    using basic_intersector<counting<Inner>>::operator();

    template <typename Ray, typename... Args>
    auto operator()(Ray const& ray, aabb const& box, Args&&... args) {
        ++num_boxes;
        if constexpr (requires { inner(ray, box, std::forward<Args>(args)...); })
            return inner(ray, box, std::forward<Args>(args)...);
        else
            return intersect(ray, box, std::forward<Args>(args)...);
    }

    template <typename Ray>
    auto operator()(Ray const& ray, triangle const& tri) {
        ++num_tris;
        if constexpr (requires { inner(ray, tri); })
            return inner(ray, tri);
        else
            return intersect(ray, tri);
    }

    template <typename Ray>
        requires filter_hook_for<Inner, Ray>
    auto filter(Ray const& ray, basic_hit_record<ray_value_t<Ray>> const& hr) {
        return inner.filter(ray, hr);
    }

    Inner inner;
    unsigned num_boxes = 0;
    unsigned num_tris = 0;
};

using cost_counter = counting<default_intersector>;

} // namespace canopy
