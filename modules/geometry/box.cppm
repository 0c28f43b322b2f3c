// canopy.geometry:box — the ray/box slab test used by BVH traversal.
//
// Conservative: Ize 2013, "Robust BVH Ray Traversal", JCGT 2(2): the far distance is scaled by
// 1 + 2γ3 so that rounding can never make a box that the ray touches look missed.
// Zero direction components: the caller passes inv_dir = 1/direction (IEEE: ±inf). A ray lying
// in a slab's boundary plane gives 0·inf = NaN there; near/far are chosen by the sign of inv_dir so
// such a NaN drops out (the slab then holds the whole ray): conservative. NaN in tmin or
// tmax makes every comparison fail: such rays miss.
module;
// No a·b + c → FMA contraction in this file, whatever -ffp-contract says: every build and
// every path (scalar, SIMD, packet) rounds the same way.
#pragma STDC FP_CONTRACT OFF
#include <type_traits>
export module canopy.geometry:box;
import canopy.math;

export namespace canopy {

// The ray's tmax as box tests compare it: widened by 2γ3 (relative), so that a primitive whose
// computed t equals tmax (a tie, as on a shared edge) is never culled because its box's
// computed entry distance rounds a little above that t.
template <typename T>
[[gnu::always_inline]] inline T box_test_tmax(T const& tmax) {
    using S = simd::scalar_type_t<T>;
    constexpr S widen = S(2) * gamma<S>(3);
    return simd::select(tmax >= T(0), tmax * T(S(1) + widen), tmax * T(S(1) - widen));
}

template <typename T>
struct box_hit {
    simd::mask_type_t<T> hit{};
    T tnear{};
    T tfar{};
};

// Ray against an axis-aligned box. inv_dir must be 1 / ray.direction, component-wise.
// hit: tmin ≤ tnear ≤ tfar ≤ tmax (in the conservative sense above).
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline box_hit<T> intersect(basic_ray<T> const& ray, basic_aabb<S> const& box,
                                                   vec3<T> const& inv_dir) {
    constexpr S far_scale = S(1) + S(2) * gamma<S>(3);
    T tnear = ray.tmin;
    T tfar = box_test_tmax(ray.tmax);
    for (int axis = 0; axis < 3; ++axis) {
        T const t0 = (T(box.min[axis]) - ray.origin[axis]) * inv_dir[axis];
        T const t1 = (T(box.max[axis]) - ray.origin[axis]) * inv_dir[axis];
        // Near/far by the sign of inv_dir (-0 → -inf counts as negative), so a NaN from a ray in
        // a slab's boundary plane lands in a slot that max(NaN, x) / min(NaN, x) ignore: that
        // slab then does not restrict the ray, as it should (the ray stays inside it).
        auto const negative = inv_dir[axis] < T(0);
        T const slab_near = simd::select(negative, t1, t0);
        T const slab_far = simd::select(negative, t0, t1) * far_scale;
        tnear = simd::max(slab_near, tnear);
        tfar = simd::min(slab_far, tfar);
    }
    return {tnear <= tfar, tnear, tfar};
}

} // namespace canopy
