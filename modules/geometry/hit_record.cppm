// canopy.geometry:hit_record — what every ray/primitive test returns.
//
// For scalar rays `hit` is a bool and the ids are std::uint32_t; for SIMD rays (T = float8, ...)
// `hit` is a mask and every field is a SIMD type with one lane per ray.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <array>
#include <canopy/check.hpp>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>
export module canopy.geometry:hit_record;
import canopy.math;

export namespace canopy {

// Id of "no primitive / no instance": 0xffffffff (all bits set, -1 in SIMD int lanes).
inline constexpr std::uint32_t invalid_id = ~0u;

// Deepest instance nesting a hit record reports (outermost plus inner levels).
inline constexpr int max_instance_depth = 4;

// Integer type of ids for scalar type T: std::uint32_t for scalars, int8 for float8, ...
template <typename T>
using index_type_t = std::conditional_t<simd::simd_width_v<T> == 1, std::uint32_t, simd::int_type_t<T>>;

template <typename T>
struct basic_hit_record {
    using value_type = T;
    using index_type = index_type_t<T>;

    simd::mask_type_t<T> hit{};
    T t{std::numeric_limits<simd::scalar_type_t<T>>::infinity()};
    index_type prim_id{index_type(invalid_id)};
    index_type geom_id{index_type(invalid_id)};
    // Outermost instance on the path to the hit (invalid_id when not instanced).
    index_type inst_id{index_type(invalid_id)};
    // Instances below the outermost: inner_inst_id[0] is one level down, and so on; invalid_id
    // past the innermost. Filled when a query accepts the hit (hooks see them unset).
    std::array<index_type, max_instance_depth - 1> inner_inst_id{
        index_type(invalid_id), index_type(invalid_id), index_type(invalid_id)};
    // Barycentric weights of the primitive's 2nd and 3rd vertex (triangles).
    T u{};
    T v{};
};

// Scalar type of a ray: float, double, float8, ...
template <typename Ray>
using ray_value_t = std::remove_cvref_t<decltype(std::declval<Ray const&>().tmin)>;

// The paper's spelling: the record a test of Ray against Prim returns.
template <typename Ray, typename Prim>
using hit_record = basic_hit_record<ray_value_t<Ray>>;

// The ids of the instances a traversal has entered, outermost first: queries keep one and copy
// it into the hit records they accept; hooks read the current one through instance_ids(ray).
// Preconditions: at most max_instance_depth instances entered at once (the queries check the
// nesting of the library's own structures at compile time; a structure of the user's own must
// keep to it), and each leave_instance after its enter_instance.
struct instance_path {
    // ids[k] for k < depth; the entries past depth hold invalid_id, so that stamping a record is a
    // plain copy.
    std::array<std::uint32_t, max_instance_depth> ids = [] {
        std::array<std::uint32_t, max_instance_depth> a;
        a.fill(invalid_id);
        return a;
    }();
    int depth = 0;

    // (inline: member functions in a named module are not implicitly inline, and these run at
    // every instance entry.)
    inline void enter_instance(std::uint32_t id) {
        CANOPY_DCHECK(depth < max_instance_depth, "enter_instance: instances nest deeper than max_instance_depth");
        ids[std::size_t(depth++)] = id;
    }
    inline void leave_instance() {
        CANOPY_DCHECK(depth > 0, "leave_instance: no instance entered");
        ids[std::size_t(--depth)] = invalid_id;
    }

    template <typename T>
    inline void stamp(basic_hit_record<T>& hr) const {
        using index_t = index_type_t<T>;
        hr.inst_id = index_t(ids[0]);
        for (std::size_t k = 1; k < max_instance_depth; ++k) hr.inner_inst_id[k - 1] = index_t(ids[k]);
    }
};

// Writes a hit into the lanes of hr where `hit` is set (for scalar rays: hit is true).
template <typename T>
[[gnu::always_inline]] inline void record_hit(basic_hit_record<T>& hr, simd::mask_type_t<T> const& hit, T t,
                                              T u, T v, std::uint32_t prim_id, std::uint32_t geom_id) {
    if constexpr (simd::simd_width_v<T> == 1) {
        hr.hit = hit;
        hr.t = t;
        hr.u = u;
        hr.v = v;
        hr.prim_id = prim_id;
        hr.geom_id = geom_id;
    } else {
        using index_t = index_type_t<T>;
        hr.hit = hit;
        hr.t = simd::select(hit, t, hr.t);
        hr.u = simd::select(hit, u, T(0));
        hr.v = simd::select(hit, v, T(0));
        hr.prim_id = simd::select(hit, index_t(std::int32_t(prim_id)), hr.prim_id);
        hr.geom_id = simd::select(hit, index_t(std::int32_t(geom_id)), hr.geom_id);
    }
}

// Lane k of a packet's record as the record of a scalar ray, and back.
template <typename T>
basic_hit_record<simd::scalar_type_t<T>> record_lane(basic_hit_record<T> const& p, int k) {
    basic_hit_record<simd::scalar_type_t<T>> r;
    r.hit = p.hit[k];
    r.t = p.t[k];
    r.u = p.u[k];
    r.v = p.v[k];
    r.prim_id = std::uint32_t(p.prim_id[k]);
    r.geom_id = std::uint32_t(p.geom_id[k]);
    r.inst_id = std::uint32_t(p.inst_id[k]);
    for (std::size_t d = 0; d < r.inner_inst_id.size(); ++d) r.inner_inst_id[d] = std::uint32_t(p.inner_inst_id[d][k]);
    return r;
}

// The records of an 8-lane packet's lanes written to out, lane k to out[k / 4 * row_stride + k % 4]
// (row_stride 4: out[0, 8); the batch queries' squares of 4 × 2 rays: the rows' length), each what
// record_lane(p, k) gives (how the batch queries return a packet's results): the eight 32-bit members that lead a scalar
// record (hit as 0 or 1, t, prim_id, geom_id, inst_id, inner_inst_id) by one 8 × 8 transposition
// and one 32-byte copy per record, then u and v lane by lane (record_lane, once per lane, extracts
// all ten members one at a time: 160 instructions a packet). Kept beside record_lane: a member
// added to the record must be added to both (the static_assert below pins the layout).
[[gnu::always_inline]] inline void write_lane_records(basic_hit_record<simd::float8> const& p, basic_hit_record<float>* out,
                                                      std::size_t row_stride = 4) {
    using R = basic_hit_record<float>;
    static_assert(std::is_trivially_copyable_v<R> && std::is_standard_layout_v<R> && sizeof(bool) == 1 &&
                      offsetof(R, hit) == 0 && offsetof(R, t) == 4 && offsetof(R, prim_id) == 8 &&
                      offsetof(R, geom_id) == 12 && offsetof(R, inst_id) == 16 && offsetof(R, inner_inst_id) == 20 &&
                      sizeof(R::inner_inst_id) == 12 && offsetof(R, u) == 32 && offsetof(R, v) == 36 && sizeof(R) == 40,
                  "write_lane_records: a scalar record is eight leading 32-bit members, then u and v");
    std::array<simd::float8, 8> rows{
        simd::as_float(simd::select(p.hit, simd::int8(1), simd::int8(0))),
        p.t,
        simd::as_float(p.prim_id),
        simd::as_float(p.geom_id),
        simd::as_float(p.inst_id),
        simd::as_float(p.inner_inst_id[0]),
        simd::as_float(p.inner_inst_id[1]),
        simd::as_float(p.inner_inst_id[2])};
    simd::transpose(rows);
    for (std::size_t k = 0; k < 8; ++k) {
        std::array<float, 8> lead;
        rows[k].store(lead.data());
        R* const o = out + k / 4 * row_stride + k % 4;
        std::memcpy(static_cast<void*>(o), lead.data(), sizeof(lead));
        o->u = p.u[int(k)];
        o->v = p.v[int(k)];
    }
}

// The records of a 16-lane packet's lanes written to out, lane k to out[k / 4 * row_stride + k % 4]
// (the batch queries' squares of 4 × 4 rays: row_stride is the rows' length), each what
// record_lane(p, k) gives: lanes 0-7 and 8-15 as two 8-lane records, each written by the 8-lane
// write_lane_records (its rows of 4 rays row_stride apart).
[[gnu::always_inline]] inline void write_lane_records(basic_hit_record<simd::float16> const& p, basic_hit_record<float>* out,
                                                      std::size_t row_stride) {
    std::array<basic_hit_record<simd::float8>, 2> half;
    auto const split = [](auto const& wide, auto& low, auto& high) {
        using narrow = std::remove_cvref_t<decltype(low)>;
        alignas(64) std::array<typename narrow::value_type, 16> lanes;
        wide.store(lanes.data());
        low = narrow::load(lanes.data());
        high = narrow::load(lanes.data() + 8);
    };
    std::uint32_t const hit = simd::movemask(p.hit);
    half[0].hit = simd::mask8::from_bits(hit & 0xffu);
    half[1].hit = simd::mask8::from_bits(hit >> 8);
    split(p.t, half[0].t, half[1].t);
    split(p.u, half[0].u, half[1].u);
    split(p.v, half[0].v, half[1].v);
    split(p.prim_id, half[0].prim_id, half[1].prim_id);
    split(p.geom_id, half[0].geom_id, half[1].geom_id);
    split(p.inst_id, half[0].inst_id, half[1].inst_id);
    for (std::size_t d = 0; d < p.inner_inst_id.size(); ++d) split(p.inner_inst_id[d], half[0].inner_inst_id[d], half[1].inner_inst_id[d]);
    write_lane_records(half[0], out, row_stride);
    write_lane_records(half[1], out + 2 * row_stride, row_stride);
}

template <typename T>
void set_record_lane(basic_hit_record<T>& p, int k, basic_hit_record<simd::scalar_type_t<T>> const& r) {
    p.hit.set(k, r.hit);
    p.t.set(k, r.t);
    p.u.set(k, r.u);
    p.v.set(k, r.v);
    p.prim_id.set(k, std::int32_t(r.prim_id));
    p.geom_id.set(k, std::int32_t(r.geom_id));
    p.inst_id.set(k, std::int32_t(r.inst_id));
    for (std::size_t d = 0; d < r.inner_inst_id.size(); ++d) p.inner_inst_id[d].set(k, std::int32_t(r.inner_inst_id[d]));
}

// Lane-wise choice between two records: m ? a : b.
template <typename T>
basic_hit_record<T> select(simd::mask_type_t<T> const& m, basic_hit_record<T> const& a,
                           basic_hit_record<T> const& b) {
    if constexpr (simd::simd_width_v<T> == 1) {
        return m ? a : b;
    } else {
        basic_hit_record<T> r;
        r.hit = (m & a.hit) | (!m & b.hit);
        r.t = simd::select(m, a.t, b.t);
        r.prim_id = simd::select(m, a.prim_id, b.prim_id);
        r.geom_id = simd::select(m, a.geom_id, b.geom_id);
        r.inst_id = simd::select(m, a.inst_id, b.inst_id);
        for (int i = 0; i < max_instance_depth - 1; ++i)
            r.inner_inst_id[i] = simd::select(m, a.inner_inst_id[i], b.inner_inst_id[i]);
        r.u = simd::select(m, a.u, b.u);
        r.v = simd::select(m, a.v, b.v);
        return r;
    }
}

} // namespace canopy
