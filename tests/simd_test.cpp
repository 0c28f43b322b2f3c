// canopy.simd: every operation, width and lane type checked lane by lane against plain scalar
// C++ over random and special values. This file is built twice: against the native backends
// (simd_test) and against the forced scalar backend (simd_scalar_test); both must match the same
// references, which proves the two give identical results.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cfloat>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

import canopy.simd;

namespace simd = canopy::simd;
using simd::float16;
using simd::float4;
using simd::float8;
using simd::int16;
using simd::int4;
using simd::int8;
using simd::mask16;
using simd::mask4;
using simd::mask8;

namespace {

constexpr float infinity = std::numeric_limits<float>::infinity();
constexpr float quiet_nan = std::numeric_limits<float>::quiet_NaN();
constexpr std::int32_t int_min = std::numeric_limits<std::int32_t>::min();
constexpr std::int32_t int_max = std::numeric_limits<std::int32_t>::max();

std::uint32_t bits_of(float x) { return std::bit_cast<std::uint32_t>(x); }

// The same bit pattern, or both NaN.
bool identical(float got, float want) {
  return std::isnan(want) ? std::isnan(got) : bits_of(got) == bits_of(want);
}
bool identical(std::int32_t got, std::int32_t want) { return got == want; }
bool identical(bool got, bool want) { return got == want; }

std::string show(float x) {
  std::ostringstream out;
  out << x << " (" << std::hexfloat << x << ")";
  return out.str();
}
std::string show(std::int32_t x) { return std::to_string(x); }
std::string show(bool x) { return x ? "true" : "false"; }

template <typename T>
std::vector<T> special_values() {
  if constexpr (std::is_same_v<T, float>) {
    return {0.0f, -0.0f, 1.0f, -1.0f, 0.5f, -0.5f, 1.5f, -1.5f, 2.5f, -2.5f, 3.0f, -7.25f, 100.75f,
            0x1p24f + 2.0f,  // float spacing 2
            FLT_MIN, -FLT_MIN, FLT_TRUE_MIN, -FLT_TRUE_MIN, 1e-40f, -3e-39f,  // denormal edges
            FLT_MAX, -FLT_MAX, infinity, -infinity, quiet_nan, -quiet_nan,
            0x1p31f, -0x1p31f, 0x1.fffffep30f, -0x1.000002p31f};  // edges of the int32 range
  } else {
    return {0, 1, -1, 2, -2, 3, -3, 7, -8, 31, 32, 33, -32, 100, 65535, -65536, 0x55555555,
            1 << 24, (1 << 24) + 1, (1 << 24) + 3, -(1 << 24) - 1, 1 << 30,  // float rounding
            int_max, int_max - 1, int_min, int_min + 1};
  }
}

template <typename T>
T random_value(std::mt19937& rng) {
  std::uint32_t const bits = static_cast<std::uint32_t>(rng());
  if constexpr (std::is_same_v<T, float>) {
    switch (bits % 4) {
      case 0: return std::bit_cast<float>(static_cast<std::uint32_t>(rng()));  // any pattern
      case 1: return std::uniform_real_distribution<float>(-4.0f, 4.0f)(rng);
      case 2: return std::round(std::uniform_real_distribution<float>(-16.0f, 16.0f)(rng)) * 0.5f;
      default:
        return std::ldexp(std::uniform_real_distribution<float>(-1.0f, 1.0f)(rng),
                          std::uniform_int_distribution<int>(-150, 128)(rng));
    }
  } else {
    if (bits % 2 == 0) return static_cast<std::int32_t>(static_cast<std::uint32_t>(rng()));
    return std::uniform_int_distribution<std::int32_t>(-100, 100)(rng);
  }
}

// Operands of the lane-wise tests: (a, b) runs through every ordered pair of special values,
// then random values (b sometimes equal to a); c mixes special and random values. Sizes are a
// multiple of 16, so every width sees every value.
template <typename T>
struct operands {
  std::vector<T> a, b, c;
};

template <typename T>
operands<T> make_operands(std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<T> const special = special_values<T>();
  operands<T> out;
  for (T x : special)
    for (T y : special) {
      out.a.push_back(x);
      out.b.push_back(y);
    }
  std::size_t const size = (out.a.size() + 2048 + 15) / 16 * 16;
  while (out.a.size() < size) {
    T const x = random_value<T>(rng);
    out.a.push_back(x);
    out.b.push_back(rng() % 8 == 0 ? x : random_value<T>(rng));
  }
  for (std::size_t i = 0; i < size; ++i)
    out.c.push_back(i % 3 == 0 ? special[i / 3 % special.size()] : random_value<T>(rng));
  return out;
}

// Applies `op` to each run of N consecutive inputs, loaded as basic_simd<T, N>, and compares lane
// i of its result with `ref` applied to the inputs of lane i. Reports the first mismatch.
template <int N, typename Op, typename Ref, typename... T>
void check_lanewise(Op op, Ref ref, std::vector<T> const&... inputs) {
  std::size_t const size = std::min({inputs.size()...});
  std::size_t mismatches = 0;
  std::string first_mismatch;
  for (std::size_t at = 0; at + N <= size; at += N) {
    auto const got = op(simd::basic_simd<T, N>::load(inputs.data() + at)...);
    for (int i = 0; i < N; ++i) {
      auto const want = ref(inputs[at + i]...);
      if (identical(got[i], want)) continue;
      if (mismatches++ == 0) {
        std::ostringstream out;
        out << "lane " << i << ", inputs";
        ((out << ' ' << show(inputs[at + i])), ...);
        out << ": got " << show(got[i]) << ", want " << show(want);
        first_mismatch = out.str();
      }
    }
  }
  INFO("first mismatch: " << first_mismatch);
  CHECK(mismatches == 0);
}

template <typename V>
std::vector<typename V::value_type> lanes_of(V v) {
  std::vector<typename V::value_type> lanes(V::width);
  v.store(lanes.data());
  return lanes;
}

template <int N>
std::vector<bool> lanes_of(simd::basic_mask<N> m) {
  std::vector<bool> lanes;
  for (int i = 0; i < N; ++i) lanes.push_back(m[i]);
  return lanes;
}

template <int N>
std::vector<bool> lanes_of_bits(std::uint32_t bits) {
  std::vector<bool> lanes;
  for (int i = 0; i < N; ++i) lanes.push_back(((bits >> i) & 1u) != 0);
  return lanes;
}

// Reference for the documented reduction order: lane i takes in lane i + half, for half = N/2,
// N/4, ..., 1.
template <typename T, typename Op>
T pairwise_fold(std::vector<T> lanes, Op op) {
  for (std::size_t half = lanes.size() / 2; half > 0; half /= 2)
    for (std::size_t i = 0; i < half; ++i) lanes[i] = op(lanes[i], lanes[i + half]);
  return lanes[0];
}

// Written once for any lane type, as the kernels are.
template <typename T>
T clamp_then_abs(T x, T lo, T hi) {
  T const clamped = simd::max(lo, simd::min(x, hi));
  return simd::select(clamped < T(0), -clamped, clamped);
}

}  // namespace

TEST_CASE("each width runs on the backend its instruction set provides", "[simd]") {
  WARN("isa_name: " << simd::isa_name() << "; float4: " << simd::backend_name<float4>()
                    << ", float8: " << simd::backend_name<float8>()
                    << ", float16: " << simd::backend_name<float16>());
#if defined(CANOPY_SIMD_FORCE_SCALAR)
  std::string_view const expected4 = "scalar", expected8 = "scalar", expected16 = "scalar";
#else
#if defined(__SSE4_2__)
  std::string_view const expected4 = "SSE4.2";
#else
  std::string_view const expected4 = "scalar";
#endif
#if defined(__AVX2__)
  std::string_view const expected8 = "AVX2";
#else
  std::string_view const expected8 = "scalar";
#endif
#if defined(__AVX512F__)
  std::string_view const expected16 = "AVX-512";
#else
  std::string_view const expected16 = "scalar";
#endif
#endif
  CHECK(simd::backend_name<float4>() == expected4);
  CHECK(simd::backend_name<int4>() == expected4);
  CHECK(simd::backend_name<mask4>() == expected4);
  CHECK(simd::backend_name<float8>() == expected8);
  CHECK(simd::backend_name<int8>() == expected8);
  CHECK(simd::backend_name<mask8>() == expected8);
  CHECK(simd::backend_name<float16>() == expected16);
  CHECK(simd::backend_name<int16>() == expected16);
  CHECK(simd::backend_name<mask16>() == expected16);
  CHECK(simd::backend_name<float>() == "scalar");
  CHECK(simd::backend_name<double>() == "scalar");
  CHECK(simd::backend_name<std::int32_t>() == "scalar");

  std::string_view const widest = expected16 != "scalar" ? expected16
                                  : expected8 != "scalar" ? expected8
                                                          : expected4;
  CHECK(simd::isa_name() == widest);
  static_assert(!simd::isa_name().empty());
}

TEST_CASE("traits describe vectors, masks and scalars alike", "[simd]") {
  static_assert(simd::simd_width_v<float4> == 4 && simd::simd_width_v<int16> == 16);
  static_assert(simd::simd_width_v<mask8> == 8);
  static_assert(std::is_same_v<simd::scalar_type_t<float8>, float>);
  static_assert(std::is_same_v<simd::scalar_type_t<int8>, std::int32_t>);
  static_assert(std::is_same_v<simd::scalar_type_t<float>, float>);
  static_assert(std::is_same_v<simd::scalar_type_t<double>, double>);
  static_assert(std::is_same_v<simd::mask_type_t<float8>, mask8>);
  static_assert(std::is_same_v<simd::mask_type_t<int8>, mask8>);
  static_assert(std::is_same_v<simd::mask_type_t<float16>, mask16>);
  static_assert(std::is_same_v<simd::mask_type_t<float>, bool>);
  static_assert(std::is_same_v<simd::mask_type_t<double>, bool>);
  static_assert(std::is_same_v<simd::mask_type_t<std::int32_t>, bool>);
  static_assert(std::is_same_v<simd::mask_type_t<bool>, bool>);
  static_assert(std::is_same_v<simd::int_type_t<float8>, int8>);
  static_assert(std::is_same_v<simd::int_type_t<float4>, int4>);
  static_assert(std::is_same_v<simd::int_type_t<float>, std::int32_t>);
  static_assert(std::is_same_v<simd::int_type_t<double>, std::int64_t>);
  static_assert(std::is_same_v<simd::float_type_t<int8>, float8>);
  static_assert(std::is_same_v<simd::float_type_t<int16>, float16>);
  static_assert(std::is_same_v<simd::float_type_t<std::int32_t>, float>);
  static_assert(simd::simd_type<float8> && simd::simd_type<int4>);
  static_assert(!simd::simd_type<float> && !simd::simd_type<mask8> && !simd::simd_type<bool>);
  static_assert(float8::width == 8 && std::is_same_v<float8::value_type, float>);
  static_assert(std::is_same_v<int16::mask_type, mask16>);
  static_assert(sizeof(float4) == 16 && alignof(float4) == 16);
  static_assert(sizeof(int8) == 32 && alignof(int8) == 32);
  static_assert(sizeof(float16) == 64 && alignof(float16) == 64);

  CHECK(simd::simd_width_v<float8> == 8);
  CHECK(simd::simd_width_v<float16> == 16);
  CHECK(simd::simd_width_v<float> == 1);
  CHECK(simd::simd_width_v<double> == 1);
  CHECK(simd::simd_width_v<std::int32_t> == 1);
  CHECK(simd::simd_width_v<bool> == 1);
}

TEMPLATE_TEST_CASE("vectors start at zero, broadcast a scalar, and iota counts the lanes",
                   "[simd]", float4, float8, float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  CHECK(lanes_of(V{}) == std::vector<T>(V::width, T(0)));
  CHECK(lanes_of(V(T(7))) == std::vector<T>(V::width, T(7)));
  V const implicit = T(3);
  CHECK(lanes_of(implicit) == std::vector<T>(V::width, T(3)));

  std::vector<T> counting;
  for (int i = 0; i < V::width; ++i) counting.push_back(static_cast<T>(i));
  CHECK(lanes_of(V::iota()) == counting);
}

TEMPLATE_TEST_CASE("load and store round-trip, aligned and unaligned", "[simd]", float4, float8,
                   float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  std::mt19937 rng(11);
  alignas(64) T source[n + 1];
  for (T& x : source) x = random_value<T>(rng);

  alignas(64) T aligned[n];
  V::load_aligned(source).store_aligned(aligned);
  for (int i = 0; i < n; ++i) CHECK(identical(aligned[i], source[i]));

  T unaligned[n + 1];
  V::load(source + 1).store(unaligned + 1);
  for (int i = 0; i < n; ++i) CHECK(identical(unaligned[i + 1], source[i + 1]));
}

TEMPLATE_TEST_CASE("lane access and set agree with store", "[simd]", float4, float8, float16,
                   int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  std::mt19937 rng(12);
  std::vector<T> lanes(V::width);
  for (T& x : lanes) x = random_value<T>(rng);
  V v = V::load(lanes.data());
  for (int i = 0; i < V::width; ++i) CHECK(identical(v[i], lanes[i]));

  for (int i = 0; i < V::width; ++i) {
    T const value = random_value<T>(rng);
    v.set(i, value);
    lanes[static_cast<std::size_t>(i)] = value;
    std::vector<T> const stored = lanes_of(v);
    bool same = true;
    for (int j = 0; j < V::width; ++j) same = same && identical(stored[j], lanes[j]);
    CHECK(same);
  }
}

TEMPLATE_TEST_CASE("float arithmetic is IEEE arithmetic lane by lane", "[simd]", float4, float8,
                   float16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<float> const ops = make_operands<float>(1);
  check_lanewise<n>([](V a, V b) { return a + b; }, [](float a, float b) { return a + b; },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a - b; }, [](float a, float b) { return a - b; },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a * b; }, [](float a, float b) { return a * b; },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a / b; }, [](float a, float b) { return a / b; },
                    ops.a, ops.b);
  check_lanewise<n>([](V a) { return -a; }, [](float a) { return -a; }, ops.a);
  // -x flips the sign bit exactly, NaN included.
  check_lanewise<n>([](V a) { return simd::as_int(-a); },
                    [](float a) { return std::bit_cast<std::int32_t>(bits_of(a) ^ 0x80000000u); },
                    ops.a);

  check_lanewise<n>([](V a, V b) { return a += b; }, [](float a, float b) { return a + b; },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a -= b; }, [](float a, float b) { return a - b; },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a *= b; }, [](float a, float b) { return a * b; },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a /= b; }, [](float a, float b) { return a / b; },
                    ops.a, ops.b);

  // A float operand is broadcast.
  check_lanewise<n>([](V a) { return a * 2.5f; }, [](float a) { return a * 2.5f; }, ops.a);
  check_lanewise<n>([](V a) { return 2.5f - a; }, [](float a) { return 2.5f - a; }, ops.a);
  check_lanewise<n>([](V a) { return 1.0f / a; }, [](float a) { return 1.0f / a; }, ops.a);
}

TEMPLATE_TEST_CASE("integer arithmetic wraps around modulo 2^32", "[simd]", int4, int8, int16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<std::int32_t> const ops = make_operands<std::int32_t>(2);
  // The exact result in 64 bits, reduced modulo 2^32.
  auto wrap = [](std::int64_t x) { return static_cast<std::int32_t>(x); };
  check_lanewise<n>([](V a, V b) { return a + b; },
                    [&](std::int32_t a, std::int32_t b) { return wrap(std::int64_t{a} + b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a - b; },
                    [&](std::int32_t a, std::int32_t b) { return wrap(std::int64_t{a} - b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a * b; },
                    [&](std::int32_t a, std::int32_t b) { return wrap(std::int64_t{a} * b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a) { return -a; }, [&](std::int32_t a) { return wrap(-std::int64_t{a}); },
                    ops.a);
  check_lanewise<n>([](V a, V b) { return a += b; },
                    [&](std::int32_t a, std::int32_t b) { return wrap(std::int64_t{a} + b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a -= b; },
                    [&](std::int32_t a, std::int32_t b) { return wrap(std::int64_t{a} - b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a *= b; },
                    [&](std::int32_t a, std::int32_t b) { return wrap(std::int64_t{a} * b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a) { return a + 5; }, [&](std::int32_t a) { return wrap(a + 5ll); },
                    ops.a);
}

TEMPLATE_TEST_CASE("integer division truncates toward zero", "[simd]", int4, int8, int16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<std::int32_t> ops = make_operands<std::int32_t>(3);
  // Division by zero and INT_MIN / -1 are outside the contract.
  for (std::size_t i = 0; i < ops.b.size(); ++i)
    if (ops.b[i] == 0 || (ops.a[i] == int_min && ops.b[i] == -1)) ops.b[i] = 7;
  check_lanewise<n>([](V a, V b) { return a / b; },
                    [](std::int32_t a, std::int32_t b) { return a / b; }, ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a /= b; },
                    [](std::int32_t a, std::int32_t b) { return a / b; }, ops.a, ops.b);
}

TEMPLATE_TEST_CASE("bitwise operators act lane by lane", "[simd]", int4, int8, int16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<std::int32_t> const ops = make_operands<std::int32_t>(4);
  using i32 = std::int32_t;
  check_lanewise<n>([](V a, V b) { return a & b; }, [](i32 a, i32 b) { return i32(a & b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a | b; }, [](i32 a, i32 b) { return i32(a | b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a ^ b; }, [](i32 a, i32 b) { return i32(a ^ b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a) { return ~a; }, [](i32 a) { return i32(~a); }, ops.a);
  check_lanewise<n>([](V a, V b) { return a &= b; }, [](i32 a, i32 b) { return i32(a & b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a |= b; }, [](i32 a, i32 b) { return i32(a | b); },
                    ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a ^= b; }, [](i32 a, i32 b) { return i32(a ^ b); },
                    ops.a, ops.b);
}

TEMPLATE_TEST_CASE("<< fills with zeros, >> with the sign, and larger counts shift all bits out",
                   "[simd]", int4, int8, int16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<std::int32_t> const ops = make_operands<std::int32_t>(5);
  for (int const count : {0, 1, 5, 16, 31, 32, 33, 100, -1, -32, int_min}) {
    INFO("count " << count);
    bool const in_range = count >= 0 && count <= 31;
    // x * 2^count modulo 2^32, and floor(x / 2^count).
    auto shifted_left = [&](std::int32_t x) {
      return in_range ? static_cast<std::int32_t>(std::int64_t{x} * (std::int64_t{1} << count)) : 0;
    };
    auto shifted_right = [&](std::int32_t x) {
      if (!in_range) return x < 0 ? -1 : 0;
      return static_cast<std::int32_t>(std::floor(static_cast<double>(x) / std::ldexp(1.0, count)));
    };
    check_lanewise<n>([&](V a) { return a << count; }, shifted_left, ops.a);
    check_lanewise<n>([&](V a) { return a >> count; }, shifted_right, ops.a);
    check_lanewise<n>([&](V a) { return a <<= count; }, shifted_left, ops.a);
    check_lanewise<n>([&](V a) { return a >>= count; }, shifted_right, ops.a);
  }
}

TEMPLATE_TEST_CASE("comparisons are IEEE: NaN compares false except with !=", "[simd]", float4,
                   float8, float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  operands<T> const ops = make_operands<T>(6);
  check_lanewise<n>([](V a, V b) { return a == b; }, [](T a, T b) { return a == b; }, ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a != b; }, [](T a, T b) { return a != b; }, ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a < b; }, [](T a, T b) { return a < b; }, ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a <= b; }, [](T a, T b) { return a <= b; }, ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a > b; }, [](T a, T b) { return a > b; }, ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return a >= b; }, [](T a, T b) { return a >= b; }, ops.a, ops.b);
  check_lanewise<n>([](V a) { return a < T(1); }, [](T a) { return a < T(1); }, ops.a);
  check_lanewise<n>([](V a) { return T(1) == a; }, [](T a) { return T(1) == a; }, ops.a);
}

TEMPLATE_TEST_CASE("min and max follow the a < b ? a : b rule, NaN included", "[simd]", float4,
                   float8, float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  operands<T> const ops = make_operands<T>(7);
  auto const lesser = [](T a, T b) { return a < b ? a : b; };
  auto const greater = [](T a, T b) { return a > b ? a : b; };
  check_lanewise<n>([](V a, V b) { return simd::min(a, b); }, lesser, ops.a, ops.b);
  check_lanewise<n>([](V a, V b) { return simd::max(a, b); }, greater, ops.a, ops.b);
  // Found by argument-dependent lookup too.
  check_lanewise<n>([](V a, V b) { return min(a, b); }, lesser, ops.a, ops.b);

  if constexpr (std::is_same_v<T, float>) {
    CHECK(simd::min(V(quiet_nan), V(1.0f))[0] == 1.0f);
    CHECK(std::isnan(simd::min(V(1.0f), V(quiet_nan))[0]));
    CHECK(simd::max(V(quiet_nan), V(1.0f))[0] == 1.0f);
    CHECK(std::isnan(simd::max(V(1.0f), V(quiet_nan))[0]));
    CHECK(bits_of(simd::min(V(-0.0f), V(0.0f))[0]) == bits_of(0.0f));
    CHECK(bits_of(simd::min(V(0.0f), V(-0.0f))[0]) == bits_of(-0.0f));
    CHECK(bits_of(simd::max(V(-0.0f), V(0.0f))[0]) == bits_of(0.0f));
  }
}

TEMPLATE_TEST_CASE("select takes a where the mask is set and b elsewhere", "[simd]", float4,
                   float8, float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  operands<T> const ops = make_operands<T>(8);
  check_lanewise<n>([](V a, V b, V c) { return simd::select(c < T(0), a, b); },
                    [](T a, T b, T c) { return c < T(0) ? a : b; }, ops.a, ops.b, ops.c);

  // Masks from random bits; the third input is each value's lane number.
  std::vector<std::int32_t> lane(ops.a.size());
  for (std::size_t i = 0; i < lane.size(); ++i) lane[i] = static_cast<std::int32_t>(i % n);
  std::mt19937 rng(9);
  for (int trial = 0; trial < 64; ++trial) {
    auto const bits = static_cast<std::uint32_t>(rng());
    check_lanewise<n>(
        [&](V a, V b, simd::basic_simd<std::int32_t, n>) {
          return select(V::mask_type::from_bits(bits), a, b);  // found by argument-dependent lookup
        },
        [&](T a, T b, std::int32_t i) { return ((bits >> i) & 1u) != 0 ? a : b; }, ops.a, ops.b,
        lane);
  }
}

TEMPLATE_TEST_CASE("free functions broadcast a scalar argument", "[simd]", float4, float8,
                   float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  operands<T> const ops = make_operands<T>(10);
  T const s = T(3);
  check_lanewise<n>([&](V a) { return simd::min(a, s); }, [&](T a) { return a < s ? a : s; },
                    ops.a);
  check_lanewise<n>([&](V a) { return simd::min(s, a); }, [&](T a) { return s < a ? s : a; },
                    ops.a);
  check_lanewise<n>([&](V a) { return simd::max(a, s); }, [&](T a) { return a > s ? a : s; },
                    ops.a);
  check_lanewise<n>([&](V a, V b) { return simd::select(b < a, a, s); },
                    [&](T a, T b) { return b < a ? a : s; }, ops.a, ops.b);
  check_lanewise<n>([&](V a, V b) { return simd::select(b < a, s, a); },
                    [&](T a, T b) { return b < a ? s : a; }, ops.a, ops.b);
  check_lanewise<n>([&](V a) { return simd::select(true, a, s); }, [](T a) { return a; }, ops.a);

  if constexpr (std::is_same_v<T, float>) {
    check_lanewise<n>([](V a, V b) { return simd::fma(a, 2.0f, b); },
                      [](float a, float b) { return std::fma(a, 2.0f, b); }, ops.a, ops.b);
    check_lanewise<n>([](V a) { return simd::fma(0.1f, a, 1.0f); },
                      [](float a) { return std::fma(0.1f, a, 1.0f); }, ops.a);
    check_lanewise<n>([](V a) { return simd::copysign(1.0f, a); },
                      [](float a) { return std::copysign(1.0f, a); }, ops.a);
  }
}

TEMPLATE_TEST_CASE("abs clears the sign bit, and abs(INT_MIN) wraps to INT_MIN", "[simd]", float4,
                   float8, float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  operands<T> const ops = make_operands<T>(12);
  if constexpr (std::is_same_v<T, float>) {
    check_lanewise<n>([](V a) { return simd::abs(a); },
                      [](float a) { return std::bit_cast<float>(bits_of(a) & 0x7fffffffu); },
                      ops.a);
  } else {
    check_lanewise<n>([](V a) { return simd::abs(a); },
                      [](std::int32_t a) {
                        return static_cast<std::int32_t>(std::abs(std::int64_t{a}));
                      },
                      ops.a);
  }
}

TEMPLATE_TEST_CASE("sqrt, rcp, floor and ceil match the correctly rounded scalar results",
                   "[simd]", float4, float8, float16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<float> const ops = make_operands<float>(13);
  check_lanewise<n>([](V a) { return simd::sqrt(a); }, [](float a) { return std::sqrt(a); },
                    ops.a);
  check_lanewise<n>([](V a) { return simd::rcp(a); }, [](float a) { return 1.0f / a; }, ops.a);
  check_lanewise<n>([](V a) { return simd::floor(a); }, [](float a) { return std::floor(a); },
                    ops.a);
  check_lanewise<n>([](V a) { return simd::ceil(a); }, [](float a) { return std::ceil(a); },
                    ops.a);

  CHECK(bits_of(simd::rcp(V(0.0f))[0]) == bits_of(infinity));
  CHECK(bits_of(simd::rcp(V(-0.0f))[0]) == bits_of(-infinity));
  CHECK(bits_of(simd::sqrt(V(-0.0f))[0]) == bits_of(-0.0f));
  CHECK(bits_of(simd::floor(V(-0.0f))[0]) == bits_of(-0.0f));
  CHECK(simd::floor(V(-0.5f))[0] == -1.0f);
  CHECK(bits_of(simd::ceil(V(-0.5f))[0]) == bits_of(-0.0f));
}

TEMPLATE_TEST_CASE("fma rounds once", "[simd]", float4, float8, float16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<float> const ops = make_operands<float>(14);
  check_lanewise<n>([](V a, V b, V c) { return simd::fma(a, b, c); },
                    [](float a, float b, float c) { return std::fma(a, b, c); }, ops.a, ops.b,
                    ops.c);

  // (1 + 2^-12)^2 = 1 + 2^-11 + 2^-24: the product alone rounds the 2^-24 away.
  float const a = 1.0f + 0x1p-12f;
  float const c = -(1.0f + 0x1p-11f);
  CHECK(simd::fma(V(a), V(a), V(c))[0] == 0x1p-24f);
  CHECK((V(a) * V(a) + V(c))[0] == 0.0f);
}

TEMPLATE_TEST_CASE("copysign combines one lane's magnitude with another lane's sign", "[simd]",
                   float4, float8, float16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<float> const ops = make_operands<float>(15);
  check_lanewise<n>([](V a, V b) { return simd::copysign(a, b); },
                    [](float a, float b) { return std::copysign(a, b); }, ops.a, ops.b);
}

TEMPLATE_TEST_CASE("isnan and isfinite classify every lane", "[simd]", float4, float8, float16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<float> const ops = make_operands<float>(16);
  check_lanewise<n>([](V a) { return simd::isnan(a); }, [](float a) { return std::isnan(a); },
                    ops.a);
  check_lanewise<n>([](V a) { return simd::isfinite(a); }, [](float a) { return std::isfinite(a); },
                    ops.a);
}

TEMPLATE_TEST_CASE("gather reads base[index] for random indices", "[simd]", float4, float8,
                   float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  std::mt19937 rng(17);
  std::vector<T> base(1000);
  for (T& x : base) x = random_value<T>(rng);
  std::vector<std::int32_t> index(1024);
  for (std::int32_t& i : index) i = std::uniform_int_distribution<std::int32_t>(0, 999)(rng);
  index.front() = 0;
  index.back() = 999;
  using index_vector = simd::int_type_t<V>;
  check_lanewise<n>([&](index_vector i) { return simd::gather(base.data(), i); },
                    [&](std::int32_t i) { return base[static_cast<std::size_t>(i)]; }, index);
}

TEMPLATE_TEST_CASE("reductions fold lane i with lane i + half, halving each step", "[simd]",
                   float4, float8, float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  operands<T> const ops = make_operands<T>(18);
  auto const lesser = [](T a, T b) { return a < b ? a : b; };
  auto const greater = [](T a, T b) { return a > b ? a : b; };
  auto const sum = [](T a, T b) {
    if constexpr (std::is_same_v<T, float>)
      return a + b;
    else
      return static_cast<std::int32_t>(std::int64_t{a} + b);
  };

  std::size_t mismatches = 0;
  for (std::size_t at = 0; at + n <= ops.a.size(); at += n) {
    std::vector<T> const lanes(ops.a.begin() + static_cast<std::ptrdiff_t>(at),
                               ops.a.begin() + static_cast<std::ptrdiff_t>(at + n));
    V const v = V::load(lanes.data());
    bool const agree = identical(simd::reduce_min(v), pairwise_fold(lanes, lesser)) &&
                       identical(simd::reduce_max(v), pairwise_fold(lanes, greater)) &&
                       identical(simd::reduce_add(v), pairwise_fold(lanes, sum));
    mismatches += agree ? 0 : 1;

    // Without NaN the order does not matter for min and max (zeros aside).
    if (std::none_of(lanes.begin(), lanes.end(), [](T x) { return x != x; })) {
      CHECK(simd::reduce_min(v) == *std::min_element(lanes.begin(), lanes.end()));
      CHECK(simd::reduce_max(v) == *std::max_element(lanes.begin(), lanes.end()));
    }
  }
  CHECK(mismatches == 0);

  if constexpr (std::is_integral_v<T>) {
    // Integer sums wrap around and do not depend on the order.
    std::int64_t total = 0;
    for (int i = 0; i < n; ++i) total += int_max - i;
    CHECK(simd::reduce_add(V(int_max) - V::iota()) == static_cast<std::int32_t>(total));
  }
}

TEMPLATE_TEST_CASE("movemask, lane access and from_bits agree", "[simd]", mask4, mask8, mask16) {
  using M = TestType;
  constexpr int n = M::width;
  std::uint32_t const all_lanes = (1u << n) - 1u;
  CHECK(simd::movemask(M{}) == 0u);
  CHECK(simd::movemask(M(false)) == 0u);
  CHECK(simd::movemask(M(true)) == all_lanes);
  M const implicit = true;
  CHECK(lanes_of(implicit) == std::vector<bool>(n, true));

  std::mt19937 rng(19);
  for (int trial = 0; trial < 100; ++trial) {
    auto const bits = static_cast<std::uint32_t>(rng());
    M m = M::from_bits(bits);
    CHECK(simd::movemask(m) == (bits & all_lanes));
    CHECK(lanes_of(m) == lanes_of_bits<n>(bits));

    int const lane = static_cast<int>(rng() % n);
    bool const value = rng() % 2 == 0;
    m.set(lane, value);
    std::uint32_t const expected = value ? bits | (1u << lane) : bits & ~(1u << lane);
    CHECK(simd::movemask(m) == (expected & all_lanes));
    CHECK(lanes_of(m) == lanes_of_bits<n>(expected));
  }
}

TEMPLATE_TEST_CASE("mask logic works lane by lane", "[simd]", mask4, mask8, mask16) {
  using M = TestType;
  constexpr int n = M::width;
  std::uint32_t const all_lanes = (1u << n) - 1u;
  std::mt19937 rng(20);
  for (int trial = 0; trial < 100; ++trial) {
    auto const x = static_cast<std::uint32_t>(rng()) & all_lanes;
    auto const y = static_cast<std::uint32_t>(rng()) & all_lanes;
    M const a = M::from_bits(x);
    M const b = M::from_bits(y);
    CHECK(simd::movemask(a & b) == (x & y));
    CHECK(simd::movemask(a | b) == (x | y));
    CHECK(simd::movemask(a ^ b) == (x ^ y));
    CHECK(simd::movemask(!a) == (~x & all_lanes));
    CHECK(simd::movemask(a == b) == (~(x ^ y) & all_lanes));
    CHECK(simd::movemask(a != b) == (x ^ y));
    CHECK(simd::movemask(a & true) == x);
    CHECK(simd::movemask(false | a) == x);

    M c = a;
    c &= b;
    CHECK(simd::movemask(c) == (x & y));
    c = a;
    c |= b;
    CHECK(simd::movemask(c) == (x | y));
    c = a;
    c ^= b;
    CHECK(simd::movemask(c) == (x ^ y));
  }
}

TEMPLATE_TEST_CASE("any, all, none and popcount count the set lanes", "[simd]", mask4, mask8,
                   mask16) {
  using M = TestType;
  constexpr int n = M::width;
  std::uint32_t const all_lanes = (1u << n) - 1u;
  std::mt19937 rng(21);
  std::vector<std::uint32_t> patterns = {0u, all_lanes, 1u, 1u << (n - 1), all_lanes - 1u};
  for (int trial = 0; trial < 100; ++trial)
    patterns.push_back(static_cast<std::uint32_t>(rng()) & all_lanes);
  for (std::uint32_t const bits : patterns) {
    INFO("bits " << bits);
    M const m = M::from_bits(bits);
    CHECK(simd::any(m) == (bits != 0));
    CHECK(simd::all(m) == (bits == all_lanes));
    CHECK(simd::none(m) == (bits == 0));
    CHECK(simd::popcount(m) == std::popcount(bits));
  }
}

TEMPLATE_TEST_CASE("masks from comparisons carry the lane-wise results in movemask", "[simd]",
                   float4, float8, float16, int4, int8, int16) {
  using V = TestType;
  using T = typename V::value_type;
  constexpr int n = V::width;
  operands<T> const ops = make_operands<T>(22);
  std::size_t mismatches = 0;
  for (std::size_t at = 0; at + n <= ops.a.size(); at += n) {
    std::uint32_t expected = 0;
    for (int i = 0; i < n; ++i)
      expected |= static_cast<std::uint32_t>(ops.a[at + i] < ops.b[at + i]) << i;
    V const a = V::load(ops.a.data() + at);
    V const b = V::load(ops.b.data() + at);
    mismatches += simd::movemask(a < b) == expected ? 0 : 1;
  }
  CHECK(mismatches == 0);
}

TEMPLATE_TEST_CASE("convert_to_int truncates toward zero, giving INT_MIN for NaN and out of range",
                   "[simd]", float4, float8, float16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<float> const ops = make_operands<float>(23);
  auto const truncated = [](float x) {
    if (std::isnan(x) || x >= 2147483648.0f || x < -2147483648.0f) return int_min;
    return static_cast<std::int32_t>(std::trunc(x));
  };
  check_lanewise<n>([](V a) { return simd::convert_to_int(a); }, truncated, ops.a);

  CHECK(simd::convert_to_int(V(-1.75f))[0] == -1);
  CHECK(simd::convert_to_int(V(0x1.fffffep30f))[0] == 2147483520);
  CHECK(simd::convert_to_int(V(-0x1p31f))[0] == int_min);
  CHECK(simd::convert_to_int(V(0x1p31f))[0] == int_min);
  CHECK(simd::convert_to_int(V(quiet_nan))[0] == int_min);
}

TEMPLATE_TEST_CASE("convert_to_float rounds to nearest, ties to even", "[simd]", int4, int8,
                   int16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<std::int32_t> const ops = make_operands<std::int32_t>(24);
  check_lanewise<n>([](V a) { return simd::convert_to_float(a); },
                    [](std::int32_t a) { return static_cast<float>(a); }, ops.a);
  CHECK(simd::convert_to_float(V((1 << 24) + 1))[0] == 0x1p24f);
  CHECK(simd::convert_to_float(V((1 << 24) + 3))[0] == 0x1p24f + 4.0f);
}

TEMPLATE_TEST_CASE("as_int and as_float reinterpret the bits unchanged", "[simd]", int4, int8,
                   int16) {
  using V = TestType;
  using F = simd::float_type_t<V>;
  constexpr int n = V::width;
  operands<std::int32_t> const int_ops = make_operands<std::int32_t>(25);
  operands<float> const float_ops = make_operands<float>(26);
  check_lanewise<n>([](V a) { return simd::as_int(simd::as_float(a)); },
                    [](std::int32_t a) { return a; }, int_ops.a);
  check_lanewise<n>([](V a) { return simd::as_float(a); },
                    [](std::int32_t a) { return std::bit_cast<float>(a); }, int_ops.a);
  check_lanewise<n>([](F a) { return simd::as_int(a); },
                    [](float a) { return std::bit_cast<std::int32_t>(a); }, float_ops.a);
}

TEMPLATE_TEST_CASE("sign_bits gives each lane's sign bit, -0 and negative NaN included", "[simd]", float4,
                   float8, float16) {
  using V = TestType;
  constexpr int n = V::width;
  float const specials[] = {0.0f, -0.0f, 1.0f, -1.0f, infinity, -infinity, quiet_nan, -quiet_nan,
                            FLT_MIN, -FLT_MIN, FLT_TRUE_MIN, -FLT_TRUE_MIN};
  std::mt19937 rng(31);
  for (int round = 0; round < 64; ++round) {
    alignas(64) float lanes[n];
    std::uint32_t expected = 0;
    for (int i = 0; i < n; ++i) {
      lanes[i] = round < 32 ? specials[std::size_t(rng() % std::size(specials))] : random_value<float>(rng);
      if (std::signbit(lanes[i])) expected |= 1u << i;
    }
    CHECK(simd::sign_bits(V::load(lanes)) == expected);
  }
}

TEMPLATE_TEST_CASE("transpose moves lane c of row r to lane r of row c", "[simd]", float4, float8, float16) {
  using V = TestType;
  constexpr int n = V::width;
  std::mt19937 rng(32);
  for (int round = 0; round < 16; ++round) {
    float m[n][n];
    std::array<V, std::size_t(n)> rows;
    for (int r = 0; r < n; ++r) {
      for (int c = 0; c < n; ++c) m[r][c] = round == 0 ? float(r * n + c) : random_value<float>(rng);
      rows[std::size_t(r)] = V::load(m[r]);
    }
    simd::transpose(rows);
    for (int c = 0; c < n; ++c) {
      alignas(64) float out[n];
      rows[std::size_t(c)].store(out);
      for (int r = 0; r < n; ++r) {
        INFO("round " << round << ", row " << r << ", lane " << c);
        CHECK(std::bit_cast<std::uint32_t>(out[r]) == std::bit_cast<std::uint32_t>(m[r][c]));
      }
    }
  }
}

TEST_CASE("scalar overloads follow the same rules as the lanes", "[simd]") {
  // min / max: the second operand when either is NaN; the second zero when both are zeros.
  CHECK(simd::min(quiet_nan, 1.0f) == 1.0f);
  CHECK(std::isnan(simd::min(1.0f, quiet_nan)));
  CHECK(simd::max(quiet_nan, 1.0f) == 1.0f);
  CHECK(std::isnan(simd::max(1.0f, quiet_nan)));
  CHECK(bits_of(simd::min(-0.0f, 0.0f)) == bits_of(0.0f));
  CHECK(bits_of(simd::min(0.0f, -0.0f)) == bits_of(-0.0f));
  double const nan_double = std::numeric_limits<double>::quiet_NaN();
  CHECK(simd::min(nan_double, 2.0) == 2.0);
  CHECK(std::isnan(simd::max(2.0, nan_double)));
  CHECK(simd::min(3, -4) == -4);
  CHECK(simd::max(3, -4) == 3);

  CHECK(simd::select(true, 1.0f, 2.0f) == 1.0f);
  CHECK(simd::select(false, 1.0, 2.0) == 2.0);
  CHECK(simd::select(false, 1, 2) == 2);

  CHECK(simd::abs(int_min) == int_min);
  CHECK(simd::abs(-3) == 3);
  CHECK(bits_of(simd::abs(-0.0f)) == bits_of(0.0f));
  CHECK(simd::abs(-2.5) == 2.5);
  CHECK(simd::sqrt(2.0f) == std::sqrt(2.0f));
  CHECK(simd::sqrt(2.0) == std::sqrt(2.0));
  CHECK(simd::rcp(0.0f) == infinity);
  CHECK(simd::rcp(-0.0f) == -infinity);
  CHECK(simd::rcp(3.0f) == 1.0f / 3.0f);
  CHECK(simd::fma(1.0f + 0x1p-12f, 1.0f + 0x1p-12f, -(1.0f + 0x1p-11f)) == 0x1p-24f);
  CHECK(simd::floor(-1.5f) == -2.0f);
  CHECK(simd::ceil(-1.5) == -1.0);
  CHECK(simd::copysign(2.0f, -0.0f) == -2.0f);
  CHECK(simd::isnan(quiet_nan));
  CHECK_FALSE(simd::isnan(infinity));
  CHECK_FALSE(simd::isfinite(-infinity));
  CHECK(simd::isfinite(FLT_MAX));

  float const table[] = {5.0f, 6.0f, 7.0f};
  CHECK(simd::gather(table, 2) == 7.0f);
  CHECK(simd::reduce_min(4.0f) == 4.0f);
  CHECK(simd::reduce_max(-4) == -4);
  CHECK(simd::reduce_add(2.5) == 2.5);

  CHECK(simd::any(true));
  CHECK_FALSE(simd::all(false));
  CHECK(simd::none(false));
  CHECK(simd::movemask(true) == 1u);
  CHECK(simd::popcount(false) == 0);

  for (float const x : special_values<float>()) {
    INFO("x = " << show(x));
    bool const in_range = x >= -2147483648.0f && x < 2147483648.0f;
    CHECK(simd::convert_to_int(x) == (in_range ? static_cast<std::int32_t>(x) : int_min));
    CHECK(simd::as_int(x) == std::bit_cast<std::int32_t>(x));
  }
  CHECK(simd::convert_to_float(int_max) == 0x1p31f);
  CHECK(simd::as_float(0x3f800000) == 1.0f);

  static_assert(simd::min(1.0f, 2.0f) == 1.0f && simd::select(true, 1, 2) == 1);
  static_assert(simd::convert_to_int(-2.5f) == -2 && simd::as_int(1.0f) == 0x3f800000);
  static_assert(simd::abs(-3) == 3 && simd::copysign(2.0f, -1.0f) == -2.0f);
}

TEMPLATE_TEST_CASE("templated code gives the same lanes for float and float8 alike", "[simd]",
                   float4, float8, float16) {
  using V = TestType;
  constexpr int n = V::width;
  operands<float> const ops = make_operands<float>(27);
  check_lanewise<n>([](V x) { return clamp_then_abs(x, V(-2.0f), V(1.5f)); },
                    [](float x) { return clamp_then_abs(x, -2.0f, 1.5f); }, ops.a);
}
