// canopy.simd: fixed-width SIMD vectors for the kernels.
//
// basic_simd<T, N> (T = float or std::int32_t, N = 4, 8 or 16) and basic_mask<N>, plus free
// functions (select, min, max, sqrt, fma, gather, reductions, ...) that also take plain float,
// double, std::int32_t and bool, so one template serves `float` and `float8` alike.
//
// Each width runs on the instruction set the target provides for it: SSE4.2 for 4 lanes, AVX2
// for 8, AVX-512 for 16. A width without its instruction set, or every width when
// CANOPY_SIMD_FORCE_SCALAR is defined, uses the portable scalar backend (std::array and loops).
//
// Every backend computes the same results: IEEE comparisons, x86 min/max rules, exact division
// and square root, single-rounding fma, wrap-around integer arithmetic, x86 float-to-int
// conversion, and one documented order for horizontal reductions. Only which NaN a NaN result
// carries may differ.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF

#include <array>
#include <bit>
#include <cmath>
#include <concepts>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <string_view>
#include <type_traits>
#include <vector>

#if !defined(CANOPY_SIMD_FORCE_SCALAR) && defined(__SSE4_2__)
#include <immintrin.h>
#define CANOPY_SIMD_SSE42 1
#if defined(__AVX2__)
#define CANOPY_SIMD_AVX2 1
#if defined(__AVX512F__)
#define CANOPY_SIMD_AVX512 1
#endif
#endif
#endif

// Every operation is inlined into its caller: the wrappers must cost nothing in hot loops.
#define CANOPY_SIMD_INLINE [[gnu::always_inline]] inline

export module canopy.simd;

namespace canopy::simd::detail {

template <typename T>
concept scalar_float = std::same_as<T, float> || std::same_as<T, double>;

template <typename T>
concept scalar_lane = scalar_float<T> || std::same_as<T, std::int32_t>;

// Integer lanes wrap around modulo 2^32, as the SIMD instructions do (no signed-overflow UB).
template <typename T>
CANOPY_SIMD_INLINE constexpr T lane_add(T a, T b) {
    if constexpr (std::integral<T>)
        return static_cast<T>(static_cast<std::uint32_t>(a) + static_cast<std::uint32_t>(b));
    else
        return a + b;
}

template <typename T>
CANOPY_SIMD_INLINE constexpr T lane_sub(T a, T b) {
    if constexpr (std::integral<T>)
        return static_cast<T>(static_cast<std::uint32_t>(a) - static_cast<std::uint32_t>(b));
    else
        return a - b;
}

template <typename T>
CANOPY_SIMD_INLINE constexpr T lane_mul(T a, T b) {
    if constexpr (std::integral<T>)
        return static_cast<T>(static_cast<std::uint32_t>(a) * static_cast<std::uint32_t>(b));
    else
        return a * b;
}

template <typename T>
CANOPY_SIMD_INLINE constexpr T lane_neg(T a) {
    if constexpr (std::integral<T>)
        return static_cast<T>(0u - static_cast<std::uint32_t>(a));
    else
        return -a;
}

// Shift counts outside [0, 31] shift every bit out, as x86 does: 0 for <<, the sign for >>.
CANOPY_SIMD_INLINE constexpr std::int32_t lane_shift_left(std::int32_t a, int count) {
    return static_cast<std::uint32_t>(count) < 32u ? static_cast<std::int32_t>(static_cast<std::uint32_t>(a) << count)
                                                   : 0;
}

CANOPY_SIMD_INLINE constexpr std::int32_t lane_shift_right(std::int32_t a, int count) {
    return a >> (static_cast<std::uint32_t>(count) < 32u ? count : 31);
}

} // namespace canopy::simd::detail

// Scalar overloads: a float, double or std::int32_t is a one-lane vector and a bool a one-lane
// mask. They define the per-lane rules that every vector backend follows.
export namespace canopy::simd {

// mask ? a : b.
template <detail::scalar_lane T>
CANOPY_SIMD_INLINE constexpr T select(bool mask, T a, T b) {
    return mask ? a : b;
}

// a < b ? a : b, which is x86 minps: b when either operand is NaN, and min(-0, +0) = +0. This is
// not std::min (b < a ? b : a); the slab test relies on the NaN rule.
template <detail::scalar_lane T>
CANOPY_SIMD_INLINE constexpr T min(T a, T b) {
    return a < b ? a : b;
}

// a > b ? a : b, which is x86 maxps: b when either operand is NaN, and max(-0, +0) = +0.
template <detail::scalar_lane T>
CANOPY_SIMD_INLINE constexpr T max(T a, T b) {
    return a > b ? a : b;
}

// |x|; floats get their sign bit cleared (NaN too), abs(INT_MIN) wraps to INT_MIN.
template <detail::scalar_lane T>
CANOPY_SIMD_INLINE constexpr T abs(T x) {
    if constexpr (std::integral<T>)
        return x < 0 ? detail::lane_neg(x) : x;
    else
        return std::fabs(x);
}

// Correctly rounded square root; NaN for x < 0, sqrt(-0) = -0.
template <detail::scalar_float T>
CANOPY_SIMD_INLINE T sqrt(T x) {
    return std::sqrt(x);
}

// 1 / x, correctly rounded (a division, not the approximate rcpps); rcp(±0) = ±inf.
template <detail::scalar_float T>
CANOPY_SIMD_INLINE constexpr T rcp(T x) {
    return T(1) / x;
}

// a * b + c with a single rounding.
template <detail::scalar_float T>
CANOPY_SIMD_INLINE T fma(T a, T b, T c) {
    return std::fma(a, b, c);
}

template <detail::scalar_float T>
CANOPY_SIMD_INLINE T floor(T x) {
    return std::floor(x);
}

template <detail::scalar_float T>
CANOPY_SIMD_INLINE T ceil(T x) {
    return std::ceil(x);
}

// The magnitude of `magnitude` with the sign bit of `sign`.
template <detail::scalar_float T>
CANOPY_SIMD_INLINE constexpr T copysign(T magnitude, T sign) {
    return std::copysign(magnitude, sign);
}

template <detail::scalar_float T>
CANOPY_SIMD_INLINE constexpr bool isnan(T x) {
    return std::isnan(x);
}

// Neither infinite nor NaN.
template <detail::scalar_float T>
CANOPY_SIMD_INLINE constexpr bool isfinite(T x) {
    return std::isfinite(x);
}

// base[index]; the index must be valid.
template <detail::scalar_lane T>
CANOPY_SIMD_INLINE constexpr T gather(T const* base, std::int32_t index) {
    return base[index];
}

// Horizontal reductions of one lane: the lane itself.
template <detail::scalar_lane T>
CANOPY_SIMD_INLINE constexpr T reduce_min(T x) {
    return x;
}

template <detail::scalar_lane T>
CANOPY_SIMD_INLINE constexpr T reduce_max(T x) {
    return x;
}

template <detail::scalar_lane T>
CANOPY_SIMD_INLINE constexpr T reduce_add(T x) {
    return x;
}

CANOPY_SIMD_INLINE constexpr bool any(bool mask) { return mask; }
CANOPY_SIMD_INLINE constexpr bool all(bool mask) { return mask; }
CANOPY_SIMD_INLINE constexpr bool none(bool mask) { return !mask; }
CANOPY_SIMD_INLINE constexpr std::uint32_t movemask(bool mask) { return mask ? 1u : 0u; }
CANOPY_SIMD_INLINE constexpr int popcount(bool mask) { return mask ? 1 : 0; }

// Truncation toward zero like static_cast, except that NaN and values outside [-2^31, 2^31)
// give INT_MIN, as x86 cvttps2dq does (no undefined behaviour).
CANOPY_SIMD_INLINE constexpr std::int32_t convert_to_int(float x) {
    return x >= -0x1p31f && x < 0x1p31f ? static_cast<std::int32_t>(x) : std::numeric_limits<std::int32_t>::min();
}

// Rounds to nearest, ties to even, like static_cast.
CANOPY_SIMD_INLINE constexpr float convert_to_float(std::int32_t x) { return static_cast<float>(x); }

// Bit reinterpretation.
CANOPY_SIMD_INLINE constexpr std::int32_t as_int(float x) { return std::bit_cast<std::int32_t>(x); }
CANOPY_SIMD_INLINE constexpr float as_float(std::int32_t x) { return std::bit_cast<float>(x); }

} // namespace canopy::simd

namespace canopy::simd::detail {

// {f(0), f(1), ..., f(N - 1)}.
template <int N, typename F>
CANOPY_SIMD_INLINE auto per_lane(F f) {
    std::array<decltype(f(0)), N> lanes;
    for (int i = 0; i < N; ++i) lanes[i] = f(i);
    return lanes;
}

// A backend is a struct of static functions over its register type `reg`. The primary templates
// are the portable scalar backends; the specialisations below replace them for the widths the
// target supports natively.

// Masks of N lanes: broadcast, conversion from and to bits (bit i = lane i), lane-wise logic.
template <int N>
struct mask_backend {
    static constexpr std::string_view name = "scalar";
    using reg = std::array<bool, N>;

    CANOPY_SIMD_INLINE static reg broadcast(bool value) {
        return per_lane<N>([&](int) { return value; });
    }
    CANOPY_SIMD_INLINE static reg from_bits(std::uint32_t bits) {
        return per_lane<N>([&](int i) { return ((bits >> i) & 1u) != 0; });
    }
    CANOPY_SIMD_INLINE static std::uint32_t bits(reg const& m) {
        std::uint32_t result = 0;
        for (int i = 0; i < N; ++i) result |= static_cast<std::uint32_t>(m[i]) << i;
        return result;
    }
    CANOPY_SIMD_INLINE static reg bit_and(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] && b[i]; });
    }
    CANOPY_SIMD_INLINE static reg bit_or(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] || b[i]; });
    }
    CANOPY_SIMD_INLINE static reg bit_xor(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] != b[i]; });
    }
    CANOPY_SIMD_INLINE static reg bit_not(reg const& a) {
        return per_lane<N>([&](int i) { return !a[i]; });
    }
    CANOPY_SIMD_INLINE static reg equal(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] == b[i]; });
    }
};

// N lanes of T: every operation is the scalar overload above, lane by lane.
template <typename T, int N>
struct backend {
    static constexpr std::string_view name = "scalar";
    using reg = std::array<T, N>;
    using mask_reg = typename mask_backend<N>::reg;
    using int_reg = std::array<std::int32_t, N>;

    CANOPY_SIMD_INLINE static reg zero() { return reg{}; }
    CANOPY_SIMD_INLINE static reg broadcast(T x) {
        return per_lane<N>([&](int) { return x; });
    }
    CANOPY_SIMD_INLINE static reg load(T const* p) {
        return per_lane<N>([&](int i) { return p[i]; });
    }
    CANOPY_SIMD_INLINE static reg load_aligned(T const* p) { return load(p); }
    CANOPY_SIMD_INLINE static void store(T* p, reg const& a) {
        for (int i = 0; i < N; ++i) p[i] = a[i];
    }
    CANOPY_SIMD_INLINE static void store_aligned(T* p, reg const& a) { store(p, a); }

    CANOPY_SIMD_INLINE static reg add(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return lane_add(a[i], b[i]); });
    }
    CANOPY_SIMD_INLINE static reg sub(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return lane_sub(a[i], b[i]); });
    }
    CANOPY_SIMD_INLINE static reg mul(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return lane_mul(a[i], b[i]); });
    }
    CANOPY_SIMD_INLINE static reg div(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] / b[i]; });
    }
    CANOPY_SIMD_INLINE static reg neg(reg const& a) {
        return per_lane<N>([&](int i) { return lane_neg(a[i]); });
    }

    CANOPY_SIMD_INLINE static mask_reg eq(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] == b[i]; });
    }
    CANOPY_SIMD_INLINE static mask_reg ne(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] != b[i]; });
    }
    CANOPY_SIMD_INLINE static mask_reg lt(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] < b[i]; });
    }
    CANOPY_SIMD_INLINE static mask_reg le(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] <= b[i]; });
    }
    CANOPY_SIMD_INLINE static mask_reg gt(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] > b[i]; });
    }
    CANOPY_SIMD_INLINE static mask_reg ge(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] >= b[i]; });
    }

    CANOPY_SIMD_INLINE static reg select(mask_reg const& m, reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return simd::select(m[i], a[i], b[i]); });
    }
    CANOPY_SIMD_INLINE static reg min(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return simd::min(a[i], b[i]); });
    }
    CANOPY_SIMD_INLINE static reg max(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return simd::max(a[i], b[i]); });
    }
    CANOPY_SIMD_INLINE static reg abs(reg const& a) {
        return per_lane<N>([&](int i) { return simd::abs(a[i]); });
    }

    CANOPY_SIMD_INLINE static reg sqrt(reg const& a) {
        return per_lane<N>([&](int i) { return simd::sqrt(a[i]); });
    }
    CANOPY_SIMD_INLINE static reg rcp(reg const& a) {
        return per_lane<N>([&](int i) { return simd::rcp(a[i]); });
    }
    CANOPY_SIMD_INLINE static reg fma(reg const& a, reg const& b, reg const& c) {
        return per_lane<N>([&](int i) { return simd::fma(a[i], b[i], c[i]); });
    }
    CANOPY_SIMD_INLINE static reg floor(reg const& a) {
        return per_lane<N>([&](int i) { return simd::floor(a[i]); });
    }
    CANOPY_SIMD_INLINE static reg ceil(reg const& a) {
        return per_lane<N>([&](int i) { return simd::ceil(a[i]); });
    }
    CANOPY_SIMD_INLINE static reg copysign(reg const& magnitude, reg const& sign) {
        return per_lane<N>([&](int i) { return simd::copysign(magnitude[i], sign[i]); });
    }
    CANOPY_SIMD_INLINE static mask_reg isnan(reg const& a) {
        return per_lane<N>([&](int i) { return simd::isnan(a[i]); });
    }
    CANOPY_SIMD_INLINE static mask_reg isfinite(reg const& a) {
        return per_lane<N>([&](int i) { return simd::isfinite(a[i]); });
    }
    CANOPY_SIMD_INLINE static reg gather(T const* base, int_reg const& index) {
        return per_lane<N>([&](int i) { return simd::gather(base, index[i]); });
    }

    // Lane i takes in lane i + N/2, then i + N/4, ..., 1: the order every backend folds in.
    template <typename F>
    CANOPY_SIMD_INLINE static T fold(reg a, F op) {
        for (int half = N / 2; half > 0; half /= 2)
            for (int i = 0; i < half; ++i) a[i] = op(a[i], a[i + half]);
        return a[0];
    }
    CANOPY_SIMD_INLINE static T reduce_min(reg const& a) {
        return fold(a, [](T x, T y) { return simd::min(x, y); });
    }
    CANOPY_SIMD_INLINE static T reduce_max(reg const& a) {
        return fold(a, [](T x, T y) { return simd::max(x, y); });
    }
    CANOPY_SIMD_INLINE static T reduce_add(reg const& a) {
        return fold(a, [](T x, T y) { return lane_add(x, y); });
    }

    CANOPY_SIMD_INLINE static reg bit_and(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] & b[i]; });
    }
    CANOPY_SIMD_INLINE static reg bit_or(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] | b[i]; });
    }
    CANOPY_SIMD_INLINE static reg bit_xor(reg const& a, reg const& b) {
        return per_lane<N>([&](int i) { return a[i] ^ b[i]; });
    }
    CANOPY_SIMD_INLINE static reg bit_not(reg const& a) {
        return per_lane<N>([&](int i) { return ~a[i]; });
    }
    CANOPY_SIMD_INLINE static reg shift_left(reg const& a, int count) {
        return per_lane<N>([&](int i) { return lane_shift_left(a[i], count); });
    }
    CANOPY_SIMD_INLINE static reg shift_right(reg const& a, int count) {
        return per_lane<N>([&](int i) { return lane_shift_right(a[i], count); });
    }

    CANOPY_SIMD_INLINE static int_reg to_int(reg const& a) {
        return per_lane<N>([&](int i) { return simd::convert_to_int(a[i]); });
    }
    CANOPY_SIMD_INLINE static auto to_float(reg const& a) {
        return per_lane<N>([&](int i) { return simd::convert_to_float(a[i]); });
    }
    CANOPY_SIMD_INLINE static int_reg as_int(reg const& a) {
        return per_lane<N>([&](int i) { return simd::as_int(a[i]); });
    }
    CANOPY_SIMD_INLINE static auto as_float(reg const& a) {
        return per_lane<N>([&](int i) { return simd::as_float(a[i]); });
    }
};

#if !defined(__FMA__) && defined(CANOPY_SIMD_SSE42)
// std::fma lane by lane through memory, for targets without FMA instructions.
template <typename Backend>
CANOPY_SIMD_INLINE typename Backend::reg fma_per_lane(typename Backend::reg a, typename Backend::reg b,
                                                      typename Backend::reg c) {
    constexpr int lanes = sizeof(typename Backend::reg) / sizeof(float);
    alignas(64) float x[lanes], y[lanes], z[lanes];
    Backend::store_aligned(x, a);
    Backend::store_aligned(y, b);
    Backend::store_aligned(z, c);
    for (int i = 0; i < lanes; ++i) x[i] = std::fma(x[i], y[i], z[i]);
    return Backend::load_aligned(x);
}
#endif

#if defined(CANOPY_SIMD_SSE42)

template <>
struct mask_backend<4> {
    static constexpr std::string_view name = "SSE4.2";
    using reg = __m128; // lanes all ones or all zeros

    CANOPY_SIMD_INLINE static reg broadcast(bool value) {
        return _mm_castsi128_ps(_mm_set1_epi32(-static_cast<int>(value)));
    }
    CANOPY_SIMD_INLINE static reg from_bits(std::uint32_t bits) {
        __m128i const lane_bit = _mm_setr_epi32(1, 2, 4, 8);
        __m128i const set = _mm_and_si128(_mm_set1_epi32(static_cast<int>(bits)), lane_bit);
        return _mm_castsi128_ps(_mm_cmpeq_epi32(set, lane_bit));
    }
    CANOPY_SIMD_INLINE static std::uint32_t bits(reg m) { return static_cast<std::uint32_t>(_mm_movemask_ps(m)); }
    CANOPY_SIMD_INLINE static reg bit_and(reg a, reg b) { return _mm_and_ps(a, b); }
    CANOPY_SIMD_INLINE static reg bit_or(reg a, reg b) { return _mm_or_ps(a, b); }
    CANOPY_SIMD_INLINE static reg bit_xor(reg a, reg b) { return _mm_xor_ps(a, b); }
    CANOPY_SIMD_INLINE static reg bit_not(reg a) { return _mm_xor_ps(a, broadcast(true)); }
    CANOPY_SIMD_INLINE static reg equal(reg a, reg b) { return bit_not(bit_xor(a, b)); }
};

template <>
struct backend<float, 4> {
    static constexpr std::string_view name = "SSE4.2";
    using reg = __m128;
    using mask_reg = __m128;
    using int_reg = __m128i;

    CANOPY_SIMD_INLINE static reg zero() { return _mm_setzero_ps(); }
    CANOPY_SIMD_INLINE static reg broadcast(float x) { return _mm_set1_ps(x); }
    CANOPY_SIMD_INLINE static reg load(float const* p) { return _mm_loadu_ps(p); }
    CANOPY_SIMD_INLINE static reg load_aligned(float const* p) { return _mm_load_ps(p); }
    CANOPY_SIMD_INLINE static void store(float* p, reg a) { _mm_storeu_ps(p, a); }
    CANOPY_SIMD_INLINE static void store_aligned(float* p, reg a) { _mm_store_ps(p, a); }

    CANOPY_SIMD_INLINE static reg add(reg a, reg b) { return _mm_add_ps(a, b); }
    CANOPY_SIMD_INLINE static reg sub(reg a, reg b) { return _mm_sub_ps(a, b); }
    CANOPY_SIMD_INLINE static reg mul(reg a, reg b) { return _mm_mul_ps(a, b); }
    CANOPY_SIMD_INLINE static reg div(reg a, reg b) { return _mm_div_ps(a, b); }
    CANOPY_SIMD_INLINE static reg neg(reg a) { return _mm_xor_ps(a, _mm_set1_ps(-0.0f)); }

    CANOPY_SIMD_INLINE static mask_reg eq(reg a, reg b) { return _mm_cmpeq_ps(a, b); }
    CANOPY_SIMD_INLINE static mask_reg ne(reg a, reg b) { return _mm_cmpneq_ps(a, b); }
    CANOPY_SIMD_INLINE static mask_reg lt(reg a, reg b) { return _mm_cmplt_ps(a, b); }
    CANOPY_SIMD_INLINE static mask_reg le(reg a, reg b) { return _mm_cmple_ps(a, b); }
    CANOPY_SIMD_INLINE static mask_reg gt(reg a, reg b) { return _mm_cmpgt_ps(a, b); }
    CANOPY_SIMD_INLINE static mask_reg ge(reg a, reg b) { return _mm_cmpge_ps(a, b); }

    CANOPY_SIMD_INLINE static reg select(mask_reg m, reg a, reg b) { return _mm_blendv_ps(b, a, m); }
    CANOPY_SIMD_INLINE static reg min(reg a, reg b) { return _mm_min_ps(a, b); }
    CANOPY_SIMD_INLINE static reg max(reg a, reg b) { return _mm_max_ps(a, b); }
    CANOPY_SIMD_INLINE static reg abs(reg a) { return _mm_andnot_ps(_mm_set1_ps(-0.0f), a); }

    CANOPY_SIMD_INLINE static reg sqrt(reg a) { return _mm_sqrt_ps(a); }
    CANOPY_SIMD_INLINE static reg rcp(reg a) { return _mm_div_ps(_mm_set1_ps(1.0f), a); }
    CANOPY_SIMD_INLINE static reg fma(reg a, reg b, reg c) {
#if defined(__FMA__)
        return _mm_fmadd_ps(a, b, c);
#else
        return fma_per_lane<backend>(a, b, c);
#endif
    }
    CANOPY_SIMD_INLINE static reg floor(reg a) { return _mm_round_ps(a, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
    CANOPY_SIMD_INLINE static reg ceil(reg a) { return _mm_round_ps(a, _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC); }
    CANOPY_SIMD_INLINE static reg copysign(reg magnitude, reg sign) {
        __m128 const sign_bit = _mm_set1_ps(-0.0f);
        return _mm_or_ps(_mm_andnot_ps(sign_bit, magnitude), _mm_and_ps(sign_bit, sign));
    }
    CANOPY_SIMD_INLINE static mask_reg isnan(reg a) { return _mm_cmpunord_ps(a, a); }
    CANOPY_SIMD_INLINE static mask_reg isfinite(reg a) {
        return _mm_cmplt_ps(abs(a), _mm_set1_ps(std::numeric_limits<float>::infinity()));
    }
    CANOPY_SIMD_INLINE static reg gather(float const* base, int_reg index) {
#if defined(CANOPY_SIMD_AVX2)
        return _mm_i32gather_ps(base, index, 4);
#else
        alignas(16) std::int32_t lane_index[4];
        _mm_store_si128(reinterpret_cast<__m128i*>(lane_index), index);
        return _mm_setr_ps(base[lane_index[0]], base[lane_index[1]], base[lane_index[2]], base[lane_index[3]]);
#endif
    }

    // Lanes 0-1 take in lanes 2-3, then lane 0 takes in lane 1 (the scalar backend's order).
    CANOPY_SIMD_INLINE static float reduce_min(reg a) {
        a = _mm_min_ps(a, _mm_movehl_ps(a, a));
        return _mm_cvtss_f32(_mm_min_ps(a, _mm_movehdup_ps(a)));
    }
    CANOPY_SIMD_INLINE static float reduce_max(reg a) {
        a = _mm_max_ps(a, _mm_movehl_ps(a, a));
        return _mm_cvtss_f32(_mm_max_ps(a, _mm_movehdup_ps(a)));
    }
    CANOPY_SIMD_INLINE static float reduce_add(reg a) {
        a = _mm_add_ps(a, _mm_movehl_ps(a, a));
        return _mm_cvtss_f32(_mm_add_ps(a, _mm_movehdup_ps(a)));
    }

    CANOPY_SIMD_INLINE static int_reg to_int(reg a) { return _mm_cvttps_epi32(a); }
    CANOPY_SIMD_INLINE static int_reg as_int(reg a) { return _mm_castps_si128(a); }
};

template <>
struct backend<std::int32_t, 4> {
    static constexpr std::string_view name = "SSE4.2";
    using reg = __m128i;
    using mask_reg = __m128;
    using int_reg = __m128i;
    using mask = mask_backend<4>;

    CANOPY_SIMD_INLINE static reg zero() { return _mm_setzero_si128(); }
    CANOPY_SIMD_INLINE static reg broadcast(std::int32_t x) { return _mm_set1_epi32(x); }
    CANOPY_SIMD_INLINE static reg load(std::int32_t const* p) {
        return _mm_loadu_si128(reinterpret_cast<__m128i const*>(p));
    }
    CANOPY_SIMD_INLINE static reg load_aligned(std::int32_t const* p) {
        return _mm_load_si128(reinterpret_cast<__m128i const*>(p));
    }
    CANOPY_SIMD_INLINE static void store(std::int32_t* p, reg a) { _mm_storeu_si128(reinterpret_cast<__m128i*>(p), a); }
    CANOPY_SIMD_INLINE static void store_aligned(std::int32_t* p, reg a) {
        _mm_store_si128(reinterpret_cast<__m128i*>(p), a);
    }

    CANOPY_SIMD_INLINE static reg add(reg a, reg b) { return _mm_add_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg sub(reg a, reg b) { return _mm_sub_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg mul(reg a, reg b) { return _mm_mullo_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg neg(reg a) { return _mm_sub_epi32(_mm_setzero_si128(), a); }

    CANOPY_SIMD_INLINE static mask_reg eq(reg a, reg b) { return _mm_castsi128_ps(_mm_cmpeq_epi32(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg ne(reg a, reg b) { return mask::bit_not(eq(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg lt(reg a, reg b) { return _mm_castsi128_ps(_mm_cmplt_epi32(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg le(reg a, reg b) { return mask::bit_not(gt(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg gt(reg a, reg b) { return _mm_castsi128_ps(_mm_cmpgt_epi32(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg ge(reg a, reg b) { return mask::bit_not(lt(a, b)); }

    CANOPY_SIMD_INLINE static reg select(mask_reg m, reg a, reg b) {
        return _mm_castps_si128(_mm_blendv_ps(_mm_castsi128_ps(b), _mm_castsi128_ps(a), m));
    }
    CANOPY_SIMD_INLINE static reg min(reg a, reg b) { return _mm_min_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg max(reg a, reg b) { return _mm_max_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg abs(reg a) { return _mm_abs_epi32(a); }
    CANOPY_SIMD_INLINE static reg gather(std::int32_t const* base, int_reg index) {
#if defined(CANOPY_SIMD_AVX2)
        return _mm_i32gather_epi32(base, index, 4);
#else
        alignas(16) std::int32_t lane_index[4];
        _mm_store_si128(reinterpret_cast<__m128i*>(lane_index), index);
        return _mm_setr_epi32(base[lane_index[0]], base[lane_index[1]], base[lane_index[2]], base[lane_index[3]]);
#endif
    }

    // The order of backend<float, 4>.
    CANOPY_SIMD_INLINE static std::int32_t reduce_min(reg a) {
        a = _mm_min_epi32(a, _mm_shuffle_epi32(a, _MM_SHUFFLE(1, 0, 3, 2)));
        return _mm_cvtsi128_si32(_mm_min_epi32(a, _mm_shuffle_epi32(a, _MM_SHUFFLE(0, 0, 0, 1))));
    }
    CANOPY_SIMD_INLINE static std::int32_t reduce_max(reg a) {
        a = _mm_max_epi32(a, _mm_shuffle_epi32(a, _MM_SHUFFLE(1, 0, 3, 2)));
        return _mm_cvtsi128_si32(_mm_max_epi32(a, _mm_shuffle_epi32(a, _MM_SHUFFLE(0, 0, 0, 1))));
    }
    CANOPY_SIMD_INLINE static std::int32_t reduce_add(reg a) {
        a = _mm_add_epi32(a, _mm_shuffle_epi32(a, _MM_SHUFFLE(1, 0, 3, 2)));
        return _mm_cvtsi128_si32(_mm_add_epi32(a, _mm_shuffle_epi32(a, _MM_SHUFFLE(0, 0, 0, 1))));
    }

    CANOPY_SIMD_INLINE static reg bit_and(reg a, reg b) { return _mm_and_si128(a, b); }
    CANOPY_SIMD_INLINE static reg bit_or(reg a, reg b) { return _mm_or_si128(a, b); }
    CANOPY_SIMD_INLINE static reg bit_xor(reg a, reg b) { return _mm_xor_si128(a, b); }
    CANOPY_SIMD_INLINE static reg bit_not(reg a) { return _mm_xor_si128(a, _mm_set1_epi32(-1)); }
    CANOPY_SIMD_INLINE static reg shift_left(reg a, int count) { return _mm_sll_epi32(a, _mm_cvtsi32_si128(count)); }
    CANOPY_SIMD_INLINE static reg shift_right(reg a, int count) { return _mm_sra_epi32(a, _mm_cvtsi32_si128(count)); }

    CANOPY_SIMD_INLINE static __m128 to_float(reg a) { return _mm_cvtepi32_ps(a); }
    CANOPY_SIMD_INLINE static __m128 as_float(reg a) { return _mm_castsi128_ps(a); }
};

#endif // CANOPY_SIMD_SSE42

#if defined(CANOPY_SIMD_AVX2)

template <>
struct mask_backend<8> {
    static constexpr std::string_view name = "AVX2";
    using reg = __m256; // lanes all ones or all zeros

    CANOPY_SIMD_INLINE static reg broadcast(bool value) {
        return _mm256_castsi256_ps(_mm256_set1_epi32(-static_cast<int>(value)));
    }
    CANOPY_SIMD_INLINE static reg from_bits(std::uint32_t bits) {
        __m256i const lane_bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        __m256i const set = _mm256_and_si256(_mm256_set1_epi32(static_cast<int>(bits)), lane_bit);
        return _mm256_castsi256_ps(_mm256_cmpeq_epi32(set, lane_bit));
    }
    CANOPY_SIMD_INLINE static std::uint32_t bits(reg m) { return static_cast<std::uint32_t>(_mm256_movemask_ps(m)); }
    CANOPY_SIMD_INLINE static reg bit_and(reg a, reg b) { return _mm256_and_ps(a, b); }
    CANOPY_SIMD_INLINE static reg bit_or(reg a, reg b) { return _mm256_or_ps(a, b); }
    CANOPY_SIMD_INLINE static reg bit_xor(reg a, reg b) { return _mm256_xor_ps(a, b); }
    CANOPY_SIMD_INLINE static reg bit_not(reg a) { return _mm256_xor_ps(a, broadcast(true)); }
    CANOPY_SIMD_INLINE static reg equal(reg a, reg b) { return bit_not(bit_xor(a, b)); }
};

template <>
struct backend<float, 8> {
    static constexpr std::string_view name = "AVX2";
    using reg = __m256;
    using mask_reg = __m256;
    using int_reg = __m256i;

    CANOPY_SIMD_INLINE static reg zero() { return _mm256_setzero_ps(); }
    CANOPY_SIMD_INLINE static reg broadcast(float x) { return _mm256_set1_ps(x); }
    CANOPY_SIMD_INLINE static reg load(float const* p) { return _mm256_loadu_ps(p); }
    CANOPY_SIMD_INLINE static reg load_aligned(float const* p) { return _mm256_load_ps(p); }
    CANOPY_SIMD_INLINE static void store(float* p, reg a) { _mm256_storeu_ps(p, a); }
    CANOPY_SIMD_INLINE static void store_aligned(float* p, reg a) { _mm256_store_ps(p, a); }

    CANOPY_SIMD_INLINE static reg add(reg a, reg b) { return _mm256_add_ps(a, b); }
    CANOPY_SIMD_INLINE static reg sub(reg a, reg b) { return _mm256_sub_ps(a, b); }
    CANOPY_SIMD_INLINE static reg mul(reg a, reg b) { return _mm256_mul_ps(a, b); }
    CANOPY_SIMD_INLINE static reg div(reg a, reg b) { return _mm256_div_ps(a, b); }
    CANOPY_SIMD_INLINE static reg neg(reg a) { return _mm256_xor_ps(a, _mm256_set1_ps(-0.0f)); }

    CANOPY_SIMD_INLINE static mask_reg eq(reg a, reg b) { return _mm256_cmp_ps(a, b, _CMP_EQ_OQ); }
    CANOPY_SIMD_INLINE static mask_reg ne(reg a, reg b) { return _mm256_cmp_ps(a, b, _CMP_NEQ_UQ); }
    CANOPY_SIMD_INLINE static mask_reg lt(reg a, reg b) { return _mm256_cmp_ps(a, b, _CMP_LT_OQ); }
    CANOPY_SIMD_INLINE static mask_reg le(reg a, reg b) { return _mm256_cmp_ps(a, b, _CMP_LE_OQ); }
    CANOPY_SIMD_INLINE static mask_reg gt(reg a, reg b) { return _mm256_cmp_ps(a, b, _CMP_GT_OQ); }
    CANOPY_SIMD_INLINE static mask_reg ge(reg a, reg b) { return _mm256_cmp_ps(a, b, _CMP_GE_OQ); }

    CANOPY_SIMD_INLINE static reg select(mask_reg m, reg a, reg b) { return _mm256_blendv_ps(b, a, m); }
    CANOPY_SIMD_INLINE static reg min(reg a, reg b) { return _mm256_min_ps(a, b); }
    CANOPY_SIMD_INLINE static reg max(reg a, reg b) { return _mm256_max_ps(a, b); }
    CANOPY_SIMD_INLINE static reg abs(reg a) { return _mm256_andnot_ps(_mm256_set1_ps(-0.0f), a); }

    CANOPY_SIMD_INLINE static reg sqrt(reg a) { return _mm256_sqrt_ps(a); }
    CANOPY_SIMD_INLINE static reg rcp(reg a) { return _mm256_div_ps(_mm256_set1_ps(1.0f), a); }
    CANOPY_SIMD_INLINE static reg fma(reg a, reg b, reg c) {
#if defined(__FMA__)
        return _mm256_fmadd_ps(a, b, c);
#else
        return fma_per_lane<backend>(a, b, c);
#endif
    }
    CANOPY_SIMD_INLINE static reg floor(reg a) { return _mm256_round_ps(a, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
    CANOPY_SIMD_INLINE static reg ceil(reg a) { return _mm256_round_ps(a, _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC); }
    CANOPY_SIMD_INLINE static reg copysign(reg magnitude, reg sign) {
        __m256 const sign_bit = _mm256_set1_ps(-0.0f);
        return _mm256_or_ps(_mm256_andnot_ps(sign_bit, magnitude), _mm256_and_ps(sign_bit, sign));
    }
    CANOPY_SIMD_INLINE static mask_reg isnan(reg a) { return _mm256_cmp_ps(a, a, _CMP_UNORD_Q); }
    CANOPY_SIMD_INLINE static mask_reg isfinite(reg a) {
        return _mm256_cmp_ps(abs(a), _mm256_set1_ps(std::numeric_limits<float>::infinity()), _CMP_LT_OQ);
    }
    CANOPY_SIMD_INLINE static reg gather(float const* base, int_reg index) {
        return _mm256_i32gather_ps(base, index, 4);
    }

    // Lanes 0-3 take in lanes 4-7, then the order of backend<float, 4>.
    CANOPY_SIMD_INLINE static float reduce_min(reg a) {
        return backend<float, 4>::reduce_min(_mm_min_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1)));
    }
    CANOPY_SIMD_INLINE static float reduce_max(reg a) {
        return backend<float, 4>::reduce_max(_mm_max_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1)));
    }
    CANOPY_SIMD_INLINE static float reduce_add(reg a) {
        return backend<float, 4>::reduce_add(_mm_add_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1)));
    }

    CANOPY_SIMD_INLINE static int_reg to_int(reg a) { return _mm256_cvttps_epi32(a); }
    CANOPY_SIMD_INLINE static int_reg as_int(reg a) { return _mm256_castps_si256(a); }
};

template <>
struct backend<std::int32_t, 8> {
    static constexpr std::string_view name = "AVX2";
    using reg = __m256i;
    using mask_reg = __m256;
    using int_reg = __m256i;
    using mask = mask_backend<8>;

    CANOPY_SIMD_INLINE static reg zero() { return _mm256_setzero_si256(); }
    CANOPY_SIMD_INLINE static reg broadcast(std::int32_t x) { return _mm256_set1_epi32(x); }
    CANOPY_SIMD_INLINE static reg load(std::int32_t const* p) {
        return _mm256_loadu_si256(reinterpret_cast<__m256i const*>(p));
    }
    CANOPY_SIMD_INLINE static reg load_aligned(std::int32_t const* p) {
        return _mm256_load_si256(reinterpret_cast<__m256i const*>(p));
    }
    CANOPY_SIMD_INLINE static void store(std::int32_t* p, reg a) {
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(p), a);
    }
    CANOPY_SIMD_INLINE static void store_aligned(std::int32_t* p, reg a) {
        _mm256_store_si256(reinterpret_cast<__m256i*>(p), a);
    }

    CANOPY_SIMD_INLINE static reg add(reg a, reg b) { return _mm256_add_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg sub(reg a, reg b) { return _mm256_sub_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg mul(reg a, reg b) { return _mm256_mullo_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg neg(reg a) { return _mm256_sub_epi32(_mm256_setzero_si256(), a); }

    CANOPY_SIMD_INLINE static mask_reg eq(reg a, reg b) { return _mm256_castsi256_ps(_mm256_cmpeq_epi32(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg ne(reg a, reg b) { return mask::bit_not(eq(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg lt(reg a, reg b) { return gt(b, a); }
    CANOPY_SIMD_INLINE static mask_reg le(reg a, reg b) { return mask::bit_not(gt(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg gt(reg a, reg b) { return _mm256_castsi256_ps(_mm256_cmpgt_epi32(a, b)); }
    CANOPY_SIMD_INLINE static mask_reg ge(reg a, reg b) { return mask::bit_not(gt(b, a)); }

    CANOPY_SIMD_INLINE static reg select(mask_reg m, reg a, reg b) {
        return _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(b), _mm256_castsi256_ps(a), m));
    }
    CANOPY_SIMD_INLINE static reg min(reg a, reg b) { return _mm256_min_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg max(reg a, reg b) { return _mm256_max_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg abs(reg a) { return _mm256_abs_epi32(a); }
    CANOPY_SIMD_INLINE static reg gather(std::int32_t const* base, int_reg index) {
        return _mm256_i32gather_epi32(base, index, 4);
    }

    // The order of backend<float, 8>.
    CANOPY_SIMD_INLINE static std::int32_t reduce_min(reg a) {
        return backend<std::int32_t, 4>::reduce_min(
            _mm_min_epi32(_mm256_castsi256_si128(a), _mm256_extracti128_si256(a, 1)));
    }
    CANOPY_SIMD_INLINE static std::int32_t reduce_max(reg a) {
        return backend<std::int32_t, 4>::reduce_max(
            _mm_max_epi32(_mm256_castsi256_si128(a), _mm256_extracti128_si256(a, 1)));
    }
    CANOPY_SIMD_INLINE static std::int32_t reduce_add(reg a) {
        return backend<std::int32_t, 4>::reduce_add(
            _mm_add_epi32(_mm256_castsi256_si128(a), _mm256_extracti128_si256(a, 1)));
    }

    CANOPY_SIMD_INLINE static reg bit_and(reg a, reg b) { return _mm256_and_si256(a, b); }
    CANOPY_SIMD_INLINE static reg bit_or(reg a, reg b) { return _mm256_or_si256(a, b); }
    CANOPY_SIMD_INLINE static reg bit_xor(reg a, reg b) { return _mm256_xor_si256(a, b); }
    CANOPY_SIMD_INLINE static reg bit_not(reg a) { return _mm256_xor_si256(a, _mm256_set1_epi32(-1)); }
    CANOPY_SIMD_INLINE static reg shift_left(reg a, int count) { return _mm256_sll_epi32(a, _mm_cvtsi32_si128(count)); }
    CANOPY_SIMD_INLINE static reg shift_right(reg a, int count) {
        return _mm256_sra_epi32(a, _mm_cvtsi32_si128(count));
    }

    CANOPY_SIMD_INLINE static __m256 to_float(reg a) { return _mm256_cvtepi32_ps(a); }
    CANOPY_SIMD_INLINE static __m256 as_float(reg a) { return _mm256_castsi256_ps(a); }
};

#endif // CANOPY_SIMD_AVX2

#if defined(CANOPY_SIMD_AVX512)

template <>
struct mask_backend<16> {
    static constexpr std::string_view name = "AVX-512";
    using reg = __mmask16;

    CANOPY_SIMD_INLINE static reg broadcast(bool value) { return value ? reg{0xFFFF} : reg{0}; }
    CANOPY_SIMD_INLINE static reg from_bits(std::uint32_t bits) { return static_cast<reg>(bits); }
    CANOPY_SIMD_INLINE static std::uint32_t bits(reg m) { return _cvtmask16_u32(m); }
    CANOPY_SIMD_INLINE static reg bit_and(reg a, reg b) { return _kand_mask16(a, b); }
    CANOPY_SIMD_INLINE static reg bit_or(reg a, reg b) { return _kor_mask16(a, b); }
    CANOPY_SIMD_INLINE static reg bit_xor(reg a, reg b) { return _kxor_mask16(a, b); }
    CANOPY_SIMD_INLINE static reg bit_not(reg a) { return _knot_mask16(a); }
    CANOPY_SIMD_INLINE static reg equal(reg a, reg b) { return _kxnor_mask16(a, b); }
};

template <>
struct backend<float, 16> {
    static constexpr std::string_view name = "AVX-512";
    using reg = __m512;
    using mask_reg = __mmask16;
    using int_reg = __m512i;

    CANOPY_SIMD_INLINE static reg zero() { return _mm512_setzero_ps(); }
    CANOPY_SIMD_INLINE static reg broadcast(float x) { return _mm512_set1_ps(x); }
    CANOPY_SIMD_INLINE static reg load(float const* p) { return _mm512_loadu_ps(p); }
    CANOPY_SIMD_INLINE static reg load_aligned(float const* p) { return _mm512_load_ps(p); }
    CANOPY_SIMD_INLINE static void store(float* p, reg a) { _mm512_storeu_ps(p, a); }
    CANOPY_SIMD_INLINE static void store_aligned(float* p, reg a) { _mm512_store_ps(p, a); }

    CANOPY_SIMD_INLINE static reg add(reg a, reg b) { return _mm512_add_ps(a, b); }
    CANOPY_SIMD_INLINE static reg sub(reg a, reg b) { return _mm512_sub_ps(a, b); }
    CANOPY_SIMD_INLINE static reg mul(reg a, reg b) { return _mm512_mul_ps(a, b); }
    CANOPY_SIMD_INLINE static reg div(reg a, reg b) { return _mm512_div_ps(a, b); }
    // Sign-bit logic on the integer side: the float forms need AVX512DQ.
    CANOPY_SIMD_INLINE static reg neg(reg a) {
        return _mm512_castsi512_ps(_mm512_xor_si512(_mm512_castps_si512(a), sign_bit()));
    }

    CANOPY_SIMD_INLINE static mask_reg eq(reg a, reg b) { return _mm512_cmp_ps_mask(a, b, _CMP_EQ_OQ); }
    CANOPY_SIMD_INLINE static mask_reg ne(reg a, reg b) { return _mm512_cmp_ps_mask(a, b, _CMP_NEQ_UQ); }
    CANOPY_SIMD_INLINE static mask_reg lt(reg a, reg b) { return _mm512_cmp_ps_mask(a, b, _CMP_LT_OQ); }
    CANOPY_SIMD_INLINE static mask_reg le(reg a, reg b) { return _mm512_cmp_ps_mask(a, b, _CMP_LE_OQ); }
    CANOPY_SIMD_INLINE static mask_reg gt(reg a, reg b) { return _mm512_cmp_ps_mask(a, b, _CMP_GT_OQ); }
    CANOPY_SIMD_INLINE static mask_reg ge(reg a, reg b) { return _mm512_cmp_ps_mask(a, b, _CMP_GE_OQ); }

    CANOPY_SIMD_INLINE static reg select(mask_reg m, reg a, reg b) { return _mm512_mask_blend_ps(m, b, a); }
    CANOPY_SIMD_INLINE static reg min(reg a, reg b) { return _mm512_min_ps(a, b); }
    CANOPY_SIMD_INLINE static reg max(reg a, reg b) { return _mm512_max_ps(a, b); }
    CANOPY_SIMD_INLINE static reg abs(reg a) { return _mm512_abs_ps(a); }

    CANOPY_SIMD_INLINE static reg sqrt(reg a) { return _mm512_sqrt_ps(a); }
    CANOPY_SIMD_INLINE static reg rcp(reg a) { return _mm512_div_ps(_mm512_set1_ps(1.0f), a); }
    CANOPY_SIMD_INLINE static reg fma(reg a, reg b, reg c) { return _mm512_fmadd_ps(a, b, c); }
    CANOPY_SIMD_INLINE static reg floor(reg a) {
        return _mm512_roundscale_ps(a, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
    }
    CANOPY_SIMD_INLINE static reg ceil(reg a) {
        return _mm512_roundscale_ps(a, _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC);
    }
    CANOPY_SIMD_INLINE static reg copysign(reg magnitude, reg sign) {
        __m512i const magnitude_bits = _mm512_andnot_si512(sign_bit(), _mm512_castps_si512(magnitude));
        __m512i const sign_bits = _mm512_and_si512(sign_bit(), _mm512_castps_si512(sign));
        return _mm512_castsi512_ps(_mm512_or_si512(magnitude_bits, sign_bits));
    }
    CANOPY_SIMD_INLINE static mask_reg isnan(reg a) { return _mm512_cmp_ps_mask(a, a, _CMP_UNORD_Q); }
    CANOPY_SIMD_INLINE static mask_reg isfinite(reg a) {
        return _mm512_cmp_ps_mask(abs(a), _mm512_set1_ps(std::numeric_limits<float>::infinity()), _CMP_LT_OQ);
    }
    CANOPY_SIMD_INLINE static reg gather(float const* base, int_reg index) {
        return _mm512_i32gather_ps(index, base, 4);
    }

    // Lanes 0-7 take in lanes 8-15, then the order of backend<float, 8>.
    CANOPY_SIMD_INLINE static float reduce_min(reg a) {
        return backend<float, 8>::reduce_min(_mm256_min_ps(low_half(a), high_half(a)));
    }
    CANOPY_SIMD_INLINE static float reduce_max(reg a) {
        return backend<float, 8>::reduce_max(_mm256_max_ps(low_half(a), high_half(a)));
    }
    CANOPY_SIMD_INLINE static float reduce_add(reg a) {
        return backend<float, 8>::reduce_add(_mm256_add_ps(low_half(a), high_half(a)));
    }

    CANOPY_SIMD_INLINE static int_reg to_int(reg a) { return _mm512_cvttps_epi32(a); }
    CANOPY_SIMD_INLINE static int_reg as_int(reg a) { return _mm512_castps_si512(a); }

private:
    CANOPY_SIMD_INLINE static __m512i sign_bit() { return _mm512_set1_epi32(std::numeric_limits<std::int32_t>::min()); }
    CANOPY_SIMD_INLINE static __m256 low_half(reg a) { return _mm512_castps512_ps256(a); }
    CANOPY_SIMD_INLINE static __m256 high_half(reg a) {
        return _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(a), 1));
    }
};

template <>
struct backend<std::int32_t, 16> {
    static constexpr std::string_view name = "AVX-512";
    using reg = __m512i;
    using mask_reg = __mmask16;
    using int_reg = __m512i;

    CANOPY_SIMD_INLINE static reg zero() { return _mm512_setzero_si512(); }
    CANOPY_SIMD_INLINE static reg broadcast(std::int32_t x) { return _mm512_set1_epi32(x); }
    CANOPY_SIMD_INLINE static reg load(std::int32_t const* p) { return _mm512_loadu_si512(p); }
    CANOPY_SIMD_INLINE static reg load_aligned(std::int32_t const* p) { return _mm512_load_si512(p); }
    CANOPY_SIMD_INLINE static void store(std::int32_t* p, reg a) { _mm512_storeu_si512(p, a); }
    CANOPY_SIMD_INLINE static void store_aligned(std::int32_t* p, reg a) { _mm512_store_si512(p, a); }

    CANOPY_SIMD_INLINE static reg add(reg a, reg b) { return _mm512_add_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg sub(reg a, reg b) { return _mm512_sub_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg mul(reg a, reg b) { return _mm512_mullo_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg neg(reg a) { return _mm512_sub_epi32(_mm512_setzero_si512(), a); }

    CANOPY_SIMD_INLINE static mask_reg eq(reg a, reg b) { return _mm512_cmpeq_epi32_mask(a, b); }
    CANOPY_SIMD_INLINE static mask_reg ne(reg a, reg b) { return _mm512_cmpneq_epi32_mask(a, b); }
    CANOPY_SIMD_INLINE static mask_reg lt(reg a, reg b) { return _mm512_cmplt_epi32_mask(a, b); }
    CANOPY_SIMD_INLINE static mask_reg le(reg a, reg b) { return _mm512_cmple_epi32_mask(a, b); }
    CANOPY_SIMD_INLINE static mask_reg gt(reg a, reg b) { return _mm512_cmpgt_epi32_mask(a, b); }
    CANOPY_SIMD_INLINE static mask_reg ge(reg a, reg b) { return _mm512_cmpge_epi32_mask(a, b); }

    CANOPY_SIMD_INLINE static reg select(mask_reg m, reg a, reg b) { return _mm512_mask_blend_epi32(m, b, a); }
    CANOPY_SIMD_INLINE static reg min(reg a, reg b) { return _mm512_min_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg max(reg a, reg b) { return _mm512_max_epi32(a, b); }
    CANOPY_SIMD_INLINE static reg abs(reg a) { return _mm512_abs_epi32(a); }
    CANOPY_SIMD_INLINE static reg gather(std::int32_t const* base, int_reg index) {
        return _mm512_i32gather_epi32(index, base, 4);
    }

    // The order of backend<float, 16>.
    CANOPY_SIMD_INLINE static std::int32_t reduce_min(reg a) {
        return backend<std::int32_t, 8>::reduce_min(_mm256_min_epi32(low_half(a), high_half(a)));
    }
    CANOPY_SIMD_INLINE static std::int32_t reduce_max(reg a) {
        return backend<std::int32_t, 8>::reduce_max(_mm256_max_epi32(low_half(a), high_half(a)));
    }
    CANOPY_SIMD_INLINE static std::int32_t reduce_add(reg a) {
        return backend<std::int32_t, 8>::reduce_add(_mm256_add_epi32(low_half(a), high_half(a)));
    }

    CANOPY_SIMD_INLINE static reg bit_and(reg a, reg b) { return _mm512_and_si512(a, b); }
    CANOPY_SIMD_INLINE static reg bit_or(reg a, reg b) { return _mm512_or_si512(a, b); }
    CANOPY_SIMD_INLINE static reg bit_xor(reg a, reg b) { return _mm512_xor_si512(a, b); }
    CANOPY_SIMD_INLINE static reg bit_not(reg a) { return _mm512_xor_si512(a, _mm512_set1_epi32(-1)); }
    CANOPY_SIMD_INLINE static reg shift_left(reg a, int count) { return _mm512_sll_epi32(a, _mm_cvtsi32_si128(count)); }
    CANOPY_SIMD_INLINE static reg shift_right(reg a, int count) {
        return _mm512_sra_epi32(a, _mm_cvtsi32_si128(count));
    }

    CANOPY_SIMD_INLINE static __m512 to_float(reg a) { return _mm512_cvtepi32_ps(a); }
    CANOPY_SIMD_INLINE static __m512 as_float(reg a) { return _mm512_castsi512_ps(a); }

private:
    CANOPY_SIMD_INLINE static __m256i low_half(reg a) { return _mm512_castsi512_si256(a); }
    CANOPY_SIMD_INLINE static __m256i high_half(reg a) { return _mm512_extracti64x4_epi64(a, 1); }
};

#endif // CANOPY_SIMD_AVX512

} // namespace canopy::simd::detail

export namespace canopy::simd {

// N boolean lanes (N = 4, 8 or 16), the result of comparing two basic_simd<T, N>. A bool converts
// implicitly (broadcast). All operators, == and != included, work lane by lane.
template <int N>
class basic_mask {
    static_assert(N == 4 || N == 8 || N == 16, "masks have 4, 8 or 16 lanes");
    using backend = detail::mask_backend<N>;

public:
    static constexpr int width = N;
    // The backend's representation: a vector register (SSE4.2, AVX2), __mmask16 (AVX-512) or
    // std::array<bool, N> (scalar).
    using register_type = typename backend::reg;

    // All lanes false.
    CANOPY_SIMD_INLINE basic_mask() : reg_(backend::broadcast(false)) {}
    // Every lane = value.
    CANOPY_SIMD_INLINE basic_mask(bool value) : reg_(backend::broadcast(value)) {}
    CANOPY_SIMD_INLINE explicit basic_mask(register_type native_mask) : reg_(native_mask) {}

    // Lane i = bit i of bits; bits N and above are ignored.
    CANOPY_SIMD_INLINE static basic_mask from_bits(std::uint32_t bits) { return basic_mask(backend::from_bits(bits)); }

    CANOPY_SIMD_INLINE register_type native() const { return reg_; }

    // Lane i, 0 <= i < N (unchecked).
    CANOPY_SIMD_INLINE bool operator[](int i) const { return ((backend::bits(reg_) >> i) & 1u) != 0; }
    CANOPY_SIMD_INLINE void set(int i, bool value) {
        std::uint32_t const others = backend::bits(reg_) & ~(1u << i);
        reg_ = backend::from_bits(others | (static_cast<std::uint32_t>(value) << i));
    }

    CANOPY_SIMD_INLINE friend basic_mask operator&(basic_mask a, basic_mask b) {
        return basic_mask(backend::bit_and(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_mask operator|(basic_mask a, basic_mask b) {
        return basic_mask(backend::bit_or(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_mask operator^(basic_mask a, basic_mask b) {
        return basic_mask(backend::bit_xor(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_mask operator!(basic_mask a) { return basic_mask(backend::bit_not(a.reg_)); }
    CANOPY_SIMD_INLINE friend basic_mask operator==(basic_mask a, basic_mask b) {
        return basic_mask(backend::equal(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_mask operator!=(basic_mask a, basic_mask b) {
        return basic_mask(backend::bit_xor(a.reg_, b.reg_));
    }

    CANOPY_SIMD_INLINE basic_mask& operator&=(basic_mask b) { return *this = *this & b; }
    CANOPY_SIMD_INLINE basic_mask& operator|=(basic_mask b) { return *this = *this | b; }
    CANOPY_SIMD_INLINE basic_mask& operator^=(basic_mask b) { return *this = *this ^ b; }

private:
    register_type reg_;
};

// N lanes of T (float or std::int32_t; N = 4, 8 or 16), N * sizeof(T) bytes aligned to their
// size on every backend. A T converts implicitly (broadcast), so `x * 2.0f` works. Operators work
// lane by lane; integer arithmetic wraps around; comparisons are IEEE (false when a lane is NaN,
// except != which is true).
template <typename T, int N>
class alignas(N * sizeof(T)) basic_simd {
    static_assert(std::same_as<T, float> || std::same_as<T, std::int32_t>, "lanes are float or std::int32_t");
    static_assert(N == 4 || N == 8 || N == 16, "vectors have 4, 8 or 16 lanes");
    using backend = detail::backend<T, N>;

public:
    static constexpr int width = N;
    using value_type = T;
    using mask_type = basic_mask<N>;
    // The backend's representation: an intrinsic vector register, or std::array<T, N> (scalar).
    using register_type = typename backend::reg;

    // All lanes zero.
    CANOPY_SIMD_INLINE basic_simd() : reg_(backend::zero()) {}
    // Every lane = value.
    CANOPY_SIMD_INLINE basic_simd(T value) : reg_(backend::broadcast(value)) {}
    CANOPY_SIMD_INLINE explicit basic_simd(register_type native_vector) : reg_(native_vector) {}

    // Lanes p[0], ..., p[N - 1]; p needs no alignment.
    CANOPY_SIMD_INLINE static basic_simd load(T const* p) { return basic_simd(backend::load(p)); }
    // Same, p aligned to N * sizeof(T) bytes (64 suffices for every width).
    CANOPY_SIMD_INLINE static basic_simd load_aligned(T const* p) { return basic_simd(backend::load_aligned(p)); }
    CANOPY_SIMD_INLINE void store(T* p) const { backend::store(p, reg_); }
    CANOPY_SIMD_INLINE void store_aligned(T* p) const { backend::store_aligned(p, reg_); }

    // 0, 1, ..., N - 1.
    CANOPY_SIMD_INLINE static basic_simd iota() {
        alignas(64) T lanes[N];
        for (int i = 0; i < N; ++i) lanes[i] = static_cast<T>(i);
        return load_aligned(lanes);
    }

    CANOPY_SIMD_INLINE register_type native() const { return reg_; }

    // Lane i, 0 <= i < N (unchecked). Goes through memory: not for hot loops.
    CANOPY_SIMD_INLINE T operator[](int i) const {
        alignas(64) T lanes[N];
        store_aligned(lanes);
        return lanes[i];
    }
    CANOPY_SIMD_INLINE void set(int i, T value) {
        alignas(64) T lanes[N];
        store_aligned(lanes);
        lanes[i] = value;
        *this = load_aligned(lanes);
    }

    CANOPY_SIMD_INLINE friend basic_simd operator+(basic_simd a, basic_simd b) {
        return basic_simd(backend::add(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_simd operator-(basic_simd a, basic_simd b) {
        return basic_simd(backend::sub(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_simd operator*(basic_simd a, basic_simd b) {
        return basic_simd(backend::mul(a.reg_, b.reg_));
    }
    // Floats: correctly rounded. Integers: truncated like the built-in /, lane by lane through
    // memory (x86 has no SIMD integer division); a lane dividing by 0 or INT_MIN by -1 is undefined.
    CANOPY_SIMD_INLINE friend basic_simd operator/(basic_simd a, basic_simd b) {
        if constexpr (std::integral<T>) {
            alignas(64) T quotient[N], divisor[N];
            a.store_aligned(quotient);
            b.store_aligned(divisor);
            for (int i = 0; i < N; ++i) quotient[i] /= divisor[i];
            return load_aligned(quotient);
        } else {
            return basic_simd(backend::div(a.reg_, b.reg_));
        }
    }
    // Floats flip the sign bit (-0 for +0, NaN too); integers wrap (-INT_MIN = INT_MIN).
    CANOPY_SIMD_INLINE friend basic_simd operator-(basic_simd a) { return basic_simd(backend::neg(a.reg_)); }

    CANOPY_SIMD_INLINE friend basic_simd operator&(basic_simd a, basic_simd b)
        requires std::integral<T>
    {
        return basic_simd(backend::bit_and(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_simd operator|(basic_simd a, basic_simd b)
        requires std::integral<T>
    {
        return basic_simd(backend::bit_or(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_simd operator^(basic_simd a, basic_simd b)
        requires std::integral<T>
    {
        return basic_simd(backend::bit_xor(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend basic_simd operator~(basic_simd a)
        requires std::integral<T>
    {
        return basic_simd(backend::bit_not(a.reg_));
    }
    // Every lane shifted by count; counts outside [0, 31] give 0.
    CANOPY_SIMD_INLINE friend basic_simd operator<<(basic_simd a, int count)
        requires std::integral<T>
    {
        return basic_simd(backend::shift_left(a.reg_, count));
    }
    // Arithmetic (sign-filling) shift; counts outside [0, 31] shift by 31.
    CANOPY_SIMD_INLINE friend basic_simd operator>>(basic_simd a, int count)
        requires std::integral<T>
    {
        return basic_simd(backend::shift_right(a.reg_, count));
    }

    CANOPY_SIMD_INLINE friend mask_type operator==(basic_simd a, basic_simd b) {
        return mask_type(backend::eq(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend mask_type operator!=(basic_simd a, basic_simd b) {
        return mask_type(backend::ne(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend mask_type operator<(basic_simd a, basic_simd b) {
        return mask_type(backend::lt(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend mask_type operator<=(basic_simd a, basic_simd b) {
        return mask_type(backend::le(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend mask_type operator>(basic_simd a, basic_simd b) {
        return mask_type(backend::gt(a.reg_, b.reg_));
    }
    CANOPY_SIMD_INLINE friend mask_type operator>=(basic_simd a, basic_simd b) {
        return mask_type(backend::ge(a.reg_, b.reg_));
    }

    CANOPY_SIMD_INLINE basic_simd& operator+=(basic_simd b) { return *this = *this + b; }
    CANOPY_SIMD_INLINE basic_simd& operator-=(basic_simd b) { return *this = *this - b; }
    CANOPY_SIMD_INLINE basic_simd& operator*=(basic_simd b) { return *this = *this * b; }
    CANOPY_SIMD_INLINE basic_simd& operator/=(basic_simd b) { return *this = *this / b; }
    CANOPY_SIMD_INLINE basic_simd& operator&=(basic_simd b)
        requires std::integral<T>
    {
        return *this = *this & b;
    }
    CANOPY_SIMD_INLINE basic_simd& operator|=(basic_simd b)
        requires std::integral<T>
    {
        return *this = *this | b;
    }
    CANOPY_SIMD_INLINE basic_simd& operator^=(basic_simd b)
        requires std::integral<T>
    {
        return *this = *this ^ b;
    }
    CANOPY_SIMD_INLINE basic_simd& operator<<=(int count)
        requires std::integral<T>
    {
        return *this = *this << count;
    }
    CANOPY_SIMD_INLINE basic_simd& operator>>=(int count)
        requires std::integral<T>
    {
        return *this = *this >> count;
    }

private:
    register_type reg_;
};

using float4 = basic_simd<float, 4>;
using float8 = basic_simd<float, 8>;
using float16 = basic_simd<float, 16>;
using int4 = basic_simd<std::int32_t, 4>;
using int8 = basic_simd<std::int32_t, 8>;
using int16 = basic_simd<std::int32_t, 16>;
using mask4 = basic_mask<4>;
using mask8 = basic_mask<8>;
using mask16 = basic_mask<16>;

// Whether a·b + c with a single rounding (fma) is one instruction in this build (FMA3), rather
// than std::fma lane by lane. Kernels that use fma only for speed check it.
inline constexpr bool native_fma =
#if defined(__FMA__)
    true;
#else
    false;
#endif

// Whether N-lane vectors run on SIMD instructions in this build (false: the portable scalar
// backend). Kernels choose their widths with it.
template <int N>
inline constexpr bool native_width =
#if defined(CANOPY_SIMD_AVX512)
    N == 4 || N == 8 || N == 16;
#elif defined(CANOPY_SIMD_AVX2)
    N == 4 || N == 8;
#elif defined(CANOPY_SIMD_SSE42)
        N == 4;
#else
        false;
#endif

} // namespace canopy::simd

namespace canopy::simd::detail {

template <typename T>
inline constexpr bool is_simd = false;
template <typename T, int N>
inline constexpr bool is_simd<basic_simd<T, N>> = true;

template <typename T>
inline constexpr bool is_mask = false;
template <int N>
inline constexpr bool is_mask<basic_mask<N>> = true;

// Lane count, lane type, mask type and same-width integer / floating-point types of T.
template <typename T>
struct traits;

template <>
struct traits<float> {
    static constexpr int width = 1;
    using scalar = float;
    using mask = bool;
    using int_type = std::int32_t;
    using float_type = float;
};

template <>
struct traits<double> {
    static constexpr int width = 1;
    using scalar = double;
    using mask = bool;
    using int_type = std::int64_t;
    using float_type = double;
};

template <>
struct traits<std::int32_t> {
    static constexpr int width = 1;
    using scalar = std::int32_t;
    using mask = bool;
    using int_type = std::int32_t;
    using float_type = float;
};

template <>
struct traits<bool> {
    static constexpr int width = 1;
    using scalar = bool;
    using mask = bool;
};

template <typename T, int N>
struct traits<basic_simd<T, N>> {
    static constexpr int width = N;
    using scalar = T;
    using mask = basic_mask<N>;
    using int_type = basic_simd<std::int32_t, N>;
    using float_type = basic_simd<float, N>;
};

template <int N>
struct traits<basic_mask<N>> {
    static constexpr int width = N;
    using scalar = bool;
    using mask = basic_mask<N>;
};

template <typename V>
using backend_of = backend<typename V::value_type, V::width>;

// The type of the first basic_simd among Args; no `type` when there is none.
template <typename... Args>
struct first_simd {};
template <typename A, typename... Rest>
struct first_simd<A, Rest...> : std::conditional_t<is_simd<A>, std::type_identity<A>, first_simd<Rest...>> {};
template <typename... Args>
using first_simd_t = typename first_simd<std::remove_cvref_t<Args>...>::type;

// A is the vector type V or its lane type, which is broadcast to every lane.
template <typename A, typename V>
concept broadcasts_to = std::same_as<std::remove_cvref_t<A>, V> ||
                        std::same_as<std::remove_cvref_t<A>, typename V::value_type>;

} // namespace canopy::simd::detail

export namespace canopy::simd {

// Traits, defined for basic_simd, basic_mask and the one-lane types float, double, std::int32_t
// and bool: lane count, lane type, mask type, and the integer / floating-point type of the same
// width (int_type_t<double> is std::int64_t).
template <typename T>
inline constexpr int simd_width_v = detail::traits<T>::width;
template <typename T>
using scalar_type_t = typename detail::traits<T>::scalar;
template <typename T>
using mask_type_t = typename detail::traits<T>::mask;
template <typename T>
using int_type_t = typename detail::traits<T>::int_type;
template <typename T>
using float_type_t = typename detail::traits<T>::float_type;

template <typename T>
concept simd_type = detail::is_simd<T>;

// The backend that V runs on: "AVX-512", "AVX2", "SSE4.2" or "scalar" ("scalar" for every
// non-vector type).
template <typename V>
constexpr std::string_view backend_name() {
    if constexpr (simd_type<V>)
        return detail::backend_of<V>::name;
    else if constexpr (detail::is_mask<V>)
        return detail::mask_backend<V::width>::name;
    else
        return "scalar";
}

// The widest native backend in use, or "scalar" when there is none.
constexpr std::string_view isa_name() {
    if (backend_name<float16>() != "scalar") return backend_name<float16>();
    if (backend_name<float8>() != "scalar") return backend_name<float8>();
    return backend_name<float4>();
}

// In the functions below taking several values, any of them may be a scalar of the lane type
// instead of the vector type: it is broadcast (`min(x, 0.0f)`, `select(m, t, inf)`).

// Lane i = m[i] ? a[i] : b[i].
template <typename A, typename B, simd_type V = detail::first_simd_t<A, B>>
    requires detail::broadcasts_to<A, V> && detail::broadcasts_to<B, V>
CANOPY_SIMD_INLINE V select(typename V::mask_type const& m, A const& a, B const& b) {
    return V(detail::backend_of<V>::select(m.native(), V(a).native(), V(b).native()));
}

// Lane i = a[i] < b[i] ? a[i] : b[i], which is x86 minps: b when either lane is NaN, and
// min(-0, +0) = +0. Not std::min's rule; the slab test relies on the NaN rule.
template <typename A, typename B, simd_type V = detail::first_simd_t<A, B>>
    requires detail::broadcasts_to<A, V> && detail::broadcasts_to<B, V>
CANOPY_SIMD_INLINE V min(A const& a, B const& b) {
    return V(detail::backend_of<V>::min(V(a).native(), V(b).native()));
}

// Lane i = a[i] > b[i] ? a[i] : b[i], which is x86 maxps: b when either lane is NaN, and
// max(-0, +0) = +0.
template <typename A, typename B, simd_type V = detail::first_simd_t<A, B>>
    requires detail::broadcasts_to<A, V> && detail::broadcasts_to<B, V>
CANOPY_SIMD_INLINE V max(A const& a, B const& b) {
    return V(detail::backend_of<V>::max(V(a).native(), V(b).native()));
}

// a * b + c with a single rounding per lane.
template <typename A, typename B, typename C, simd_type V = detail::first_simd_t<A, B, C>>
    requires std::same_as<typename V::value_type, float> && detail::broadcasts_to<A, V> &&
             detail::broadcasts_to<B, V> && detail::broadcasts_to<C, V>
CANOPY_SIMD_INLINE V fma(A const& a, B const& b, C const& c) {
    return V(detail::backend_of<V>::fma(V(a).native(), V(b).native(), V(c).native()));
}

// The magnitude of `magnitude` with the sign bit of `sign`, per lane.
template <typename A, typename B, simd_type V = detail::first_simd_t<A, B>>
    requires std::same_as<typename V::value_type, float> && detail::broadcasts_to<A, V> && detail::broadcasts_to<B, V>
CANOPY_SIMD_INLINE V copysign(A const& magnitude, B const& sign) {
    return V(detail::backend_of<V>::copysign(V(magnitude).native(), V(sign).native()));
}

// |x| per lane; floats get their sign bit cleared (NaN too), abs(INT_MIN) wraps to INT_MIN.
template <typename T, int N>
CANOPY_SIMD_INLINE basic_simd<T, N> abs(basic_simd<T, N> x) {
    return basic_simd<T, N>(detail::backend<T, N>::abs(x.native()));
}

// Correctly rounded square root per lane; NaN for x < 0, sqrt(-0) = -0.
template <int N>
CANOPY_SIMD_INLINE basic_simd<float, N> sqrt(basic_simd<float, N> x) {
    return basic_simd<float, N>(detail::backend<float, N>::sqrt(x.native()));
}

// 1 / x per lane, correctly rounded (a division, not the approximate rcpps); rcp(±0) = ±inf.
template <int N>
CANOPY_SIMD_INLINE basic_simd<float, N> rcp(basic_simd<float, N> x) {
    return basic_simd<float, N>(detail::backend<float, N>::rcp(x.native()));
}

template <int N>
CANOPY_SIMD_INLINE basic_simd<float, N> floor(basic_simd<float, N> x) {
    return basic_simd<float, N>(detail::backend<float, N>::floor(x.native()));
}

template <int N>
CANOPY_SIMD_INLINE basic_simd<float, N> ceil(basic_simd<float, N> x) {
    return basic_simd<float, N>(detail::backend<float, N>::ceil(x.native()));
}

template <int N>
CANOPY_SIMD_INLINE basic_mask<N> isnan(basic_simd<float, N> x) {
    return basic_mask<N>(detail::backend<float, N>::isnan(x.native()));
}

// Neither infinite nor NaN, per lane.
template <int N>
CANOPY_SIMD_INLINE basic_mask<N> isfinite(basic_simd<float, N> x) {
    return basic_mask<N>(detail::backend<float, N>::isfinite(x.native()));
}

// Lane i = base[index[i]]; every index must be valid.
template <typename T, int N>
CANOPY_SIMD_INLINE basic_simd<T, N> gather(T const* base, basic_simd<std::int32_t, N> index) {
    return basic_simd<T, N>(detail::backend<T, N>::gather(base, index.native()));
}

// Horizontal reductions, all folding in one order on every backend: lane i takes in lane
// i + N/2, then lane i + N/4, ..., then lane 0 takes in lane 1, each step as op(lane i, lane
// i + half). reduce_min and reduce_max follow the min/max NaN rule at each step (so a NaN lane
// may or may not survive); reduce_add wraps around for integers.
template <typename T, int N>
CANOPY_SIMD_INLINE T reduce_min(basic_simd<T, N> x) {
    return detail::backend<T, N>::reduce_min(x.native());
}

template <typename T, int N>
CANOPY_SIMD_INLINE T reduce_max(basic_simd<T, N> x) {
    return detail::backend<T, N>::reduce_max(x.native());
}

template <typename T, int N>
CANOPY_SIMD_INLINE T reduce_add(basic_simd<T, N> x) {
    return detail::backend<T, N>::reduce_add(x.native());
}

// Bit i = lane i.
template <int N>
CANOPY_SIMD_INLINE std::uint32_t movemask(basic_mask<N> m) {
    return detail::mask_backend<N>::bits(m.native());
}

template <int N>
CANOPY_SIMD_INLINE bool any(basic_mask<N> m) {
    return movemask(m) != 0;
}

template <int N>
CANOPY_SIMD_INLINE bool all(basic_mask<N> m) {
    return movemask(m) == (1u << N) - 1u;
}

template <int N>
CANOPY_SIMD_INLINE bool none(basic_mask<N> m) {
    return movemask(m) == 0;
}

// The number of true lanes.
template <int N>
CANOPY_SIMD_INLINE int popcount(basic_mask<N> m) {
    return std::popcount(movemask(m));
}

// Truncation toward zero per lane; NaN and values outside [-2^31, 2^31) give INT_MIN, as x86
// cvttps2dq does.
template <int N>
CANOPY_SIMD_INLINE basic_simd<std::int32_t, N> convert_to_int(basic_simd<float, N> x) {
    return basic_simd<std::int32_t, N>(detail::backend<float, N>::to_int(x.native()));
}

// Rounds to nearest, ties to even, per lane.
template <int N>
CANOPY_SIMD_INLINE basic_simd<float, N> convert_to_float(basic_simd<std::int32_t, N> x) {
    return basic_simd<float, N>(detail::backend<std::int32_t, N>::to_float(x.native()));
}

// Bit reinterpretation per lane.
template <int N>
CANOPY_SIMD_INLINE basic_simd<std::int32_t, N> as_int(basic_simd<float, N> x) {
    return basic_simd<std::int32_t, N>(detail::backend<float, N>::as_int(x.native()));
}

template <int N>
CANOPY_SIMD_INLINE basic_simd<float, N> as_float(basic_simd<std::int32_t, N> x) {
    return basic_simd<float, N>(detail::backend<std::int32_t, N>::as_float(x.native()));
}

} // namespace canopy::simd

namespace canopy::simd::detail {

#if defined(CANOPY_SIMD_AVX2)
// The 8 × 8 transposition of simd::transpose with AVX: unpack pairs of rows, shuffle pairs of
// pairs, swap 128-bit halves. Not a template, so that the intrinsics it names stay reachable
// from the modules that instantiate transpose.
CANOPY_SIMD_INLINE void transpose_8x8(std::array<__m256, 8>& r) {
    __m256 const t0 = _mm256_unpacklo_ps(r[0], r[1]), t1 = _mm256_unpackhi_ps(r[0], r[1]);
    __m256 const t2 = _mm256_unpacklo_ps(r[2], r[3]), t3 = _mm256_unpackhi_ps(r[2], r[3]);
    __m256 const t4 = _mm256_unpacklo_ps(r[4], r[5]), t5 = _mm256_unpackhi_ps(r[4], r[5]);
    __m256 const t6 = _mm256_unpacklo_ps(r[6], r[7]), t7 = _mm256_unpackhi_ps(r[6], r[7]);
    __m256 const s0 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 const s1 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(3, 2, 3, 2));
    __m256 const s2 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 const s3 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(3, 2, 3, 2));
    __m256 const s4 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 const s5 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(3, 2, 3, 2));
    __m256 const s6 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 const s7 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(3, 2, 3, 2));
    r[0] = _mm256_permute2f128_ps(s0, s4, 0x20);
    r[1] = _mm256_permute2f128_ps(s1, s5, 0x20);
    r[2] = _mm256_permute2f128_ps(s2, s6, 0x20);
    r[3] = _mm256_permute2f128_ps(s3, s7, 0x20);
    r[4] = _mm256_permute2f128_ps(s0, s4, 0x31);
    r[5] = _mm256_permute2f128_ps(s1, s5, 0x31);
    r[6] = _mm256_permute2f128_ps(s2, s6, 0x31);
    r[7] = _mm256_permute2f128_ps(s3, s7, 0x31);
}
#endif

} // namespace canopy::simd::detail

export namespace canopy::simd {

// Bit i = the sign bit of lane i (set for -0 and negative NaNs too, as std::signbit).
template <int N>
CANOPY_SIMD_INLINE std::uint32_t sign_bits(basic_simd<float, N> x) {
    return movemask(as_int(x) < basic_simd<std::int32_t, N>(0));
}

// An N × N block of floats transposed in registers: lane c of rows[r] goes to lane r of rows[c]
// (an array of N structures of N floats, loaded one structure per vector, becomes one vector
// per member). AVX2 (8 lanes) and SSE4.2 (4 lanes): unpack and shuffle steps in registers; other
// widths and backends go through memory.
template <int N>
CANOPY_SIMD_INLINE void transpose(std::array<basic_simd<float, N>, std::size_t(N)>& rows) {
#if defined(CANOPY_SIMD_AVX2)
    if constexpr (N == 8) {
        std::array<__m256, 8> r;
        for (std::size_t i = 0; i < 8; ++i) r[i] = rows[i].native();
        detail::transpose_8x8(r);
        for (std::size_t i = 0; i < 8; ++i) rows[i] = basic_simd<float, N>(r[i]);
        return;
    }
#endif
#if defined(CANOPY_SIMD_SSE42)
    if constexpr (N == 4) {
        __m128 r0 = rows[0].native(), r1 = rows[1].native(), r2 = rows[2].native(), r3 = rows[3].native();
        _MM_TRANSPOSE4_PS(r0, r1, r2, r3);
        rows = {basic_simd<float, N>(r0), basic_simd<float, N>(r1), basic_simd<float, N>(r2), basic_simd<float, N>(r3)};
        return;
    }
#endif
    std::array<float, std::size_t(N) * std::size_t(N)> m;
    for (std::size_t i = 0; i < std::size_t(N); ++i) rows[i].store(m.data() + i * std::size_t(N));
    for (std::size_t c = 0; c < std::size_t(N); ++c) {
        std::array<float, std::size_t(N)> column;
        for (std::size_t i = 0; i < std::size_t(N); ++i) column[i] = m[i * std::size_t(N) + c];
        rows[c] = basic_simd<float, N>::load(column.data());
    }
}

} // namespace canopy::simd

// The instruction set the library was compiled for, and whether this CPU runs it. Defined in
// modules/isa/isa.cpp, compiled for the baseline x86-64 ISA: an application may call them first
// thing in main() on any x86-64 CPU (the project's own programs link canopy_cpu_guard, which does
// it before main). Feature names are those of the compilers' -m flags (avx2, avx512vl, ...).
export namespace canopy::simd {
extern "C++" {

// The ISA's name as the configure probe recorded it: a CPU name (znver5) or x86-64-vN.
std::string_view build_isa() noexcept;
// The flags the library and its importers are compiled with, e.g. "-march=x86-64-v3".
std::string_view build_isa_flags() noexcept;
// The features of that ISA that a CPU must have.
std::vector<std::string_view> build_isa_features();
// The features this CPU and operating system provide (cpuid, and xgetbv for AVX/AVX-512 state).
std::vector<std::string_view> cpu_features();
// The features of build_isa_features() missing from `cpu` (a list like cpu_features()).
std::vector<std::string_view> missing_isa_features(std::span<std::string_view const> cpu);
// Whether this CPU provides every feature of build_isa_features().
bool cpu_supports_build_isa() noexcept;

} // extern "C++"
} // namespace canopy::simd
