// canopy.geometry:box — the ray/box slab test used by BVH traversal.
//
// Conservative twice over: for the exact box (Ize, below), and, in traversal, for the box grown
// by the rounding of the watertight triangle test (box_margin_origins), so that no triangle that
// test hits is ever in a culled box.
//
// Conservative: Ize 2013, "Robust BVH Ray Traversal", JCGT 2(2): the far distance is scaled by
// 1 + 2γ3 so that rounding can never make a box that the ray touches look missed.
// Zero direction components: the caller passes inv_dir = 1/direction (IEEE: ±inf). A ray lying
// in a slab's boundary plane gives 0·inf = NaN there; near/far are chosen by the sign of inv_dir so
// such a NaN drops out (the slab then holds the whole ray): conservative. NaN in tmin or
// tmax makes every comparison fail: such rays miss.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <limits>
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

// The widening of a box test's far distances (Ize 2013: the three roundings of a slab distance,
// 1 + 2γ3), shared by every box test, the 8-wide and packet tests of canopy.bvh included.
template <typename S>
inline constexpr S box_far_scale = S(1) + S(2) * gamma<S>(3);

template <typename T>
struct box_hit {
    simd::mask_type_t<T> hit{};
    T tnear{};
    T tfar{};
};

// Ray against an axis-aligned box, with the distances to the near planes measured from
// `near_origin` and those to the far planes from `far_origin` (both the ray's origin in the plain
// test; see box_margin_origins for why they may differ). inv_dir must be 1 / ray.direction,
// component-wise. hit: tmin ≤ tnear ≤ tfar ≤ tmax (in the conservative sense above). The shifts
// are added to plane − origin before the product: box_margin_origins' margins on the axes of
// origins far from the world origin, −0 (which changes nothing) elsewhere.
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline box_hit<T> intersect_slabs(basic_ray<T> const& ray, basic_aabb<S> const& box,
                                                         vec3<T> const& inv_dir, vec3<T> const& near_origin,
                                                         vec3<T> const& far_origin, vec3<T> const& near_shift,
                                                         vec3<T> const& far_shift) {
    T tnear = ray.tmin;
    T tfar = box_test_tmax(ray.tmax);
    for (int axis = 0; axis < 3; ++axis) {
        // Near/far by the sign of inv_dir (-0 → -inf counts as negative), so a NaN from a ray in
        // a slab's boundary plane lands in a slot that max(NaN, x) / min(NaN, x) ignore: that
        // slab then does not restrict the ray, as it should (the ray stays inside it).
        auto const negative = inv_dir[axis] < T(0);
        T const near_plane = simd::select(negative, T(box.max[axis]), T(box.min[axis]));
        T const far_plane = simd::select(negative, T(box.min[axis]), T(box.max[axis]));
        T const slab_near = ((near_plane - near_origin[axis]) + near_shift[axis]) * inv_dir[axis];
        T const slab_far = ((far_plane - far_origin[axis]) + far_shift[axis]) * inv_dir[axis] * box_far_scale<S>;
        tnear = simd::max(slab_near, tnear);
        tfar = simd::min(slab_far, tfar);
    }
    return {tnear <= tfar, tnear, tfar};
}

// Without shifts (x + (−0) is x: the compiler drops the additions).
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline box_hit<T> intersect_slabs(basic_ray<T> const& ray, basic_aabb<S> const& box,
                                                         vec3<T> const& inv_dir, vec3<T> const& near_origin,
                                                         vec3<T> const& far_origin) {
    vec3<T> const none(T(S(-0.0)));
    return intersect_slabs(ray, box, inv_dir, near_origin, far_origin, none, none);
}

// The per-ray constants of the fused slab test: the plane distances measured from the near and
// far origins are fma(plane, inv_dir, -offset) with offset = origin · inv_dir rounded once per
// ray, one instruction per plane instead of a subtraction and a product (Embree's form).
// `usable` says, lane by lane, whether the fused form applies: inv_dir finite and non-zero, and
// both offsets finite. Otherwise (a zero or infinite direction component, an origin so far out
// that origin · inv_dir overflows) the ray keeps the subtraction form (intersect_slabs), whose
// infinities and NaN are handled as described at the top of this file.
//
// Why it stays conservative: fma rounds once, so the fused distance is
// fl(plane · r − fl(o · r)) = fl((plane − o(1 + ε)) · r) with |ε| ≤ u: the exact distance from an
// origin moved by at most u·|o| along the axis, rounded once. The traversal's origins are moved
// by at least 4u·|o| (box_margin_origins) beyond what the watertight test needs, which absorbs
// that move; the rounding of r and of the fma is covered by the far scale 1 + 2γ3 as in Ize's
// analysis (there, three roundings). With finite non-zero r and finite offsets no NaN can arise:
// an empty box's infinite planes (min +inf, max -inf) give tnear = +inf and tfar = -inf, a miss
// whatever tmin and tmax are, so the 8-wide node test needs no mask of used slots in this form.
template <typename T>
struct slab_offsets {
    vec3<T> near_offset, far_offset;
    simd::mask_type_t<T> usable{};
};

template <typename T>
[[gnu::always_inline]] inline slab_offsets<T> fused_slab_offsets(vec3<T> const& inv_dir, vec3<T> const& near_origin,
                                                                 vec3<T> const& far_origin) {
    slab_offsets<T> s;
    // x − x is 0 for finite x and NaN for ±inf or NaN, and a NaN survives the sums: one
    // comparison tells whether inv_dir and both offsets are all finite. (An infinite direction
    // component gives inv_dir 0 and offsets 0 on that axis: both forms then compute 0 there.)
    T finite(simd::scalar_type_t<T>(0));
    for (int axis = 0; axis < 3; ++axis) {
        s.near_offset[axis] = near_origin[axis] * inv_dir[axis];
        s.far_offset[axis] = far_origin[axis] * inv_dir[axis];
        finite = finite + (inv_dir[axis] - inv_dir[axis]) + (s.near_offset[axis] - s.near_offset[axis]) +
                 (s.far_offset[axis] - s.far_offset[axis]);
    }
    T const zero(simd::scalar_type_t<T>(0));
    s.usable = (finite == zero) & (inv_dir.x != zero) & (inv_dir.y != zero) & (inv_dir.z != zero);
    return s;
}

// The fused slab test (see slab_offsets), for lanes where offsets.usable holds; same hits as
// intersect_slabs in the conservative sense, with tmax widened the same way.
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline box_hit<T> intersect_slabs_fused(basic_ray<T> const& ray, basic_aabb<S> const& box,
                                                               vec3<T> const& inv_dir, slab_offsets<T> const& offsets) {
    T tnear = ray.tmin;
    T tfar(std::numeric_limits<S>::infinity());
    for (int axis = 0; axis < 3; ++axis) {
        auto const negative = inv_dir[axis] < T(0);
        T const near_plane = simd::select(negative, T(box.max[axis]), T(box.min[axis]));
        T const far_plane = simd::select(negative, T(box.min[axis]), T(box.max[axis]));
        tnear = simd::max(simd::fma(near_plane, inv_dir[axis], -offsets.near_offset[axis]), tnear);
        tfar = simd::min(simd::fma(far_plane, inv_dir[axis], -offsets.far_offset[axis]), tfar);
    }
    // One scaling after the minimum: rounding is monotonic, so this equals scaling each slab.
    tfar = simd::min(tfar * T(box_far_scale<S>), box_test_tmax(ray.tmax));
    return {tnear <= tfar, tnear, tfar};
}

// Ray against an axis-aligned box. inv_dir must be 1 / ray.direction, component-wise.
// hit: tmin ≤ tnear ≤ tfar ≤ tmax (in the conservative sense above).
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline box_hit<T> intersect(basic_ray<T> const& ray, basic_aabb<S> const& box,
                                                   vec3<T> const& inv_dir) {
    return intersect_slabs(ray, box, inv_dir, ray.origin, ray.origin);
}

// The origins of a box test that is conservative with respect to the watertight triangle test,
// for a ray meeting primitives inside `bounds`.
//
// Woop et al.'s test decides exactly, but for vertices that it has rounded: translated to the ray
// origin (u·R per coordinate, R = ‖v − o‖∞), sheared with a rounded shear constant and a rounded
// product and difference (≤ 5u·R more). The test is therefore exact for a triangle whose corners
// lie within 6u·R (plus higher-order terms) of the true ones, sideways to the ray. A ray that
// passes just outside a leaf's box, through the neighbour across an edge on that box's face, can
// then be given to the triangle inside the box, whose leaf the exact box test culls: a leak (rays
// from inside a closed cylinder of radius 0.01 and length 16 found 1 in 250,000). Growing every
// box by δ ≥ 6u·R on each side closes it. The boxes are not touched: the near planes are measured
// from the origin moved by δ towards them, the far planes from the origin moved by δ away, which
// in exact arithmetic is the grown box, and costs nothing per node. Ize's rounding analysis holds
// for any float origin, so the test stays conservative for the grown box.
//
// δ is 2^-20·R (16u·R) with R bounded by the largest distance from the origin to `bounds`. The
// moved origin must differ from the origin by at least δ once rounded, so the move is at least
// 2^-21·|o| (four ulps or more; rounded, at least 4u·|o|). The fused slab test (slab_offsets) may
// take back u·|o| of the move; what remains, at least max(16u·R, 4u·|o|) − u·|o| ≥ 12u·R, still
// exceeds 6u·R.
//
// Far from the world origin that floor would dominate: at |o| = 10^6 a move of 2^-21·|o| grows
// every box by about 0.5, and a ray in a scene of that size visits most of its BVH. So on an axis
// where 2^-21·|o| exceeds the margin the origin stays and the margin shifts the difference
// instead: the near plane's distance is ((plane − o) + near_shift) · inv_dir with near_shift =
// ∓margin (towards the ray's origin side), the far one's likewise with the opposite shift.
// Their two roundings are relative to |plane − o| ≤ R (every plane of the BVH lies in `bounds`)
// and to |plane − o| + margin: together about 2u·R, which leaves some 30u·R of the 32u·R margin
// (2 · 2^-20 · R, below); the box stays grown by more than 6u·R, and the product with inv_dir
// has Ize's analysis as before. Such rays cannot take the fused form (its rounding of o·(1/d) is
// relative to |o|): their slab_offsets are not usable.
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
void box_margin_origins(basic_ray<T> const& ray, vec3<T> const& inv_dir, basic_aabb<S> const& bounds,
                        vec3<T>& near_origin, vec3<T>& far_origin, vec3<T>& near_shift, vec3<T>& far_shift) {
    // R in simd::reduce_max's order over the lanes (x, y, z, 0) of a 4-lane vector, so that
    // box_test_constants' vector form below gives the same bits, NaN included.
    vec3<T> m;
    for (int axis = 0; axis < 3; ++axis)
        m[axis] = simd::max(simd::abs(T(bounds.min[axis]) - ray.origin[axis]),
                            simd::abs(T(bounds.max[axis]) - ray.origin[axis]));
    T const reach = simd::max(simd::max(m.x, m.z), simd::max(m.y, T(S(0))));
    T const delta = reach * T(S(1.0 / 524288.0)); // 2 · 2^-20 · R: rounding the move keeps ≥ half
    for (int axis = 0; axis < 3; ++axis) {
        T const floor = simd::abs(ray.origin[axis]) * T(S(1.0 / 2097152.0));
        auto const shifted = floor > delta; // the origin stays, the margin shifts the difference
        T const move = simd::select(shifted, T(S(0)), simd::max(delta, floor));
        auto const negative = inv_dir[axis] < T(0);
        T const towards_near = simd::select(negative, -move, move);
        near_origin[axis] = ray.origin[axis] + towards_near;
        far_origin[axis] = ray.origin[axis] - towards_near;
        // −0 elsewhere: x + (−0) is x for every x, so unshifted axes keep the plain test's bits.
        near_shift[axis] = simd::select(shifted, simd::select(negative, delta, -delta), T(S(-0.0)));
        far_shift[axis] = simd::select(shifted, simd::select(negative, -delta, delta), T(S(-0.0)));
    }
}

// Both per-ray constants of traversal's box test: the widened origins and shifts
// (box_margin_origins) and the fused test's offsets (fused_slab_offsets), usable only where no
// axis is shifted.
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline void box_test_constants(basic_ray<T> const& ray, vec3<T> const& inv_dir,
                                                      basic_aabb<S> const& bounds, vec3<T>& near_origin,
                                                      vec3<T>& far_origin, vec3<T>& near_shift, vec3<T>& far_shift,
                                                      slab_offsets<T>& slabs) {
    if constexpr (std::is_same_v<T, float> && simd::native_width<4>) {
        // One scalar ray: its three axes in the lanes of one vector (lane 3 holds zeros), the same
        // operations lane by lane as the two functions, so the same bits in a third of the
        // instructions. Paid once per ray and per instance entered.
        using simd::float4;
        float4 const o = to_lanes(ray.origin), inv = to_lanes(inv_dir);
        float4 const m = simd::max(simd::abs(to_lanes(bounds.min) - o), simd::abs(to_lanes(bounds.max) - o));
        float4 const delta(simd::reduce_max(m) * float(1.0 / 524288.0));
        float4 const floor = simd::abs(o) * float4(float(1.0 / 2097152.0));
        auto const shifted = floor > delta;
        float4 const move = simd::select(shifted, float4(0.0f), simd::max(delta, floor));
        auto const negative = inv < float4(0.0f);
        float4 const towards_near = simd::select(negative, -move, move);
        float4 const near = o + towards_near, far = o - towards_near;
        float4 const unshifted(-0.0f);
        near_shift = from_lanes(simd::select(shifted, simd::select(negative, delta, -delta), unshifted));
        far_shift = from_lanes(simd::select(shifted, simd::select(negative, -delta, delta), unshifted));
        float4 const near_offset = near * inv, far_offset = far * inv;
        float4 const finite = (inv - inv) + (near_offset - near_offset) + (far_offset - far_offset);
        near_origin = from_lanes(near);
        far_origin = from_lanes(far);
        slabs.near_offset = from_lanes(near_offset);
        slabs.far_offset = from_lanes(far_offset);
        slabs.usable = (simd::movemask((finite == float4(0.0f)) & (inv != float4(0.0f)) & !shifted) & 7u) == 7u;
    } else {
        box_margin_origins(ray, inv_dir, bounds, near_origin, far_origin, near_shift, far_shift);
        slabs = fused_slab_offsets(inv_dir, near_origin, far_origin);
        T const zero(S(0));
        slabs.usable = slabs.usable & (near_shift.x == zero) & (near_shift.y == zero) & (near_shift.z == zero);
    }
}

} // namespace canopy
