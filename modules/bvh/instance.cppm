// canopy.bvh:instance — a placed reference to a shared BVH (two-level and deeper instancing).
//
// An instance stores a pointer to its BVH (which must outlive it), the object→world affine
// transform, its inverse (computed in double, rounded once) and an id. Rays are taken into object
// space with the inverse; the direction is not normalised, so t means the same thing at every
// level and hits from inside compare directly with hits outside. Identity instances skip the
// transform: their results are bit-identical to tracing the BVH itself.
//
// Instance ids in hit records: inst_id is the outermost instance on the path to the hit,
// inner_inst_id[0] the next one down, and so on (see canopy.geometry:hit_record).
module;
// No a·b + c → FMA contraction in this file, whatever -ffp-contract says: every build and
// every path (scalar, SIMD, packet) rounds the same way.
#pragma STDC FP_CONTRACT OFF
#include <cstdint>
export module canopy.bvh:instance;
import canopy.intersector;
import :storage;
import :traverse;

export namespace canopy {

template <typename BVH>
struct instance {
    using bvh_type = BVH;
    using value_type = typename BVH::value_type;
    using acceleration_structure_tag = void;

    instance() = default;
    instance(BVH const& b, affine_transform<value_type> const& object_to_world_, std::uint32_t id)
        : bvh(&b), object_to_world(object_to_world_), world_to_object(inverse(object_to_world_)),
          identity(object_to_world_.is_identity()), inst_id(id) {}

    BVH const* bvh = nullptr;
    affine_transform<value_type> object_to_world = affine_transform<value_type>::identity();
    affine_transform<value_type> world_to_object = affine_transform<value_type>::identity();
    bool identity = true;
    std::uint32_t inst_id = 0;
};

// Levels of instances inside a primitive type: 0 for triangles, 1 for instance<bvh<triangle>>, ...
template <typename P>
inline constexpr int instance_nesting_v = 0;
template <typename P>
inline constexpr int instance_nesting_v<bvh<P>> = instance_nesting_v<P>;
template <typename BVH>
inline constexpr int instance_nesting_v<instance<BVH>> = 1 + instance_nesting_v<BVH>;

template <typename BVH>
basic_aabb<typename BVH::value_type> get_bounds(instance<BVH> const& inst) {
    if (inst.bvh == nullptr || inst.bvh->empty()) return {};
    return inst.identity ? inst.bvh->bounds() : transform_box(inst.object_to_world, inst.bvh->bounds());
}

template <typename Ray, typename BVH, typename I, typename Query>
bool traverse(Ray& ray, instance<BVH> const& inst, I& isect, Query& query) {
    if (inst.bvh == nullptr) return false;
    query.enter_instance(inst.inst_id);
    bool stop;
    if (inst.identity) {
        // Same ray, same per-ray constants: bit-identical to tracing the BVH itself.
        stop = traverse(ray, *inst.bvh, isect, query);
    } else {
        // A plain ray: constants cached for the outer frame do not hold in object space.
        basic_ray<ray_value_t<Ray>> local = ray;
        local.origin = inst.world_to_object.transform_point(ray.origin);
        local.direction = inst.world_to_object.transform_vector(ray.direction);
        stop = traverse(local, *inst.bvh, isect, query);
        ray.tmax = local.tmax;
    }
    query.leave_instance();
    return stop;
}

} // namespace canopy
