// canopy.scene — what a scene compiles into, ready for queries and rendering.
//
// Meshes are built into BVHs once each; instances place them with affine transforms under one
// top-level BVH. A scene that is one untransformed mesh has no top level: it is traced directly.
// Ids in hit records: geom_id = mesh index, prim_id = triangle index in that mesh, inst_id =
// instance index (invalid_id when there is no top level).
//
// compiled_scene provides what canopy.render's kernels need (closest_hit, any_hit, surface,
// background) and the texture coordinates at a hit (uv), which alpha-mask intersectors use.
module;
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>
export module canopy.scene;
export import canopy.render;
export import canopy.texture;

export namespace canopy {

struct material {
    vec3<float> albedo{0.7f, 0.7f, 0.7f};
    int texture = -1;           // index into compiled_scene::textures, or -1
    bool alpha_mask = false;    // the texture's alpha (or a procedural rule) cuts the surface
    float alpha_cutoff = 0.01f; // texels with alpha below this are holes
};

struct compiled_mesh {
    std::vector<triangle> triangles;                // in input order: triangles[prim_id]
    std::vector<std::array<vec2<float>, 3>> uvs;    // per triangle, or empty
    int material = 0;
    bvh<triangle> accel;
};

struct compiled_scene {
    using top_level = bvh<instance<bvh<triangle>>>;

    // Instances point into meshes: a compiled scene moves but does not copy.
    compiled_scene() = default;
    compiled_scene(compiled_scene const&) = delete;
    compiled_scene& operator=(compiled_scene const&) = delete;
    compiled_scene(compiled_scene&&) = default;
    compiled_scene& operator=(compiled_scene&&) = default;

    std::vector<compiled_mesh> meshes;
    std::vector<material> materials{material{}};
    std::vector<texture2d<vec4<float>>> textures;
    std::vector<instance<bvh<triangle>>> instances; // inst_id = index
    std::vector<std::uint32_t> instance_mesh;       // mesh of each instance
    top_level top;
    bool instanced = false;
    vec3<float> sky_zenith{0.35f, 0.55f, 0.9f};
    vec3<float> sky_horizon{0.85f, 0.9f, 0.95f};

    // Builds every mesh BVH, then (when there are instances) the top level. Meshes must not be
    // added afterwards: instances point at the mesh BVHs.
    void build(bvh_build_options const& options = {}) {
        for (std::size_t g = 0; g < meshes.size(); ++g) {
            for (auto& t : meshes[g].triangles) t.geom_id = std::uint32_t(g);
            meshes[g].accel = build_binned_sah(meshes[g].triangles, options);
        }
        instances.clear();
        if (!instanced) return;
        for (std::size_t k = 0; k < instance_mesh.size(); ++k)
            instances.emplace_back(meshes[instance_mesh[k]].accel, instance_transforms[k], std::uint32_t(k));
        top = build_binned_sah(instances, options);
    }

    // Object→world transform of each instance, set before build().
    std::vector<affine_transform<float>> instance_transforms;

    aabb bounds() const {
        if (instanced) return top.bounds();
        return meshes.empty() ? aabb{} : meshes[0].accel.bounds();
    }

    template <typename I>
    basic_hit_record<float> closest_hit(ray const& r, I& isect) const {
        if (instanced) return canopy::closest_hit(r, &top, &top + 1, isect);
        return canopy::closest_hit(r, &meshes[0].accel, &meshes[0].accel + 1, isect);
    }

    template <typename I>
    basic_hit_record<float> any_hit(ray const& r, I& isect) const {
        if (instanced) return canopy::any_hit(r, &top, &top + 1, isect);
        return canopy::any_hit(r, &meshes[0].accel, &meshes[0].accel + 1, isect);
    }

    // Texture coordinates at a hit (hooks may call this: it needs only geom_id, prim_id, u, v).
    vec2<float> uv(basic_hit_record<float> const& hr) const {
        auto const& mesh = meshes[hr.geom_id];
        if (mesh.uvs.empty()) return {hr.u, hr.v};
        auto const& t = mesh.uvs[hr.prim_id];
        return lerp(t[0], t[1], t[2], hr.u, hr.v);
    }

    material const& material_of(basic_hit_record<float> const& hr) const {
        return materials[std::size_t(meshes[hr.geom_id].material)];
    }

    surface_sample surface(basic_hit_record<float> const& hr, ray const& r) const {
        surface_sample s;
        triangle tri = meshes[hr.geom_id].triangles[hr.prim_id];
        if (instanced && hr.inst_id != invalid_id) {
            auto const& m = instances[hr.inst_id].object_to_world;
            tri.v0 = m.transform_point(tri.v0);
            tri.v1 = m.transform_point(tri.v1);
            tri.v2 = m.transform_point(tri.v2);
        }
        s.world_triangle = tri;
        s.u = hr.u;
        s.v = hr.v;
        vec3<float> n = normalize(geometric_normal(tri));
        if (dot(n, r.direction) > 0.0f) n = -n;
        s.normal = n;
        material const& mat = material_of(hr);
        s.albedo = mat.albedo;
        if (mat.texture >= 0) {
            vec4<float> const texel = tex2D(textures[std::size_t(mat.texture)], uv(hr));
            s.albedo = s.albedo * vec3<float>(texel.x, texel.y, texel.z);
        }
        return s;
    }

    vec3<float> background(ray const& r) const {
        float const up = r.direction.y / length(r.direction);
        float const t = std::sqrt(std::clamp(up, 0.0f, 1.0f));
        return lerp(sky_horizon, sky_zenith, t);
    }
};

// The paper's texture alpha mask: a candidate on a masked material is kept only where the
// texture's alpha at the hit's texture coordinates reaches the cutoff.
struct texture_alpha_mask : basic_intersector<texture_alpha_mask> {
    using basic_intersector<texture_alpha_mask>::operator();

    template <typename Ray>
    auto operator()(Ray const& ray, triangle const& tri) {
        auto hr = intersect(ray, tri);
        if (hr.hit) {
            material const& mat = scene->material_of(hr);
            if (mat.alpha_mask && mat.texture >= 0)
                hr.hit &= tex2D(scene->textures[std::size_t(mat.texture)], scene->uv(hr)).w >= mat.alpha_cutoff;
        }
        return hr;
    }

    compiled_scene const* scene = nullptr;
};

// A procedural alpha mask on masked materials: concentric rings around the centre of texture
// space, cut off outside the unit disc.
struct procedural_alpha_mask : basic_intersector<procedural_alpha_mask> {
    using basic_intersector<procedural_alpha_mask>::operator();

    template <typename Ray>
    auto operator()(Ray const& ray, triangle const& tri) {
        auto hr = intersect(ray, tri);
        if (hr.hit && scene->material_of(hr).alpha_mask) hr.hit &= keeps(scene->uv(hr));
        return hr;
    }

    // The rule: with d = 2·|uv − (0.5, 0.5)|, keep where d < 1 and frac(5d) < 0.6.
    static bool keeps(vec2<float> uv) {
        float const d = 2.0f * length(uv - vec2<float>(0.5f, 0.5f));
        float const ring = 5.0f * d - std::floor(5.0f * d);
        return d < 1.0f && ring < 0.6f;
    }

    compiled_scene const* scene = nullptr;
};

} // namespace canopy
