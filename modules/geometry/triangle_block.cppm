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

// The testable lanes of b against a prepared ray (its watertight shear and permuted origin
// known). Lane by lane the operations of intersect_watertight (canopy.geometry:triangle), in the
// same order.
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
