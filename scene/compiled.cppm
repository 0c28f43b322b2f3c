// canopy.scene:compiled — what a scene compiles into, ready for queries and rendering.
//
// Meshes are built into BVHs once each. Placements put them in the world in up to two instance
// levels, chosen by compile() (canopy.scene:compile) or set by hand before build(). The level
// says which BVH is the root, the one every query starts from (visit_root):
//   levels 0  meshes[0].accel: one mesh traced directly, no top level (a single untransformed mesh)
//   levels 1  top_meshes_bvh: a BVH over instances of meshes (top_meshes)
//   levels 2  top_groups_bvh: a BVH over instances of groups (top_groups); each group is a BVH
//             over instances of meshes (a shared subtree of the scene graph, built once)
// Ids in hit records: geom_id = mesh index, prim_id = triangle index in that mesh; inst_id = the
// index of the top-level placement (invalid_id at level 0); at level 2 inner_inst_id[0] = the
// index of the placement inside its group.
//
// compiled_scene provides what canopy.render's kernels need (closest_hit, any_hit, surface,
// background), the texture coordinates at a hit (uv), which alpha-mask intersectors use, and the
// camera and lights an application renders it with (render_camera, render_lights).
module;
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>
export module canopy.scene:compiled;
export import canopy.render;
export import canopy.texture;
import :error;
import :graph;

export namespace canopy {

// A material as kernels and masks read it: the fields and defaults of the scene graph's
// material_data (canopy.scene:graph), its image resolved to a texture of the compiled scene.
struct material {
    vec3<float> colour{0.7f, 0.7f, 0.7f}; // linear base colour
    int texture = -1;                      // base-colour texture: index into compiled_scene::textures, or -1
    alpha_mode alpha = alpha_mode::opaque; // mask: texels whose alpha < alpha_cutoff are holes (or a
                                           // procedural rule cuts the surface)
    float alpha_cutoff = 0.5f;             // glTF's default
};

struct compiled_mesh {
    std::string name;
    std::vector<triangle> triangles;                // in input order: triangles[prim_id]
    std::vector<std::array<vec2<float>, 3>> uvs;    // per triangle, or empty
    int material = 0;
    bvh<triangle> accel;
    double build_seconds = 0.0;                     // the time build() took to build accel
};

// What compile() did (all zero for scenes assembled by hand). decisions: one line per rule
// that applied, for `canopy info`.
struct compile_statistics {
    std::size_t nodes = 0;
    std::size_t custom_nodes_expanded = 0;
    std::size_t meshes_in_scene = 0;
    std::size_t meshes_built = 0;
    std::size_t meshes_unreferenced = 0;  // not built
    std::size_t meshes_empty = 0;         // placed but without triangles: dropped
    std::size_t subtrees_empty = 0;       // instances of subtrees without meshes: dropped
    std::size_t triangles_stored = 0;     // in built meshes
    std::size_t triangles_placed = 0;     // in the world: once per placement, at every level
    std::size_t placements = 0;           // mesh placements built (a group's count once)
    std::size_t identity_placements = 0;  // placements whose transform is not applied
    std::size_t identity_transform_nodes = 0;
    std::size_t groups = 0;               // level-2 groups (shared subtrees with several meshes)
    std::size_t group_instances = 0;
    std::size_t flattened_placements = 0; // from nesting deeper than two levels
    std::size_t faces_fanned = 0;         // polygon faces of built meshes fanned by the fallback (mesh_data)
    std::size_t materials = 0;
    std::size_t masked_materials_used = 0;
    std::size_t images_used = 0;
    std::size_t images_unused = 0;
    std::size_t cameras = 0;
    std::size_t lights = 0;
    int levels = 0;
    bool alpha_mask_needed = false;
    double build_seconds = 0.0;
    build_quality quality = build_quality::automatic; // asked for the mesh BVHs (compile_options::bvh.quality); each compiled_mesh's accel.quality says what it used
    double mesh_build_seconds = 0.0;              // building the mesh BVHs, the sum of compiled_mesh::build_seconds
    std::vector<std::string> decisions;
};

// A mesh or group put in place: index into compiled_scene::meshes or ::groups, object→world.
// id: the user id of the scene graph's instance node that placed it (invalid_id for placements
// made by mesh nodes); hits report placement indices, ids map them back.
struct placement {
    std::uint32_t index = 0;
    affine_transform<float> transform = affine_transform<float>::identity();
    std::uint32_t id = invalid_id;
};

using mesh_instance = instance<bvh<triangle>>;
using group_bvh = bvh<mesh_instance>;
using group_instance = instance<group_bvh>;

// A shared subtree: meshes placed relative to the subtree's own frame, under one BVH.
struct compiled_group {
    std::string name;
    std::vector<placement> placements;    // set before build()
    std::vector<mesh_instance> instances; // instances[k] places placements[k]
    group_bvh accel;
};

struct compiled_scene {
    // Instances point into meshes and groups: a compiled scene moves but does not copy.
    compiled_scene() = default;
    compiled_scene(compiled_scene const&) = delete;
    compiled_scene& operator=(compiled_scene const&) = delete;
    compiled_scene(compiled_scene&&) = default;
    compiled_scene& operator=(compiled_scene&&) = default;

    std::vector<compiled_mesh> meshes;
    std::vector<material> materials{material{}};
    std::vector<texture2d<vec4<float>>> textures;
    std::vector<compiled_group> groups;

    int levels = 0;                    // which BVH is the root: see the file comment and visit_root
    std::vector<placement> top_meshes; // levels 1
    std::vector<placement> top_groups; // levels 2

    std::vector<mesh_instance> top_mesh_instances;   // built from top_meshes
    std::vector<group_instance> top_group_instances; // built from top_groups
    bvh<mesh_instance> top_meshes_bvh;  // levels 1: the root, over top_mesh_instances
    bvh<group_instance> top_groups_bvh; // levels 2: the root, over top_group_instances

    // World-space camera and lights of the scene, when it has them. camera_file and camera_node
    // name the camera in messages (its file, and "camera 'main'" or "camera #12").
    std::optional<camera_data> camera;
    std::string camera_file, camera_node;
    std::vector<light_data> lights;

    compile_statistics statistics;

    vec3<float> sky_zenith{0.35f, 0.55f, 0.9f};
    vec3<float> sky_horizon{0.85f, 0.9f, 0.95f};

    // Places mesh `m` at the top level (levels becomes at least 1).
    void place(std::uint32_t m, affine_transform<float> const& object_to_world) {
        levels = std::max(levels, 1);
        top_meshes.push_back({m, object_to_world, invalid_id});
    }

    // Builds every mesh BVH (each timed in compiled_mesh::build_seconds), then the groups, then
    // the top level. Meshes and groups must not be added afterwards: instances point at their
    // BVHs. options.quality applies to the mesh BVHs (the others are BVHs of instances).
    void build(bvh_build_options const& options = {}) {
        if (levels < 0 || levels > 2) throw std::invalid_argument("compiled_scene: levels must be 0, 1 or 2");
        if (levels == 0 && meshes.size() != 1)
            throw std::invalid_argument("compiled_scene: level 0 needs exactly one mesh");
        for (std::size_t g = 0; g < meshes.size(); ++g) {
            for (auto& t : meshes[g].triangles) t.geom_id = std::uint32_t(g);
            auto const start = std::chrono::steady_clock::now();
            meshes[g].accel = build_binned_sah(meshes[g].triangles, options);
            meshes[g].build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        }
        auto const mesh_instances = [&](std::vector<placement> const& ps) {
            std::vector<mesh_instance> out;
            out.reserve(ps.size());
            for (std::size_t k = 0; k < ps.size(); ++k)
                out.emplace_back(meshes.at(ps[k].index).accel, ps[k].transform, std::uint32_t(k));
            return out;
        };
        for (auto& g : groups) {
            g.instances = mesh_instances(g.placements);
            g.accel = build_binned_sah(g.instances, options);
        }
        top_mesh_instances.clear();
        top_group_instances.clear();
        if (levels == 1) {
            top_mesh_instances = mesh_instances(top_meshes);
            top_meshes_bvh = build_binned_sah(top_mesh_instances, options);
        } else if (levels == 2) {
            for (std::size_t k = 0; k < top_groups.size(); ++k)
                top_group_instances.emplace_back(groups.at(top_groups[k].index).accel, top_groups[k].transform,
                                                 std::uint32_t(k));
            top_groups_bvh = build_binned_sah(top_group_instances, options);
        }
    }

    // Calls f(root) with the BVH every query starts from, by level: meshes[0].accel (a
    // bvh<triangle>) at 0, top_meshes_bvh (a bvh<mesh_instance>) at 1, top_groups_bvh (a
    // bvh<group_instance>) at 2; returns what f returns (the same type for the three). The one
    // place that picks the root: the queries below, the command line, the benchmarks and the
    // batch queries (f calls them on &root, &root + 1) all go through it. Needs a built scene.
    template <typename F>
    inline decltype(auto) visit_root(F&& f) const {
        if (levels == 2) return f(top_groups_bvh);
        if (levels == 1) return f(top_meshes_bvh);
        return f(meshes[0].accel);
    }

    aabb bounds() const {
        if (levels == 0 && meshes.empty()) return aabb{};
        return visit_root([](auto const& root) { return root.bounds(); });
    }

    template <typename I>
    inline basic_hit_record<float> closest_hit(ray const& r, I& isect) const {
        return visit_root([&](auto const& root) { return canopy::closest_hit(r, &root, &root + 1, isect); });
    }

    template <typename I>
    inline basic_hit_record<float> any_hit(ray const& r, I& isect) const {
        return visit_root([&](auto const& root) { return canopy::any_hit(r, &root, &root + 1, isect); });
    }

    // The batch queries (canopy.query:batch): out[i] as closest_hit(rays[i], isect) and
    // any_hit(rays[i], isect).hit would give, bit for bit; coherent runs of rays traced as packets
    // (while they pay, unless `packing` says always).
    template <typename I>
    inline batch_stats closest_hit(std::span<ray const> rays, std::span<basic_hit_record<float>> out, I& isect,
                                   batch_packing packing = batch_packing::adaptive) const {
        return visit_root(
            [&](auto const& root) { return canopy::closest_hit(rays, &root, &root + 1, out, isect, packing); });
    }

    template <typename I>
    inline batch_stats any_hit(std::span<ray const> rays, std::span<bool> out, I& isect,
                               batch_packing packing = batch_packing::adaptive) const {
        return visit_root([&](auto const& root) { return canopy::any_hit(rays, &root, &root + 1, out, isect, packing); });
    }

    // The user id of the instance a hit lies in: the innermost placement made by an instance node
    // (invalid_id when no instance node placed it).
    std::uint32_t instance_id(basic_hit_record<float> const& hr) const {
        if (hr.inst_id == invalid_id || levels == 0) return invalid_id;
        if (levels == 1) return top_meshes[hr.inst_id].id;
        std::uint32_t const inner = groups[top_groups[hr.inst_id].index].placements[hr.inner_inst_id[0]].id;
        return inner != invalid_id ? inner : top_groups[hr.inst_id].id;
    }

    // Object→world transform of the mesh a hit lies on (identity at level 0).
    affine_transform<float> object_to_world(basic_hit_record<float> const& hr) const {
        if (levels == 1 && hr.inst_id != invalid_id) return top_mesh_instances[hr.inst_id].object_to_world;
        if (levels == 2 && hr.inst_id != invalid_id) {
            group_instance const& outer = top_group_instances[hr.inst_id];
            mesh_instance const& inner = groups[top_groups[hr.inst_id].index].instances[hr.inner_inst_id[0]];
            if (inner.identity) return outer.object_to_world;
            if (outer.identity) return inner.object_to_world;
            return outer.object_to_world * inner.object_to_world;
        }
        return affine_transform<float>::identity();
    }

    // Texture coordinates at a hit (hooks may call this: it needs only geom_id, prim_id, u, v).
    inline vec2<float> uv(basic_hit_record<float> const& hr) const {
        auto const& mesh = meshes[hr.geom_id];
        if (mesh.uvs.empty()) return {hr.u, hr.v};
        auto const& t = mesh.uvs[hr.prim_id];
        return lerp(t[0], t[1], t[2], hr.u, hr.v);
    }

    inline material const& material_of(basic_hit_record<float> const& hr) const {
        return materials[std::size_t(meshes[hr.geom_id].material)];
    }

    surface_sample surface(basic_hit_record<float> const& hr, ray const& r) const {
        surface_sample s;
        triangle tri = meshes[hr.geom_id].triangles[hr.prim_id];
        if (levels > 0) {
            auto const m = object_to_world(hr);
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
        s.albedo = mat.colour;
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

    // The camera to render the scene with, for images of aspect width / height: the scene's own,
    // else one looking at the middle of the bounding box from above and in front (+z), far enough
    // to see all of it (45° field of view). `name` names the scene in errors (its file, or
    // gen:...). Throws scene_error when the values give no camera (pinhole_camera::look_at_problem),
    // naming the scene's camera (camera_file, camera_node), or for the automatic one "NAME:
    // automatic camera" with bounds that are empty, beyond float range or without extent.
    pinhole_camera render_camera(float aspect, std::string const& name = {}) const {
        if (camera)
            return checked_camera(camera_file.empty() ? name : camera_file, camera_node.empty() ? "camera" : camera_node,
                                  camera->eye, camera->target, camera->up, camera->fovy_degrees, aspect);
        aabb const box = bounds();
        auto const c = center(box);
        float const extent = length(diagonal(box));
        vec3<float> const eye = c + vec3<float>(0.35f, 0.45f, 1.0f) * extent;
        std::string const where = "automatic camera";
        std::string const bounds_text = "the scene's bounds " + text(box.min) + " .. " + text(box.max);
        if (!all_finite(box.min) || !all_finite(box.max) || !(box.min.x <= box.max.x) || !(box.min.y <= box.max.y) ||
            !(box.min.z <= box.max.z) || !std::isfinite(extent) || !all_finite(eye))
            throw scene_error(name, where, bounds_text + " are empty or beyond float range: give the scene a camera");
        if (!(extent > 0.0f))
            throw scene_error(name, where,
                              bounds_text + " have no extent in float (a point, or a scene scaled to almost nothing): "
                                            "give the scene a camera");
        return checked_camera(name, where, eye, c, {0.0f, 1.0f, 0.0f}, 45.0f, aspect);
    }

    // The lights of the path kernel (light_options): the scene's first directional light is the
    // sun and its first point light the point light; without a point light, one stands above the
    // middle of the bounding box (0.35 of its diagonal up), its intensity (1, 0.8, 0.6) times
    // 0.05 · diagonal². Throws scene_error, naming the scene by `name`, for a light whose values
    // give no finite light, or bounds too large for the default point light.
    light_options render_lights(std::string const& name = {}) const {
        light_options light;
        bool sun = false, point = false;
        for (auto const& l : lights) {
            if (l.kind == light_data::directional && !sun) {
                light.sun_direction = normalize(l.direction);
                if (!all_finite(light.sun_direction) || !all_finite(l.colour))
                    throw scene_error(name, "directional light",
                                      "direction " + text(l.direction) + " or colour " + text(l.colour) +
                                          " gives no finite light");
                light.sun_colour = l.colour;
                sun = true;
            } else if (l.kind == light_data::point && !point) {
                if (!all_finite(l.position) || !all_finite(l.colour))
                    throw scene_error(name, "point light",
                                      "position " + text(l.position) + " or intensity " + text(l.colour) + " is not finite");
                light.point_position = l.position;
                light.point_intensity = l.colour;
                point = true;
            }
        }
        light.point_light = true;
        if (!point) {
            aabb const box = bounds();
            float const extent = length(diagonal(box));
            light.point_position = center(box) + vec3<float>(0.0f, 0.35f * extent, 0.0f);
            light.point_intensity = vec3<float>(1.0f, 0.8f, 0.6f) * (0.05f * extent * extent);
            if (!all_finite(light.point_position) || !all_finite(light.point_intensity))
                throw scene_error(name, "",
                                  "the bounding box (diagonal " + text(extent) +
                                      ") is beyond float range for the default point light of the path kernel: give "
                                      "the scene a point light");
        }
        return light;
    }

private:
    static std::string text(float f) {
        char buffer[32];
        std::snprintf(buffer, sizeof buffer, "%g", double(f));
        return buffer;
    }
    static std::string text(vec3<float> v) { return "(" + text(v.x) + ", " + text(v.y) + ", " + text(v.z) + ")"; }

    // look_at, or a scene_error naming the camera when the values give none.
    static pinhole_camera checked_camera(std::string const& file, std::string const& where, vec3<float> eye,
                                         vec3<float> target, vec3<float> up, float fovy, float aspect) {
        std::string const problem = pinhole_camera::look_at_problem(eye, target, up, fovy, aspect);
        if (!problem.empty()) throw scene_error(file, where, problem);
        return pinhole_camera::look_at(eye, target, up, fovy, aspect);
    }
};

} // namespace canopy

namespace canopy::detail {

// A filter's answer for a scalar record (keep(hr)) or a packet's (keep(lane) for every hit lane,
// false for the others), keep taking a scalar record: the alpha masks below serve both.
template <typename T, typename Keep>
simd::mask_type_t<T> keep_lanes(basic_hit_record<T> const& hr, Keep const& keep) {
    if constexpr (simd::simd_width_v<T> == 1) {
        return keep(hr);
    } else {
        simd::mask_type_t<T> kept;
        for (int k = 0; k < simd::simd_width_v<T>; ++k)
            if (hr.hit[k]) kept.set(k, keep(record_lane(hr, k)));
        return kept;
    }
}

} // namespace canopy::detail

export namespace canopy {

// The paper's texture alpha mask: a candidate on a masked material is kept only where the
// texture's alpha at the hit's texture coordinates reaches the cutoff. Written as a filter
// (canopy.intersector), so that leaves keep their SIMD test; `keeps` serves intersectors that
// compose it with hooks of their own.
struct texture_alpha_mask : basic_intersector<texture_alpha_mask> {
    // For scalar rays and packets (lane by lane, the candidate lanes only).
    template <typename Ray, typename T>
    simd::mask_type_t<T> filter(Ray const&, basic_hit_record<T> const& hr) const {
        return detail::keep_lanes(hr, [&](basic_hit_record<float> const& lane) { return keeps(lane); });
    }

    inline bool keeps(basic_hit_record<float> const& hr) const {
        material const& mat = scene->material_of(hr);
        return !(mat.alpha == alpha_mode::mask && mat.texture >= 0) ||
               tex2D(scene->textures[std::size_t(mat.texture)], scene->uv(hr)).w >= mat.alpha_cutoff;
    }

    compiled_scene const* scene = nullptr;
};

// A procedural alpha mask on masked materials: concentric rings around the centre of texture
// space, cut off outside the unit disc. A filter, as above.
struct procedural_alpha_mask : basic_intersector<procedural_alpha_mask> {
    // For scalar rays and packets (lane by lane, the candidate lanes only).
    template <typename Ray, typename T>
    simd::mask_type_t<T> filter(Ray const&, basic_hit_record<T> const& hr) const {
        return detail::keep_lanes(hr, [&](basic_hit_record<float> const& lane) {
            return scene->material_of(lane).alpha != alpha_mode::mask || keeps(scene->uv(lane));
        });
    }

    // The rule: with d = 2·|uv − (0.5, 0.5)|, keep where d < 1 and frac(5d) < 0.6.
    static inline bool keeps(vec2<float> uv) {
        float const d = 2.0f * length(uv - vec2<float>(0.5f, 0.5f));
        float const ring = 5.0f * d - std::floor(5.0f * d);
        return d < 1.0f && ring < 0.6f;
    }

    compiled_scene const* scene = nullptr;
};

} // namespace canopy
