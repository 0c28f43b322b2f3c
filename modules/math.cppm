// canopy.math: small vectors and matrices, affine transforms, axis-aligned boxes, rays and
// floating-point ULP helpers.
//
// Every template over T accepts T = float, double or a canopy.simd type (one lane per ray).
// Arithmetic on T goes only through T's operators and the canopy::simd free functions, so lane i
// of a vec3<simd::float8> result is bit-identical to the same computation on vec3<float>.
// Comparisons return simd::mask_type_t<T> (bool for scalars). Nothing here throws.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <array>
#include <bit>
#include <canopy/check.hpp>
#include <concepts>
#include <cstdint>
#include <limits>
#include <type_traits>
export module canopy.math;
export import canopy.simd;

export namespace canopy {

template <typename T> struct vec2 {
    using value_type = T;
    T x{}, y{};

    constexpr vec2() = default;
    constexpr vec2(T x, T y) : x(x), y(y) {}
    explicit constexpr vec2(T s) : x(s), y(s) {}
    template <typename U> explicit constexpr vec2(vec2<U> const& v) : x(T(v.x)), y(T(v.y)) {}

    // Precondition: 0 <= i < 2.
    constexpr T& operator[](int i) { return i == 0 ? x : y; }
    constexpr T const& operator[](int i) const { return i == 0 ? x : y; }
};

template <typename T> struct vec3 {
    using value_type = T;
    T x{}, y{}, z{};

    constexpr vec3() = default;
    constexpr vec3(T x, T y, T z) : x(x), y(y), z(z) {}
    explicit constexpr vec3(T s) : x(s), y(s), z(s) {}
    template <typename U> explicit constexpr vec3(vec3<U> const& v) : x(T(v.x)), y(T(v.y)), z(T(v.z)) {}

    // Precondition: 0 <= i < 3.
    constexpr T& operator[](int i) { return i == 0 ? x : i == 1 ? y : z; }
    constexpr T const& operator[](int i) const { return i == 0 ? x : i == 1 ? y : z; }
};

template <typename T> struct vec4 {
    using value_type = T;
    T x{}, y{}, z{}, w{};

    constexpr vec4() = default;
    constexpr vec4(T x, T y, T z, T w) : x(x), y(y), z(z), w(w) {}
    explicit constexpr vec4(T s) : x(s), y(s), z(s), w(s) {}
    constexpr vec4(vec3<T> const& v, T w) : x(v.x), y(v.y), z(v.z), w(w) {}
    template <typename U>
    explicit constexpr vec4(vec4<U> const& v) : x(T(v.x)), y(T(v.y)), z(T(v.z)), w(T(v.w)) {}

    // Precondition: 0 <= i < 4.
    constexpr T& operator[](int i) { return i == 0 ? x : i == 1 ? y : i == 2 ? z : w; }
    constexpr T const& operator[](int i) const { return i == 0 ? x : i == 1 ? y : i == 2 ? z : w; }

    constexpr vec3<T> xyz() const { return {x, y, z}; }
};

} // namespace canopy

namespace canopy::detail {

template <typename V> struct vector_traits : std::false_type {};
template <typename T> struct vector_traits<vec2<T>> : std::true_type {
    static constexpr int size = 2;
    template <typename U> using rebind = vec2<U>;
};
template <typename T> struct vector_traits<vec3<T>> : std::true_type {
    static constexpr int size = 3;
    template <typename U> using rebind = vec3<U>;
};
template <typename T> struct vector_traits<vec4<T>> : std::true_type {
    static constexpr int size = 4;
    template <typename U> using rebind = vec4<U>;
};

template <typename V>
concept vector = vector_traits<V>::value;

// The constant c (exactly representable in T's scalar type) in every lane of T.
template <typename T> constexpr T splat(double c) { return T(static_cast<simd::scalar_type_t<T>>(c)); }

template <typename M> constexpr M mask_and(M const& a, M const& b) {
    if constexpr (std::same_as<M, bool>)
        return a && b;
    else
        return a & b;
}

template <typename M> constexpr M mask_or(M const& a, M const& b) {
    if constexpr (std::same_as<M, bool>)
        return a || b;
    else
        return a | b;
}

// Lane i of v; a scalar is its own lane 0.
template <typename T> constexpr simd::scalar_type_t<T> lane(T const& v, [[maybe_unused]] int i) {
    if constexpr (simd::simd_type<T>)
        return v[i];
    else
        return v;
}

template <typename T> constexpr void set_lane(T& v, [[maybe_unused]] int i, simd::scalar_type_t<T> s) {
    if constexpr (simd::simd_type<T>)
        v.set(i, s);
    else
        v = s;
}

// Component-wise application of f, and the left-to-right fold of f over the components.
template <typename T, typename F> constexpr vec2<T> map(vec2<T> const& a, F f) { return {f(a.x), f(a.y)}; }
template <typename T, typename F> constexpr vec3<T> map(vec3<T> const& a, F f) {
    return {f(a.x), f(a.y), f(a.z)};
}
template <typename T, typename F> constexpr vec4<T> map(vec4<T> const& a, F f) {
    return {f(a.x), f(a.y), f(a.z), f(a.w)};
}

template <typename T, typename F> constexpr vec2<T> zip(vec2<T> const& a, vec2<T> const& b, F f) {
    return {f(a.x, b.x), f(a.y, b.y)};
}
template <typename T, typename F> constexpr vec3<T> zip(vec3<T> const& a, vec3<T> const& b, F f) {
    return {f(a.x, b.x), f(a.y, b.y), f(a.z, b.z)};
}
template <typename T, typename F> constexpr vec4<T> zip(vec4<T> const& a, vec4<T> const& b, F f) {
    return {f(a.x, b.x), f(a.y, b.y), f(a.z, b.z), f(a.w, b.w)};
}

template <typename T, typename F> constexpr auto fold(vec2<T> const& a, F f) { return f(a.x, a.y); }
template <typename T, typename F> constexpr auto fold(vec3<T> const& a, F f) { return f(f(a.x, a.y), a.z); }
template <typename T, typename F> constexpr auto fold(vec4<T> const& a, F f) {
    return f(f(f(a.x, a.y), a.z), a.w);
}

// combine(...combine(predicate(v[0]), predicate(v[1]))..., predicate(v[n-1])).
template <vector V, typename P, typename C> constexpr auto reduce_mask(V const& v, P predicate, C combine) {
    auto m = predicate(v[0]);
    for (int k = 1; k < vector_traits<V>::size; ++k)
        m = combine(m, predicate(v[k]));
    return m;
}

inline constexpr auto plus = [](auto const& a, auto const& b) { return a + b; };
inline constexpr auto minus = [](auto const& a, auto const& b) { return a - b; };
inline constexpr auto times = [](auto const& a, auto const& b) { return a * b; };
inline constexpr auto divides = [](auto const& a, auto const& b) { return a / b; };

template <typename T>
concept ieee_float = std::same_as<T, float> || std::same_as<T, double>;

template <ieee_float F>
using bits_t = std::conditional_t<std::same_as<F, float>, std::uint32_t, std::uint64_t>;

// The vector type V with T's scalar lanes: vec3<float> for vec3<simd::float8>.
template <vector V>
using scalar_vector_t =
    typename vector_traits<V>::template rebind<simd::scalar_type_t<typename V::value_type>>;

} // namespace canopy::detail

export namespace canopy {

// Component-wise arithmetic: vector with vector, and vector with a T on either side.

template <detail::vector V> constexpr V operator+(V const& a, V const& b) {
    return detail::zip(a, b, detail::plus);
}
template <detail::vector V> constexpr V operator-(V const& a, V const& b) {
    return detail::zip(a, b, detail::minus);
}
template <detail::vector V> constexpr V operator*(V const& a, V const& b) {
    return detail::zip(a, b, detail::times);
}
template <detail::vector V> constexpr V operator/(V const& a, V const& b) {
    return detail::zip(a, b, detail::divides);
}

template <detail::vector V> constexpr V operator+(V const& a, typename V::value_type const& s) {
    return detail::map(a, [&](auto const& c) { return c + s; });
}
template <detail::vector V> constexpr V operator-(V const& a, typename V::value_type const& s) {
    return detail::map(a, [&](auto const& c) { return c - s; });
}
template <detail::vector V> constexpr V operator*(V const& a, typename V::value_type const& s) {
    return detail::map(a, [&](auto const& c) { return c * s; });
}
template <detail::vector V> constexpr V operator/(V const& a, typename V::value_type const& s) {
    return detail::map(a, [&](auto const& c) { return c / s; });
}

template <detail::vector V> constexpr V operator+(typename V::value_type const& s, V const& a) {
    return detail::map(a, [&](auto const& c) { return s + c; });
}
template <detail::vector V> constexpr V operator-(typename V::value_type const& s, V const& a) {
    return detail::map(a, [&](auto const& c) { return s - c; });
}
template <detail::vector V> constexpr V operator*(typename V::value_type const& s, V const& a) {
    return detail::map(a, [&](auto const& c) { return s * c; });
}
template <detail::vector V> constexpr V operator/(typename V::value_type const& s, V const& a) {
    return detail::map(a, [&](auto const& c) { return s / c; });
}

template <detail::vector V> constexpr V operator-(V const& a) {
    return detail::map(a, [](auto const& c) { return -c; });
}

template <detail::vector V> constexpr V& operator+=(V& a, V const& b) { return a = a + b; }
template <detail::vector V> constexpr V& operator-=(V& a, V const& b) { return a = a - b; }
template <detail::vector V> constexpr V& operator*=(V& a, V const& b) { return a = a * b; }
template <detail::vector V> constexpr V& operator/=(V& a, V const& b) { return a = a / b; }
template <detail::vector V> constexpr V& operator+=(V& a, typename V::value_type const& s) {
    return a = a + s;
}
template <detail::vector V> constexpr V& operator-=(V& a, typename V::value_type const& s) {
    return a = a - s;
}
template <detail::vector V> constexpr V& operator*=(V& a, typename V::value_type const& s) {
    return a = a * s;
}
template <detail::vector V> constexpr V& operator/=(V& a, typename V::value_type const& s) {
    return a = a / s;
}

// Sum of products, accumulated left to right (x first).
template <detail::vector V> constexpr typename V::value_type dot(V const& a, V const& b) {
    return detail::fold(a * b, detail::plus);
}

template <typename T> constexpr vec3<T> cross(vec3<T> const& a, vec3<T> const& b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

template <detail::vector V> constexpr typename V::value_type length_squared(V const& v) { return dot(v, v); }

template <detail::vector V> constexpr typename V::value_type length(V const& v) {
    return simd::sqrt(length_squared(v));
}

// Each component divided by the length (no reciprocal); the zero vector gives NaN components.
template <detail::vector V> constexpr V normalize(V const& v) { return v / length(v); }

// (1 - t) a + t b: exactly a at t = 0 and exactly b at t = 1.
template <detail::vector V> constexpr V lerp(V const& a, V const& b, typename V::value_type const& t) {
    using T = typename V::value_type;
    return (detail::splat<T>(1) - t) * a + t * b;
}

// Barycentric interpolation (1 - u - v) a + u b + v c.
template <detail::vector V>
constexpr V lerp(V const& a, V const& b, V const& c, typename V::value_type const& u,
                 typename V::value_type const& v) {
    using T = typename V::value_type;
    return (detail::splat<T>(1) - u - v) * a + u * b + v * c;
}

// Component-wise simd::min / simd::max: a < b ? a : b, so a NaN in a yields b's component.
template <detail::vector V> constexpr V min(V const& a, V const& b) {
    return detail::zip(a, b, [](auto const& p, auto const& q) { return simd::min(p, q); });
}
template <detail::vector V> constexpr V max(V const& a, V const& b) {
    return detail::zip(a, b, [](auto const& p, auto const& q) { return simd::max(p, q); });
}

template <detail::vector V> constexpr V abs(V const& v) {
    return detail::map(v, [](auto const& c) { return simd::abs(c); });
}

// min(max(v, lo), hi) component-wise; NaN components become lo's.
template <detail::vector V> constexpr V clamp(V const& v, V const& lo, V const& hi) {
    return min(max(v, lo), hi);
}
template <detail::vector V>
constexpr V clamp(V const& v, typename V::value_type const& lo, typename V::value_type const& hi) {
    return clamp(v, V(lo), V(hi));
}

// Per lane: a where m is set, b elsewhere.
template <detail::vector V>
constexpr V select(simd::mask_type_t<typename V::value_type> const& m, V const& a, V const& b) {
    return detail::zip(a, b, [&](auto const& p, auto const& q) { return simd::select(m, p, q); });
}

template <detail::vector V> constexpr typename V::value_type min_component(V const& v) {
    return detail::fold(v, [](auto const& p, auto const& q) { return simd::min(p, q); });
}
template <detail::vector V> constexpr typename V::value_type max_component(V const& v) {
    return detail::fold(v, [](auto const& p, auto const& q) { return simd::max(p, q); });
}

// Index of the component of largest magnitude; ties go to the higher index.
template <std::floating_point T> constexpr int max_dimension(vec3<T> const& v) {
    vec3<T> const a = abs(v);
    return a.x > a.y ? (a.x > a.z ? 0 : 2) : (a.y > a.z ? 1 : 2);
}

// The components of v in lanes 0-2 of a 4-lane vector and `w` in lane 3, and back (lane 3
// dropped): for code that treats the three axes of a point or a box at once.
inline simd::float4 to_lanes(vec3<float> const& v, float w = 0.0f) {
    alignas(16) float const lanes[4] = {v.x, v.y, v.z, w};
    return simd::float4::load_aligned(lanes);
}
inline vec3<float> from_lanes(simd::float4 const& v) {
    alignas(16) float lanes[4];
    v.store_aligned(lanes);
    return {lanes[0], lanes[1], lanes[2]};
}

// {v[kx], v[ky], v[kz]}; preconditions: each index in [0, 3).
template <typename T> constexpr vec3<T> permute(vec3<T> const& v, int kx, int ky, int kz) {
    CANOPY_DCHECK(unsigned(kx) < 3u && unsigned(ky) < 3u && unsigned(kz) < 3u, "permute: indices in [0, 3)");
    return {v[kx], v[ky], v[kz]};
}

template <detail::vector V> constexpr simd::mask_type_t<typename V::value_type> any_nan(V const& v) {
    return detail::reduce_mask(v, [](auto const& c) { return simd::isnan(c); },
                               [](auto const& p, auto const& q) { return detail::mask_or(p, q); });
}

template <detail::vector V> constexpr simd::mask_type_t<typename V::value_type> all_finite(V const& v) {
    return detail::reduce_mask(v, [](auto const& c) { return simd::isfinite(c); },
                               [](auto const& p, auto const& q) { return detail::mask_and(p, q); });
}

// Lane i of a SIMD vector as a scalar vector (precondition: 0 <= i < simd_width_v<T>); for a
// scalar T, lane 0 is the vector itself.
template <detail::vector V> constexpr detail::scalar_vector_t<V> get_lane(V const& v, int i) {
    CANOPY_DCHECK(i >= 0 && i < simd::simd_width_v<typename V::value_type>, "get_lane: lane in [0, simd width)");
    detail::scalar_vector_t<V> r;
    for (int k = 0; k < detail::vector_traits<V>::size; ++k)
        r[k] = detail::lane(v[k], i);
    return r;
}

// The same precondition: 0 <= i < simd_width_v<T>.
template <detail::vector V> constexpr void set_lane(V& v, int i, detail::scalar_vector_t<V> const& s) {
    CANOPY_DCHECK(i >= 0 && i < simd::simd_width_v<typename V::value_type>, "set_lane: lane in [0, simd width)");
    for (int k = 0; k < detail::vector_traits<V>::size; ++k)
        detail::set_lane(v[k], i, s[k]);
}

// 3x3 matrix stored as three columns; element (row r, column c) is col<c>[r]. Default: zero.
template <typename T> struct mat3 {
    using value_type = T;
    vec3<T> col0, col1, col2;

    static constexpr mat3 identity() {
        T const o = detail::splat<T>(1), z = detail::splat<T>(0);
        return {{o, z, z}, {z, o, z}, {z, z, o}};
    }
};

template <typename T> constexpr vec3<T> operator*(mat3<T> const& m, vec3<T> const& v) {
    return m.col0 * v.x + m.col1 * v.y + m.col2 * v.z;
}

template <typename T> constexpr mat3<T> operator*(mat3<T> const& a, mat3<T> const& b) {
    return {a * b.col0, a * b.col1, a * b.col2};
}

template <typename T> constexpr mat3<T> transpose(mat3<T> const& m) {
    return {{m.col0.x, m.col1.x, m.col2.x}, {m.col0.y, m.col1.y, m.col2.y}, {m.col0.z, m.col1.z, m.col2.z}};
}

template <typename T> constexpr T determinant(mat3<T> const& m) { return dot(m.col0, cross(m.col1, m.col2)); }

// Adjugate divided by the determinant; a singular matrix gives non-finite entries.
template <typename T> constexpr mat3<T> inverse(mat3<T> const& m) {
    vec3<T> const r0 = cross(m.col1, m.col2), r1 = cross(m.col2, m.col0), r2 = cross(m.col0, m.col1);
    T const det = dot(m.col0, r0);
    return transpose(mat3<T>{r0 / det, r1 / det, r2 / det});
}

// 4x4 matrix stored as four columns; element (row r, column c) is col<c>[r]. Default: zero.
template <typename T> struct mat4 {
    using value_type = T;
    vec4<T> col0, col1, col2, col3;

    static constexpr mat4 identity() {
        T const o = detail::splat<T>(1), z = detail::splat<T>(0);
        return {{o, z, z, z}, {z, o, z, z}, {z, z, o, z}, {z, z, z, o}};
    }
};

template <typename T> constexpr vec4<T> operator*(mat4<T> const& m, vec4<T> const& v) {
    return m.col0 * v.x + m.col1 * v.y + m.col2 * v.z + m.col3 * v.w;
}

template <typename T> constexpr mat4<T> operator*(mat4<T> const& a, mat4<T> const& b) {
    return {a * b.col0, a * b.col1, a * b.col2, a * b.col3};
}

template <typename T> constexpr mat4<T> transpose(mat4<T> const& m) {
    return {{m.col0.x, m.col1.x, m.col2.x, m.col3.x},
            {m.col0.y, m.col1.y, m.col2.y, m.col3.y},
            {m.col0.z, m.col1.z, m.col2.z, m.col3.z},
            {m.col0.w, m.col1.w, m.col2.w, m.col3.w}};
}

} // namespace canopy

namespace canopy::detail {

// Laplace expansion of a 4x4 matrix along its first two rows: s[k] are the 2x2 minors of rows
// 0-1, c[k] the complementary minors of rows 2-3.
template <typename T> struct mat4_minors {
    T s[6], c[6], det;
};

template <typename T> constexpr mat4_minors<T> minors(mat4<T> const& m) {
    auto const& [a00, a10, a20, a30] = m.col0;
    auto const& [a01, a11, a21, a31] = m.col1;
    auto const& [a02, a12, a22, a32] = m.col2;
    auto const& [a03, a13, a23, a33] = m.col3;
    mat4_minors<T> r{{a00 * a11 - a10 * a01, a00 * a12 - a10 * a02, a00 * a13 - a10 * a03,
                      a01 * a12 - a11 * a02, a01 * a13 - a11 * a03, a02 * a13 - a12 * a03},
                     {a20 * a31 - a30 * a21, a20 * a32 - a30 * a22, a20 * a33 - a30 * a23,
                      a21 * a32 - a31 * a22, a21 * a33 - a31 * a23, a22 * a33 - a32 * a23},
                     {}};
    r.det = r.s[0] * r.c[5] - r.s[1] * r.c[4] + r.s[2] * r.c[3] + r.s[3] * r.c[2] - r.s[4] * r.c[1] +
            r.s[5] * r.c[0];
    return r;
}

} // namespace canopy::detail

export namespace canopy {

template <typename T> constexpr T determinant(mat4<T> const& m) { return detail::minors(m).det; }

// Adjugate divided by the determinant; a singular matrix gives non-finite entries.
template <typename T> constexpr mat4<T> inverse(mat4<T> const& m) {
    auto const& [a00, a10, a20, a30] = m.col0;
    auto const& [a01, a11, a21, a31] = m.col1;
    auto const& [a02, a12, a22, a32] = m.col2;
    auto const& [a03, a13, a23, a33] = m.col3;
    auto const [s, c, det] = detail::minors(m);
    vec4<T> const row0(a11 * c[5] - a12 * c[4] + a13 * c[3], -a01 * c[5] + a02 * c[4] - a03 * c[3],
                       a31 * s[5] - a32 * s[4] + a33 * s[3], -a21 * s[5] + a22 * s[4] - a23 * s[3]);
    vec4<T> const row1(-a10 * c[5] + a12 * c[2] - a13 * c[1], a00 * c[5] - a02 * c[2] + a03 * c[1],
                       -a30 * s[5] + a32 * s[2] - a33 * s[1], a20 * s[5] - a22 * s[2] + a23 * s[1]);
    vec4<T> const row2(a10 * c[4] - a11 * c[2] + a13 * c[0], -a00 * c[4] + a01 * c[2] - a03 * c[0],
                       a30 * s[4] - a31 * s[2] + a33 * s[0], -a20 * s[4] + a21 * s[2] - a23 * s[0]);
    vec4<T> const row3(-a10 * c[3] + a11 * c[1] - a12 * c[0], a00 * c[3] - a01 * c[1] + a02 * c[0],
                       -a30 * s[3] + a31 * s[1] - a32 * s[0], a20 * s[3] - a21 * s[1] + a22 * s[0]);
    return transpose(mat4<T>{row0 / det, row1 / det, row2 / det, row3 / det});
}

// The affine map p -> linear * p + translation (a 3x4 matrix whose last column is the
// translation). Default: the identity.
template <typename T> struct affine_transform {
    using value_type = T;
    mat3<T> linear = mat3<T>::identity();
    vec3<T> translation;

    static constexpr affine_transform identity() { return {}; }

    // From a row-major 3x4 matrix r00 r01 r02 r03 r10 ... r23; column 3 is the translation.
    static constexpr affine_transform from_rows(std::array<T, 12> const& r) {
        return {{{r[0], r[4], r[8]}, {r[1], r[5], r[9]}, {r[2], r[6], r[10]}}, {r[3], r[7], r[11]}};
    }

    // Exact comparison with the identity (-0 equals 0), per lane.
    constexpr simd::mask_type_t<T> is_identity() const {
        T const o = detail::splat<T>(1), z = detail::splat<T>(0);
        auto const equals = [](vec3<T> const& v, T const& x, T const& y, T const& w) {
            return detail::mask_and(detail::mask_and(v.x == x, v.y == y), v.z == w);
        };
        return detail::mask_and(
            detail::mask_and(equals(linear.col0, o, z, z), equals(linear.col1, z, o, z)),
            detail::mask_and(equals(linear.col2, z, z, o), equals(translation, z, z, z)));
    }

    // linear * v, without the translation. V is T, or a SIMD type whose lanes are T (one
    // transform applied to a packet).
    template <typename V>
        requires std::same_as<V, T> || std::same_as<simd::scalar_type_t<V>, T>
    constexpr vec3<V> transform_vector(vec3<V> const& v) const {
        return vec3<V>(linear.col0) * v.x + vec3<V>(linear.col1) * v.y + vec3<V>(linear.col2) * v.z;
    }

    // linear * p + translation, evaluated as ((col0 x + col1 y) + col2 z) + translation.
    template <typename V>
        requires std::same_as<V, T> || std::same_as<simd::scalar_type_t<V>, T>
    constexpr vec3<V> transform_point(vec3<V> const& p) const {
        return transform_vector(p) + vec3<V>(translation);
    }
};

// Free-function spellings of the members a.transform_vector(v) and a.transform_point(p).
template <typename T, typename V>
constexpr vec3<V> transform_vector(affine_transform<T> const& a, vec3<V> const& v)
    requires requires { a.transform_vector(v); }
{
    return a.transform_vector(v);
}

template <typename T, typename V>
constexpr vec3<V> transform_point(affine_transform<T> const& a, vec3<V> const& p)
    requires requires { a.transform_point(p); }
{
    return a.transform_point(p);
}

// The map that applies b first, then a.
template <typename T>
constexpr affine_transform<T> operator*(affine_transform<T> const& a, affine_transform<T> const& b) {
    return {a.linear * b.linear, a.linear * b.translation + a.translation};
}

// Every entry finite, per lane.
template <typename T> constexpr simd::mask_type_t<T> all_finite(affine_transform<T> const& a) {
    return detail::mask_and(detail::mask_and(all_finite(a.linear.col0), all_finite(a.linear.col1)),
                            detail::mask_and(all_finite(a.linear.col2), all_finite(a.translation)));
}

// The same matrix or map in precision U, each entry converted once (double → float rounds to
// nearest; a value beyond the float range becomes infinite: check all_finite after narrowing).
// Transforms are composed in double and rounded to float once (the scene loaders, compile()).
template <std::floating_point U, std::floating_point T> constexpr mat3<U> convert(mat3<T> const& m) {
    return {vec3<U>(m.col0), vec3<U>(m.col1), vec3<U>(m.col2)};
}
template <std::floating_point U, std::floating_point T>
constexpr affine_transform<U> convert(affine_transform<T> const& a) {
    return {convert<U>(a.linear), vec3<U>(a.translation)};
}

// T · R · S: scale along the axes by `scale`, then apply `rotation` (a rotation matrix, or any
// linear map), then translate. The linear part is rotation's columns times the scale factors (one
// product per entry, no sum), so it is exact in T up to that one rounding.
template <typename T>
constexpr affine_transform<T> from_trs(vec3<T> const& translation, mat3<T> const& rotation, vec3<T> const& scale) {
    return {{rotation.col0 * scale.x, rotation.col1 * scale.y, rotation.col2 * scale.z}, translation};
}

} // namespace canopy

namespace canopy::detail {

template <std::floating_point T>
constexpr affine_transform<T> inverse_in_double(affine_transform<T> const& a) {
    mat3<double> const linear = inverse(convert<double>(a.linear));
    return {convert<T>(linear), vec3<T>(-(linear * vec3<double>(a.translation)))};
}

} // namespace canopy::detail

export namespace canopy {

// Computed in double and rounded to T once per entry. Measured for float transforms of
// condition number <= 4: every entry is the correctly rounded exact inverse (the tests assert
// <= 1 ulp). A singular linear part gives non-finite entries. SIMD transforms are inverted lane
// by lane.
template <typename T> constexpr affine_transform<T> inverse(affine_transform<T> const& a) {
    if constexpr (std::floating_point<T>) {
        return detail::inverse_in_double(a);
    } else {
        using S = simd::scalar_type_t<T>;
        affine_transform<T> r;
        for (int i = 0; i < simd::simd_width_v<T>; ++i) {
            affine_transform<S> const lane_inverse = detail::inverse_in_double(affine_transform<S>{
                {get_lane(a.linear.col0, i), get_lane(a.linear.col1, i), get_lane(a.linear.col2, i)},
                get_lane(a.translation, i)});
            set_lane(r.linear.col0, i, lane_inverse.linear.col0);
            set_lane(r.linear.col1, i, lane_inverse.linear.col1);
            set_lane(r.linear.col2, i, lane_inverse.linear.col2);
            set_lane(r.translation, i, lane_inverse.translation);
        }
        return r;
    }
}

// ULP helpers (float and double). The next representable value above / below v: -0 and +0 both
// step to the smallest denormal, +inf stays +inf going up (-inf going down), -inf goes up to
// -max (+inf down to max), NaN stays NaN.
template <detail::ieee_float F> constexpr F next_float_up(F v) {
    using bits = detail::bits_t<F>;
    if (v != v || v == std::numeric_limits<F>::infinity())
        return v;
    if (v == F(0))
        return std::numeric_limits<F>::denorm_min();
    bits const b = std::bit_cast<bits>(v);
    return std::bit_cast<F>(v > F(0) ? bits(b + 1) : bits(b - 1));
}

template <detail::ieee_float F> constexpr F next_float_down(F v) {
    using bits = detail::bits_t<F>;
    if (v != v || v == -std::numeric_limits<F>::infinity())
        return v;
    if (v == F(0))
        return -std::numeric_limits<F>::denorm_min();
    bits const b = std::bit_cast<bits>(v);
    return std::bit_cast<F>(v > F(0) ? bits(b - 1) : bits(b + 1));
}

// Higham's gamma_n = n u / (1 - n u), u = epsilon / 2: bounds the relative error of n rounded
// operations (pbrt's gamma). Precondition: n u < 1. Evaluated in T's scalar type.
template <typename T> constexpr T gamma(int n) {
    using S = simd::scalar_type_t<T>;
    S const nu = static_cast<S>(n) * (std::numeric_limits<S>::epsilon() / 2);
    return T(nu / (S(1) - nu));
}

// Number of representable values between a and b (0 when a == b, with -0 == +0), through a
// monotone mapping of the bit patterns to unsigned integers. NaN gives the maximum count.
template <detail::ieee_float F> constexpr detail::bits_t<F> ulp_distance(F a, F b) {
    using bits = detail::bits_t<F>;
    if (a != a || b != b)
        return std::numeric_limits<bits>::max();
    constexpr bits sign = bits(1) << (sizeof(F) * 8 - 1);
    auto const key = [](F v) {
        bits const b = std::bit_cast<bits>(v);
        return (b & sign) ? bits(sign - (b & ~sign)) : bits(sign + b);
    };
    bits const ka = key(a), kb = key(b);
    return ka > kb ? bits(ka - kb) : bits(kb - ka);
}

// Axis-aligned box [min, max]. Default: empty (min = +inf, max = -inf), the identity of extend.
// A box is empty when min > max on some axis.
template <typename T> struct basic_aabb {
    using value_type = T;
    vec3<T> min = vec3<T>(detail::splat<T>(std::numeric_limits<simd::scalar_type_t<T>>::infinity()));
    vec3<T> max = vec3<T>(detail::splat<T>(-std::numeric_limits<simd::scalar_type_t<T>>::infinity()));

    // The empty box (same as default construction).
    static constexpr basic_aabb empty() { return {}; }
};

using aabb = basic_aabb<float>;

template <typename T> constexpr simd::mask_type_t<T> is_empty(basic_aabb<T> const& b) {
    return detail::mask_or(detail::mask_or(b.min.x > b.max.x, b.min.y > b.max.y), b.min.z > b.max.z);
}

// The smallest box holding box and p; NaN coordinates of p are ignored.
template <typename T> constexpr basic_aabb<T> extend(basic_aabb<T> const& box, vec3<T> const& p) {
    return {min(p, box.min), max(p, box.max)};
}

// The smallest box holding a and b; empty boxes are identities.
template <typename T> constexpr basic_aabb<T> extend(basic_aabb<T> const& a, basic_aabb<T> const& b) {
    return {min(b.min, a.min), max(b.max, a.max)};
}

// Empty (per is_empty) when a and b are disjoint.
template <typename T> constexpr basic_aabb<T> intersection(basic_aabb<T> const& a, basic_aabb<T> const& b) {
    return {max(a.min, b.min), min(a.max, b.max)};
}

// Meaningless for an empty box.
template <typename T> constexpr vec3<T> center(basic_aabb<T> const& b) {
    return (b.min + b.max) * detail::splat<T>(0.5);
}

template <typename T> constexpr vec3<T> diagonal(basic_aabb<T> const& b) { return b.max - b.min; }

// 0 for an empty box.
template <typename T> constexpr T surface_area(basic_aabb<T> const& b) {
    vec3<T> const d = diagonal(b);
    T const area = detail::splat<T>(2) * (d.x * d.y + d.y * d.z + d.z * d.x);
    return simd::select(is_empty(b), detail::splat<T>(0), area);
}

// Closed box: points on the boundary are contained.
template <typename T> constexpr simd::mask_type_t<T> contains(basic_aabb<T> const& b, vec3<T> const& p) {
    auto const inside = [](T const& lo, T const& x, T const& hi) {
        return detail::mask_and(lo <= x, x <= hi);
    };
    return detail::mask_and(detail::mask_and(inside(b.min.x, p.x, b.max.x), inside(b.min.y, p.y, b.max.y)),
                            inside(b.min.z, p.z, b.max.z));
}

// Closed boxes: touching boxes overlap; an empty box overlaps nothing.
template <typename T>
constexpr simd::mask_type_t<T> overlaps(basic_aabb<T> const& a, basic_aabb<T> const& b) {
    auto const axis = [](T const& lo0, T const& hi0, T const& lo1, T const& hi1) {
        return detail::mask_and(lo0 <= hi1, lo1 <= hi0);
    };
    return detail::mask_and(detail::mask_and(axis(a.min.x, a.max.x, b.min.x, b.max.x),
                                             axis(a.min.y, a.max.y, b.min.y, b.max.y)),
                            axis(a.min.z, a.max.z, b.min.z, b.max.z));
}

// Axis of the longest extent of a non-empty box; ties go to the higher axis.
template <std::floating_point T> constexpr int largest_axis(basic_aabb<T> const& b) {
    return max_dimension(diagonal(b));
}

// A box holding the images of box's 8 corners, both the exact ones and those transform_point
// rounds to: each rounded corner is widened by a bound on its rounding error,
// gamma(5) (|linear| |p| + |translation|) plus 2 denormals for products that underflow, and
// rounded outward. An empty box stays empty. Preconditions: finite box and transform, no overflow.
template <std::floating_point T>
constexpr basic_aabb<T> transform_box(affine_transform<T> const& a, basic_aabb<T> const& box) {
    if (is_empty(box))
        return {};
    affine_transform<T> const magnitude{{abs(a.linear.col0), abs(a.linear.col1), abs(a.linear.col2)},
                                        abs(a.translation)};
    T const underflow = 2 * std::numeric_limits<T>::denorm_min();
    basic_aabb<T> r;
    for (int corner = 0; corner < 8; ++corner) {
        vec3<T> const p((corner & 1) ? box.max.x : box.min.x, (corner & 2) ? box.max.y : box.min.y,
                        (corner & 4) ? box.max.z : box.min.z);
        vec3<T> const image = transform_point(a, p);
        vec3<T> const error = transform_point(magnitude, abs(p)) * gamma<T>(5) + underflow;
        r = extend(r, basic_aabb<T>{detail::map(image - error, [](T x) { return next_float_down(x); }),
                                    detail::map(image + error, [](T x) { return next_float_up(x); })});
    }
    return r;
}

// A ray origin + t direction for t in [tmin, tmax]; direction is never normalised.
template <typename T> struct basic_ray {
    using value_type = T;
    vec3<T> origin;
    T tmin{};
    vec3<T> direction;
    T tmax{};

    constexpr vec3<T> operator()(T const& t) const { return origin + t * direction; }
};

using ray = basic_ray<float>;

template <typename T> constexpr vec3<T> point_at(basic_ray<T> const& r, std::type_identity_t<T> const& t) {
    return r.origin + t * r.direction;
}

} // namespace canopy
