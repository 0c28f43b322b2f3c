// Tests of canopy.texture. References are hand-computed texels and blends, a double-precision
// bilinear filter whose address modes are written as loops (repeated shifts and reflections),
// and, for SIMD coordinates, the scalar tex2D run lane by lane. Then the reading of texture
// files (canopy.image, canopy.plugins.oiio): hand-written image files with known texels, and
// hostile ones (a header claiming 16384 × 16384, a /dev/zero symlink) refused by name before
// anything is decoded.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <concepts>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

import canopy.texture;
import canopy.scene;
import canopy.image;
import canopy.plugins.oiio;
import canopy.testing;
import canopy.testing.scene;

namespace {

using canopy::address_mode;
using canopy::filter_mode;
using canopy::tex2D;
using canopy::texture2d;
using canopy::vec2;
using canopy::vec4;
using rgba = vec4<float>;

constexpr float inf = std::numeric_limits<float>::infinity();
constexpr float quiet_nan = std::numeric_limits<float>::quiet_NaN();

constexpr std::array all_filters{filter_mode::nearest, filter_mode::bilinear};
constexpr std::array all_address_modes{address_mode::wrap, address_mode::clamp, address_mode::mirror};

// 4 x 3 texels: texel (x, y) = {x / 4, y / 4, id / 16, 1 - id / 16} with id = x + 4y, so every
// texel differs and every blend used below is exact in float.
texture2d<rgba> grid_4x3(filter_mode filter, address_mode address) {
    std::vector<rgba> texels;
    for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 4; ++x) {
            float const id = float(x + 4 * y) / 16;
            texels.emplace_back(float(x) / 4, float(y) / 4, id, 1 - id);
        }
    return texture2d<rgba>(4, 3, std::move(texels), {.filter = filter, .address = address});
}

template <typename Texel> Texel random_texel(std::mt19937& rng) {
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    if constexpr (std::same_as<Texel, float>)
        return unit(rng);
    else
        return {unit(rng), unit(rng), unit(rng), unit(rng)};
}

template <typename Texel> texture2d<Texel> random_texture(int width, int height, std::mt19937& rng) {
    std::vector<Texel> texels(std::size_t(width) * std::size_t(height));
    for (Texel& t : texels)
        t = random_texel<Texel>(rng);
    return texture2d<Texel>(width, height, std::move(texels));
}

// Equal bit patterns, or both NaN.
bool same_bits(float a, float b) {
    return std::bit_cast<std::uint32_t>(a) == std::bit_cast<std::uint32_t>(b) || (std::isnan(a) && std::isnan(b));
}
bool same_bits(rgba const& a, rgba const& b) {
    return same_bits(a.x, b.x) && same_bits(a.y, b.y) && same_bits(a.z, b.z) && same_bits(a.w, b.w);
}

std::array<float, 4> channels(rgba const& t) { return {t.x, t.y, t.z, t.w}; }
std::array<float, 1> channels(float t) { return {t}; }

bool equal(rgba const& a, rgba const& b) { return a.x == b.x && a.y == b.y && a.z == b.z && a.w == b.w; }

rgba sample(texture2d<rgba> const& texture, float u, float v) { return tex2D(texture, vec2<float>(u, v)); }

// Index i brought into [0, n) by moving it a period at a time (wrap), stopping at the edge
// (clamp), or reflecting it about the edge it crossed (mirror).
int reference_address(long long i, int n, address_mode mode) {
    switch (mode) {
    case address_mode::wrap:
        while (i < 0)
            i += n;
        while (i >= n)
            i -= n;
        return int(i);
    case address_mode::clamp:
        return int(std::clamp<long long>(i, 0, n - 1));
    case address_mode::mirror:
        while (i < 0 || i >= n)
            i = i < 0 ? -1 - i : 2LL * n - 1 - i;
        return int(i);
    }
    return -1;
}

// Texel indices of the bilinear footprint along one axis: floor(s * n - 0.5) and the next one,
// with the scaled coordinate rounded to float as the filter does.
std::pair<long long, long long> footprint(float s, int n) {
    auto const first = static_cast<long long>(std::floor(s * float(n) - 0.5f));
    return {first, first + 1};
}

// Bilinear filter in double: weights from the exact position s * n - 0.5, texels fetched
// through reference_address.
template <typename Texel> auto reference_bilinear(texture2d<Texel> const& texture, double u, double v) {
    address_mode const mode = texture.address();
    double const px = u * texture.width() - 0.5;
    double const py = v * texture.height() - 0.5;
    auto const x0 = static_cast<long long>(std::floor(px));
    auto const y0 = static_cast<long long>(std::floor(py));
    double const fx = px - double(x0);
    double const fy = py - double(y0);
    std::array<double, std::same_as<Texel, float> ? 1 : 4> result{};
    for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 2; ++dx) {
            double const weight = (dx == 1 ? fx : 1 - fx) * (dy == 1 ? fy : 1 - fy);
            auto const texel = channels(texture.texel(reference_address(x0 + dx, texture.width(), mode),
                                                      reference_address(y0 + dy, texture.height(), mode)));
            for (std::size_t c = 0; c < result.size(); ++c)
                result[c] += weight * texel[c];
        }
    return result;
}

} // namespace

TEST_CASE("texture2d stores texels row-major with row 0 at the top") {
    texture2d<float> texture(3, 2, {1, 2, 3, 4, 5, 6});
    CHECK(texture.width() == 3);
    CHECK(texture.height() == 2);
    CHECK(texture.texel(0, 0) == 1);
    CHECK(texture.texel(2, 0) == 3);
    CHECK(texture.texel(0, 1) == 4);
    CHECK(texture.texel(2, 1) == 6);
    CHECK(texture.texels().size() == 6);

    SECTION("the modes default to bilinear and wrap and can be changed") {
        CHECK(texture.filter() == filter_mode::bilinear);
        CHECK(texture.address() == address_mode::wrap);
        texture.set_filter(filter_mode::nearest);
        texture.set_address(address_mode::mirror);
        CHECK(texture.filter() == filter_mode::nearest);
        CHECK(texture.address() == address_mode::mirror);
    }

    SECTION("texels can be edited in place") {
        texture.texel(1, 1) = 9;
        CHECK(texture.texels()[4] == 9);
    }
}

TEST_CASE("texture2d construction rejects zero sizes and texel counts that do not match") {
    using Catch::Matchers::Contains;
    CHECK_THROWS_AS(texture2d<float>(0, 2, {}), std::invalid_argument);
    CHECK_THROWS_WITH(texture2d<float>(0, 2, {}), Contains("width") && Contains("got 0"));
    CHECK_THROWS_WITH(texture2d<float>(2, 0, {}), Contains("height") && Contains("got 0"));
    CHECK_THROWS_WITH(texture2d<float>(-3, 2, {}), Contains("width") && Contains("got -3"));
    CHECK_THROWS_WITH(texture2d<float>(texture2d<float>::max_side + 1, 1, {}), Contains("width"));
    CHECK_THROWS_WITH(texture2d<rgba>(4, 3, std::vector<rgba>(11)),
                      Contains("4 x 3 texels need 12 values, got 11"));
    CHECK_THROWS_WITH(texture2d<float>(2, 2, {1, 2, 3, 4, 5}), Contains("need 4 values, got 5"));
    CHECK_THROWS_WITH(texture2d<rgba>(1 << 15, 1 << 14, {}), Contains("exceed 2^31 - 1 floats"));
    CHECK_NOTHROW(texture2d<float>(1, 1, {0.5f}));
}

TEST_CASE("nearest filtering returns the texel containing the coordinate") {
    auto const texture = grid_4x3(filter_mode::nearest, address_mode::wrap);
    for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 4; ++x) {
            INFO("texel " << x << ", " << y);
            // Centre, and just inside the top-left and bottom-right corners of the texel.
            CHECK(equal(sample(texture, (float(x) + 0.5f) / 4, (float(y) + 0.5f) / 3), texture.texel(x, y)));
            CHECK(equal(sample(texture, float(x) / 4, float(y) / 3 + 1e-6f), texture.texel(x, y)));
            CHECK(equal(sample(texture, (float(x) + 0.99f) / 4, (float(y) + 0.99f) / 3), texture.texel(x, y)));
        }
    CHECK(equal(sample(texture, 0.0f, 0.0f), texture.texel(0, 0)));
    CHECK(equal(sample(texture, 0.999f, 0.999f), texture.texel(3, 2)));
    CHECK(equal(sample(texture, 0.999f, 0.0f), texture.texel(3, 0)));
    CHECK(equal(sample(texture, 0.0f, 0.999f), texture.texel(0, 2)));
}

TEST_CASE("bilinear filtering at texel centres returns the texel exactly") {
    for (address_mode const mode : all_address_modes) {
        auto const texture = grid_4x3(filter_mode::bilinear, mode);
        for (int y = 0; y < 3; ++y)
            for (int x = 0; x < 4; ++x) {
                INFO("texel " << x << ", " << y);
                CHECK(equal(sample(texture, (float(x) + 0.5f) / 4, (float(y) + 0.5f) / 3), texture.texel(x, y)));
            }
    }
    std::mt19937 rng(7);
    auto const random = random_texture<rgba>(8, 5, rng);
    for (int y = 0; y < 5; ++y)
        for (int x = 0; x < 8; ++x)
            CHECK(equal(sample(random, (float(x) + 0.5f) / 8, (float(y) + 0.5f) / 5), random.texel(x, y)));
}

TEST_CASE("bilinear filtering halfway between texel centres returns the exact average") {
    auto const texture = grid_4x3(filter_mode::bilinear, address_mode::clamp);
    // Between texels (1, 1) and (2, 1).
    CHECK(equal(sample(texture, 0.5f, 0.5f), {0.375f, 0.25f, 11.0f / 32, 21.0f / 32}));
    // Between texels (2, 0) and (2, 1).
    CHECK(equal(sample(texture, 2.5f / 4, 1.0f / 3), {0.5f, 0.125f, 8.0f / 32, 24.0f / 32}));
    // Amid texels (1, 0), (2, 0), (1, 1) and (2, 1).
    CHECK(equal(sample(texture, 0.5f, 1.0f / 3), {0.375f, 0.125f, 7.0f / 32, 25.0f / 32}));
    // A quarter of the way from texel (0, 2) to texel (1, 2).
    CHECK(equal(sample(texture, 0.75f / 4, 2.5f / 3), {0.0625f, 0.5f, 33.0f / 64, 31.0f / 64}));
}

TEST_CASE("bilinear filtering at the image corners follows the address mode") {
    rgba const wrapped{0.375f, 0.25f, 11.0f / 32, 21.0f / 32}; // mean of the four corner texels
    for (auto const& [u, v] : {std::pair{0.0f, 0.0f}, std::pair{1.0f, 1.0f}, std::pair{1.0f, 0.0f}}) {
        INFO("corner " << u << ", " << v);
        CHECK(equal(sample(grid_4x3(filter_mode::bilinear, address_mode::wrap), u, v), wrapped));
    }
    auto const clamped = grid_4x3(filter_mode::bilinear, address_mode::clamp);
    auto const mirrored = grid_4x3(filter_mode::bilinear, address_mode::mirror);
    CHECK(equal(sample(clamped, 0.0f, 0.0f), clamped.texel(0, 0)));
    CHECK(equal(sample(clamped, 1.0f, 1.0f), clamped.texel(3, 2)));
    CHECK(equal(sample(clamped, 1.0f, 0.0f), clamped.texel(3, 0)));
    CHECK(equal(sample(mirrored, 0.0f, 0.0f), mirrored.texel(0, 0)));
    CHECK(equal(sample(mirrored, 1.0f, 1.0f), mirrored.texel(3, 2)));
    CHECK(equal(sample(mirrored, 0.0f, 1.0f), mirrored.texel(0, 2)));
}

TEST_CASE("nearest filtering outside [0, 1] wraps, clamps or mirrors the texel index") {
    // Scaled by 4 x 3: u -> 11, -1, 5, -4, -2.4 and v -> 8.25, -0.75, 4.5, -3, -1.8.
    struct expected_texels {
        float u, v;
        int wrap_x, wrap_y, clamp_x, clamp_y, mirror_x, mirror_y;
    };
    std::array const cases{
        expected_texels{2.75f, 2.75f, 3, 2, 3, 2, 3, 2},  expected_texels{-0.25f, -0.25f, 3, 2, 0, 0, 0, 0},
        expected_texels{1.25f, 1.5f, 1, 1, 3, 2, 2, 1},   expected_texels{-1.0f, -1.0f, 0, 0, 0, 0, 3, 2},
        expected_texels{-0.6f, -0.6f, 1, 1, 0, 0, 2, 1},
    };
    auto const wrapped = grid_4x3(filter_mode::nearest, address_mode::wrap);
    auto const clamped = grid_4x3(filter_mode::nearest, address_mode::clamp);
    auto const mirrored = grid_4x3(filter_mode::nearest, address_mode::mirror);
    for (auto const& c : cases) {
        INFO("coordinate " << c.u << ", " << c.v);
        CHECK(equal(sample(wrapped, c.u, c.v), wrapped.texel(c.wrap_x, c.wrap_y)));
        CHECK(equal(sample(clamped, c.u, c.v), clamped.texel(c.clamp_x, c.clamp_y)));
        CHECK(equal(sample(mirrored, c.u, c.v), mirrored.texel(c.mirror_x, c.mirror_y)));
    }
}

TEST_CASE("bilinear filtering outside [0, 1] blends the wrapped, clamped or mirrored texels") {
    auto const wrapped = grid_4x3(filter_mode::bilinear, address_mode::wrap);
    auto const clamped = grid_4x3(filter_mode::bilinear, address_mode::clamp);
    auto const mirrored = grid_4x3(filter_mode::bilinear, address_mode::mirror);

    SECTION("u = -0.25 on the centre row: halfway between columns -2 and -1") {
        CHECK(equal(sample(wrapped, -0.25f, 0.5f), {0.625f, 0.25f, 13.0f / 32, 19.0f / 32}));  // columns 2, 3
        CHECK(equal(sample(clamped, -0.25f, 0.5f), clamped.texel(0, 1)));                     // columns 0, 0
        CHECK(equal(sample(mirrored, -0.25f, 0.5f), {0.125f, 0.25f, 9.0f / 32, 23.0f / 32})); // columns 1, 0
    }
    SECTION("u = 2.75 on the centre row: halfway between columns 10 and 11") {
        CHECK(equal(sample(wrapped, 2.75f, 0.5f), {0.625f, 0.25f, 13.0f / 32, 19.0f / 32}));  // columns 2, 3
        CHECK(equal(sample(clamped, 2.75f, 0.5f), clamped.texel(3, 1)));                      // columns 3, 3
        CHECK(equal(sample(mirrored, 2.75f, 0.5f), {0.625f, 0.25f, 13.0f / 32, 19.0f / 32})); // columns 2, 3
    }
    SECTION("v = -0.25 in column 1: rows -2 and -1 weighted 1/4 and 3/4") {
        CHECK(equal(sample(wrapped, 0.375f, -0.25f), {0.25f, 0.4375f, 0.5f, 0.5f}));      // rows 1, 2
        CHECK(equal(sample(clamped, 0.375f, -0.25f), clamped.texel(1, 0)));              // rows 0, 0
        CHECK(equal(sample(mirrored, 0.375f, -0.25f), {0.25f, 0.0625f, 0.125f, 0.875f})); // rows 1, 0
    }
}

TEST_CASE("bilinear filtering matches a double-precision reference at random coordinates") {
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> coordinate(-3.0f, 3.0f);
    auto const check_texture = [&](auto texture) {
        for (address_mode const mode : all_address_modes) {
            texture.set_address(mode);
            for (int k = 0; k < 2000; ++k) {
                float const u = coordinate(rng), v = coordinate(rng);
                auto const expected = reference_bilinear(texture, u, v);
                auto const actual = channels(tex2D(texture, vec2<float>(u, v)));
                INFO("mode " << int(mode) << " at " << u << ", " << v);
                for (std::size_t c = 0; c < actual.size(); ++c)
                    CHECK(actual[c] == Approx(expected[c]).margin(1e-5));
            }
        }
    };
    check_texture(random_texture<rgba>(4, 3, rng));
    check_texture(random_texture<rgba>(1, 5, rng));
    check_texture(random_texture<float>(5, 2, rng));
}

TEST_CASE("bilinear results stay within the range of the four neighbouring texels") {
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> coordinate(-2.0f, 2.0f);
    auto texture = random_texture<rgba>(5, 4, rng);
    for (address_mode const mode : all_address_modes) {
        texture.set_address(mode);
        for (int k = 0; k < 5000; ++k) {
            float const u = coordinate(rng), v = coordinate(rng);
            auto const [x0, x1] = footprint(u, 5);
            auto const [y0, y1] = footprint(v, 4);
            std::array const neighbours{
                channels(texture.texel(reference_address(x0, 5, mode), reference_address(y0, 4, mode))),
                channels(texture.texel(reference_address(x1, 5, mode), reference_address(y0, 4, mode))),
                channels(texture.texel(reference_address(x0, 5, mode), reference_address(y1, 4, mode))),
                channels(texture.texel(reference_address(x1, 5, mode), reference_address(y1, 4, mode)))};
            auto const result = channels(sample(texture, u, v));
            for (std::size_t c = 0; c < 4; ++c) {
                float lowest = inf, highest = -inf;
                for (auto const& n : neighbours) {
                    lowest = std::min(lowest, n[c]);
                    highest = std::max(highest, n[c]);
                }
                INFO("mode " << int(mode) << " at " << u << ", " << v << ", channel " << c);
                CHECK(result[c] >= lowest);
                CHECK(result[c] <= highest);
            }
        }
    }
}

TEST_CASE("NaN, infinite and huge coordinates sample the documented texels") {
    SECTION("a NaN component samples as 0") {
        for (filter_mode const filter : all_filters)
            for (address_mode const mode : all_address_modes) {
                auto const texture = grid_4x3(filter, mode);
                CHECK(same_bits(sample(texture, quiet_nan, quiet_nan), sample(texture, 0.0f, 0.0f)));
                CHECK(same_bits(sample(texture, quiet_nan, 0.7f), sample(texture, 0.0f, 0.7f)));
                CHECK(same_bits(sample(texture, 0.3f, -quiet_nan), sample(texture, 0.3f, 0.0f)));
            }
        CHECK(equal(sample(grid_4x3(filter_mode::nearest, address_mode::wrap), quiet_nan, quiet_nan), {0, 0, 0, 1}));
    }
    SECTION("infinities sample at ±2^30 texels") {
        // 2^30 mod 4 = 0, 2^30 mod 3 = 1, -2^30 mod 3 = 2; mirrored: 2^30 mod 6 = 4 -> row 1.
        auto const wrapped = grid_4x3(filter_mode::nearest, address_mode::wrap);
        auto const clamped = grid_4x3(filter_mode::nearest, address_mode::clamp);
        auto const mirrored = grid_4x3(filter_mode::nearest, address_mode::mirror);
        CHECK(equal(sample(wrapped, inf, inf), wrapped.texel(0, 1)));
        CHECK(equal(sample(wrapped, -inf, -inf), wrapped.texel(0, 2)));
        CHECK(equal(sample(clamped, inf, inf), clamped.texel(3, 2)));
        CHECK(equal(sample(clamped, -inf, -inf), clamped.texel(0, 0)));
        CHECK(equal(sample(mirrored, inf, inf), mirrored.texel(0, 1)));
        CHECK(same_bits(sample(wrapped, 1e30f, -1e30f), sample(wrapped, inf, -inf)));
        CHECK(equal(sample(grid_4x3(filter_mode::bilinear, address_mode::clamp), inf, -inf), clamped.texel(3, 0)));
    }
    SECTION("a 1 x 1 texture returns its texel everywhere") {
        for (filter_mode const filter : all_filters)
            for (address_mode const mode : all_address_modes) {
                texture2d<rgba> const single(1, 1, {rgba(0.1f, 0.2f, 0.3f, 0.4f)}, {.filter = filter, .address = mode});
                for (float const s : {0.0f, -0.0f, 0.5f, 1.0f, -7.3f, 1e30f, inf, -inf, quiet_nan})
                    CHECK(same_bits(sample(single, s, 0.25f - s), single.texel(0, 0)));
            }
    }
}

TEST_CASE("float textures sample like the matching channel of an RGBA texture") {
    std::mt19937 rng(5);
    auto rgba_texture = random_texture<rgba>(6, 5, rng);
    std::vector<float> blue;
    for (rgba const& t : rgba_texture.texels())
        blue.push_back(t.z);
    texture2d<float> blue_texture(6, 5, std::move(blue));
    std::uniform_real_distribution<float> coordinate(-2.0f, 2.0f);
    for (filter_mode const filter : all_filters)
        for (address_mode const mode : all_address_modes) {
            rgba_texture.set_filter(filter);
            rgba_texture.set_address(mode);
            blue_texture.set_filter(filter);
            blue_texture.set_address(mode);
            for (int k = 0; k < 1000; ++k) {
                vec2<float> const coord(coordinate(rng), coordinate(rng));
                CHECK(same_bits(tex2D(blue_texture, coord), tex2D(rgba_texture, coord).z));
            }
        }
}

TEMPLATE_TEST_CASE("tex2D on SIMD coordinates equals scalar tex2D lane by lane, bit for bit", "",
                   canopy::simd::float4, canopy::simd::float8, canopy::simd::float16) {
    constexpr int width = canopy::simd::simd_width_v<TestType>;
    float const max = std::numeric_limits<float>::max();
    float const denormal = std::numeric_limits<float>::denorm_min();
    std::array const special{0.0f,   -0.0f,   inf,   -inf,   quiet_nan,     -quiet_nan,     1.0f,       -1.0f,
                             0.5f,   0.75f,   2.75f, -0.25f, 1e30f,   -1e30f,   max,        -max,
                             denormal, -denormal, 0x1p24f, 0x1p30f, 0x1p31f, -0x1p31f, 0.99999994f, 1.0000001f};
    std::vector<vec2<float>> coords;
    for (float const u : special)
        for (float const v : special)
            coords.emplace_back(u, v);
    std::mt19937 rng(13);
    std::uniform_real_distribution<float> near_image(-3.0f, 3.0f);
    std::uniform_int_distribution<std::uint32_t> bits;
    for (int k = 0; k < 2000; ++k) {
        coords.emplace_back(near_image(rng), near_image(rng));
        coords.emplace_back(std::bit_cast<float>(bits(rng)), std::bit_cast<float>(bits(rng)));
    }
    while (coords.size() % width != 0)
        coords.emplace_back(0.25f, 0.25f);

    auto const check_texture = [&](auto texture) {
        for (filter_mode const filter : all_filters)
            for (address_mode const mode : all_address_modes) {
                texture.set_filter(filter);
                texture.set_address(mode);
                for (std::size_t first = 0; first < coords.size(); first += width) {
                    vec2<TestType> packet;
                    for (int i = 0; i < width; ++i)
                        canopy::set_lane(packet, i, coords[first + std::size_t(i)]);
                    auto const result = tex2D(texture, packet);
                    for (int i = 0; i < width; ++i) {
                        vec2<float> const coord = coords[first + std::size_t(i)];
                        auto const expected = tex2D(texture, coord);
                        auto const lane = [&] {
                            if constexpr (std::same_as<decltype(result), TestType const>)
                                return result[i];
                            else
                                return canopy::get_lane(result, i);
                        }();
                        INFO("filter " << int(filter) << ", mode " << int(mode) << " at " << coord.x << ", "
                                       << coord.y);
                        CHECK(same_bits(lane, expected));
                    }
                }
            }
    };
    check_texture(random_texture<rgba>(4, 3, rng));
    check_texture(random_texture<rgba>(7, 1, rng));
    check_texture(random_texture<float>(5, 6, rng));
    check_texture(random_texture<float>(1, 1, rng));
}

// ---- Texture files --------------------------------------------------------------------------------

namespace {

namespace fs = std::filesystem;
using test_support::temp_folder;
using test_support::limits_guard;

std::uint32_t crc32(std::string const& bytes) {
    std::uint32_t c = 0xFFFFFFFFu;
    for (unsigned char b : bytes) {
        c ^= b;
        for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return ~c;
}

void put_be32(std::string& out, std::uint32_t v) {
    for (int k = 3; k >= 0; --k) out += char((v >> (8 * k)) & 0xFF);
}

// A PNG whose header (IHDR) says width × height, RGBA 8-bit, followed by a few bytes of image
// data and the end: some 60 bytes that claim width · height texels.
std::string png_claiming(std::uint32_t width, std::uint32_t height) {
    auto const chunk = [](std::string& out, std::string const& type, std::string const& data) {
        put_be32(out, std::uint32_t(data.size()));
        out += type + data;
        put_be32(out, crc32(type + data));
    };
    std::string png = "\x89PNG\r\n\x1a\n";
    std::string ihdr;
    put_be32(ihdr, width);
    put_be32(ihdr, height);
    ihdr += std::string("\x08\x06\x00\x00\x00", 5);
    chunk(png, "IHDR", ihdr);
    chunk(png, "IDAT", std::string("\x78\x9c\x63\x00\x00", 5));
    chunk(png, "IEND", "");
    return png;
}

std::string problem_of(auto&& f) {
    try {
        f();
    } catch (canopy::scene_error const& e) {
        return e.what();
    }
    FAIL_CHECK("no error");
    return {};
}

} // namespace

TEST_CASE("an image whose header claims more than --max-texels texels is refused before decoding") {
    temp_folder const tmp("canopy_texture_test");
    fs::path const big = tmp.path / "big.png";
    std::string const png = png_claiming(16384, 16384);
    tmp.write("big.png", png);
    CHECK(png.size() < 100);
    std::string const expected =
        "big.png: image is 16384 × 16384 (268435456 texels), over the limit of 67108864 texels (--max-texels)";
    CHECK_THAT(problem_of([&] { (void)canopy::read_image(big); }), Catch::Contains(expected));
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(big); }), Catch::Contains(expected));
    canopy::registry r;
    canopy::register_oiio_plugin(r);
    CHECK_THAT(problem_of([&] { (void)r.load_image(big); }), Catch::Contains(expected));

    // The limit is --max-texels: at it an image is read, one texel more is refused.
    limits_guard const guard;
    canopy::rgba_image two;
    two.width = 2;
    two.height = 1;
    two.pixels = {1, 0, 0, 1, 0, 1, 0, 1};
    canopy::write_image(tmp.path / "two.png", two);
    canopy::default_limits().max_texels = 2;
    auto const read = canopy::read_texture(tmp.path / "two.png");
    REQUIRE(read.texels.size() == 2);
    CHECK(read.texels[1].y == 1.0f);
    CHECK(read.texels[1].w == 1.0f);
    canopy::default_limits().max_texels = 1;
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "two.png"); }),
               Catch::Contains("two.png: image is 2 × 1 (2 texels), over the limit of 1 texels (--max-texels)"));
    canopy::default_limits().max_file_bytes = 20;
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "two.png"); }),
               Catch::Contains("two.png: is ") && Catch::Contains("bytes, over the limit of 20 bytes per file (--max-file-bytes)"));
}

TEST_CASE("the images of a scene share a texel budget (--max-total-texels), checked from each header before decoding") {
    temp_folder const tmp("canopy_texture_test");
    limits_guard const guard;
    canopy::default_limits().max_total_texels = 10050;
    canopy::registry r;
    canopy::register_oiio_plugin(r);
    // A header claiming 100 × 100 texels over a few bytes of data: decoding it would fail. The
    // budget refuses it first, naming the texels held before it and the option.
    fs::path const claim = tmp.write("claim.png", png_claiming(100, 100));
    CHECK(problem_of([&] { (void)r.load_image(claim, 100); }) ==
          claim.string() + ": image is 100 × 100 (10000 texels): with the 100 texels of the images loaded before it, "
                           "10100 texels in all exceed the limit of 10050 (--max-total-texels)");
    CHECK(problem_of([&] { (void)canopy::read_texture(claim, 51); }) ==
          claim.string() + ": image is 100 × 100 (10000 texels): with the 51 texels of the images loaded before it, "
                           "10051 texels in all exceed the limit of 10050 (--max-total-texels)");
    // Within the budget, the header passes and decoding fails on the missing data.
    CHECK_THAT(problem_of([&] { (void)r.load_image(claim, 50); }),
               Catch::Contains(claim.string() + ": cannot read pixels") && !Catch::Contains("--max-total-texels"));
    // Held texels beyond the budget refuse any image, and the sum never wraps.
    CHECK_THAT(problem_of([&] { (void)r.load_image(claim, std::numeric_limits<std::uint64_t>::max()); }),
               Catch::Contains("more than 2^64 texels in all exceed the limit of 10050 (--max-total-texels)"));

    // A real 2 × 1 image: read up to the budget, refused one texel over it.
    canopy::rgba_image two;
    two.width = 2;
    two.height = 1;
    two.pixels = {1, 0, 0, 1, 0, 1, 0, 1};
    canopy::write_image(tmp.path / "two.png", two);
    CHECK(r.load_image(tmp.path / "two.png", 10048).texels.size() == 2);
    CHECK(problem_of([&] { (void)r.load_image(tmp.path / "two.png", 10049); }) ==
          (tmp.path / "two.png").string() + ": image is 2 × 1 (2 texels): with the 10049 texels of the images loaded "
                                            "before it, 10051 texels in all exceed the limit of 10050 (--max-total-texels)");
    // canopy.image's own limits, without the registry.
    canopy::image_read_limits const limits{1 << 20, 1 << 20, 10, 9};
    CHECK_THAT(problem_of([&] { (void)canopy::read_image(tmp.path / "two.png", limits); }),
               Catch::Contains("11 texels in all exceed the limit of 10 (--max-total-texels)"));

    // A loader that decodes without looking at the budget is held to it by the registry.
    r.add_image_loader(".raw", "test", [](fs::path const& file, std::uint64_t) {
        canopy::image_data img;
        img.source = file.string();
        img.width = img.height = 2;
        img.texels.assign(4, {});
        return img;
    });
    fs::path const raw = tmp.write("any.raw", "x");
    CHECK(r.load_image(raw, 10046).texels.size() == 4);
    CHECK(problem_of([&] { (void)r.load_image(raw, 10047); }) ==
          raw.string() + ": image is 2 × 2 (4 texels): with the 10047 texels of the images loaded before it, 10051 "
                         "texels in all exceed the limit of 10050 (--max-total-texels)");
}

TEST_CASE("GIF, WebP and BMP headers are checked before OpenImageIO opens them (it decodes them as it opens)") {
    temp_folder const tmp("canopy_texture_test");
    auto const u16 = [](std::string& out, std::uint32_t v) { out += char(v & 0xFF), out += char(v >> 8 & 0xFF); };
    auto const u32 = [&](std::string& out, std::uint32_t v) { u16(out, v & 0xFFFF), u16(out, v >> 16); };
    // GIF: a 1 × 1 image on a 65535 × 65535 canvas (OpenImageIO fills the canvas: 16 GiB).
    auto const gif = [&](std::uint32_t w, std::uint32_t h) {
        std::string g = "GIF89a";
        u16(g, w), u16(g, h);
        g += std::string("\x80\x00\x00\x00\x00\x00\xff\xff\xff\x2c\x00\x00\x00\x00\x01\x00\x01\x00\x00\x02\x02\x44\x01\x00\x3b", 25);
        return g;
    };
    tmp.write("big.gif", gif(65535, 65535));
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "big.gif"); }),
               Catch::Contains("big.gif: image is 65535 × 65535 (4294836225 texels), over the limit of 67108864 texels (--max-texels)"));
    tmp.write("small.gif", gif(1, 1));
    auto const small = canopy::read_texture(tmp.path / "small.gif");
    CHECK(small.width == 1);
    CHECK(small.height == 1);
    // BMP, run-length encoded, 20000 × 20000 (OpenImageIO decodes it whole as it opens it).
    std::string bmp = "BM";
    u32(bmp, 66), u32(bmp, 0), u32(bmp, 62);
    u32(bmp, 40), u32(bmp, 20000), u32(bmp, 20000);
    u16(bmp, 1), u16(bmp, 8), u32(bmp, 1), u32(bmp, 4), u32(bmp, 2835), u32(bmp, 2835), u32(bmp, 2), u32(bmp, 0);
    bmp += std::string("\x00\x00\x00\x00\xff\xff\xff\x00\x00\x01\x00\x00", 12);
    tmp.write("big.bmp", bmp);
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "big.bmp"); }),
               Catch::Contains("big.bmp: image is 20000 × 20000 (400000000 texels), over the limit"));
    // WebP, lossless, 16383 × 16383.
    std::string webp = "RIFF";
    u32(webp, 4 + 8 + 69);
    webp += "WEBPVP8L";
    u32(webp, 69);
    webp += '\x2f';
    u32(webp, 16382u | 16382u << 14 | 1u << 28);
    webp += std::string(64, '\0');
    tmp.write("big.webp", webp);
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "big.webp"); }),
               Catch::Contains("big.webp: image is 16383 × 16383 (268402689 texels), over the limit"));
}

TEST_CASE("a texture that is a device, a folder or not what its extension says is refused by name") {
    temp_folder const tmp("canopy_texture_test");
    fs::create_symlink("/dev/zero", tmp.path / "zero.png");
    fs::create_directory(tmp.path / "folder.png");
    CHECK_THAT(problem_of([&] { (void)canopy::read_image(tmp.path / "zero.png"); }),
               Catch::Contains("zero.png: is a character device, not a regular file"));
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "zero.png"); }),
               Catch::Contains("zero.png: is a character device, not a regular file"));
    canopy::registry r;
    canopy::register_oiio_plugin(r);
    CHECK_THAT(problem_of([&] { (void)r.load_image(tmp.path / "zero.png"); }),
               Catch::Contains("zero.png: is a character device, not a regular file (texture)"));
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "folder.png"); }),
               Catch::Contains("folder.png: is a folder, not a regular file"));
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "absent.png"); }),
               Catch::Contains("absent.png: file not found"));

    // A PPM named .png is read by the PNG reader only (no guessing among every format), and a
    // PNG that claims no pixels is refused.
    tmp.write("ppm.png", std::string("P6\n1 1\n255\n\x10\x20\x30", 14));
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "ppm.png"); }),
               Catch::Contains("ppm.png: cannot read image"));
    tmp.write("empty.png", png_claiming(0, 5));
    CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "empty.png"); }),
               Catch::Contains("empty.png: cannot read image"));
}

TEST_CASE("a PNG cut anywhere after its pixel data, before the end of its IEND chunk, is a truncated file") {
    temp_folder const tmp("canopy_texture_test");
    canopy::rgba_image two;
    two.width = 2;
    two.height = 1;
    two.pixels = {1, 0, 0, 1, 0, 1, 0, 1};
    canopy::write_image(tmp.path / "two.png", two);
    std::ifstream in(tmp.path / "two.png", std::ios::binary);
    std::string const whole((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    REQUIRE(whole.ends_with(std::string("IEND\xAE\x42\x60\x82", 8)));
    CHECK(canopy::read_texture(tmp.path / "two.png").texels.size() == 2);
    // Bytes after IEND are tolerated; a file cut in its last 12 bytes (the IEND chunk) is not.
    tmp.write("trailing.png", whole + "junk");
    CHECK(canopy::read_texture(tmp.path / "trailing.png").texels.size() == 2);
    for (std::size_t cut : {1u, 4u, 8u, 12u}) {
        INFO("cut " << cut);
        tmp.write("cut.png", whole.substr(0, whole.size() - cut));
        CHECK_THAT(problem_of([&] { (void)canopy::read_texture(tmp.path / "cut.png"); }),
                   Catch::Contains("cut.png: PNG file without its IEND chunk at the end (truncated?)"));
    }
}

TEST_CASE("texture files decode to RGBA: grey to RGB, missing alpha 1, 8-bit data marked sRGB") {
    temp_folder const tmp("canopy_texture_test");
    tmp.write("grey.pgm", std::string("P5\n2 1\n255\n\x00\xff", 13));
    auto const grey = canopy::read_texture(tmp.path / "grey.pgm");
    REQUIRE(grey.width == 2);
    REQUIRE(grey.height == 1);
    CHECK(grey.srgb);
    CHECK(grey.texels[0].x == 0.0f);
    CHECK(grey.texels[1].x == 1.0f);
    CHECK(grey.texels[1].y == 1.0f);
    CHECK(grey.texels[1].z == 1.0f);
    CHECK(grey.texels[1].w == 1.0f);
    tmp.write("rgb.ppm", std::string("P6\n1 2\n255\n\x33\x66\x99\xff\x00\x00", 17));
    auto const rgb = canopy::read_image(tmp.path / "rgb.ppm");
    REQUIRE(rgb.pixels.size() == 8);
    CHECK(rgb.pixels[0] == Approx(51.0 / 255.0).epsilon(1e-6));
    CHECK(rgb.pixels[1] == Approx(102.0 / 255.0).epsilon(1e-6));
    CHECK(rgb.pixels[2] == Approx(153.0 / 255.0).epsilon(1e-6));
    CHECK(rgb.pixels[3] == 1.0f);
    CHECK(rgb.at(0, 1)[0] == 1.0f);
    CHECK(rgb.at(0, 1)[3] == 1.0f);
}

TEST_CASE("write_framebuffer writes display values: exposure, tone curve and sRGB, or colours as they are") {
    temp_folder const tmp("canopy_texture_test");
    canopy::framebuffer fb(4, 1);
    float const nan = std::numeric_limits<float>::quiet_NaN();
    fb.at(0, 0) = {0.5f, 0.0f, 1.0f, 0.3f};
    fb.at(1, 0) = {nan, 0.5f, 0.5f, 1.0f};
    fb.at(2, 0) = {2.0f, 4.0f, 0.4f, 1.0f};
    fb.at(3, 0) = {1.0f, 0.25f, 8.0f, 1.0f};
    // A linear value over 0.0031308, sRGB-encoded (IEC 61966-2-1) and stored in 8 bits.
    auto const srgb8 = [](double linear) { return std::round((1.055 * std::pow(linear, 1.0 / 2.4) - 0.055) * 255.0) / 255.0; };
    CHECK(srgb8(0.5) == Approx(188.0 / 255.0));

    // Exposure 2^-2, no tone curve (clipped at 1): (0.5, 0, 1) → (0.125, 0, 0.25), (2, 4, 0.4) → (0.5, 1, 0.1).
    CHECK(canopy::write_framebuffer(tmp.path / "shaded.png", fb, {.exposure_scale = 0.25f}) == 1);
    auto const shaded = canopy::read_image(tmp.path / "shaded.png");
    REQUIRE(shaded.width == 4);
    CHECK(shaded.at(0, 0)[0] == Approx(srgb8(0.125)));
    CHECK(shaded.at(0, 0)[1] == 0.0f);
    CHECK(shaded.at(0, 0)[2] == Approx(srgb8(0.25)));
    CHECK(shaded.at(0, 0)[3] == 1.0f); // alpha is always 1
    CHECK(shaded.at(1, 0)[0] == 0.0f); // a NaN pixel is black
    CHECK(shaded.at(1, 0)[1] == 0.0f);
    CHECK(shaded.at(2, 0)[0] == Approx(srgb8(0.5)));
    CHECK(shaded.at(2, 0)[1] == 1.0f);
    CHECK(shaded.at(2, 0)[2] == Approx(srgb8(0.1)));
    CHECK(shaded.at(3, 0)[2] == 1.0f);

    // Reinhard, no exposure: 1 → 1 / (1 + 1) = 0.5.
    CHECK(canopy::write_framebuffer(tmp.path / "reinhard.png", fb, {.tone = canopy::tone_curve::reinhard}) == 1);
    CHECK(canopy::read_image(tmp.path / "reinhard.png").at(3, 0)[0] == Approx(srgb8(0.5)));

    // Colours as they are (heat maps): no exposure, no sRGB; 0.4 → 102 / 255.
    CHECK(canopy::write_framebuffer(tmp.path / "colours.png", fb, {.linear = false, .exposure_scale = 0.25f}) == 1);
    auto const colours = canopy::read_image(tmp.path / "colours.png");
    CHECK(colours.at(2, 0)[2] == Approx(102.0 / 255.0));
    CHECK(colours.at(0, 0)[2] == 1.0f);
}
