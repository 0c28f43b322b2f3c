// canopy.geometry — primitives and their ray tests, found by ADL as `intersect(ray, prim)`:
// triangles (watertight by default, Möller–Trumbore opt-in; blocks tested at once), spheres, the conservative ray/box
// slab test, hit_record, and robust secondary-ray origins (spawn_ray). Every test works for float, double and SIMD packet rays.
//
// A user-defined primitive joins the library by providing, in its own namespace:
//   basic_aabb<S> get_bounds(P const&);                  (for BVH builds)
//   hit_record<Ray, P> intersect(Ray const&, P const&);  (for queries)
// and members prim_id / geom_id if the builder should number it (concept canopy::primitive,
// canopy.bvh:protocol).
export module canopy.geometry;
export import canopy.math;
export import :hit_record;
export import :box;
export import :triangle;
export import :triangle_block;
export import :sphere;
export import :spawn;
