// canopy.render:film — the framebuffer, tone curves, sRGB encoding, heat-map colours and the
// one heat map (a cost image → colours), and the framebuffer's display values (what
// canopy.image's write_framebuffer writes).
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>
export module canopy.render:film;
import canopy.query;

export namespace canopy {

// Linear RGBA pixels, row 0 at the top.
struct framebuffer {
    int width = 0;
    int height = 0;
    std::vector<vec4<float>> pixels;

    framebuffer() = default;
    framebuffer(int w, int h) : width(w), height(h), pixels(std::size_t(w) * std::size_t(h)) {}
    vec4<float>& at(int x, int y) { return pixels[std::size_t(y) * std::size_t(width) + std::size_t(x)]; }
    vec4<float> const& at(int x, int y) const { return pixels[std::size_t(y) * std::size_t(width) + std::size_t(x)]; }
};

// Tone curves from scaled linear radiance to display-linear values in [0, 1], per channel:
//   none      clips at 1 (the primary and AO kernels give values in [0, 1] or a little above)
//   reinhard  x / (1 + x)                                  (Reinhard et al. 2002, eq. 3)
//   aces      x(2.51x + 0.03) / (x(2.43x + 0.59) + 0.14)   (Narkowicz 2015, fit of the ACES
//             filmic curve; reaches 1 at x ≈ 7.2)
enum class tone_curve { none, reinhard, aces };

// `scale` is the exposure as a factor (2^EV). NaN stays NaN (to be counted, not hidden); +∞ and
// values over 1e6 map like 1e6.
inline float tone_map(float linear, tone_curve curve, float scale = 1.0f) {
    float const x = linear * scale;
    switch (curve) {
    case tone_curve::none: return x;
    case tone_curve::reinhard: {
        float const c = std::clamp(x, 0.0f, 1e6f);
        return c / (1.0f + c);
    }
    case tone_curve::aces: {
        float const c = std::clamp(x, 0.0f, 1e6f);
        float const y = c * (2.51f * c + 0.03f) / (c * (2.43f * c + 0.59f) + 0.14f);
        return y > 1.0f ? 1.0f : y;
    }
    }
    return x;
}

// Linear → sRGB-encoded display value in [0, 1].
inline float to_srgb(float linear) {
    float const c = std::clamp(linear, 0.0f, 1.0f);
    return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
}

// Heat-map colour of a cost relative to max_cost: blue → green → yellow → red.
inline vec3<float> heat_colour(float cost, float max_cost) {
    float const x = std::clamp(cost / max_cost, 0.0f, 1.0f);
    vec3<float> const stops[4] = {{0.05f, 0.05f, 0.4f}, {0.1f, 0.7f, 0.2f}, {0.95f, 0.9f, 0.1f}, {0.9f, 0.1f, 0.05f}};
    float const f = x * 3.0f;
    int const i = std::min(int(f), 2);
    return lerp(stops[i], stops[i + 1], f - float(i));
}

// The framebuffer as display values, RGBA in [0, 1] (alpha 1), 4 floats a pixel, row 0 first.
struct display_options {
    // true: radiance through exposure, tone curve and sRGB encoding; false: the values as they
    // are (heat-map colours).
    bool linear = true;
    tone_curve tone = tone_curve::none;
    float exposure_scale = 1.0f; // 2^EV
};

// NaN pixels are given black and counted in nan_pixels.
inline std::vector<float> display_values(framebuffer const& fb, display_options const& options,
                                         std::size_t& nan_pixels) {
    std::vector<float> out(4 * fb.pixels.size());
    nan_pixels = 0;
    auto const display = [&](float v) {
        return options.linear ? to_srgb(tone_map(v, options.tone, options.exposure_scale)) : v;
    };
    for (std::size_t i = 0; i < fb.pixels.size(); ++i) {
        auto const& p = fb.pixels[i];
        bool const nan = std::isnan(p.x) || std::isnan(p.y) || std::isnan(p.z);
        nan_pixels += nan;
        out[4 * i + 0] = nan ? 0.0f : display(p.x);
        out[4 * i + 1] = nan ? 0.0f : display(p.y);
        out[4 * i + 2] = nan ? 0.0f : display(p.z);
        out[4 * i + 3] = 1.0f;
    }
    return out;
}

// The heat map of a cost image: each pixel's cost (its x) becomes heat_colour(cost, red), where
// red is the 99th percentile of the costs (at least 1), so that a few very expensive rays do not
// wash out the rest. Returns red.
inline float heat_map(framebuffer& fb) {
    if (fb.pixels.empty()) return 1.0f;
    std::vector<float> costs;
    costs.reserve(fb.pixels.size());
    for (auto const& p : fb.pixels) costs.push_back(p.x);
    auto const p99 = costs.begin() + std::ptrdiff_t(costs.size() * 99 / 100);
    std::nth_element(costs.begin(), p99, costs.end());
    float const red = std::max(1.0f, *p99);
    for (auto& p : fb.pixels) p = vec4<float>(heat_colour(p.x, red), 1.0f);
    return red;
}

} // namespace canopy
