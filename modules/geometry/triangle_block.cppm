// canopy.geometry:triangle_block — triangles stored structure-of-arrays in blocks of
// triangle_block_width (8 with AVX2, else 4), tested against one ray at once (the layout of
// Embree's triangle4; Wald et al. 2008, "Getting Rid of Packets").
//
// A block holds the triangles exactly as given (vertices, prim_id, geom_id): triangle_at(lane)
// gives back the very triangle, so hooks that see one triangle at a time are fed from blocks.
// Lanes past a leaf's last triangle are unused. `testable` marks the used lanes whose triangle
// is not degenerate (is_degenerate, exact in double, decided once when the block is filled):
// the block test never reports the others, as the one-triangle test never reports a degenerate
// triangle. A block is 192 bytes (four lanes) or 384 (eight): whole cache lines.
//
// The block test is the watertight test of canopy.geometry:triangle (Woop, Benthin, Wald 2013)
// run lane by lane with the same operations in the same order, so each lane's hit, t, u and v are
// bit-identical to intersect(ray, triangle(lane)): same translation, permutation and shear of each
// vertex, the same Kahan difference of products for the edge functions, the same divisions. The
// degenerate-triangle check (zero area, exact in double) is left to the caller, for the lanes it
// reports, as the scalar test does it only for hits.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <array>
#include <bit>
#include <canopy/check.hpp>
#include <cstdint>
#include <limits>
#include <vector>
export module canopy.geometry:triangle_block;
import canopy.math;
import :hit_record;
import :triangle;

export namespace canopy {

// Eight triangles to a block where 8-lane vectors are native (AVX2, AVX-512), else four: measured
// on a 1.3M-triangle mesh (AVX-512 machine, 1 thread), eight against four gave primary closest
// 141 → 117 ns per ray, random closest 505 → 434, shadow any 362 → 297 (fewer, fuller leaves:
// 123k → 40k wide nodes); sixteen gave 116, 506 and 269.
inline constexpr int triangle_block_width = simd::native_width<8> ? 8 : 4;
using block_float = simd::basic_simd<float, triangle_block_width>;
using block_mask = simd::basic_mask<triangle_block_width>;

struct alignas(64) triangle_block {
    using lanes = std::array<float, triangle_block_width>;
    // vertex[k][c][lane]: component c (x, y, z) of vertex k (v0, v1, v2).
    std::array<std::array<lanes, 3>, 3> vertex;
    // A block made with {} (or by a vector's resize) holds no triangle: zero vertices, invalid ids,
    // no lane testable; set() fills a lane.
    std::array<std::uint32_t, triangle_block_width> prim_id = invalid_ids();
    std::array<std::uint32_t, triangle_block_width> geom_id = invalid_ids();
    std::uint32_t testable = 0; // bit i: lane i holds a triangle that is not degenerate

    // (inline: member functions in a named module are not implicitly inline.)
    // lane in [0, triangle_block_width) for both.
    [[gnu::always_inline]] inline triangle triangle_at(int lane) const {
        CANOPY_DCHECK(lane >= 0 && lane < triangle_block_width, "triangle_block: lane in [0, triangle_block_width)");
        auto const l = std::size_t(lane);
        auto const v = [&](std::size_t k) { return vec3<float>(vertex[k][0][l], vertex[k][1][l], vertex[k][2][l]); };
        return {v(0), v(1), v(2), prim_id[l], geom_id[l]};
    }

    static constexpr std::array<std::uint32_t, triangle_block_width> invalid_ids() {
        std::array<std::uint32_t, triangle_block_width> ids;
        ids.fill(invalid_id);
        return ids;
    }

    inline void set(int lane, triangle const& t) {
        CANOPY_DCHECK(lane >= 0 && lane < triangle_block_width, "triangle_block: lane in [0, triangle_block_width)");
        auto const l = std::size_t(lane);
        vec3<float> const v[3] = {t.v0, t.v1, t.v2};
        for (std::size_t k = 0; k < 3; ++k)
            for (int c = 0; c < 3; ++c) vertex[k][std::size_t(c)][l] = v[k][c];
        prim_id[l] = t.prim_id;
        geom_id[l] = t.geom_id;
        if (is_degenerate(t))
            testable &= ~(1u << lane);
        else
            testable |= 1u << lane;
    }
};

// Blocks holding the triangles [first, last) in order, triangle_block_width to a block; unused
// lanes of the last block hold zero vertices and invalid ids and are never tested.
template <typename It>
void append_triangle_blocks(std::vector<triangle_block>& blocks, It first, It last) {
    for (int lane = triangle_block_width; first != last; ++first, ++lane) {
        if (lane == triangle_block_width) {
            blocks.push_back({});
            lane = 0;
        }
        blocks.back().set(lane, *first);
    }
}

// The candidates of one block test: bit i of `mask` set when lane i hits, with t in [tmin, tmax];
// the edge functions ev, ew and the determinant give u = ev / det, v = ew / det.
struct triangle_block_hits {
    std::uint32_t mask = 0;
    std::array<float, triangle_block_width> t, ev, ew, det;

    // The record of lane i as intersect(ray, triangle) returns it for that triangle.
    [[gnu::always_inline]] inline basic_hit_record<float> record(triangle_block const& b, int i) const {
        auto const l = std::size_t(i);
        basic_hit_record<float> hr;
        record_hit(hr, true, t[l], ev[l] / det[l], ew[l] / det[l], b.prim_id[l], b.geom_id[l]);
        return hr;
    }
};

// What the block test needs of one ray: its watertight shear (the axis permutation and the
// shear constants), its origin in the permuted axis order, and [tmin, tmax]. From a scalar
// prepared ray, or from one lane of a packet whose lanes share the permutation
// (intersect_block_by_lanes).
struct block_test_ray {
    std::size_t kx, ky, kz;
    float ox, oy, oz;
    float sx, sy, sz;
    float tmin, tmax;
};

// The testable lanes of b against one ray. Lane by lane the operations of intersect_watertight
// (canopy.geometry:triangle), in the same order.
[[gnu::always_inline]] inline triangle_block_hits intersect_block(block_test_ray const& ray, triangle_block const& b) {
    using V = block_float;
    triangle_block_hits h;
    auto const kx = ray.kx, ky = ray.ky, kz = ray.kz;
    V const ox(ray.ox), oy(ray.oy), oz(ray.oz);
    V const sx(ray.sx), sy(ray.sy), sz(ray.sz);

    // Translate to the ray origin, permute, shear (each vertex on its own).
    auto const sheared = [&](std::size_t k, V& x, V& y, V& z) {
        z = V::load(b.vertex[k][kz].data()) - oz;
        x = (V::load(b.vertex[k][kx].data()) - ox) - sx * z;
        y = (V::load(b.vertex[k][ky].data()) - oy) - sy * z;
    };
    V ax, ay, az, bx, by, bz, cx, cy, cz;
    sheared(0, ax, ay, az);
    sheared(1, bx, by, bz);
    sheared(2, cx, cy, cz);

    // Sign-exact edge functions; inside (edges included) when all share a sign.
    V const eu = difference_of_products(cx, by, cy, bx);
    V const ev = difference_of_products(ax, cy, ay, cx);
    V const ew = difference_of_products(bx, ay, by, ax);
    V const zero(0.0f);
    auto const inside = block_mask::from_bits(b.testable) & (((eu >= zero) & (ev >= zero) & (ew >= zero)) | ((eu <= zero) & (ev <= zero) & (ew <= zero)));
    if (simd::none(inside)) return h;

    V const det = eu + ev + ew;
    V const scaled_t = eu * (sz * az) + ev * (sz * bz) + ew * (sz * cz);
    V const t = scaled_t / det;
    auto const hit = inside & (det != zero) & (t >= V(ray.tmin)) & (t <= V(ray.tmax));
    h.mask = simd::movemask(hit);
    if (h.mask == 0) return h;
    t.store(h.t.data());
    ev.store(h.ev.data());
    ew.store(h.ew.data());
    det.store(h.det.data());
    return h;
}

// The testable lanes of b against a prepared ray (its watertight shear and permuted origin
// known). Lane by lane the operations of intersect_watertight (canopy.geometry:triangle), in the
// same order. The same body as the block_test_ray form above, kept as it is written here: built
// with -ffp-contract=fast (which overrides this file's pragma) the scalar paths then still round
// as the one-triangle test does, which the contract-fast preset's stress tests check; calling the
// other form made 83 of its hit-iff-tmin-≤-t-≤-tmax checks fail there.
[[gnu::always_inline]] inline triangle_block_hits intersect_block(prepared_ray<float> const& ray,
                                                                  triangle_block const& b) {
    using V = block_float;
    triangle_block_hits h;
    auto const& shear = ray.shear;
    auto const kx = std::size_t(shear.kx), ky = std::size_t(shear.ky), kz = std::size_t(shear.kz);
    V const ox(ray.permuted_origin.x), oy(ray.permuted_origin.y), oz(ray.permuted_origin.z);
    V const sx(shear.sx), sy(shear.sy), sz(shear.sz);

    // Translate to the ray origin, permute, shear (each vertex on its own).
    auto const sheared = [&](std::size_t k, V& x, V& y, V& z) {
        z = V::load(b.vertex[k][kz].data()) - oz;
        x = (V::load(b.vertex[k][kx].data()) - ox) - sx * z;
        y = (V::load(b.vertex[k][ky].data()) - oy) - sy * z;
    };
    V ax, ay, az, bx, by, bz, cx, cy, cz;
    sheared(0, ax, ay, az);
    sheared(1, bx, by, bz);
    sheared(2, cx, cy, cz);

    // Sign-exact edge functions; inside (edges included) when all share a sign.
    V const eu = difference_of_products(cx, by, cy, bx);
    V const ev = difference_of_products(ax, cy, ay, cx);
    V const ew = difference_of_products(bx, ay, by, ax);
    V const zero(0.0f);
    auto const inside = block_mask::from_bits(b.testable) & (((eu >= zero) & (ev >= zero) & (ew >= zero)) | ((eu <= zero) & (ev <= zero) & (ew <= zero)));
    if (simd::none(inside)) return h;

    V const det = eu + ev + ew;
    V const scaled_t = eu * (sz * az) + ev * (sz * bz) + ew * (sz * cz);
    V const t = scaled_t / det;
    auto const hit = inside & (det != zero) & (t >= V(ray.tmin)) & (t <= V(ray.tmax));
    h.mask = simd::movemask(hit);
    if (h.mask == 0) return h;
    t.store(h.t.data());
    ev.store(h.ev.data());
    ew.store(h.ew.data());
    det.store(h.det.data());
    return h;
}

// The lanes of b in `used` (a leaf's triangles) of a packet whose lanes share one shear
// permutation (ray.shear.uniform), tested lane by lane of the packet instead of triangle by
// triangle: each lane in `live` runs the block test of a scalar ray (intersect_block) with its own
// shear constants, permuted origin, tmin and tmax. The same operations on the same values as
// intersect_lane, so every (lane, triangle) pair hits or misses alike, with the same t, u and v.
// Each lane's record holds one of its hits: the first in block order when !Nearest (what an
// any-hit query keeps, testing the triangles in order), else the one with the smallest t, then
// the smallest prim_id (what a closest-hit query keeps: its rule, canopy.query:single, among hits
// of one leaf, which share the instance path). Cheaper than the triangle-by-triangle loop when
// fewer lanes take part than the block has triangles (a packet's lanes that did not reach the leaf,
// or finished, have tmax −inf and are not in `live`).
template <bool Nearest, typename T>
    requires(simd::simd_width_v<T> > 1)
[[gnu::always_inline]] inline basic_hit_record<T> intersect_block_by_lanes(prepared_ray<T> const& ray,
                                                                           triangle_block const& b,
                                                                           std::uint32_t used, std::uint32_t live) {
    constexpr int W = simd::simd_width_v<T>;
    using index_t = index_type_t<T>;
    alignas(64) std::array<float, W> ox, oy, oz, sx, sy, sz, tmin, tmax;
    ray.permuted_origin.x.store(ox.data());
    ray.permuted_origin.y.store(oy.data());
    ray.permuted_origin.z.store(oz.data());
    ray.shear.sx.store(sx.data());
    ray.shear.sy.store(sy.data());
    ray.shear.sz.store(sz.data());
    ray.tmin.store(tmin.data());
    ray.tmax.store(tmax.data());
    alignas(64) std::array<float, W> t, u, v;
    alignas(64) std::array<std::int32_t, W> prim, geom;
    std::uint32_t hit = 0;
    auto const kx = std::size_t(ray.shear.kx), ky = std::size_t(ray.shear.ky), kz = std::size_t(ray.shear.kz);
    for (; live != 0; live &= live - 1) {
        auto const k = std::size_t(std::countr_zero(live));
        auto const h = intersect_block(block_test_ray{kx, ky, kz, ox[k], oy[k], oz[k], sx[k], sy[k], sz[k], tmin[k], tmax[k]}, b);
        std::uint32_t const mask = h.mask & used;
        if (mask == 0) continue;
        int lane = std::countr_zero(mask);
        if constexpr (Nearest) {
            for (std::uint32_t rest = mask & (mask - 1); rest != 0; rest &= rest - 1) {
                int const other = std::countr_zero(rest);
                auto const o = std::size_t(other), l = std::size_t(lane);
                if (h.t[o] < h.t[l] || (h.t[o] == h.t[l] && b.prim_id[o] < b.prim_id[l])) lane = other;
            }
        }
        auto const l = std::size_t(lane);
        hit |= 1u << k;
        t[k] = h.t[l];
        u[k] = h.ev[l] / h.det[l];
        v[k] = h.ew[l] / h.det[l];
        prim[k] = std::int32_t(b.prim_id[l]);
        geom[k] = std::int32_t(b.geom_id[l]);
    }
    basic_hit_record<T> hr;
    if (hit == 0) return hr;
    hr.hit = simd::mask_type_t<T>::from_bits(hit);
    hr.t = simd::select(hr.hit, T::load(t.data()), hr.t);
    hr.u = simd::select(hr.hit, T::load(u.data()), T(0));
    hr.v = simd::select(hr.hit, T::load(v.data()), T(0));
    hr.prim_id = simd::select(hr.hit, index_t::load(prim.data()), hr.prim_id);
    hr.geom_id = simd::select(hr.hit, index_t::load(geom.data()), hr.geom_id);
    return hr;
}

// Lane `lane` of b against a SIMD ray (a packet): what intersect(ray, b.triangle_at(lane)) returns,
// bit for bit. When the packet's lanes share one shear permutation (coherent packets), the
// vertex components are read from the block in that order and broadcast, with no per-lane
// selects; the lane's degenerate flag is the block's (`testable`).
template <typename T>
[[gnu::always_inline]] inline basic_hit_record<T> intersect_lane(prepared_ray<T> const& ray, triangle_block const& b,
                                                                 int lane) {
    if (!ray.shear.uniform) return intersect(ray, b.triangle_at(lane));
    auto const l = std::size_t(lane);
    constexpr auto stride = std::size_t(triangle_block_width);
    auto const vertex = [&](std::size_t k) {
        return uniformly_permuted(ray.shear, &b.vertex[k][0][l], stride, ray.permuted_origin);
    };
    return watertight_from_permuted(ray, ray.shear, vertex(0), vertex(1), vertex(2), b.prim_id[l], b.geom_id[l],
                                    [&] { return (b.testable >> lane & 1u) == 0; });
}

} // namespace canopy
