// canopy.bench_tracing — what the benchmark drivers share: a bench scene compiled as `canopy
// trace` compiles a file of the bench formats (canopy.plugins.bench's layout, then compile() with
// keep_single_instance: one mesh BVH, or a top-level BVH over instances of the mesh, inst_id = the
// instance's index), one query on it, a counting intersector, and the ray sets of a scene.
//
//   primary   a 512 × 512 pinhole camera looking at the scene's box from outside, its pixels row
//             by row (pixel_order::rows, the default) or in tiles of 4 × 4 pixels, the tiles row by
//             row and each tile's pixels row by row (pixel_order::tiles: 8 consecutive rays cover
//             4 × 2 pixels, 16 cover 4 × 4; the drivers' --tiles)
//   random    origins uniform in the scene's box, directions from a normal distribution
//   shadow    from every primary hit toward a light outside the box (tmin 1e-4, tmax 1: the light)
//   vertices  16,384 rays from origins uniform in the scene's box through a vertex of the mesh (a
//             random triangle's corner k mod 3 for the k-th ray, placed by a random instance when instanced):
//             where many triangles meet (a fan's apex), every one of their leaves is reached
//   inside    from the scene's interior points (bench_scene::interior, inside closed thin solids:
//             the slivers' spindle and cylinder) in random directions; empty for other scenes
module;
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <random>
#include <span>
#include <string>
#include <utility>
#include <vector>
export module canopy.bench_tracing;
export import canopy;
export import canopy.bench_scenes;
export import canopy.plugins.bench; // with the format readers and writers (:formats)
export import canopy.scene;

export namespace canopy::bench {

struct canopy_scene {
    compiled_scene scene; // levels 0: the mesh alone; levels 1: instances of meshes[0]
    std::size_t bytes = 0; // of the BVHs (canopy::compute_stats)
};

// Bytes of the scene's BVHs: the mesh's and, when instanced, the top level's.
std::size_t bvh_bytes(compiled_scene const& c) {
    std::size_t bytes = compute_stats(c.meshes[0].accel).bytes;
    if (c.levels > 0) bytes += c.visit_root([](auto const& root) { return compute_stats(root).bytes; });
    return bytes;
}

// Frees the scene's BVHs (the meshes', the groups' and the top levels'), as the Embree side
// releases its previous scene before its build is timed: a rebuild timed after this one pays
// neither for freeing the old BVHs nor for holding both in memory at once.
void release_bvhs(canopy_scene& s) {
    auto& c = s.scene;
    c.top_meshes_bvh = {};
    c.top_groups_bvh = {};
    c.top_mesh_instances.clear();
    c.top_group_instances.clear();
    for (auto& g : c.groups) {
        g.accel = {};
        g.instances.clear();
    }
    for (auto& m : c.meshes) m.accel = {};
}

// The scene compiled with `options` for the mesh BVH (the top level over instances is no
// triangle BVH: the quality does not apply to it).
std::unique_ptr<canopy_scene> build_canopy(bench_scene const& in, bvh_build_options const& options = {}) {
    scene graph;
    add_bench_scene(graph, graph.root(), in.mesh, in.instances, in.name, in.name);
    auto s = std::make_unique<canopy_scene>();
    s->scene = compile(graph, {.bvh = options, .name = in.name, .keep_single_instance = true});
    s->bytes = bvh_bytes(s->scene);
    return s;
}

// "fast", "high" or "automatic" → the build quality; false for another name.
inline bool parse_quality(std::string const& name, build_quality& quality) {
    if (name == "fast") quality = build_quality::fast;
    else if (name == "high") quality = build_quality::high;
    else if (name == "automatic") quality = build_quality::automatic;
    else return false;
    return true;
}

// The batch queries (canopy.query:batch) over all of `rays`.
template <typename Isect>
batch_stats canopy_trace_batch(canopy_scene const& s, std::span<ray const> rays, bool closest, Isect& isect,
                               std::span<basic_hit_record<float>> out, batch_packing packing = batch_packing::adaptive) {
    return s.scene.visit_root([&](auto const& root) {
        return closest ? closest_hit(rays, &root, &root + 1, out, isect, packing)
                       : any_hit(rays, &root, &root + 1, out, isect, packing);
    });
}

template <typename Isect>
basic_hit_record<float> canopy_trace_record(canopy_scene const& s, ray const& r, bool closest, Isect& isect) {
    return s.scene.visit_root([&](auto const& root) {
        return closest ? closest_hit(r, &root, &root + 1, isect) : any_hit(r, &root, &root + 1, isect);
    });
}

template <typename Isect>
bench_hit canopy_trace(canopy_scene const& s, ray const& r, bool closest, Isect& isect) {
    basic_hit_record<float> const hr = canopy_trace_record(s, r, closest, isect);
    if (!hr.hit) return {};
    return {hr.t, hr.prim_id, hr.inst_id, hr.u, hr.v};
}

// Counts the tests a query makes through `Inner` (whose triangle test it calls). Its box hook is
// called once per box instead of the 8-wide SIMD test, so it is never timed. Tests of packets
// (batch queries) are counted apart, once for the packet's 8 lanes.
template <typename Inner>
struct counting_intersector : basic_intersector<counting_intersector<Inner>> {
    using basic_intersector<counting_intersector<Inner>>::operator();

    template <typename Ray, typename... Args>
    auto operator()(Ray const& ray, aabb const& box, Args&&... args) {
        ++(is_packet<Ray> ? packet_boxes : boxes);
        return intersect(ray, box, std::forward<Args>(args)...);
    }

    template <typename Ray>
    auto operator()(Ray const& ray, triangle const& tri) {
        ++(is_packet<Ray> ? packet_triangles : triangles);
        return test_primitive(inner, ray, tri);
    }

    template <typename Ray>
    static constexpr bool is_packet = simd::simd_width_v<ray_value_t<Ray>> > 1;

    template <typename Ray, typename T>
        requires filter_hook_for<Inner, Ray>
    auto filter(Ray const& ray, basic_hit_record<T> const& hr) {
        return inner.filter(ray, hr);
    }

    Inner inner;
    std::uint64_t boxes = 0;
    std::uint64_t triangles = 0;
    std::uint64_t packet_boxes = 0;     // tests of packets (8 lanes each)
    std::uint64_t packet_triangles = 0;
};

struct ray_set {
    std::string name;
    std::vector<ray> rays;
    bool shadow = false; // traced with any-hit only
};

// The order of the camera's pixels in the primary set, and so in the shadow set made from it (see
// the top of this file).
enum class pixel_order { rows, tiles };

// The ray sets of the scene (`in`, compiled as `s`).
std::vector<ray_set> make_rays(canopy_scene const& s, bench_scene const& in, pixel_order order = pixel_order::rows) {
    std::vector<ray_set> sets;
    aabb const box = s.scene.bounds();
    auto const c = center(box);
    auto const d = diagonal(box);
    float const extent = length(d);
    constexpr int w = 512, h = 512;
    vec3<float> const eye = c + vec3<float>(0.3f, 0.4f, 1.0f) * extent;
    vec3<float> const forward = normalize(c - eye);
    vec3<float> const right = normalize(cross(forward, vec3<float>(0, 1, 0)));
    vec3<float> const up = cross(right, forward);
    ray_set primary{"primary", {}, false};
    constexpr int tile = 4; // pixel_order::tiles
    static_assert(w % tile == 0 && h % tile == 0, "the tiles cover the image");
    for (int pixel = 0; pixel < w * h; ++pixel) {
        int i = pixel % w, j = pixel / w;
        if (order == pixel_order::tiles) {
            int const t = pixel / (tile * tile), in_tile = pixel % (tile * tile);
            i = t % (w / tile) * tile + in_tile % tile;
            j = t / (w / tile) * tile + in_tile / tile;
        }
        float const x = (float(i) + 0.5f) / float(w) - 0.5f, y = (float(j) + 0.5f) / float(h) - 0.5f;
        primary.rays.push_back({eye, 0.0f, forward + right * (0.8f * x) + up * (0.8f * y),
                                std::numeric_limits<float>::infinity()});
    }
    ray_set random{"random", {}, false};
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u01(0.0f, 1.0f);
    std::normal_distribution<float> n01(0.0f, 1.0f);
    for (int k = 0; k < w * h; ++k) {
        vec3<float> const o(box.min.x + d.x * u01(rng), box.min.y + d.y * u01(rng), box.min.z + d.z * u01(rng));
        random.rays.push_back({o, 0.0f, {n01(rng), n01(rng), n01(rng)}, std::numeric_limits<float>::infinity()});
    }
    ray_set shadow{"shadow", {}, true};
    vec3<float> const light = c + vec3<float>(-0.5f, 1.0f, 0.5f) * extent;
    default_intersector none;
    for (auto const& r : primary.rays) {
        auto const hit = canopy_trace(s, r, true, none);
        if (hit.prim == invalid_id) continue;
        vec3<float> const p = r.origin + r.direction * hit.t;
        shadow.rays.push_back({p, 1e-4f, light - p, 1.0f});
    }
    // The vertex rays' indices and origins from the raw stream; the inside rays' directions as the
    // random set's.
    auto const index = [&](std::size_t n) { return std::size_t(rng() % n); };
    auto const in_box = [&] {
        auto const u = [&] { return float(rng() >> 8) * (1.0f / 16777216.0f); };
        return vec3<float>(box.min.x + d.x * u(), box.min.y + d.y * u(), box.min.z + d.z * u());
    };
    ray_set vertices{"vertices", {}, false};
    if (!in.mesh.empty()) {
        for (int k = 0; k < 16384; ++k) {
            triangle const& t = in.mesh[index(in.mesh.size())];
            vec3<float> v = k % 3 == 0 ? t.v0 : (k % 3 == 1 ? t.v1 : t.v2);
            if (!in.instances.empty()) v = transform_point(in.instances[index(in.instances.size())], v);
            vec3<float> const o = in_box();
            if (o.x == v.x && o.y == v.y && o.z == v.z) continue;
            vertices.rays.push_back({o, 0.0f, v - o, std::numeric_limits<float>::infinity()});
        }
    }
    ray_set inside{"inside", {}, false};
    for (vec3<float> const& o : in.interior)
        inside.rays.push_back({o, 0.0f, {n01(rng), n01(rng), n01(rng)}, std::numeric_limits<float>::infinity()});
    sets.push_back(std::move(primary));
    sets.push_back(std::move(random));
    sets.push_back(std::move(shadow));
    sets.push_back(std::move(vertices));
    sets.push_back(std::move(inside));
    return sets;
}

} // namespace canopy::bench
