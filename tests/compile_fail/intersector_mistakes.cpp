// Intersector mistakes that must not compile (tests/CMakeLists.txt: one compile of this file,
// whose errors each "intersector mistake" test looks for). Each case is a query with an
// intersector whose hooks would never be called, or whose result the library cannot use; the
// query must refuse it with the message of canopy.query's report_intersector_mistake, and the
// error's instantiation notes must name the case's intersector.
#include <vector>

import canopy.query;

using canopy::aabb;
using canopy::ray;
using canopy::triangle;

// A const intersector whose hook is not const.
struct const_case : canopy::basic_intersector<const_case> {
    using canopy::basic_intersector<const_case>::operator();
    template <typename Ray>
    auto operator()(Ray const& r, triangle const& tri) {
        return intersect(r, tri);
    }
};

// Parameters in the order (tri, ray).
struct swapped_case : canopy::basic_intersector<swapped_case> {
    using canopy::basic_intersector<swapped_case>::operator();
    template <typename Ray>
    auto operator()(triangle const& tri, Ray const& r) {
        return intersect(r, tri);
    }
};

// A box hook without Args&&...
struct box_without_args_case : canopy::basic_intersector<box_without_args_case> {
    using canopy::basic_intersector<box_without_args_case>::operator();
    template <typename Ray>
    auto operator()(Ray const& r, aabb const& box) {
        return intersect(r, box, canopy::vec3<float>(1, 1, 1));
    }
};

// triangle& without const.
struct non_const_case : canopy::basic_intersector<non_const_case> {
    using canopy::basic_intersector<non_const_case>::operator();
    template <typename Ray>
    auto operator()(Ray const& r, triangle& tri) {
        return intersect(r, tri);
    }
};

// A basic_triangle<double> hook on a float scene.
struct double_case : canopy::basic_intersector<double_case> {
    using canopy::basic_intersector<double_case>::operator();
    template <typename Ray>
    auto operator()(Ray const& r, canopy::basic_triangle<double> const& tri) {
        return intersect(r, tri);
    }
};

// A hook that returns bool.
struct bool_case : canopy::basic_intersector<bool_case> {
    template <typename Ray>
    bool operator()(Ray const& r, triangle const& tri) {
        return intersect(r, tri).hit;
    }
};

// An operator() of its own (no using-declaration) that serves no query: a sphere hook over triangles.
struct unusable_case : canopy::basic_intersector<unusable_case> {
    template <typename Ray>
    auto operator()(Ray const& r, canopy::sphere const& s) {
        return intersect(r, s);
    }
};

void queries(std::vector<triangle> const& tris, canopy::bvh<triangle> const& b, ray const& r) {
    const_case const c;
    (void)canopy::closest_hit(r, &b, &b + 1, c);
    (void)canopy::closest_hit(r, &b, &b + 1, swapped_case{});
    (void)canopy::closest_hit(r, &b, &b + 1, box_without_args_case{});
    (void)canopy::any_hit(r, tris.begin(), tris.end(), non_const_case{});
    (void)canopy::closest_hit(r, &b, &b + 1, double_case{});
    (void)canopy::multi_hit<2>(r, &b, &b + 1, bool_case{});
    (void)canopy::closest_hit(r, &b, &b + 1, unusable_case{});
}
