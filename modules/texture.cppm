// canopy.texture: 2-D textures and tex2D, for alpha masks in custom intersectors and for shading.
//
// texture2d<Texel> holds width x height texels (Texel = vec4<float>, RGBA in [0, 1], or float),
// row-major with row 0 at the top of the image. Texture coordinates put (0, 0) at the top-left
// corner of the image and (1, 1) at the bottom-right one: texel (i, j) covers
// [i, i + 1) / width x [j, j + 1) / height, and its centre is ((i + 0.5) / width, (j + 0.5) / height).
//
// tex2D(texture, coord) takes vec2<float> or vec2<simd::floatN> coordinates. Both are one code
// path over the coordinate type T, using only canopy::simd operations, so lane i of a SIMD result
// is bit-identical to the scalar tex2D at lane i's coordinate. tex2D never throws, and reads only
// inside the texel array for every coordinate, NaN and infinities included.
//
// Sampling, per axis (n = width for x, height for y; s = the coordinate component):
//   1. A NaN s is replaced by 0.
//   2. p = s * n for nearest, s * n - 0.5 for bilinear, then clamped to [-2^30, 2^30]; so ±inf
//      and huge coordinates sample at ±2^30 texels (beyond 2^24, floats are whole texels apart).
//   3. Nearest: texel index floor(p). Bilinear: indices i0 = floor(p) and i1 = i0 + 1, weight
//      f = p - floor(p), exact and in [0, 1).
//   4. The address mode maps an index i into [0, n):
//        wrap   i mod n, taken non-negative (-1 -> n - 1);
//        clamp  min(max(i, 0), n - 1);
//        mirror r = i mod 2n (non-negative), then r < n ? r : 2n - 1 - r: the image reflected
//               at its edges, edge texels repeated (..., 1, 0 | 0, 1, ..., n - 1 | n - 1, ...).
// Bilinear then blends the texels t(x, y) at (x0|x1, y0|y1), evaluated in exactly this order,
// each operation rounded on its own (the build pins -ffp-contract=off):
//   top    = (1 - fx) * t(x0, y0) + fx * t(x1, y0)
//   bottom = (1 - fx) * t(x0, y1) + fx * t(x1, y1)
//   result = (1 - fy) * top + fy * bottom,
// clamped per channel to the range of the four texels, which rounding could otherwise leave by
// an ulp. At a texel centre the result is that texel exactly; halfway between two centres it is
// their average, rounded once. Texel values are expected to be finite.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <concepts>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>
export module canopy.texture;
export import canopy.math;

export namespace canopy {

enum class filter_mode { nearest, bilinear };
enum class address_mode { wrap, clamp, mirror };

// How tex2D reads a texture; the defaults suit tiling images.
struct sampler {
    filter_mode filter = filter_mode::bilinear;
    address_mode address = address_mode::wrap;
};

template <typename Texel>
concept texel_type = std::same_as<Texel, float> || std::same_as<Texel, vec4<float>>;

template <texel_type Texel> class texture2d {
public:
    using value_type = Texel;

    // Largest width or height: texel indices stay exact in float and mirror periods in int32.
    static constexpr int max_side = 1 << 24;
    static constexpr int floats_per_texel = int(sizeof(Texel) / sizeof(float));

    // width x height texels, row-major, row 0 at the top. Throws std::invalid_argument when a side
    // is outside [1, max_side], when texels.size() != width * height, or when the texels hold more
    // than 2^31 - 1 floats (SIMD lanes index them with 32-bit integers).
    texture2d(int width, int height, std::vector<Texel> texels, sampler sampling = {})
        : width_(width), height_(height), texels_(std::move(texels)), sampling_(sampling) {
        check_side("width", width_);
        check_side("height", height_);
        auto const count = std::size_t(width_) * std::size_t(height_);
        std::string const size = std::to_string(width_) + " x " + std::to_string(height_) + " texels";
        if (count * std::size_t(floats_per_texel) > std::size_t(std::numeric_limits<std::int32_t>::max()))
            throw std::invalid_argument("texture2d: " + size + " exceed 2^31 - 1 floats");
        if (texels_.size() != count)
            throw std::invalid_argument("texture2d: " + size + " need " + std::to_string(count) + " values, got " +
                                        std::to_string(texels_.size()));
    }

    int width() const { return width_; }
    int height() const { return height_; }

    filter_mode filter() const { return sampling_.filter; }
    address_mode address() const { return sampling_.address; }
    void set_filter(filter_mode filter) { sampling_.filter = filter; }
    void set_address(address_mode address) { sampling_.address = address; }

    // Texel in column x of row y (row 0 at the top). Precondition: 0 <= x < width, 0 <= y < height.
    Texel const& texel(int x, int y) const { return texels_[index(x, y)]; }
    Texel& texel(int x, int y) { return texels_[index(x, y)]; }

    // All texels, row-major.
    std::span<Texel const> texels() const { return texels_; }

    // The texels as width * height * floats_per_texel consecutive floats.
    float const* floats() const {
        static_assert(sizeof(Texel) == std::size_t(floats_per_texel) * sizeof(float) &&
                      std::is_standard_layout_v<Texel>);
        return reinterpret_cast<float const*>(texels_.data());
    }

private:
    static void check_side(char const* name, int side) {
        if (side < 1 || side > max_side)
            throw std::invalid_argument(std::string("texture2d: ") + name + " must be in [1, " +
                                        std::to_string(max_side) + "], got " + std::to_string(side));
    }

    std::size_t index(int x, int y) const { return std::size_t(y) * std::size_t(width_) + std::size_t(x); }

    int width_;
    int height_;
    std::vector<Texel> texels_;
    sampler sampling_;
};

// What tex2D returns for Texel at coordinates of type T: T for float textures, vec4<T> for RGBA.
template <typename Texel, typename T>
using sampled_texel_t = std::conditional_t<std::same_as<Texel, float>, T, vec4<T>>;

} // namespace canopy

namespace canopy::detail {

inline constexpr float max_texel_coordinate = 0x1p30f;

// Steps 1 and 2 of the header: s * n - offset with NaN read as 0, clamped to ±2^30.
template <typename T> T texel_coordinate(T s, int n, float offset) {
    T const p = simd::select(simd::isnan(s), T(0.0f), s) * T(float(n)) - T(offset);
    return simd::min(simd::max(p, T(-max_texel_coordinate)), T(max_texel_coordinate));
}

// a mod m in [0, m); |a| <= 2^30 + 1 and 0 < m <= 2^25, so nothing overflows.
template <typename I> I floor_mod(I a, int m) {
    I const r = a - (a / I(m)) * I(m);
    return simd::select(r < I(0), r + I(m), r);
}

// Step 4 of the header: index i mapped into [0, n) by the address mode.
template <typename I> I apply_address_mode(I i, int n, address_mode mode) {
    if (mode == address_mode::wrap) return floor_mod(i, n);
    if (mode == address_mode::clamp) return simd::min(simd::max(i, I(0)), I(n - 1));
    I const r = floor_mod(i, 2 * n);
    return simd::select(r < I(n), r, I(2 * n - 1) - r);
}

// Texel number `index` (row-major, in range) of texture floats, one gathered lane per coordinate.
template <typename Texel, typename T>
sampled_texel_t<Texel, T> fetch_texel(float const* floats, simd::int_type_t<T> index) {
    using I = simd::int_type_t<T>;
    if constexpr (std::same_as<Texel, float>) {
        return simd::gather(floats, index);
    } else {
        I const first = index * I(4);
        return {simd::gather(floats, first), simd::gather(floats, first + I(1)), simd::gather(floats, first + I(2)),
                simd::gather(floats, first + I(3))};
    }
}

template <typename V> V channel_min(V const& a, V const& b) {
    if constexpr (requires { a.w; })
        return canopy::min(a, b);
    else
        return simd::min(a, b);
}

template <typename V> V channel_max(V const& a, V const& b) {
    if constexpr (requires { a.w; })
        return canopy::max(a, b);
    else
        return simd::max(a, b);
}

} // namespace canopy::detail

export namespace canopy {

// The texture sampled at coord with its filter and address modes (see the header for the exact
// arithmetic). T = float, or simd::float4/8/16 for one coordinate per lane.
template <typename Texel, typename T>
    requires std::same_as<simd::scalar_type_t<T>, float>
sampled_texel_t<Texel, T> tex2D(texture2d<Texel> const& texture, vec2<T> const& coord) {
    using I = simd::int_type_t<T>;
    int const width = texture.width();
    int const height = texture.height();
    address_mode const mode = texture.address();
    auto const fetch = [&](I x, I y) {
        return detail::fetch_texel<Texel, T>(texture.floats(), y * I(width) + x);
    };

    if (texture.filter() == filter_mode::nearest) {
        T const px = detail::texel_coordinate(coord.x, width, 0.0f);
        T const py = detail::texel_coordinate(coord.y, height, 0.0f);
        return fetch(detail::apply_address_mode(simd::convert_to_int(simd::floor(px)), width, mode),
                     detail::apply_address_mode(simd::convert_to_int(simd::floor(py)), height, mode));
    }

    // Bilinear: the four texels around the coordinate, with the weights of the header's formula.
    T const px = detail::texel_coordinate(coord.x, width, 0.5f);
    T const py = detail::texel_coordinate(coord.y, height, 0.5f);
    T const x0f = simd::floor(px);
    T const y0f = simd::floor(py);
    T const fx = px - x0f;
    T const fy = py - y0f;
    I const x0i = simd::convert_to_int(x0f);
    I const y0i = simd::convert_to_int(y0f);
    I const x0 = detail::apply_address_mode(x0i, width, mode);
    I const x1 = detail::apply_address_mode(x0i + I(1), width, mode);
    I const y0 = detail::apply_address_mode(y0i, height, mode);
    I const y1 = detail::apply_address_mode(y0i + I(1), height, mode);
    auto const t00 = fetch(x0, y0);
    auto const t10 = fetch(x1, y0);
    auto const t01 = fetch(x0, y1);
    auto const t11 = fetch(x1, y1);

    T const one(1.0f);
    auto const top = (one - fx) * t00 + fx * t10;
    auto const bottom = (one - fx) * t01 + fx * t11;
    auto const blend = (one - fy) * top + fy * bottom;
    auto const lowest = detail::channel_min(detail::channel_min(t00, t10), detail::channel_min(t01, t11));
    auto const highest = detail::channel_max(detail::channel_max(t00, t10), detail::channel_max(t01, t11));
    return detail::channel_min(detail::channel_max(blend, lowest), highest);
}

} // namespace canopy
