// canopy.bvh:instance — a placed reference to a shared BVH (two-level and deeper instancing).
//
// An instance stores where its BVH's nodes and leaves live (bvh_storage: heap buffers, which stay
// in place when the bvh object moves, so a BVH may be moved — into a growing std::vector, say —
// after instances of it are made; it must not be destroyed, reassigned or rebuilt while they are
// used), the object→world affine transform, its inverse (computed in double, rounded once) and an
// id. Rays are taken into object space with the inverse; the direction is not normalised, so t
// means the same thing at every level and hits from inside compare directly with hits outside.
// Identity instances skip the transform: their results are bit-identical to tracing the BVH
// itself.
//
// A transform without a usable inverse is refused when the instance is made, never traced into
// NaN: the constructor throws std::invalid_argument (construction is not a hot path) when the
// transform has a NaN or infinite entry, is singular (determinant 0 in double), or its inverse
// overflows value_type.
//
// Instance ids in hit records: inst_id is the outermost instance on the path to the hit,
// inner_inst_id[0] the next one down, and so on (see canopy.geometry:hit_record).
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <stdexcept>
#include <string>
export module canopy.bvh:instance;
import canopy.intersector;
import :storage;
import :protocol;
import :traverse;

export namespace canopy {

template <typename BVH>
struct instance {
    using bvh_type = BVH;
    using value_type = typename BVH::value_type;
    using acceleration_structure_tag = void;

    instance() = default;
    // Throws std::invalid_argument naming the instance id when object_to_world_ has no usable
    // inverse (see the top of this file).
    instance(BVH const& b, affine_transform<value_type> const& object_to_world_, std::uint32_t id)
        : storage(b), object_to_world(object_to_world_), world_to_object(inverse(object_to_world_)),
          identity(object_to_world_.is_identity()), inst_id(id) {
        check_invertible();
    }

    bvh_storage<typename BVH::primitive_type> storage;
    affine_transform<value_type> object_to_world = affine_transform<value_type>::identity();
    affine_transform<value_type> world_to_object = affine_transform<value_type>::identity();
    bool identity = true;
    std::uint32_t inst_id = 0;

private:
    static bool finite(affine_transform<value_type> const& a) {
        for (auto const& c : {a.linear.col0, a.linear.col1, a.linear.col2, a.translation})
            if (!std::isfinite(c.x) || !std::isfinite(c.y) || !std::isfinite(c.z)) return false;
        return true;
    }

    void check_invertible() const {
        auto const refuse = [&](std::string const& problem) {
            throw std::invalid_argument("canopy::instance " + std::to_string(inst_id) +
                                        ": the object-to-world transform " + problem);
        };
        if (!finite(object_to_world)) refuse("has a NaN or infinite entry");
        auto const& l = object_to_world.linear;
        double const det = determinant(mat3<double>{vec3<double>(l.col0), vec3<double>(l.col1), vec3<double>(l.col2)});
        char text[32];
        std::snprintf(text, sizeof text, "%.3g", det);
        if (det == 0.0) refuse("is singular (determinant 0): it has no inverse, so rays cannot enter the instance");
        if (!finite(world_to_object))
            refuse(std::string("is nearly singular (determinant ") + text + "): its inverse overflows");
    }
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
    if (inst.storage.empty()) return {};
    return inst.identity ? inst.storage.bounds() : transform_box(inst.object_to_world, inst.storage.bounds());
}

template <typename Ray, typename BVH, typename I, hit_collector<ray_value_t<Ray>> Query>
bool traverse(Ray& ray, instance<BVH> const& inst, I& isect, Query& query) {
    if (inst.storage.empty()) return false;
    query.enter_instance(inst.inst_id);
    bool stop;
    if (inst.identity) {
        // Same ray, same per-ray constants: bit-identical to tracing the BVH itself.
        stop = traverse(ray, inst.storage, isect, query);
    } else {
        // A plain ray: constants cached for the outer frame do not hold in object space.
        basic_ray<ray_value_t<Ray>> local = ray;
        local.origin = inst.world_to_object.transform_point(ray.origin);
        local.direction = inst.world_to_object.transform_vector(ray.direction);
        stop = traverse(local, inst.storage, isect, query);
        ray.tmax = local.tmax;
    }
    query.leave_instance();
    return stop;
}

} // namespace canopy
