// canopy.render:waves — the kernels of :kernels over a wave of samples at once (for example one
// sample of every pixel of a tile): each step of the kernels traces the wave's rays together
// through the scene's batch queries, so that coherent rays (camera rays, shadow rays of
// neighbouring pixels towards the sun) go through the BVH as packets (canopy.query:batch).
//
//   primary_wave(scene, rays, isect, colours, light)       // colours[i] = primary_kernel(scene, rays[i], ...)
//   ao_wave(scene, rays, rngs, isect, colours, ao)         // colours[i] = ao_kernel(scene, rays[i], ..., rngs[i], ao)
//   path_wave(scene, rays, rngs, isect, colours, path)     // colours[i] = path_kernel(scene, rays[i], ..., rngs[i], path)
//
// Contract: colours[i] is bit for bit what the per-sample kernel returns for rays[i] and rngs[i]
// (which advance as they would), with the same rays traced: every ray the kernel would trace, and
// no other. The arithmetic is the kernel's, operation for operation, and the batch queries return
// what single rays do. The intersector is shared by the wave (the per-sample kernels take a copy
// each): the waves are for intersectors whose answers do not depend on the calls before (the
// alpha masks, filters); a counting intersector counts the wave's tests together.
//
// A scene usable by the waves provides, besides what :kernels needs (S const& s, I& isect):
//   s.closest_hit(std::span<ray const>, std::span<basic_hit_record<float>>, isect)
//   s.any_hit(std::span<ray const>, std::span<bool>, isect)        (out[i]: rays[i] is occluded)
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <cmath>
#include <cstddef>
#include <memory>
#include <span>
#include <stdexcept>
#include <vector>
export module canopy.render:waves;
import canopy.query;
import :kernels;

namespace canopy::detail {

// Occlusion results: std::vector<bool> has no span.
class occlusion_buffer {
public:
    std::span<bool> first(std::size_t n) {
        if (n > capacity_) {
            flags_ = std::make_unique<bool[]>(n);
            capacity_ = n;
        }
        return {flags_.get(), n};
    }

private:
    std::unique_ptr<bool[]> flags_;
    std::size_t capacity_ = 0;
};

inline void check_wave_sizes(std::size_t rays, std::size_t rngs, std::size_t colours) {
    if (rngs < rays || colours < rays)
        throw std::invalid_argument("canopy: a wave needs one random sequence and one colour per ray");
}

} // namespace canopy::detail

export namespace canopy {

// primary_kernel over a wave (see the top of this file).
template <typename Scene, typename I>
void primary_wave(Scene const& scene, std::span<ray const> rays, I& isect, std::span<vec4<float>> colours,
                  light_options const& light = {}) {
    detail::check_wave_sizes(rays.size(), rays.size(), colours.size());
    std::vector<basic_hit_record<float>> hits(rays.size());
    scene.closest_hit(rays, std::span(hits), isect);
    // The lit pixels' shadow rays, in pixel order, and the colour before the sun's term.
    std::vector<ray> shadows;
    std::vector<std::size_t> lit;
    std::vector<surface_sample> surfaces(rays.size());
    for (std::size_t i = 0; i < rays.size(); ++i) {
        if (!hits[i].hit) {
            colours[i] = vec4<float>(scene.background(rays[i]), 1.0f);
            continue;
        }
        surface_sample const& s = surfaces[i] = scene.surface(hits[i], rays[i]);
        float const cos_sun = dot(s.normal, light.sun_direction);
        colours[i] = vec4<float>(primary_colour(s, light, cos_sun, false), 1.0f);
        if (cos_sun > 0.0f) {
            shadows.push_back(spawn_ray(s.world_triangle, s.u, s.v, light.sun_direction));
            lit.push_back(i);
        }
    }
    detail::occlusion_buffer buffer;
    auto const occluded = buffer.first(shadows.size());
    scene.any_hit(std::span<ray const>(shadows), occluded, isect);
    for (std::size_t k = 0; k < lit.size(); ++k) {
        if (occluded[k]) continue;
        std::size_t const i = lit[k];
        surface_sample const& s = surfaces[i];
        colours[i] = vec4<float>(primary_colour(s, light, dot(s.normal, light.sun_direction), true), 1.0f);
    }
}

// ao_kernel over a wave: the occlusion rays of every hit, options.samples per pixel one after the
// other, traced as one batch.
template <typename Scene, typename I>
void ao_wave(Scene const& scene, std::span<ray const> rays, std::span<pixel_random> rngs, I& isect,
             std::span<vec4<float>> colours, ao_options const& options = {}) {
    detail::check_wave_sizes(rays.size(), rngs.size(), colours.size());
    int const samples = options.samples;
    float const radius = options.radius;
    std::vector<basic_hit_record<float>> hits(rays.size());
    scene.closest_hit(rays, std::span(hits), isect);
    std::vector<ray> occlusion;
    std::vector<std::size_t> shaded;
    for (std::size_t i = 0; i < rays.size(); ++i) {
        if (!hits[i].hit) {
            colours[i] = vec4<float>(scene.background(rays[i]), 1.0f);
            continue;
        }
        surface_sample const s = scene.surface(hits[i], rays[i]);
        pixel_random& rng = rngs[i];
        for (int k = 0; k < samples; ++k) {
            vec3<float> const d = cosine_direction(s.normal, rng.next(), rng.next());
            occlusion.push_back(spawn_ray(s.world_triangle, s.u, s.v, d, radius));
        }
        shaded.push_back(i);
    }
    detail::occlusion_buffer buffer;
    auto const occluded = buffer.first(occlusion.size());
    scene.any_hit(std::span<ray const>(occlusion), occluded, isect);
    for (std::size_t j = 0; j < shaded.size(); ++j) {
        int open = 0;
        for (int k = 0; k < samples; ++k) open += !occluded[j * std::size_t(samples) + std::size_t(k)];
        float const a = float(open) / float(samples);
        colours[shaded[j]] = {a, a, a, 1.0f};
    }
}

// path_kernel over a wave: bounce by bounce, the paths still going traced together (their
// closest hits, then their shadow rays towards the sun and the point light).
template <typename Scene, typename I>
void path_wave(Scene const& scene, std::span<ray const> rays, std::span<pixel_random> rngs, I& isect,
               std::span<vec4<float>> colours, path_options const& options = {}) {
    detail::check_wave_sizes(rays.size(), rngs.size(), colours.size());
    int const bounces = options.bounces;
    light_options const& light = options.light;
    std::size_t const n = rays.size();
    std::vector<vec3<float>> radiance(n), throughput(n, vec3<float>(1.0f));
    std::vector<ray> current(rays.begin(), rays.end()), next;
    std::vector<std::size_t> going(n), still_going; // going[j]: the path current[j] belongs to
    for (std::size_t i = 0; i < n; ++i) going[i] = i;
    std::vector<basic_hit_record<float>> hits;
    std::vector<surface_sample> surfaces;
    std::vector<ray> shadows;
    // Per path of this bounce: the index of its sun and point-light shadow rays, or none.
    constexpr std::size_t none = ~std::size_t(0);
    std::vector<std::size_t> sun_ray, light_ray;
    std::vector<float> cos_light, distance2;
    detail::occlusion_buffer buffer;
    for (int depth = 0; depth <= bounces && !going.empty(); ++depth) {
        std::size_t const m = going.size();
        hits.resize(m);
        scene.closest_hit(std::span<ray const>(current), std::span(hits), isect);
        surfaces.resize(m);
        shadows.clear();
        sun_ray.assign(m, none);
        light_ray.assign(m, none);
        cos_light.resize(m);
        distance2.resize(m);
        for (std::size_t j = 0; j < m; ++j) {
            if (!hits[j].hit) continue;
            surface_sample const& s = surfaces[j] = scene.surface(hits[j], current[j]);
            if (dot(s.normal, light.sun_direction) > 0.0f) {
                sun_ray[j] = shadows.size();
                shadows.push_back(spawn_ray(s.world_triangle, s.u, s.v, light.sun_direction));
            }
            if (light.point_light) {
                ray const to_light = spawn_ray_to(s.world_triangle, s.u, s.v, light.point_position);
                distance2[j] = dot(to_light.direction, to_light.direction);
                cos_light[j] = dot(s.normal, to_light.direction) / std::sqrt(distance2[j]);
                if (cos_light[j] > 0.0f) {
                    light_ray[j] = shadows.size();
                    shadows.push_back(to_light);
                }
            }
        }
        auto const occluded = buffer.first(shadows.size());
        scene.any_hit(std::span<ray const>(shadows), occluded, isect);
        next.clear();
        still_going.clear();
        for (std::size_t j = 0; j < m; ++j) {
            std::size_t const i = going[j];
            if (!hits[j].hit) {
                radiance[i] = radiance[i] + throughput[i] * scene.background(current[j]);
                continue;
            }
            surface_sample const& s = surfaces[j];
            float const cos_sun = dot(s.normal, light.sun_direction);
            if (sun_ray[j] != none && !occluded[sun_ray[j]])
                radiance[i] = radiance[i] + throughput[i] * s.albedo * light.sun_colour * cos_sun;
            if (light_ray[j] != none && !occluded[light_ray[j]])
                radiance[i] = radiance[i] + throughput[i] * s.albedo * light.point_intensity * (cos_light[j] / distance2[j]);
            throughput[i] = throughput[i] * s.albedo;
            pixel_random& rng = rngs[i];
            ray const bounce = spawn_ray(s.world_triangle, s.u, s.v, cosine_direction(s.normal, rng.next(), rng.next()));
            if (depth < bounces) {
                next.push_back(bounce);
                still_going.push_back(i);
            }
        }
        current.swap(next);
        going.swap(still_going);
    }
    for (std::size_t i = 0; i < n; ++i) colours[i] = vec4<float>(radiance[i], 1.0f);
}

} // namespace canopy
