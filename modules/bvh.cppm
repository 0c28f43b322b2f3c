// canopy.bvh — bounding volume hierarchies over any primitive with get_bounds/intersect, built
// by a parallel binned SAH builder, traversed with a custom intersector; instance<BVH> places a
// shared BVH with an affine transform, and BVHs of instances nest to any depth
// (bvh<instance<bvh<instance<bvh<triangle>>>>>); refit updates a BVH's boxes after its geometry moved.
// The traversal protocol (:protocol) names what primitives, structures and queries provide, and
// is where every test goes through the intersector. Partitions export only the public API; the
// builder's steps (:parallel, :wide, :binning, :object, :spatial, and the detail namespaces) stay inside.
export module canopy.bvh;
export import canopy.intersector;
export import :storage;
export import :protocol;
export import :parallel;
export import :block_cache;
export import :build_buffer;
export import :wide;
export import :binning;
export import :object;
export import :spatial;
export import :build;
export import :traverse;
export import :instance;
export import :refit;
