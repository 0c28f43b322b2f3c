// Tests of canopy.math. References are hand-computed values, long double arithmetic, the C
// library's nextafter, or the scalar code run lane by lane.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <utility>

import canopy.math;

using canopy::aabb;
using canopy::affine_transform;
using canopy::basic_aabb;
using canopy::basic_ray;
using canopy::mat3;
using canopy::mat4;
using canopy::vec2;
using canopy::vec3;
using canopy::vec4;

namespace {

template <typename T> std::array<T, 2> as_array(vec2<T> const& v) { return {v.x, v.y}; }
template <typename T> std::array<T, 3> as_array(vec3<T> const& v) { return {v.x, v.y, v.z}; }
template <typename T> std::array<T, 4> as_array(vec4<T> const& v) { return {v.x, v.y, v.z, v.w}; }

// Equal bit patterns, or both NaN.
bool same_bits(float a, float b) {
    return std::bit_cast<std::uint32_t>(a) == std::bit_cast<std::uint32_t>(b) ||
           (std::isnan(a) && std::isnan(b));
}

template <typename T> bool same_bits(vec3<T> const& a, vec3<T> const& b) {
    return same_bits(a.x, b.x) && same_bits(a.y, b.y) && same_bits(a.z, b.z);
}

// Unit roundoff of float.
constexpr double u_float = 0x1p-24;

std::array<long double, 3> row(mat3<float> const& m, int r) {
    return {m.col0[r], m.col1[r], m.col2[r]};
}

// Largest absolute row sum.
double norm_inf(mat3<float> const& m) {
    double largest = 0;
    for (int r = 0; r < 3; ++r)
        largest = std::max(largest,
                           double(std::fabs(m.col0[r])) + std::fabs(m.col1[r]) + std::fabs(m.col2[r]));
    return largest;
}

double norm_inf(mat4<float> const& m) {
    double largest = 0;
    for (int r = 0; r < 4; ++r)
        largest = std::max(largest, double(std::fabs(m.col0[r])) + std::fabs(m.col1[r]) +
                                        std::fabs(m.col2[r]) + std::fabs(m.col3[r]));
    return largest;
}

struct random_source {
    std::mt19937 engine{20240611};

    float uniform(float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(engine); }

    vec3<float> point(float extent) {
        return {uniform(-extent, extent), uniform(-extent, extent), uniform(-extent, extent)};
    }

    // rotation * diag(scales in [0.5, 2]) with translation in [-extent, extent]^3: condition number <= 4.
    affine_transform<float> transform(float extent) {
        std::normal_distribution<double> normal;
        double q[4];
        double norm = 0;
        for (double& c : q) {
            c = normal(engine);
            norm += c * c;
        }
        norm = std::sqrt(norm);
        double const w = q[0] / norm, x = q[1] / norm, y = q[2] / norm, z = q[3] / norm;
        double const rotation[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                                       {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                                       {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
        double const scale[3] = {uniform(0.5f, 2.f), uniform(0.5f, 2.f), uniform(0.5f, 2.f)};
        std::array<float, 12> rows{};
        for (int r = 0; r < 3; ++r) {
            for (int c = 0; c < 3; ++c)
                rows[4 * r + c] = static_cast<float>(rotation[r][c] * scale[c]);
            rows[4 * r + 3] = uniform(-extent, extent);
        }
        return affine_transform<float>::from_rows(rows);
    }
};

} // namespace

// Vectors

TEST_CASE("vectors default to zero, broadcast, convert and index their components") {
    CHECK(as_array(vec3<float>{}) == std::array{0.f, 0.f, 0.f});
    CHECK(as_array(vec2<float>(2.f)) == std::array{2.f, 2.f});
    CHECK(as_array(vec4<int>(7)) == std::array{7, 7, 7, 7});
    CHECK(as_array(vec3<double>(vec3<float>{0.1f, 2.f, -3.f})) == std::array{double(0.1f), 2.0, -3.0});

    vec4<float> v(vec3<float>{1, 2, 3}, 4);
    CHECK(as_array(v) == std::array{1.f, 2.f, 3.f, 4.f});
    CHECK(as_array(v.xyz()) == std::array{1.f, 2.f, 3.f});
    v[2] = 9;
    CHECK(v[0] == 1);
    CHECK(v[1] == 2);
    CHECK(v.z == 9);
    CHECK(v[3] == 4);
    vec3<float> const c{5, 6, 7};
    CHECK(c[0] == 5);
    CHECK(c[1] == 6);
    CHECK(c[2] == 7);
}

TEST_CASE("vector arithmetic is component-wise, with scalars on either side") {
    vec3<float> const a{1, 2, 3}, b{4, -5, 6};
    CHECK(as_array(a + b) == std::array{5.f, -3.f, 9.f});
    CHECK(as_array(a - b) == std::array{-3.f, 7.f, -3.f});
    CHECK(as_array(a * b) == std::array{4.f, -10.f, 18.f});
    CHECK(as_array(b / a) == std::array{4.f, -2.5f, 2.f});
    CHECK(as_array(a * 2.f) == std::array{2.f, 4.f, 6.f});
    CHECK(as_array(2.f * a) == std::array{2.f, 4.f, 6.f});
    CHECK(as_array(a + 1.f) == std::array{2.f, 3.f, 4.f});
    CHECK(as_array(1.f - a) == std::array{0.f, -1.f, -2.f});
    CHECK(as_array(a / 2.f) == std::array{0.5f, 1.f, 1.5f});
    CHECK(as_array(6.f / a) == std::array{6.f, 3.f, 2.f});
    CHECK(as_array(-a) == std::array{-1.f, -2.f, -3.f});

    vec3<float> c = a;
    c += b;
    CHECK(as_array(c) == std::array{5.f, -3.f, 9.f});
    c *= 2.f;
    CHECK(as_array(c) == std::array{10.f, -6.f, 18.f});
    c -= 1.f;
    CHECK(as_array(c) == std::array{9.f, -7.f, 17.f});
    c /= vec3<float>{9, -7, 17};
    CHECK(as_array(c) == std::array{1.f, 1.f, 1.f});
    c -= a;
    c /= 2.f;
    CHECK(as_array(c) == std::array{0.f, -0.5f, -1.f});

    CHECK(as_array(vec2<double>{1, 2} + vec2<double>{3, 4}) == std::array{4.0, 6.0});
    CHECK(as_array(vec4<float>{1, 2, 3, 4} * vec4<float>{2, 2, 2, 2} - 1.f) ==
          std::array{1.f, 3.f, 5.f, 7.f});
}

TEST_CASE("dot, cross and length match hand-computed values") {
    vec3<float> const a{1, 2, 3}, b{4, -5, 6};
    CHECK(dot(a, b) == 12);
    CHECK(as_array(cross(a, b)) == std::array{27.f, 6.f, -13.f});
    CHECK(as_array(cross(vec3<float>{1, 0, 0}, vec3<float>{0, 1, 0})) == std::array{0.f, 0.f, 1.f});
    CHECK(length_squared(vec3<float>{3, 4, 12}) == 169);
    CHECK(length(vec3<float>{3, 4, 12}) == 13);
    CHECK(length(vec2<double>{3, 4}) == 5);
    CHECK(dot(vec4<float>{1, 2, 3, 4}, vec4<float>{1, 1, 1, 1}) == 10);
    CHECK(as_array(normalize(vec3<float>{0, -8, 0})) == std::array{0.f, -1.f, 0.f});
}

TEST_CASE("cross product is orthogonal to its operands within the gamma error bound") {
    random_source random;
    double const gamma2 = canopy::gamma<float>(2), gamma3 = canopy::gamma<float>(3);
    for (int i = 0; i < 10000; ++i) {
        vec3<float> const a = random.point(100), b = random.point(100);
        vec3<float> const c = cross(a, b);
        for (vec3<float> const& operand : {a, b}) {
            // |fl(c . x)| <= gamma3 sum |c_i x_i| + sum |x_i| |c_i - exact c_i|, and each cross
            // component carries at most gamma2 (|a_j b_k| + |a_k b_j|).
            double bound = 0;
            for (int k = 0; k < 3; ++k) {
                int const j1 = (k + 1) % 3, j2 = (k + 2) % 3;
                double const cross_error =
                    gamma2 * (std::fabs(double(a[j1]) * b[j2]) + std::fabs(double(a[j2]) * b[j1]));
                bound += gamma3 * std::fabs(double(c[k]) * operand[k]) +
                         std::fabs(double(operand[k])) * cross_error;
            }
            CHECK(std::fabs(double(dot(c, operand))) <= bound);
        }
    }
}

TEST_CASE("Lagrange's identity |a x b|^2 + (a . b)^2 = |a|^2 |b|^2 holds within 32 u relative") {
    // The gamma bounds of the cross product, the dot products and the squares add up to about
    // 24 u relative to |a|^2 |b|^2; the largest error measured over 10^6 pairs is 7.1 u.
    random_source random;
    for (int i = 0; i < 10000; ++i) {
        vec3<float> const a = random.point(100), b = random.point(100);
        float const d = dot(a, b);
        double const lhs = double(length_squared(cross(a, b))) + double(d * d);
        double const rhs = length_squared(a) * length_squared(b);
        CHECK(std::fabs(lhs - rhs) <= 32 * u_float * rhs);
    }
}

TEST_CASE("normalize gives a length within 4 u of 1") {
    // Measured over 10^6 vectors: at most 2.4 u.
    random_source random;
    for (int i = 0; i < 10000; ++i) {
        vec3<float> const n = normalize(random.point(100));
        double const exact_length = std::sqrt(double(n.x) * n.x + double(n.y) * n.y + double(n.z) * n.z);
        CHECK(std::fabs(exact_length - 1) <= 4 * u_float);
    }
}

TEST_CASE("lerp is exact at its endpoints and barycentric lerp at the corners") {
    vec3<float> const a{0.1f, -3.f, 7.f}, b{2.f, 1e-3f, -5.f}, c{-1.f, 4.f, 0.3f};
    CHECK(as_array(lerp(a, b, 0.f)) == as_array(a));
    CHECK(as_array(lerp(a, b, 1.f)) == as_array(b));
    CHECK(as_array(lerp(vec2<float>{0, 2}, vec2<float>{4, 6}, 0.25f)) == std::array{1.f, 3.f});
    CHECK(as_array(lerp(a, b, c, 0.f, 0.f)) == as_array(a));
    CHECK(as_array(lerp(a, b, c, 1.f, 0.f)) == as_array(b));
    CHECK(as_array(lerp(a, b, c, 0.f, 1.f)) == as_array(c));
    CHECK(as_array(lerp(vec3<float>{0, 0, 0}, vec3<float>{4, 0, 0}, vec3<float>{0, 8, 0}, 0.25f, 0.5f)) ==
          std::array{1.f, 4.f, 0.f});
}

TEST_CASE("min, max, abs, clamp and select are component-wise with simd::min semantics") {
    float const nan = std::numeric_limits<float>::quiet_NaN();
    vec3<float> const a{1, -2, 3}, b{0, 5, 3};
    CHECK(as_array(min(a, b)) == std::array{0.f, -2.f, 3.f});
    CHECK(as_array(max(a, b)) == std::array{1.f, 5.f, 3.f});
    CHECK(as_array(abs(vec3<float>{-1, 2, -0.f})) == std::array{1.f, 2.f, 0.f});
    CHECK(!std::signbit(abs(vec3<float>{-0.f, 0, 0}).x));
    CHECK(as_array(clamp(vec3<float>{-1, 0.5f, 7}, 0.f, 1.f)) == std::array{0.f, 0.5f, 1.f});
    CHECK(as_array(clamp(vec3<float>{-1, 0.5f, 7}, vec3<float>{0, 0, 0}, vec3<float>{1, 2, 3})) ==
          std::array{0.f, 0.5f, 3.f});
    CHECK(as_array(select(true, a, b)) == as_array(a));
    CHECK(as_array(select(false, a, b)) == as_array(b));

    // a < b ? a : b: a NaN in the first operand yields the second, and the reverse keeps the NaN.
    vec3<float> const with_nan{nan, 1, 1};
    CHECK(min(with_nan, b).x == 0);
    CHECK(max(with_nan, b).x == 0);
    CHECK(std::isnan(min(b, with_nan).x));
    CHECK(clamp(with_nan, 0.25f, 1.f).x == 0.25f);
}

TEST_CASE("min_component, max_component, max_dimension and permute") {
    vec3<float> const v{3, -7, 5};
    CHECK(min_component(v) == -7);
    CHECK(max_component(v) == 5);
    CHECK(min_component(vec4<float>{4, 3, 2, 1}) == 1);
    CHECK(max_component(vec2<double>{-1, -2}) == -1);
    CHECK(canopy::max_dimension(v) == 1);
    CHECK(canopy::max_dimension(vec3<float>{8, -7, 5}) == 0);
    CHECK(canopy::max_dimension(vec3<double>{1, 2, -3}) == 2);
    CHECK(canopy::max_dimension(vec3<float>{2, 2, 1}) == 1);
    CHECK(canopy::max_dimension(vec3<float>{1, 1, 1}) == 2);
    CHECK(as_array(canopy::permute(v, 2, 0, 1)) == std::array{5.f, 3.f, -7.f});
    CHECK(as_array(canopy::permute(v, 1, 1, 0)) == std::array{-7.f, -7.f, 3.f});
}

TEST_CASE("any_nan and all_finite inspect every component") {
    float const inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
    CHECK(!any_nan(vec3<float>{1, inf, -inf}));
    CHECK(any_nan(vec3<float>{1, 2, nan}));
    CHECK(any_nan(vec2<double>{std::nan(""), 0}));
    CHECK(all_finite(vec4<float>{1, 2, 3, std::numeric_limits<float>::max()}));
    CHECK(!all_finite(vec3<float>{1, inf, 0}));
    CHECK(!all_finite(vec3<float>{nan, 0, 0}));
}

// Matrices

TEST_CASE("mat3 product, transpose and determinant match hand-computed values") {
    // Rows (2 1 0), (0 3 1), (1 0 4): determinant 2 (12 - 0) - 1 (0 - 1) = 25.
    mat3<float> const m = transpose(mat3<float>{{2, 1, 0}, {0, 3, 1}, {1, 0, 4}});
    CHECK(as_array(m.col0) == std::array{2.f, 0.f, 1.f});
    CHECK(as_array(m.col1) == std::array{1.f, 3.f, 0.f});
    CHECK(as_array(m.col2) == std::array{0.f, 1.f, 4.f});
    CHECK(determinant(m) == 25);
    CHECK(as_array(m * vec3<float>{1, 2, 3}) == std::array{4.f, 9.f, 13.f});
    mat3<float> const mm = m * m;
    CHECK(as_array(mm.col0) == std::array{4.f, 1.f, 6.f});
    CHECK(as_array(mm.col1) == std::array{5.f, 9.f, 1.f});
    CHECK(as_array(mm.col2) == std::array{1.f, 7.f, 16.f});
    CHECK(determinant(mat3<double>::identity()) == 1);
    CHECK(as_array((mat3<float>::identity() * m).col2) == as_array(m.col2));
}

TEST_CASE("mat3 inverse times the matrix is the identity within 4 u cond(m)") {
    // |inverse(m) m - I| (largest entry) <= 4 u |m| |inverse(m)| in the infinity norm; the largest
    // ratio measured over 10^6 matrices with entries in [-1, 1] (condition up to 10^7) is 2.4.
    random_source random;
    for (int i = 0; i < 10000; ++i) {
        mat3<float> m;
        for (vec3<float>* column : {&m.col0, &m.col1, &m.col2})
            *column = random.point(1);
        mat3<float> const inv = inverse(m);
        mat3<float> const product = inv * m;
        double const tolerance = 4 * u_float * norm_inf(m) * norm_inf(inv);
        for (int r = 0; r < 3; ++r) {
            CHECK(std::fabs(product.col0[r] - (r == 0)) <= tolerance);
            CHECK(std::fabs(product.col1[r] - (r == 1)) <= tolerance);
            CHECK(std::fabs(product.col2[r] - (r == 2)) <= tolerance);
        }
    }
    mat3<double> const diagonal{{2, 0, 0}, {0, 4, 0}, {0, 0, 0.5}};
    CHECK(as_array(inverse(diagonal).col2) == std::array{0.0, 0.0, 2.0});
}

TEST_CASE("mat4 determinant and inverse of a block-diagonal matrix are exact") {
    // Rows (1 2 0 0), (3 4 0 0), (0 0 5 6), (0 0 7 8): blocks of determinant -2 each.
    mat4<float> const m = transpose(mat4<float>{{1, 2, 0, 0}, {3, 4, 0, 0}, {0, 0, 5, 6}, {0, 0, 7, 8}});
    CHECK(determinant(m) == 4);
    mat4<float> const inv = inverse(m);
    // Inverse rows: (-2 1 0 0), (1.5 -0.5 0 0), (0 0 -4 3), (0 0 3.5 -2.5).
    CHECK(as_array(inv.col0) == std::array{-2.f, 1.5f, 0.f, 0.f});
    CHECK(as_array(inv.col1) == std::array{1.f, -0.5f, 0.f, 0.f});
    CHECK(as_array(inv.col2) == std::array{0.f, 0.f, -4.f, 3.5f});
    CHECK(as_array(inv.col3) == std::array{0.f, 0.f, 3.f, -2.5f});
    CHECK(as_array(m * vec4<float>{1, 1, 1, 1}) == std::array{3.f, 7.f, 11.f, 15.f});
    CHECK(as_array((m * mat4<float>::identity()).col3) == as_array(m.col3));
    // Upper triangular: the determinant is the product of the diagonal.
    mat4<double> const triangular =
        transpose(mat4<double>{{1, 5, 6, 7}, {0, 2, 8, 9}, {0, 0, 3, 1}, {0, 0, 0, 4}});
    CHECK(determinant(triangular) == 24);
}

TEST_CASE("mat4 inverse times the matrix is the identity within 8 u cond(m)") {
    // As for mat3, with the largest ratio measured over 10^6 matrices 4.7.
    random_source random;
    for (int i = 0; i < 10000; ++i) {
        mat4<float> m;
        for (vec4<float>* column : {&m.col0, &m.col1, &m.col2, &m.col3})
            *column = vec4<float>(random.point(1), random.uniform(-1, 1));
        mat4<float> const inv = inverse(m);
        mat4<float> const product = inv * m;
        double const tolerance = 8 * u_float * norm_inf(m) * norm_inf(inv);
        for (int r = 0; r < 4; ++r) {
            CHECK(std::fabs(product.col0[r] - (r == 0)) <= tolerance);
            CHECK(std::fabs(product.col1[r] - (r == 1)) <= tolerance);
            CHECK(std::fabs(product.col2[r] - (r == 2)) <= tolerance);
            CHECK(std::fabs(product.col3[r] - (r == 3)) <= tolerance);
        }
    }
}

// Affine transforms

TEST_CASE("from_rows reads a row-major 3x4 matrix whose last column is the translation") {
    auto const t = affine_transform<float>::from_rows({1, 2, 3, 10,  //
                                                       4, 5, 6, 20,  //
                                                       7, 8, 9, 30});
    CHECK(as_array(t.linear.col0) == std::array{1.f, 4.f, 7.f});
    CHECK(as_array(t.linear.col2) == std::array{3.f, 6.f, 9.f});
    CHECK(as_array(t.translation) == std::array{10.f, 20.f, 30.f});
    CHECK(as_array(transform_point(t, vec3<float>{1, 0, -1})) == std::array{8.f, 18.f, 28.f});
    CHECK(as_array(transform_vector(t, vec3<float>{1, 0, -1})) == std::array{-2.f, -2.f, -2.f});
    CHECK(as_array(t.transform_point(vec3<float>{1, 0, -1})) == std::array{8.f, 18.f, 28.f});
    CHECK(as_array(t.transform_vector(vec3<float>{1, 0, -1})) == std::array{-2.f, -2.f, -2.f});
}

TEST_CASE("composition a * b applies b first") {
    auto const translate = affine_transform<float>::from_rows({1, 0, 0, 1, 0, 1, 0, 0, 0, 0, 1, 0});
    auto const scale = affine_transform<float>::from_rows({2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0});
    vec3<float> const p{1, 1, 1};
    CHECK(as_array(transform_point(translate * scale, p)) == std::array{3.f, 2.f, 2.f});
    CHECK(as_array(transform_point(scale * translate, p)) == std::array{4.f, 2.f, 2.f});
    CHECK(as_array(transform_point(translate * scale, p)) ==
          as_array(transform_point(translate, transform_point(scale, p))));
}

TEST_CASE("from_trs is T · R · S: the hand-computed matrix, and the product of the three maps") {
    // A quarter turn about z (x → y, y → -x), scale (2, 3, 4), translation (5, 6, 7): row by row
    //   [0 -3 0 | 5]
    //   [2  0 0 | 6]
    //   [0  0 4 | 7]
    mat3<double> const quarter{{0, 1, 0}, {-1, 0, 0}, {0, 0, 1}};
    auto const m = canopy::from_trs(vec3<double>{5, 6, 7}, quarter, vec3<double>{2, 3, 4});
    auto const expected = affine_transform<double>::from_rows({0, -3, 0, 5, 2, 0, 0, 6, 0, 0, 4, 7});
    CHECK(as_array(m.linear.col0) == as_array(expected.linear.col0));
    CHECK(as_array(m.linear.col1) == as_array(expected.linear.col1));
    CHECK(as_array(m.linear.col2) == as_array(expected.linear.col2));
    CHECK(as_array(m.translation) == as_array(expected.translation));
    CHECK(as_array(transform_point(m, vec3<double>{1, 1, 1})) == std::array{2.0, 8.0, 11.0});
    // Any rotation: the same map as translate * rotate * scale composed as general products.
    double const c = 0.6, s = 0.8; // a rotation about x with cos 0.6, sin 0.8
    mat3<double> const about_x{{1, 0, 0}, {0, c, s}, {0, -s, c}};
    auto const composed = affine_transform<double>{mat3<double>::identity(), {-1, 2, 0.5}} *
                          affine_transform<double>{about_x, {}} *
                          affine_transform<double>{{{0.5, 0, 0}, {0, 3, 0}, {0, 0, -2}}, {}};
    auto const trs = canopy::from_trs(vec3<double>{-1, 2, 0.5}, about_x, vec3<double>{0.5, 3, -2});
    for (vec3<double> const p : {vec3<double>{1, 2, 3}, vec3<double>{-4, 0.25, 8}})
        CHECK(as_array(transform_point(trs, p)) == as_array(transform_point(composed, p)));
}

TEST_CASE("convert changes precision entry by entry, and all_finite finds what narrowing overflows") {
    auto const wide = affine_transform<double>::from_rows({0.1, 1, 0, 1e300, 0, 1, 0, 0, 0, 0, 1, -2.5});
    auto const narrow = canopy::convert<float>(wide);
    CHECK(narrow.linear.col0.x == 0.1f); // rounded once, to nearest
    CHECK(narrow.translation.z == -2.5f);
    CHECK(std::isinf(narrow.translation.x));
    CHECK(canopy::all_finite(wide));
    CHECK(!canopy::all_finite(narrow));
    auto const back = canopy::convert<double>(affine_transform<float>::from_rows({0.1f, 0, 0, 3, 0, 1, 0, 0, 0, 0, 1, 0}));
    CHECK(back.linear.col0.x == double(0.1f)); // widened exactly
    CHECK(back.translation.x == 3.0);
    CHECK(as_array(canopy::convert<float>(mat3<double>::identity()).col1) == std::array{0.f, 1.f, 0.f});
}

TEST_CASE("affine inverse entries are within 1 ulp of the exact inverse") {
    // Over 10^5 random transforms of condition number <= 4, all 1.2 million entries measured equal
    // the correctly rounded exact inverse.
    random_source random;
    for (int i = 0; i < 2000; ++i) {
        affine_transform<float> const t = random.transform(100);
        affine_transform<float> const inv = inverse(t);
        std::array<long double, 3> const m[3] = {row(t.linear, 0), row(t.linear, 1), row(t.linear, 2)};
        long double const det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                                m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                                m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        for (int r = 0; r < 3; ++r) {
            long double exact_row[3];
            for (int c = 0; c < 3; ++c) {
                int const r1 = (c + 1) % 3, r2 = (c + 2) % 3, c1 = (r + 1) % 3, c2 = (r + 2) % 3;
                exact_row[c] = (m[r1][c1] * m[r2][c2] - m[r1][c2] * m[r2][c1]) / det;
                float const entry = static_cast<float>(row(inv.linear, r)[c]);
                CHECK(canopy::ulp_distance(entry, static_cast<float>(exact_row[c])) <= 1);
            }
            long double const exact_translation =
                -(exact_row[0] * t.translation.x + exact_row[1] * t.translation.y +
                  exact_row[2] * t.translation.z);
            CHECK(canopy::ulp_distance(inv.translation[r], static_cast<float>(exact_translation)) <= 1);
        }
    }
}

TEST_CASE("affine inverse composed with the transform returns points within 8 eps of max(|p|, |t|)") {
    // |inverse(t)(t(p)) - p| (max norm) <= 8 eps max(|p|, |translation|) for condition number <= 4,
    // points and translations in [-100, 100]^3; the largest measured over 10^6 points is 6.5 eps.
    random_source random;
    double const eps = std::numeric_limits<float>::epsilon();
    for (int i = 0; i < 2000; ++i) {
        affine_transform<float> const t = random.transform(100);
        affine_transform<float> const inv = inverse(t);
        for (int k = 0; k < 10; ++k) {
            vec3<float> const p = random.point(100);
            vec3<float> const back = transform_point(inv, transform_point(t, p));
            double const scale = std::max(max_component(abs(p)), max_component(abs(t.translation)));
            for (int c = 0; c < 3; ++c)
                CHECK(std::fabs(double(back[c]) - p[c]) <= 8 * eps * scale);
        }
    }
}

TEST_CASE("inverse of a translation and power-of-two scale is exact") {
    auto const t = affine_transform<float>::from_rows({4, 0, 0, 1.5f, 0, 0.5f, 0, -3, 0, 0, -2, 0.25f});
    auto const inv = inverse(t);
    CHECK(as_array(inv.linear.col0) == std::array{0.25f, 0.f, 0.f});
    CHECK(as_array(inv.linear.col1) == std::array{0.f, 2.f, 0.f});
    CHECK(as_array(inv.linear.col2) == std::array{0.f, 0.f, -0.5f});
    CHECK(as_array(inv.translation) == std::array{-0.375f, 6.f, 0.125f});
    vec3<float> const p{0.125f, -7.25f, 1e3f};
    CHECK(as_array(transform_point(inv, transform_point(t, p))) == as_array(p));
    CHECK(inverse(affine_transform<double>::identity()).is_identity());
}

TEST_CASE("is_identity compares exactly") {
    CHECK(affine_transform<float>{}.is_identity());
    CHECK(affine_transform<float>::identity().is_identity());
    CHECK(affine_transform<float>::from_rows({1, 0, 0, -0.f, 0, 1, 0, 0, 0, 0, 1, 0}).is_identity());
    CHECK(!affine_transform<float>::from_rows({1, 0, 0, 1e-30f, 0, 1, 0, 0, 0, 0, 1, 0}).is_identity());
    CHECK(!affine_transform<float>::from_rows({1, 0, 0, 0, 0, 1, 0, 0, 0, 0, std::nextafter(1.f, 2.f), 0})
               .is_identity());
}

TEST_CASE("transform_box contains the exact and the rounded images of all 8 corners") {
    random_source random;
    double const eps = std::numeric_limits<float>::epsilon();
    for (int i = 0; i < 2000; ++i) {
        affine_transform<float> const t = random.transform(100);
        vec3<float> const a = random.point(50), b = random.point(50);
        aabb const box{min(a, b), max(a, b)};
        aabb const image = transform_box(t, box);
        for (int corner = 0; corner < 8; ++corner) {
            vec3<float> const p((corner & 1) ? box.max.x : box.min.x, (corner & 2) ? box.max.y : box.min.y,
                                (corner & 4) ? box.max.z : box.min.z);
            CHECK(contains(image, transform_point(t, p)));
            for (int r = 0; r < 3; ++r) {
                // Float products are exact in long double; the sum is far below float resolution.
                std::array<long double, 3> const m = row(t.linear, r);
                long double const exact = m[0] * p.x + m[1] * p.y + m[2] * p.z + t.translation[r];
                CHECK(image.min[r] <= exact);
                CHECK(exact <= image.max[r]);
            }
        }
        // Tightness: within a few eps of the magnitude of the box of the rounded corners.
        aabb rounded;
        for (int corner = 0; corner < 8; ++corner)
            rounded = extend(rounded, transform_point(t, vec3<float>((corner & 1) ? box.max.x : box.min.x,
                                                                      (corner & 2) ? box.max.y : box.min.y,
                                                                      (corner & 4) ? box.max.z : box.min.z)));
        double const magnitude = 400;
        for (int r = 0; r < 3; ++r) {
            CHECK(rounded.min[r] - image.min[r] <= 8 * eps * magnitude);
            CHECK(image.max[r] - rounded.max[r] <= 8 * eps * magnitude);
        }
    }
}

TEST_CASE("transform_box of a scaled, translated unit box is its image widened by a few ulps") {
    auto const t = affine_transform<float>::from_rows({2, 0, 0, 1, 0, 1, 0, 0, 0, 0, 1, 0});
    aabb const image = transform_box(t, aabb{{0, 0, 0}, {1, 1, 1}});
    CHECK(image.min.x <= 1);
    CHECK(image.max.x >= 3);
    CHECK(image.min.y <= 0);
    CHECK(image.max.z >= 1);
    CHECK(canopy::ulp_distance(image.min.x, 1.f) <= 8);
    CHECK(canopy::ulp_distance(image.max.x, 3.f) <= 8);
    CHECK(canopy::ulp_distance(image.max.y, 1.f) <= 8);
    CHECK(is_empty(transform_box(t, aabb{})));

    auto const t_double = affine_transform<double>::from_rows({2, 0, 0, 1, 0, 1, 0, 0, 0, 0, 1, 0});
    basic_aabb<double> const image_double = transform_box(t_double, basic_aabb<double>{{0, 0, 0}, {1, 1, 1}});
    CHECK(image_double.min.x <= 1);
    CHECK(image_double.max.x >= 3);
    CHECK(canopy::ulp_distance(image_double.min.x, 1.0) <= 8);
    CHECK(canopy::ulp_distance(image_double.max.x, 3.0) <= 8);
}

// Boxes

TEST_CASE("a default aabb is empty and the identity of extend") {
    aabb const empty;
    CHECK(is_empty(empty));
    CHECK(is_empty(aabb::empty()));
    CHECK(empty.min.x == std::numeric_limits<float>::infinity());
    CHECK(empty.max.z == -std::numeric_limits<float>::infinity());
    CHECK(surface_area(empty) == 0);
    CHECK(!contains(empty, vec3<float>{0, 0, 0}));
    aabb const box{{-1, 0, 2}, {3, 1, 5}};
    CHECK(!overlaps(empty, box));
    CHECK(as_array(extend(empty, box).min) == as_array(box.min));
    CHECK(as_array(extend(box, empty).max) == as_array(box.max));
    aabb const point_box = extend(empty, vec3<float>{1, 2, 3});
    CHECK(!is_empty(point_box));
    CHECK(as_array(point_box.min) == std::array{1.f, 2.f, 3.f});
    CHECK(as_array(point_box.max) == std::array{1.f, 2.f, 3.f});
    CHECK(surface_area(point_box) == 0);
}

TEST_CASE("extend, intersection, center, diagonal and surface_area match hand-computed values") {
    aabb const a{{0, 0, 0}, {2, 3, 4}}, b{{1, -1, 3}, {5, 2, 6}};
    aabb const both = extend(a, b);
    CHECK(as_array(both.min) == std::array{0.f, -1.f, 0.f});
    CHECK(as_array(both.max) == std::array{5.f, 3.f, 6.f});
    aabb const common = intersection(a, b);
    CHECK(as_array(common.min) == std::array{1.f, 0.f, 3.f});
    CHECK(as_array(common.max) == std::array{2.f, 2.f, 4.f});
    CHECK(is_empty(intersection(a, aabb{{3, 0, 0}, {4, 1, 1}})));
    CHECK(as_array(center(a)) == std::array{1.f, 1.5f, 2.f});
    CHECK(as_array(diagonal(b)) == std::array{4.f, 3.f, 3.f});
    // 2 (2*3 + 3*4 + 4*2) = 52.
    CHECK(surface_area(a) == 52);
    CHECK(surface_area(basic_aabb<double>{{0, 0, 0}, {1, 1, 0}}) == 2);
    aabb const extended = extend(a, vec3<float>{-1, 10, 2});
    CHECK(as_array(extended.min) == std::array{-1.f, 0.f, 0.f});
    CHECK(as_array(extended.max) == std::array{2.f, 10.f, 4.f});
    CHECK(largest_axis(a) == 2);
    CHECK(largest_axis(aabb{{0, 0, 0}, {5, 1, 1}}) == 0);
}

TEST_CASE("extend ignores NaN coordinates of the point") {
    aabb const box{{0, 0, 0}, {1, 1, 1}};
    aabb const extended = extend(box, vec3<float>{std::numeric_limits<float>::quiet_NaN(), 2, 0.5f});
    CHECK(as_array(extended.min) == std::array{0.f, 0.f, 0.f});
    CHECK(as_array(extended.max) == std::array{1.f, 2.f, 1.f});
}

TEST_CASE("contains and overlaps treat boxes as closed") {
    aabb const box{{0, 0, 0}, {1, 1, 1}};
    CHECK(contains(box, vec3<float>{0.5f, 0.5f, 0.5f}));
    CHECK(contains(box, vec3<float>{1, 0, 1}));
    CHECK(!contains(box, vec3<float>{1, 0, std::nextafter(1.f, 2.f)}));
    CHECK(!contains(box, vec3<float>{std::numeric_limits<float>::quiet_NaN(), 0, 0}));
    CHECK(overlaps(box, aabb{{1, 1, 1}, {2, 2, 2}}));
    CHECK(overlaps(box, aabb{{0.2f, 0.2f, -5}, {0.3f, 0.3f, 5}}));
    CHECK(!overlaps(box, aabb{{0, 0, std::nextafter(1.f, 2.f)}, {1, 1, 2}}));
    CHECK(!overlaps(aabb{{-2, 0, 0}, {-1, 1, 1}}, box));
}

// Rays

TEST_CASE("point_at is origin + t direction with the direction left unnormalised") {
    basic_ray<float> const r{{1, 2, 3}, 0.5f, {0, 2, -4}, 10};
    CHECK(as_array(r.direction) == std::array{0.f, 2.f, -4.f});
    CHECK(as_array(point_at(r, 2.f)) == std::array{1.f, 6.f, -5.f});
    CHECK(as_array(r(0.25f)) == std::array{1.f, 2.5f, 2.f});
    CHECK(as_array(point_at(r, 0)) == as_array(r.origin));
    canopy::ray const defaulted;
    CHECK(defaulted.tmin == 0);
    CHECK(defaulted.tmax == 0);
    basic_ray<double> const d{{0, 0, 0}, 0, {3, 4, 0}, 1};
    CHECK(length(point_at(d, 1.0)) == 5);
}

// ULP helpers

TEMPLATE_TEST_CASE("next_float_up and next_float_down step to the neighbouring representable value", "",
                   float, double) {
    using limits = std::numeric_limits<TestType>;
    TestType const inf = limits::infinity(), max = limits::max(), tiny = limits::denorm_min();
    CHECK(canopy::next_float_up(TestType(1)) == 1 + limits::epsilon());
    CHECK(canopy::next_float_down(TestType(1)) == 1 - limits::epsilon() / 2);
    CHECK(canopy::next_float_up(TestType(0)) == tiny);
    CHECK(canopy::next_float_up(-TestType(0)) == tiny);
    CHECK(canopy::next_float_down(TestType(0)) == -tiny);
    CHECK(canopy::next_float_down(-TestType(0)) == -tiny);
    CHECK(canopy::next_float_up(tiny) == 2 * tiny);
    CHECK(canopy::next_float_down(tiny) == 0);
    CHECK(canopy::next_float_up(-tiny) == 0);
    CHECK(canopy::next_float_down(limits::min()) == limits::min() - tiny);
    CHECK(canopy::next_float_up(limits::min() - tiny) == limits::min());
    CHECK(canopy::next_float_up(max) == inf);
    CHECK(canopy::next_float_down(-max) == -inf);
    CHECK(canopy::next_float_up(inf) == inf);
    CHECK(canopy::next_float_down(-inf) == -inf);
    CHECK(canopy::next_float_up(-inf) == -max);
    CHECK(canopy::next_float_down(inf) == max);
    CHECK(std::isnan(canopy::next_float_up(limits::quiet_NaN())));
    CHECK(std::isnan(canopy::next_float_down(limits::quiet_NaN())));

    std::mt19937 engine(5);
    std::uniform_real_distribution<TestType> mantissa(-1, 1);
    std::uniform_int_distribution<int> exponent(limits::min_exponent - limits::digits,
                                                limits::max_exponent - 1);
    for (int i = 0; i < 10000; ++i) {
        TestType const x = std::ldexp(mantissa(engine), exponent(engine));
        if (x == 0)
            continue;
        CHECK(canopy::next_float_up(x) == std::nextafter(x, inf));
        CHECK(canopy::next_float_down(x) == std::nextafter(x, -inf));
    }
}

TEMPLATE_TEST_CASE("gamma(n) is n u / (1 - n u) correctly rounded", "", float, double) {
    long double const u = std::numeric_limits<TestType>::epsilon() / 2.0L;
    for (int n : {1, 2, 3, 5, 7, 64}) {
        // Within half an ulp of the long double value (itself exact to 2^-64 relative).
        long double const exact = n * u / (1 - n * u);
        TestType const gamma = canopy::gamma<TestType>(n);
        long double const ulp = canopy::next_float_up(gamma) - static_cast<long double>(gamma);
        CHECK(std::fabs(gamma - exact) <= ulp / 2);
        CHECK(gamma >= n * u);
    }
    static_assert(canopy::gamma<TestType>(3) > 3 * std::numeric_limits<TestType>::epsilon() / 2);
}

TEMPLATE_TEST_CASE("ulp_distance counts representable values between its arguments", "", float, double) {
    using limits = std::numeric_limits<TestType>;
    TestType const tiny = limits::denorm_min();
    CHECK(canopy::ulp_distance(TestType(1), canopy::next_float_up(TestType(1))) == 1);
    CHECK(canopy::ulp_distance(canopy::next_float_up(TestType(1)), TestType(1)) == 1);
    CHECK(canopy::ulp_distance(TestType(3), TestType(3)) == 0);
    CHECK(canopy::ulp_distance(-TestType(0), TestType(0)) == 0);
    CHECK(canopy::ulp_distance(-tiny, tiny) == 2);
    CHECK(canopy::ulp_distance(-2 * tiny, 2 * tiny) == 4);
    CHECK(canopy::ulp_distance(TestType(1), TestType(2)) == (std::uint64_t(1) << (limits::digits - 1)));
    using bits = decltype(canopy::ulp_distance(TestType(0), TestType(0)));
    auto const bits_of_one = std::bit_cast<bits>(TestType(1));
    CHECK(canopy::ulp_distance(TestType(-1), TestType(1)) == 2 * std::uint64_t(bits_of_one));
    auto const bits_of_inf = std::bit_cast<bits>(limits::infinity());
    CHECK(canopy::ulp_distance(-limits::infinity(), limits::infinity()) == 2 * std::uint64_t(bits_of_inf));
    CHECK(canopy::ulp_distance(limits::quiet_NaN(), TestType(1)) == std::numeric_limits<bits>::max());

    TestType x = -3 * tiny;
    for (int steps = 1; steps <= 6; ++steps) {
        x = canopy::next_float_up(x);
        CHECK(canopy::ulp_distance(-3 * tiny, x) == std::uint64_t(steps));
    }
}

// SIMD types

namespace {

namespace simd = canopy::simd;

template <typename V> V pack(std::array<float, simd::simd_width_v<V>> const& lanes) {
    V v;
    for (int i = 0; i < simd::simd_width_v<V>; ++i)
        v.set(i, lanes[i]);
    return v;
}

template <typename V> vec3<V> pack(std::array<vec3<float>, simd::simd_width_v<V>> const& lanes) {
    vec3<V> v;
    for (int i = 0; i < simd::simd_width_v<V>; ++i)
        set_lane(v, i, lanes[i]);
    return v;
}

template <typename V> basic_aabb<V> pack(std::array<aabb, simd::simd_width_v<V>> const& lanes) {
    basic_aabb<V> b;
    for (int i = 0; i < simd::simd_width_v<V>; ++i) {
        set_lane(b.min, i, lanes[i].min);
        set_lane(b.max, i, lanes[i].max);
    }
    return b;
}

// Inputs with a NaN, an infinity and a negative zero in some lanes, to compare special cases too.
template <int width> struct lane_inputs {
    std::array<vec3<float>, width> a, b, c;
    std::array<float, width> s, t;

    explicit lane_inputs(random_source& random) {
        for (int i = 0; i < width; ++i) {
            a[i] = random.point(10);
            b[i] = random.point(10);
            c[i] = random.point(10);
            s[i] = random.uniform(-2, 2);
            t[i] = random.uniform(-2, 2);
        }
        a[1].x = std::numeric_limits<float>::quiet_NaN();
        b[2].y = std::numeric_limits<float>::infinity();
        a[3].z = -0.f;
    }
};

} // namespace

TEMPLATE_TEST_CASE("vec3 of SIMD lanes equals vec3<float> lane by lane, bit for bit", "", simd::float4,
                   simd::float8, simd::float16) {
    using V = TestType;
    constexpr int width = simd::simd_width_v<V>;
    random_source random;
    for (int round = 0; round < 50; ++round) {
        lane_inputs<width> const in(random);
        vec3<V> const a = pack<V>(in.a), b = pack<V>(in.b), c = pack<V>(in.c);
        V const s = pack<V>(in.s), t = pack<V>(in.t);
        auto const mask = a.x < b.x;
        auto const m = mat3<V>{a, b, c};
        auto const scalar_transform = random.transform(10);
        affine_transform<V> const transform{m, c};

        for (int i = 0; i < width; ++i) {
            vec3<float> const ai = in.a[i], bi = in.b[i], ci = in.c[i];
            float const si = in.s[i], ti = in.t[i];
            CAPTURE(round, i);
            CHECK(same_bits(get_lane(a + b, i), ai + bi));
            CHECK(same_bits(get_lane(a - b, i), ai - bi));
            CHECK(same_bits(get_lane(a * b, i), ai * bi));
            CHECK(same_bits(get_lane(a / b, i), ai / bi));
            CHECK(same_bits(get_lane(a * s, i), ai * si));
            CHECK(same_bits(get_lane(s * a, i), si * ai));
            CHECK(same_bits(get_lane(a + 2.f, i), ai + 2.f));
            CHECK(same_bits(get_lane(a / s, i), ai / si));
            CHECK(same_bits(get_lane(-a, i), -ai));
            CHECK(same_bits(dot(a, b)[i], dot(ai, bi)));
            CHECK(same_bits(get_lane(cross(a, b), i), cross(ai, bi)));
            CHECK(same_bits(length(b)[i], length(bi)));
            CHECK(same_bits(get_lane(normalize(b), i), normalize(bi)));
            CHECK(same_bits(get_lane(lerp(a, b, s), i), lerp(ai, bi, si)));
            CHECK(same_bits(get_lane(lerp(a, b, c, s, t), i), lerp(ai, bi, ci, si, ti)));
            CHECK(same_bits(get_lane(min(a, b), i), min(ai, bi)));
            CHECK(same_bits(get_lane(max(a, b), i), max(ai, bi)));
            CHECK(same_bits(get_lane(abs(a), i), abs(ai)));
            CHECK(same_bits(get_lane(clamp(a, -1.f, 1.f), i), clamp(ai, -1.f, 1.f)));
            CHECK(same_bits(get_lane(select(mask, a, b), i), select(ai.x < bi.x, ai, bi)));
            CHECK(same_bits(min_component(b)[i], min_component(bi)));
            CHECK(same_bits(max_component(b)[i], max_component(bi)));
            CHECK(any_nan(a)[i] == any_nan(ai));
            CHECK(all_finite(b)[i] == all_finite(bi));

            mat3<float> const mi{ai, bi, ci};
            CHECK(same_bits(get_lane(m * c, i), mi * ci));
            CHECK(same_bits(get_lane((m * m).col1, i), (mi * mi).col1));
            CHECK(same_bits(determinant(m)[i], determinant(mi)));
            CHECK(same_bits(get_lane(inverse(m).col2, i), inverse(mi).col2));
            // One scalar transform applied to a packet.
            CHECK(same_bits(get_lane(transform_point(scalar_transform, a), i),
                            transform_point(scalar_transform, ai)));
            CHECK(same_bits(get_lane(transform_vector(scalar_transform, a), i),
                            transform_vector(scalar_transform, ai)));
            affine_transform<float> const ti_transform{mi, ci};
            CHECK(same_bits(get_lane(transform_point(transform, b), i), transform_point(ti_transform, bi)));
            affine_transform<V> const inv = inverse(transform);
            affine_transform<float> const inv_i = inverse(ti_transform);
            CHECK(same_bits(get_lane(inv.linear.col0, i), inv_i.linear.col0));
            CHECK(same_bits(get_lane(inv.translation, i), inv_i.translation));
            CHECK(transform.is_identity()[i] == ti_transform.is_identity());

            basic_ray<V> const r{a, s, b, t};
            basic_ray<float> const ri{ai, si, bi, ti};
            CHECK(same_bits(get_lane(point_at(r, t), i), point_at(ri, ti)));
            CHECK(same_bits(get_lane(r(s), i), ri(si)));
        }
    }
}

TEMPLATE_TEST_CASE("basic_aabb of SIMD lanes equals aabb lane by lane", "", simd::float8, simd::float16) {
    using V = TestType;
    constexpr int width = simd::simd_width_v<V>;
    random_source random;
    for (int round = 0; round < 50; ++round) {
        std::array<aabb, width> boxes, others;
        std::array<vec3<float>, width> points;
        for (int i = 0; i < width; ++i) {
            vec3<float> const p = random.point(4), q = random.point(4);
            vec3<float> const r = random.point(4), s = random.point(4);
            boxes[i] = {min(p, q), max(p, q)};
            others[i] = {min(r, s), max(r, s)};
            points[i] = random.point(4);
        }
        boxes[0] = aabb{};
        basic_aabb<V> const box = pack<V>(boxes), other = pack<V>(others);
        vec3<V> const point = pack<V>(points);
        CHECK(simd::all(is_empty(basic_aabb<V>{})));
        for (int i = 0; i < width; ++i) {
            CAPTURE(round, i);
            CHECK(is_empty(box)[i] == is_empty(boxes[i]));
            CHECK(same_bits(get_lane(extend(box, point).min, i), extend(boxes[i], points[i]).min));
            CHECK(same_bits(get_lane(extend(box, other).max, i), extend(boxes[i], others[i]).max));
            CHECK(same_bits(get_lane(intersection(box, other).min, i),
                            intersection(boxes[i], others[i]).min));
            CHECK(same_bits(get_lane(center(other), i), center(others[i])));
            CHECK(same_bits(surface_area(box)[i], surface_area(boxes[i])));
            CHECK(contains(box, point)[i] == contains(boxes[i], points[i]));
            CHECK(overlaps(box, other)[i] == overlaps(boxes[i], others[i]));
        }
    }
}

TEST_CASE("get_lane and set_lane round-trip for vec2, vec3 and vec4") {
    vec4<simd::float8> v;
    vec3<simd::float8> w;
    vec2<simd::float8> x;
    for (int i = 0; i < 8; ++i) {
        float const f = float(i);
        set_lane(v, i, vec4<float>{f, -f, 2 * f, 0.5f * f});
        set_lane(w, i, vec3<float>{f, f + 1, f + 2});
        set_lane(x, i, vec2<float>{-f, f * f});
    }
    for (int i = 0; i < 8; ++i) {
        float const f = float(i);
        CHECK(as_array(get_lane(v, i)) == std::array{f, -f, 2 * f, 0.5f * f});
        CHECK(as_array(get_lane(w, i)) == std::array{f, f + 1, f + 2});
        CHECK(as_array(get_lane(x, i)) == std::array{-f, f * f});
        CHECK(w.y[i] == f + 1);
    }
    CHECK(as_array(get_lane(vec3<simd::float8>(vec3<float>{1, 2, 3}), 7)) == std::array{1.f, 2.f, 3.f});

    vec3<float> scalar{1, 2, 3};
    CHECK(as_array(get_lane(scalar, 0)) == std::array{1.f, 2.f, 3.f});
    set_lane(scalar, 0, vec3<float>{4, 5, 6});
    CHECK(as_array(scalar) == std::array{4.f, 5.f, 6.f});
}
