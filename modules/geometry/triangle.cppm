// canopy.geometry:triangle — triangles and their ray tests.
//
// Default test: watertight, Woop, Benthin, Wald 2013, "Watertight Ray/Triangle Intersection",
// JCGT 2(1). The ray is sheared so it runs along +z through the origin; each vertex is
// transformed on its own, so triangles sharing a vertex (bit-identical coordinates) see the same
// transformed vertex and no ray slips between them. The three 2-D edge functions are evaluated
// with Kahan's FMA difference of products (relative error ≤ 2u, Jeannerod, Louvet, Muller 2013),
// so their signs are exact for the transformed vertices (barring under/overflow). Edges and
// vertices count as inside, and a ray through an edge or vertex shared by triangles never slips
// between them. What is not guaranteed: a ray exactly through the *open boundary* of a mesh may
// hit or miss, since the rounded shear can move the boundary by an ulp (a closed mesh has none).
//
// Contracts of every test here: hit iff tmin ≤ t ≤ tmax for the returned t; degenerate
// (zero-area) triangles never hit; NaN/Inf in the ray make it miss (all tests are accept-style
// comparisons that NaN fails). u, v are the barycentric weights of v1 and v2.
//
// Möller & Trumbore 1997 is kept as an opt-in (intersect_moller_trumbore): faster to set up, not
// watertight.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <type_traits>
#include <utility>
export module canopy.geometry:triangle;
import canopy.math;
import :box;
import :hit_record;

export namespace canopy {

template <typename T>
struct basic_triangle {
    using value_type = T;
    vec3<T> v0, v1, v2;
    // Index in the sequence a BVH was built from (the builder sets it), and a user-chosen
    // geometry id (e.g. which mesh / texture).
    std::uint32_t prim_id = 0;
    std::uint32_t geom_id = 0;
};
using triangle = basic_triangle<float>;

template <typename T>
basic_aabb<T> get_bounds(basic_triangle<T> const& tri) {
    return extend(extend(basic_aabb<T>{tri.v0, tri.v0}, tri.v1), tri.v2);
}

// True when the three vertices are collinear or repeated: the cross product of the edges,
// evaluated in double (exact for float vertices of similar magnitude), is zero.
template <typename T>
bool is_degenerate(basic_triangle<T> const& tri) {
    vec3<double> const a(tri.v0), b(tri.v1), c(tri.v2);
    vec3<double> const n = cross(b - a, c - a);
    return n.x == 0.0 && n.y == 0.0 && n.z == 0.0;
}

// a·b − c·d with one rounding error of at most 2u relative (Kahan's algorithm with FMA).
template <typename T>
[[gnu::always_inline]] inline T difference_of_products(T a, T b, T c, T d) {
    T const cd = c * d;
    T const error = simd::fma(-c, d, cd);
    T const ab_minus_cd = simd::fma(a, b, -cd);
    return ab_minus_cd + error;
}

// Woop et al.'s ray shear, computed once per ray: axis permutation (kx, ky, kz) with kz the
// largest |direction| component, and the shear constants.
template <typename T>
struct watertight_shear {
    // Component k of v in the permuted frame (x → kx, y → ky, z → kz).
    vec3<T> permute(vec3<T> const& v) const {
        if constexpr (simd::simd_width_v<T> == 1) {
            T const c[3] = {v.x, v.y, v.z};
            return {c[kx], c[ky], c[kz]};
        } else {
            // Per lane: kz = x, y or z; (kx, ky) is the cyclic successor pair, swapped when
            // the direction along kz is negative (keeps the winding).
            T const px = simd::select(z_is_x, v.y, simd::select(z_is_y, v.z, v.x));
            T const py = simd::select(z_is_x, v.z, simd::select(z_is_y, v.x, v.y));
            T const pz = simd::select(z_is_x, v.x, simd::select(z_is_y, v.y, v.z));
            return {simd::select(swap_xy, py, px), simd::select(swap_xy, px, py), pz};
        }
    }

    int kx = 0, ky = 1, kz = 2;                       // scalar rays; SIMD rays when uniform
    simd::mask_type_t<T> z_is_x{}, z_is_y{}, swap_xy{}; // SIMD rays
    // SIMD rays: every lane has the same permutation, (kx, ky, kz) above (coherent packets).
    bool uniform = false;
    T sx{}, sy{}, sz{};
};

template <typename T>
watertight_shear<T> make_watertight_shear(vec3<T> const& dir) {
    watertight_shear<T> s;
    vec3<T> const a = abs(dir);
    if constexpr (simd::simd_width_v<T> == 1) {
        s.kz = (a.x >= a.y && a.x >= a.z) ? 0 : (a.y >= a.z ? 1 : 2);
        s.kx = s.kz == 2 ? 0 : s.kz + 1;
        s.ky = s.kx == 2 ? 0 : s.kx + 1;
        if (dir[s.kz] < T(0)) std::swap(s.kx, s.ky);
    } else {
        s.z_is_x = (a.x >= a.y) & (a.x >= a.z);
        s.z_is_y = !s.z_is_x & (a.y >= a.z);
        T const dz = simd::select(s.z_is_x, dir.x, simd::select(s.z_is_y, dir.y, dir.z));
        s.swap_xy = dz < T(0);
        constexpr std::uint32_t all = (std::uint32_t(1) << simd::simd_width_v<T>) - 1u;
        auto const same = [](std::uint32_t bits) { return bits == 0 || bits == all; };
        std::uint32_t const x = simd::movemask(s.z_is_x), y = simd::movemask(s.z_is_y), swap = simd::movemask(s.swap_xy);
        if (same(x) && same(y) && same(swap)) {
            s.uniform = true;
            s.kz = x != 0 ? 0 : (y != 0 ? 1 : 2);
            s.kx = s.kz == 2 ? 0 : s.kz + 1;
            s.ky = s.kx == 2 ? 0 : s.kx + 1;
            if (swap != 0) std::swap(s.kx, s.ky);
        }
    }
    vec3<T> const d = s.permute(dir);
    s.sx = d.x / d.z;
    s.sy = d.y / d.z;
    s.sz = T(1) / d.z;
    // An infinite dominant component gives sz = 0 and would turn every t into 0: poison the
    // shear so that such rays miss (a NaN edge function fails every comparison).
    s.sx = simd::select(s.sz == T(0), T(std::numeric_limits<simd::scalar_type_t<T>>::quiet_NaN()), s.sx);
    return s;
}

// A ray with its per-ray constants computed once: the inverse direction of the box test and the
// watertight shear (with the origin in the shear's axis order). Traversal hands these to hooks as
// their `Ray`; since it derives from basic_ray, hooks read origin/direction/tmin/tmax as usual and
// `intersect(ray, tri)` inside a hook picks up the cached shear. Results are bit-identical to a
// plain basic_ray. The shear is computed only where primitives are tested (canopy.bvh prepares it
// when the ray reaches its first leaf of primitives, so never for misses or for BVHs of instances
// or of BVHs): has_shear says whether it is there. `instances` points to the traversal's instance path (see instance_ids).
template <typename T>
struct prepared_ray : basic_ray<T> {
    prepared_ray() = default;
    explicit prepared_ray(basic_ray<T> const& r, bool with_shear = true)
        : basic_ray<T>(r), inv_dir(simd::rcp(r.direction.x), simd::rcp(r.direction.y), simd::rcp(r.direction.z)),
          near_origin(r.origin), far_origin(r.origin) {
        if (with_shear) prepare_shear();
    }

    // Makes the ray's box tests conservative with respect to its watertight triangle tests for
    // primitives inside `bounds` (canopy.geometry:box, box_margin_origins). Traversal calls it
    // once per BVH entered with a new ray, with the BVH's bounds (which hold every nested BVH
    // traversed with the same ray).
    template <typename S>
    [[gnu::always_inline]] inline void widen_box_tests_for(basic_aabb<S> const& bounds) {
        box_test_constants(static_cast<basic_ray<T> const&>(*this), inv_dir, bounds, near_origin, far_origin, near_shift,
                           far_shift, slabs);
    }

    // Out of line: called once per ray from inside traversal loops, where inlining it would only
    // add to their register pressure.
    [[gnu::noinline]] void prepare_shear() {
        shear = make_watertight_shear(this->direction);
        permuted_origin = shear.permute(this->origin);
        has_shear = true;
    }

    watertight_shear<T> shear;
    vec3<T> inv_dir;
    vec3<T> near_origin, far_origin; // where box tests measure near and far planes from
    // Added to plane − origin before the product (canopy.geometry:box, box_margin_origins): −0,
    // which changes nothing, except on the axes of origins far from the world origin.
    vec3<T> near_shift{T(-0.0f), T(-0.0f), T(-0.0f)}, far_shift{T(-0.0f), T(-0.0f), T(-0.0f)};
    slab_offsets<T> slabs; // the fused box test's constants (canopy.geometry:box); set by widen_box_tests_for
    vec3<T> permuted_origin;
    bool has_shear = false;
    instance_path const* instances = nullptr;
};

// Lane k of a prepared packet as a prepared scalar ray: the same ray and box-test constants, bit
// for bit, as preparing that lane's ray on its own would give (they are computed lane by lane).
// The shear is left to be prepared at the first leaf, as for any prepared ray.
template <typename T>
prepared_ray<simd::scalar_type_t<T>> prepared_lane(prepared_ray<T> const& ray, int k) {
    prepared_ray<simd::scalar_type_t<T>> r;
    r.origin = get_lane(ray.origin, k);
    r.direction = get_lane(ray.direction, k);
    r.tmin = ray.tmin[k];
    r.tmax = ray.tmax[k];
    r.inv_dir = get_lane(ray.inv_dir, k);
    r.near_origin = get_lane(ray.near_origin, k);
    r.far_origin = get_lane(ray.far_origin, k);
    r.near_shift = get_lane(ray.near_shift, k);
    r.far_shift = get_lane(ray.far_shift, k);
    r.slabs.near_offset = get_lane(ray.slabs.near_offset, k);
    r.slabs.far_offset = get_lane(ray.slabs.far_offset, k);
    r.slabs.usable = ray.slabs.usable[k];
    return r;
}

template <typename Ray>
inline constexpr bool is_prepared_ray_v = false;
template <typename T>
inline constexpr bool is_prepared_ray_v<prepared_ray<T>> = true;

// The ids of the instances the traversal is inside when a hook receives `ray`, outermost first
// (empty outside instances, and for rays that traversal did not prepare: tests over a plain
// range of primitives). Filters read the same ids from the hit record (inst_id, inner_inst_id).
template <typename Ray>
std::span<std::uint32_t const> instance_ids(Ray const& ray) {
    if constexpr (is_prepared_ray_v<Ray>) {
        if (ray.instances != nullptr)
            return std::span<std::uint32_t const>(ray.instances->ids.data(), std::size_t(ray.instances->depth));
    }
    return {};
}

// The box test of traversal: as the plain one, from the ray's widened origins, in the fused form
// where the build has FMA instructions and the ray allows it (slab_offsets), else the subtraction
// form. inv_dir must be the ray's own (traversal passes ray.inv_dir). The 8-wide node test of
// canopy.bvh makes the same choice per ray, so both give the same hits.
template <typename T>
[[gnu::always_inline]] inline bool uses_fused_slabs(prepared_ray<T> const& ray) {
    if constexpr (!simd::native_fma)
        return false;
    else
        return simd::all(ray.slabs.usable);
}

template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline box_hit<T> intersect(prepared_ray<T> const& ray, basic_aabb<S> const& box,
                                                   vec3<T> const& inv_dir) {
    if constexpr (simd::native_fma) {
        if (simd::all(ray.slabs.usable)) return intersect_slabs_fused(ray, box, inv_dir, ray.slabs);
        if constexpr (simd::simd_width_v<T> != 1) {
            if (simd::any(ray.slabs.usable)) {
                auto const fused = intersect_slabs_fused(ray, box, inv_dir, ray.slabs);
                auto const plain = intersect_slabs(ray, box, inv_dir, ray.near_origin, ray.far_origin, ray.near_shift, ray.far_shift);
                auto const& use = ray.slabs.usable;
                return {(use & fused.hit) | (!use & plain.hit), simd::select(use, fused.tnear, plain.tnear),
                        simd::select(use, fused.tfar, plain.tfar)};
            }
        }
    }
    return intersect_slabs(ray, box, inv_dir, ray.near_origin, ray.far_origin, ray.near_shift, ray.far_shift);
}

// The watertight test from the triangle's vertices translated to the ray origin and permuted
// into the shear's axis order (a, b, c): shear, edge functions, t. `degenerate()` is asked only
// for a hit (the exact check in double is the costliest step, and most tests miss).
template <typename T, typename Degenerate>
[[gnu::always_inline]] inline basic_hit_record<T> watertight_from_permuted(basic_ray<T> const& ray,
                                                                           watertight_shear<T> const& shear,
                                                                           vec3<T> const& a, vec3<T> const& b,
                                                                           vec3<T> const& c, std::uint32_t prim_id,
                                                                           std::uint32_t geom_id,
                                                                           Degenerate&& degenerate) {
    basic_hit_record<T> hr;
    T const ax = a.x - shear.sx * a.z, ay = a.y - shear.sy * a.z;
    T const bx = b.x - shear.sx * b.z, by = b.y - shear.sy * b.z;
    T const cx = c.x - shear.sx * c.z, cy = c.y - shear.sy * c.z;

    // Sign-exact edge functions; inside (edges included) when all share a sign.
    T const eu = difference_of_products(cx, by, cy, bx);
    T const ev = difference_of_products(ax, cy, ay, cx);
    T const ew = difference_of_products(bx, ay, by, ax);
    auto const inside = ((eu >= T(0)) & (ev >= T(0)) & (ew >= T(0))) |
                        ((eu <= T(0)) & (ev <= T(0)) & (ew <= T(0)));
    if (simd::none(inside)) return hr;

    T const det = eu + ev + ew;
    T const scaled_t = eu * (shear.sz * a.z) + ev * (shear.sz * b.z) + ew * (shear.sz * c.z);
    T const t = scaled_t / det;
    auto const hit = inside & (det != T(0)) & (t >= ray.tmin) & (t <= ray.tmax);
    if (simd::none(hit) || degenerate()) return hr;

    record_hit(hr, hit, t, ev / det, ew / det, prim_id, geom_id);
    return hr;
}

// v − origin in the shear's axis order, for a SIMD ray whose lanes share one permutation
// (shear.uniform): the vertex's components are picked before they are broadcast, with the origin
// permuted once per ray. The same values as shear.permute(vec3<T>(v) − origin), with no per-lane
// selects.
// The vertex's component k is v[k * stride].
template <typename T, typename S>
[[gnu::always_inline]] inline vec3<T> uniformly_permuted(watertight_shear<T> const& shear, S const* v,
                                                         std::size_t stride, vec3<T> const& permuted_origin) {
    auto const at = [&](int k) { return T(v[std::size_t(k) * stride]); };
    return {at(shear.kx) - permuted_origin.x, at(shear.ky) - permuted_origin.y, at(shear.kz) - permuted_origin.z};
}

// Woop et al.'s test for a ray whose shear is already known (and its origin permuted by it).
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline basic_hit_record<T> intersect_watertight(basic_ray<T> const& ray,
                                                                       watertight_shear<T> const& shear,
                                                                       vec3<T> const& permuted_origin,
                                                                       basic_triangle<S> const& tri) {
    auto const degenerate = [&] { return is_degenerate(tri); };
    if constexpr (simd::simd_width_v<T> != 1) {
        if (shear.uniform) {
            S const v0[3] = {tri.v0.x, tri.v0.y, tri.v0.z}, v1[3] = {tri.v1.x, tri.v1.y, tri.v1.z},
                    v2[3] = {tri.v2.x, tri.v2.y, tri.v2.z};
            return watertight_from_permuted(ray, shear, uniformly_permuted(shear, v0, 1, permuted_origin),
                                            uniformly_permuted(shear, v1, 1, permuted_origin),
                                            uniformly_permuted(shear, v2, 1, permuted_origin), tri.prim_id,
                                            tri.geom_id, degenerate);
        }
    }
    // Translate to the ray origin, permute (each vertex on its own).
    return watertight_from_permuted(ray, shear, shear.permute(vec3<T>(tri.v0) - ray.origin),
                                    shear.permute(vec3<T>(tri.v1) - ray.origin),
                                    shear.permute(vec3<T>(tri.v2) - ray.origin), tri.prim_id, tri.geom_id, degenerate);
}

// Watertight ray/triangle test (the default).
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
basic_hit_record<T> intersect(basic_ray<T> const& ray, basic_triangle<S> const& tri) {
    auto const shear = make_watertight_shear(ray.direction);
    return intersect_watertight(ray, shear, shear.permute(ray.origin), tri);
}

template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::always_inline]] inline basic_hit_record<T> intersect(prepared_ray<T> const& ray, basic_triangle<S> const& tri) {
    return intersect_watertight(ray, ray.shear, ray.permuted_origin, tri);
}

// Möller & Trumbore 1997, "Fast, Minimum Storage Ray/Triangle Intersection" (opt-in; not
// watertight: rays through shared edges can miss both triangles). Out of line: its products and
// sums are not written as explicit fma, so a build with -ffp-contract=fast (which overrides the
// pragma above) could fuse them differently where it is inlined; one body gives the same result
// to a BVH's leaves and to a loop over the triangles.
template <typename T, typename S>
    requires std::is_same_v<simd::scalar_type_t<T>, S>
[[gnu::noinline]] basic_hit_record<T> intersect_moller_trumbore(basic_ray<T> const& ray, basic_triangle<S> const& tri) {
    basic_hit_record<T> hr;
    vec3<T> const e1(tri.v1 - tri.v0);
    vec3<T> const e2(tri.v2 - tri.v0);
    vec3<T> const p = cross(ray.direction, e2);
    T const det = dot(e1, p);
    T const inv_det = T(1) / det;
    vec3<T> const s = ray.origin - vec3<T>(tri.v0);
    T const u = dot(s, p) * inv_det;
    vec3<T> const q = cross(s, e1);
    T const v = dot(ray.direction, q) * inv_det;
    T const t = dot(e2, q) * inv_det;
    auto const hit = (det != T(0)) & (u >= T(0)) & (v >= T(0)) & (u + v <= T(1)) & (t >= ray.tmin) &
                     (t <= ray.tmax);
    if (simd::none(hit) || is_degenerate(tri)) return hr;
    record_hit(hr, hit, t, u, v, tri.prim_id, tri.geom_id);
    return hr;
}

} // namespace canopy
