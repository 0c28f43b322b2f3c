// canopy.render — cameras (refusing degenerate ones), ray generation, a parallel tile scheduler,
// rendering kernels and tone curves.
//
// Every kernel is a function template over the scene and the custom intersector (the paper's
// "scheduling parameters"): the same kernel runs with no intersector, an alpha mask or a cost
// counter. Each pixel owns a copy of the intersector prototype (counters are per pixel) and a
// random sequence seeded by (seed, x, y, sample): images do not depend on the thread count or the
// tile order.
//
// A scene usable by the kernels provides (S const& s, I& isect, ray r, hit h):
//   s.closest_hit(r, isect) → basic_hit_record<float>     (world space)
//   s.any_hit(r, isect)     → basic_hit_record<float>
//   s.surface(h, r)         → surface_sample (world-space triangle, unit normal facing the ray,
//                             albedo)
//   s.background(r)         → vec3<float>
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>
export module canopy.render;
export import canopy.query;

export namespace canopy {

// ---- camera -----------------------------------------------------------------------------

struct pinhole_camera {
    vec3<float> eye;
    vec3<float> forward; // unit, towards the image centre
    vec3<float> right;   // scaled: half the image width at distance 1
    vec3<float> up;      // scaled: half the image height at distance 1

    // fovy in degrees; aspect = width / height. Throws std::invalid_argument with look_at_problem's
    // text when the values give no camera. An up hint parallel to the view direction (within
    // 0.06°) is no error: the fallback up is then +y, or -z when the view is along ±y (looking
    // straight down, the top of the image is towards -z).
    static pinhole_camera look_at(vec3<float> eye, vec3<float> target, vec3<float> up_hint, float fovy, float aspect) {
        pinhole_camera c;
        std::string const problem = build(c, eye, target, up_hint, fovy, aspect);
        if (!problem.empty()) throw std::invalid_argument("camera: " + problem);
        return c;
    }

    // Why look_at cannot make a camera of these values, in plain words; empty when it can. The
    // basis is computed in float as the renderer uses it, and refused unless it is finite and
    // orthonormal: a value that is not finite, a field of view outside (0°, 180°), a bad aspect,
    // eye and target that coincide or are too close (or too far apart) for a float direction (a
    // camera under a scale of 1e-30), an up hint of zero or underflowing length.
    static std::string look_at_problem(vec3<float> eye, vec3<float> target, vec3<float> up_hint, float fovy,
                                       float aspect) {
        pinhole_camera c;
        return build(c, eye, target, up_hint, fovy, aspect);
    }

    // Ray through image position (px, py) in pixels, (0, 0) the top-left corner of the image.
    inline ray primary_ray(float px, float py, int width, int height) const {
        float const sx = 2.0f * px / float(width) - 1.0f;
        float const sy = 1.0f - 2.0f * py / float(height);
        return {eye, 0.0f, forward + right * sx + up * sy, std::numeric_limits<float>::infinity()};
    }

private:
    static std::string text(float f) {
        char buffer[32];
        std::snprintf(buffer, sizeof buffer, "%g", double(f));
        return buffer;
    }
    static std::string text(vec3<float> v) { return "(" + text(v.x) + ", " + text(v.y) + ", " + text(v.z) + ")"; }

    static bool unit(vec3<float> v) {
        double const l = std::sqrt(double(v.x) * double(v.x) + double(v.y) * double(v.y) + double(v.z) * double(v.z));
        return std::fabs(l - 1.0) <= 1e-5;
    }

    static std::string build(pinhole_camera& c, vec3<float> eye, vec3<float> target, vec3<float> up_hint, float fovy,
                             float aspect) {
        if (!all_finite(eye)) return "eye " + text(eye) + " is not finite";
        if (!all_finite(target)) return "target " + text(target) + " is not finite";
        if (!all_finite(up_hint)) return "up " + text(up_hint) + " is not finite";
        if (!(fovy > 0.0f && fovy < 180.0f)) return "field of view " + text(fovy) + " is not in (0, 180) degrees";
        if (!(aspect > 0.0f && aspect < std::numeric_limits<float>::infinity()))
            return "aspect ratio " + text(aspect) + " is not a positive number";
        vec3<float> const view = target - eye;
        if (eye.x == target.x && eye.y == target.y && eye.z == target.z)
            return "eye and target coincide at " + text(eye) + ": no view direction";
        if (!all_finite(view)) return "eye " + text(eye) + " and target " + text(target) + " are too far apart for float";
        c.eye = eye;
        c.forward = normalize(view);
        if (!all_finite(c.forward) || !unit(c.forward))
            return "eye " + text(eye) + " and target " + text(target) +
                   " are too close to give a view direction in float (a collapsed camera)";
        if (up_hint.x == 0.0f && up_hint.y == 0.0f && up_hint.z == 0.0f) return "up is zero: no orientation";
        vec3<float> const up_direction = normalize(up_hint);
        if (!all_finite(up_direction) || !unit(up_direction))
            return "up " + text(up_hint) + " has no direction in float (its length under- or overflows)";
        vec3<float> up = up_hint;
        if (length(cross(c.forward, up_direction)) < 1e-3f)
            up = std::fabs(c.forward.y) < 0.9f ? vec3<float>(0.0f, 1.0f, 0.0f) : vec3<float>(0.0f, 0.0f, -1.0f);
        vec3<float> const r = normalize(cross(c.forward, up));
        vec3<float> const u = cross(r, c.forward);
        float const half_height = std::tan(fovy * std::numbers::pi_v<float> / 360.0f);
        c.up = u * half_height;
        c.right = r * (half_height * aspect);
        if (!all_finite(c.up) || !all_finite(c.right) || !unit(r) || !unit(u))
            return "the camera's basis is not finite (field of view " + text(fovy) + ", aspect " + text(aspect) + ")";
        return {};
    }
};

// ---- images and scheduling --------------------------------------------------------------

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

// Deterministic per-sample random numbers: a hash of (seed, x, y, sample, dimension).
struct pixel_random {
    std::uint32_t state;

    pixel_random(std::uint32_t seed, int x, int y, int sample)
        : state(hash(seed ^ hash(std::uint32_t(x) ^ hash(std::uint32_t(y) ^ hash(std::uint32_t(sample)))))) {}

    // Uniform in [0, 1).
    inline float next() {
        state = hash(state + 0x9e3779b9u);
        return float(state >> 8) * 0x1p-24f;
    }

    static inline std::uint32_t hash(std::uint32_t x) {
        // Wellons' lowbias32.
        x ^= x >> 16;
        x *= 0x7feb352du;
        x ^= x >> 15;
        x *= 0x846ca68bu;
        x ^= x >> 16;
        return x;
    }
};

// The image cut into square tiles of `tile` pixels (the last row and column may be narrower),
// numbered row by row from the top left: the unit of work of render_tiles, also across processes
// (canopy.distributed).
struct tile_grid {
    int width = 0, height = 0, tile = 16;

    struct rect {
        int x0, y0, x1, y1; // pixels [x0, x1) × [y0, y1)
        int pixels() const { return (x1 - x0) * (y1 - y0); }
    };

    tile_grid(int w, int h, int tile_size) : width(w), height(h), tile(std::max(1, tile_size)) {}
    int columns() const { return (width + tile - 1) / tile; }
    int rows() const { return (height + tile - 1) / tile; }
    int count() const { return columns() * rows(); }
    rect bounds(int t) const {
        int const x0 = (t % columns()) * tile, y0 = (t / columns()) * tile;
        return {x0, y0, std::min(x0 + tile, width), std::min(y0 + tile, height)};
    }
};

struct tile_options {
    int tile_size = 16;
    // Called with the fraction done, from the worker that finished a tile (serialised).
    std::function<void(float)> progress;
};

// Runs shade(x, y) → vec4 for every pixel, tiles in parallel on all cores (oneTBB).
void render_tiles(framebuffer& fb, std::function<vec4<float>(int, int)> const& shade, tile_options const& options = {});

// ---- surfaces and sampling ----------------------------------------------------------------

struct surface_sample {
    triangle world_triangle;   // the hit triangle in world space (for spawn_ray)
    vec3<float> normal;        // unit geometric normal, facing the incoming ray
    vec3<float> albedo;
    float u = 0.0f, v = 0.0f;  // barycentrics of the hit
};

// Cosine-weighted direction around unit normal n (Malley's method).
inline vec3<float> cosine_direction(vec3<float> const& n, float r1, float r2) {
    float const phi = 2.0f * std::numbers::pi_v<float> * r1;
    float const r = std::sqrt(r2);
    vec3<float> const a = std::fabs(n.x) > 0.5f ? vec3<float>(0, 1, 0) : vec3<float>(1, 0, 0);
    vec3<float> const t = normalize(cross(a, n));
    vec3<float> const b = cross(n, t);
    return t * (r * std::cos(phi)) + b * (r * std::sin(phi)) + n * std::sqrt(std::max(0.0f, 1.0f - r2));
}

// ---- kernels ------------------------------------------------------------------------------

struct light_options {
    vec3<float> sun_direction = normalize(vec3<float>(-0.4f, 1.0f, 0.5f)); // towards the sun
    vec3<float> sun_colour{1.0f, 0.95f, 0.85f};
    float ambient = 0.25f;
    // An optional point light (path kernel): radiant intensity, falling off with distance².
    bool point_light = false;
    vec3<float> point_position{0.0f, 10.0f, 0.0f};
    vec3<float> point_intensity{50.0f, 50.0f, 50.0f};
};

// Primary visibility: albedo lit by the sun with hard shadows (shadow rays go through the same
// intersector, so alpha-masked surfaces cast masked shadows), plus ambient; sky where nothing is hit.
template <typename Scene, typename I>
vec4<float> primary_kernel(Scene const& scene, ray const& r, I isect, light_options const& light = {}) {
    auto const hit = scene.closest_hit(r, isect);
    if (!hit.hit) return vec4<float>(scene.background(r), 1.0f);
    surface_sample const s = scene.surface(hit, r);
    float const cos_sun = dot(s.normal, light.sun_direction);
    vec3<float> colour = s.albedo * light.ambient;
    if (cos_sun > 0.0f) {
        ray const shadow = spawn_ray(s.world_triangle, s.u, s.v, light.sun_direction);
        if (!scene.any_hit(shadow, isect).hit) colour = colour + s.albedo * light.sun_colour * cos_sun;
    }
    return vec4<float>(colour, 1.0f);
}

// Ambient occlusion: fraction of `samples` cosine-weighted rays of length `radius` that escape.
template <typename Scene, typename I>
vec4<float> ao_kernel(Scene const& scene, ray const& r, I isect, pixel_random& rng, int samples = 16,
                      float radius = 1.0f) {
    auto const hit = scene.closest_hit(r, isect);
    if (!hit.hit) return vec4<float>(scene.background(r), 1.0f);
    surface_sample const s = scene.surface(hit, r);
    int open = 0;
    for (int k = 0; k < samples; ++k) {
        vec3<float> const d = cosine_direction(s.normal, rng.next(), rng.next());
        open += !scene.any_hit(spawn_ray(s.world_triangle, s.u, s.v, d, radius), isect).hit;
    }
    float const a = float(open) / float(samples);
    return {a, a, a, 1.0f};
}

// Path tracing: Lambertian surfaces, the sun as a directional light and the optional point light
// sampled at every bounce (next-event estimation, shadow rays through the same intersector), the
// sky as environment light; `bounces` indirect bounces.
template <typename Scene, typename I>
vec4<float> path_kernel(Scene const& scene, ray r, I isect, pixel_random& rng, int bounces = 3,
                        light_options const& light = {}) {
    vec3<float> radiance, throughput(1.0f);
    for (int depth = 0; depth <= bounces; ++depth) {
        auto const hit = scene.closest_hit(r, isect);
        if (!hit.hit) {
            radiance = radiance + throughput * scene.background(r);
            break;
        }
        surface_sample const s = scene.surface(hit, r);
        float const cos_sun = dot(s.normal, light.sun_direction);
        if (cos_sun > 0.0f && !scene.any_hit(spawn_ray(s.world_triangle, s.u, s.v, light.sun_direction), isect).hit)
            radiance = radiance + throughput * s.albedo * light.sun_colour * cos_sun;
        if (light.point_light) {
            ray const to_light = spawn_ray_to(s.world_triangle, s.u, s.v, light.point_position);
            float const distance2 = dot(to_light.direction, to_light.direction);
            float const cos_light = dot(s.normal, to_light.direction) / std::sqrt(distance2);
            if (cos_light > 0.0f && !scene.any_hit(to_light, isect).hit)
                radiance = radiance + throughput * s.albedo * light.point_intensity * (cos_light / distance2);
        }
        throughput = throughput * s.albedo;
        r = spawn_ray(s.world_triangle, s.u, s.v, cosine_direction(s.normal, rng.next(), rng.next()));
    }
    return vec4<float>(radiance, 1.0f);
}

// The paper's cost counter (its bvh_costs, §4): ray/box and ray/triangle tests, at every level of
// the scene. Named differently so that the paper's own code, which defines bvh_costs, compiles
// under `using namespace canopy;`.
struct cost_counter : basic_intersector<cost_counter> {
    using basic_intersector<cost_counter>::operator();

    template <typename Ray, typename... Args>
    auto operator()(Ray const& ray, aabb const& box, Args&&... args) {
        ++num_boxes;
        return intersect(ray, box, std::forward<Args>(args)...);
    }

    template <typename Ray>
    auto operator()(Ray const& ray, triangle const& tri) {
        ++num_tris;
        return intersect(ray, tri);
    }

    unsigned num_boxes = 0;
    unsigned num_tris = 0;
};

// Heat-map colour of a cost relative to max_cost: blue → green → yellow → red.
inline vec3<float> heat_colour(float cost, float max_cost) {
    float const x = std::clamp(cost / max_cost, 0.0f, 1.0f);
    vec3<float> const stops[4] = {{0.05f, 0.05f, 0.4f}, {0.1f, 0.7f, 0.2f}, {0.95f, 0.9f, 0.1f}, {0.9f, 0.1f, 0.05f}};
    float const f = x * 3.0f;
    int const i = std::min(int(f), 2);
    return lerp(stops[i], stops[i + 1], f - float(i));
}

// ---- display ------------------------------------------------------------------------------

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

} // namespace canopy
