// canopy.render:kernels — what a pixel's samples compute: per-sample random numbers, surface
// sampling, the lights, and the primary, ambient-occlusion and path-tracing kernels (options as
// aggregates with designated initialisers: ao_kernel(s, r, isect, rng, {.samples = 8, .radius = 2})).
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
#include <cmath>
#include <cstdint>
#include <numbers>
export module canopy.render:kernels;
import canopy.query;

export namespace canopy {

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

// The primary kernel's colour of a surface: ambient, plus the sun's term where the sun reaches it
// (sunlit: cos_sun > 0 and its shadow ray unoccluded). The one expression of primary_kernel and
// primary_wave (canopy.render:waves), so that both give the same bits.
inline vec3<float> primary_colour(surface_sample const& s, light_options const& light, float cos_sun, bool sunlit) {
    vec3<float> colour = s.albedo * light.ambient;
    if (sunlit) colour = colour + s.albedo * light.sun_colour * cos_sun;
    return colour;
}

// Primary visibility: albedo lit by the sun with hard shadows (shadow rays go through the same
// intersector, so alpha-masked surfaces cast masked shadows), plus ambient; sky where nothing is hit.
template <typename Scene, typename I>
vec4<float> primary_kernel(Scene const& scene, ray const& r, I isect, light_options const& light = {}) {
    auto const hit = scene.closest_hit(r, isect);
    if (!hit.hit) return vec4<float>(scene.background(r), 1.0f);
    surface_sample const s = scene.surface(hit, r);
    float const cos_sun = dot(s.normal, light.sun_direction);
    bool const sunlit =
        cos_sun > 0.0f && !scene.any_hit(spawn_ray(s.world_triangle, s.u, s.v, light.sun_direction), isect).hit;
    return vec4<float>(primary_colour(s, light, cos_sun, sunlit), 1.0f);
}

// Ambient occlusion: fraction of `samples` cosine-weighted rays of length `radius` that escape.
struct ao_options {
    int samples = 16;     // occlusion rays per primary hit
    float radius = 1.0f;  // their length, in scene units
};

template <typename Scene, typename I>
vec4<float> ao_kernel(Scene const& scene, ray const& r, I isect, pixel_random& rng, ao_options const& options = {}) {
    int const samples = options.samples;
    float const radius = options.radius;
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
struct path_options {
    int bounces = 3;     // indirect bounces after the primary hit
    light_options light = {}; // the sun and the point light (not the ambient term: the sky lights)
};

template <typename Scene, typename I>
vec4<float> path_kernel(Scene const& scene, ray r, I isect, pixel_random& rng, path_options const& options = {}) {
    int const bounces = options.bounces;
    light_options const& light = options.light;
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

} // namespace canopy
