// canopy.scene:compile — scene graph → compiled_scene, skipping what the scene does not need.
//
//   compiled_scene c = compile(s, {.plugins = &registry});
//   for (auto const& line : c.statistics.decisions) std::puts(line.c_str());
//
// Rules, each counted in compile_statistics and stated in its decisions list:
//   - every mesh is built once, however often it is placed; meshes no node reaches are not built,
//     images no used material refers to are not converted;
//   - a scene that is one mesh with an identity transform gets no top-level BVH (levels 0);
//   - identity transforms (transform nodes, instances) are not applied: the placement is marked
//     identity and the traversal reuses the ray as it is;
//   - an instance of a subtree that holds one mesh places that mesh directly (no extra level); a
//     subtree with several meshes becomes a group: one BVH, built once, instanced at level 2;
//     subtrees nested deeper than that are flattened into their group (transforms composed in
//     double, rounded once);
//   - a scene that is one untransformed group uses the group's BVH as its top level;
//   - meshes without triangles and subtrees without meshes are dropped;
//   - polygon faces a loader had to fan although the fan may cover more than the face
//     (mesh_data::fanned_faces) are counted and the first is named;
//   - colour textures stored sRGB-encoded (image_data::srgb) are decoded to linear once, here;
//   - the alpha-mask intersector is needed only when a placed mesh has a masked material
//     (compile_statistics::alpha_mask_needed); kernels run without one otherwise;
//   - custom nodes are expanded by the plugins that registered their types.
// Placements keep the order of the graph (depth first, children in order), so the inst_id of a
// hit is the index of its placement in that order; placement::id keeps the instance node's own id.
// Errors (scene_error): instance cycles (the message lists the nodes on the cycle), custom nodes
// of an unregistered type, and a scene with nothing to trace.
module;
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>
export module canopy.scene:compile;
import canopy.math;
import canopy.bvh;
import :error;
import :limits;
import :graph;
import :registry;
import :compiled;
import :polygon;

export namespace canopy {

struct compile_options {
    registry const* plugins = nullptr; // expands custom nodes (required when the scene has any)
    bvh_build_options bvh{};
    std::string name{};                // how errors name the scene (usually its file)
    resource_limits limits = default_limits(); // placements after flattening, nesting depth
};


compiled_scene compile(scene const& s, compile_options const& options = {});

} // namespace canopy

namespace canopy {

namespace {

using xf64 = affine_transform<double>;

xf64 widen(affine_transform<float> const& a) {
    return {{vec3<double>(a.linear.col0), vec3<double>(a.linear.col1), vec3<double>(a.linear.col2)},
            vec3<double>(a.translation)};
}

affine_transform<float> narrow(xf64 const& a) {
    return {{vec3<float>(a.linear.col0), vec3<float>(a.linear.col1), vec3<float>(a.linear.col2)},
            vec3<float>(a.translation)};
}

// A transform on the way down: `identity` is exact (no product was ever taken).
struct frame {
    xf64 xf = xf64::identity();
    bool identity = true;

    frame then(affine_transform<float> const& local) const {
        if (local.is_identity()) return *this;
        if (identity) return {widen(local), false};
        return {xf * widen(local), false};
    }
    frame then(frame const& inner) const {
        if (inner.identity) return *this;
        if (identity) return inner;
        return {xf * inner.xf, false};
    }
    affine_transform<float> rounded() const { return identity ? affine_transform<float>::identity() : narrow(xf); }
};

// A placement found by the walk: a mesh (target = no_node) or an instanced subtree.
struct item {
    std::uint32_t mesh;
    node_id target;
    frame where;
    std::uint32_t id; // the user id of the instance node that placed it, or invalid_id
};

std::string node_label(scene const& s, node_id n) {
    node const& nd = s.at(n);
    return std::string(to_string(nd.kind)) + (nd.name.empty() ? " #" + std::to_string(n) : " '" + nd.name + "'");
}

class compiler {
public:
    compiler(scene const& s, compile_options const& o) : s_(s), o_(o) {}

    compiled_scene run() {
        auto const start = std::chrono::steady_clock::now();
        stats_.nodes = s_.nodes().size();
        stats_.meshes_in_scene = s_.meshes().size();
        check_cycles();

        std::vector<item> found;
        walk(s_.root(), frame{}, found, true);

        // Resolve instanced subtrees: one mesh → placed directly; several → a group.
        struct group_item {
            std::uint32_t group;
            frame where;
            std::uint32_t id;
        };
        std::vector<group_item> groups_placed;
        std::vector<item> meshes; // in the order of the graph
        for (auto const& st : found) {
            if (st.target == no_node) {
                meshes.push_back(st);
                continue;
            }
            prototype const& p = prototype_of(st.target);
            if (p.meshes.empty()) {
                ++stats_.subtrees_empty;
                continue;
            }
            if (p.meshes.size() == 1) {
                meshes.push_back({p.meshes[0].mesh, no_node, st.where.then(p.meshes[0].where), st.id});
                ++direct_single_mesh_;
                continue;
            }
            groups_placed.push_back({group_of(st.target), st.where, st.id});
        }

        if (meshes.empty() && groups_placed.empty())
            throw scene_error(o_.name, "", "the scene has nothing to trace (no mesh with triangles is placed in it)");

        compiled_scene c;
        // Meshes: only those placed, in order of first use.
        for (auto const& m : meshes) compiled_mesh_of(m.mesh);
        for (auto const& g : group_protos_)
            for (auto const& m : g.meshes) compiled_mesh_of(m.mesh);

        // Levels and placements.
        if (groups_placed.empty()) {
            if (meshes.size() == 1 && meshes[0].where.identity) {
                c.levels = 0;
                compiled_mesh_of(meshes[0].mesh);
                stats_.placements = stats_.identity_placements = 1;
                decide("one mesh with an identity transform: traced directly, no top-level BVH (levels 0)");
            } else {
                c.levels = 1;
                for (auto const& m : meshes) add_placement(c.top_meshes, m);
                decide("top-level BVH over " + std::to_string(c.top_meshes.size()) + " mesh placements (levels 1)");
            }
        } else if (groups_placed.size() == 1 && meshes.empty() && groups_placed[0].where.identity) {
            c.levels = 1;
            for (auto const& m : group_protos_[groups_placed[0].group].meshes)
                add_placement(c.top_meshes, m);
            group_protos_.clear();
            decide("one untransformed subtree: its placements form the top level (levels 1)");
        } else {
            c.levels = 2;
            for (auto const& g : group_protos_) {
                compiled_group cg;
                cg.name = g.name;
                for (auto const& m : g.meshes) add_placement(cg.placements, m);
                c.groups.push_back(std::move(cg));
            }
            for (auto const& [g, where, id] : groups_placed) {
                c.top_groups.push_back({g, where.rounded(), id});
                ++stats_.group_instances;
            }
            if (!meshes.empty()) {
                // Meshes placed outside any multi-mesh subtree share one extra group, placed
                // with the identity (the traversal reuses the ray: no transform is applied).
                compiled_group loose;
                loose.name = "(meshes outside instanced subtrees)";
                for (auto const& m : meshes) add_placement(loose.placements, m);
                c.top_groups.push_back({std::uint32_t(c.groups.size()), affine_transform<float>::identity(), invalid_id});
                c.groups.push_back(std::move(loose));
                decide(std::to_string(meshes.size()) +
                       " mesh placements outside instanced subtrees: one extra group, placed with the identity");
            }
            decide("top-level BVH over " + std::to_string(c.top_groups.size()) + " instances of " +
                   std::to_string(c.groups.size()) + " groups (levels 2)");
        }
        stats_.groups = c.groups.size();
        stats_.levels = c.levels;
        if (direct_single_mesh_ > 0)
            decide(std::to_string(direct_single_mesh_) +
                   " instances of single-mesh subtrees: the mesh is placed directly, no extra level");
        if (stats_.flattened_placements > 0)
            decide(std::to_string(stats_.flattened_placements) +
                   " placements nested deeper than two levels: flattened into their group");

        // Materials: compiled material 0 is the default; scene material i is i + 1.
        std::vector<int> texture_of_image(s_.images().size(), -1);
        c.materials.assign(1, material{});
        for (auto const& md : s_.materials()) {
            material m;
            m.albedo = md.colour;
            m.alpha_cutoff = md.alpha_cutoff;
            m.alpha_mask = md.alpha == alpha_mode::mask;
            c.materials.push_back(m);
        }
        stats_.materials = s_.materials().size();
        std::vector<bool> material_used(c.materials.size(), false);
        c.meshes.resize(mesh_map_.size());
        for (auto const& [source, index] : mesh_map_) {
            mesh_data const& md = s_.meshes()[source];
            compiled_mesh& cm = c.meshes[index];
            cm.name = md.name;
            cm.material = md.material + 1;
            material_used[std::size_t(cm.material)] = true;
            cm.triangles.reserve(md.triangles.size());
            for (std::size_t f = 0; f < md.triangles.size(); ++f) {
                auto const& t = md.triangles[f];
                cm.triangles.push_back(triangle{md.positions[t[0]], md.positions[t[1]], md.positions[t[2]],
                                                std::uint32_t(f), index});
            }
            cm.uvs = md.uvs;
            stats_.triangles_stored += md.triangles.size();
            if (md.fanned_faces > 0) {
                if (stats_.faces_fanned == 0) {
                    bool const line = !md.first_fanned.empty() &&
                                      md.first_fanned.find_first_not_of("0123456789") == std::string::npos;
                    first_fanned_ = "mesh '" + excerpt(md.name) + "'" +
                                    (md.source.empty() && md.first_fanned.empty() ? std::string()
                                     : " (" + md.source + (md.first_fanned.empty() ? "" : (line ? ":" : ": ") + md.first_fanned) + ")");
                }
                stats_.faces_fanned += md.fanned_faces;
            }
        }
        stats_.meshes_built = c.meshes.size();
        // Triangles in the world: every placement at every level.
        auto const triangles_of = [&](std::vector<placement> const& ps) {
            std::size_t n = 0;
            for (auto const& p : ps) n += c.meshes[p.index].triangles.size();
            return n;
        };
        if (c.levels == 0) stats_.triangles_placed = c.meshes[0].triangles.size();
        if (c.levels == 1) stats_.triangles_placed = triangles_of(c.top_meshes);
        for (auto const& g : c.top_groups) stats_.triangles_placed += triangles_of(c.groups[g.index].placements);
        stats_.meshes_unreferenced = s_.meshes().size() - c.meshes.size() - empty_meshes_.size();
        stats_.meshes_empty = empty_meshes_.size();
        for (std::size_t i = 1; i < c.materials.size(); ++i) {
            if (!material_used[i]) continue;
            int const image = s_.materials()[i - 1].image;
            if (image >= 0) {
                if (texture_of_image[std::size_t(image)] < 0) {
                    image_data const& img = s_.images()[std::size_t(image)];
                    texture_of_image[std::size_t(image)] = int(c.textures.size());
                    std::vector<vec4<float>> texels = img.texels;
                    if (img.srgb)
                        for (auto& t : texels) t = {srgb_to_linear(t.x), srgb_to_linear(t.y), srgb_to_linear(t.z), t.w};
                    c.textures.emplace_back(img.width, img.height, std::move(texels),
                                            sampler{filter_mode::bilinear, address_mode::wrap});
                }
                c.materials[i].texture = texture_of_image[std::size_t(image)];
            }
            if (c.materials[i].alpha_mask) {
                if (c.materials[i].texture < 0) c.materials[i].alpha_mask = false; // nothing to mask by
                else ++stats_.masked_materials_used;
            }
        }
        stats_.images_used = c.textures.size();
        stats_.images_unused = s_.images().size() - c.textures.size();
        stats_.alpha_mask_needed = stats_.masked_materials_used > 0;
        decide(stats_.alpha_mask_needed
                   ? std::to_string(stats_.masked_materials_used) + " masked materials in use: the alpha-mask intersector is needed"
                   : "no material in use has an alpha mask: no mask intersector");
        if (stats_.meshes_unreferenced > 0)
            decide(std::to_string(stats_.meshes_unreferenced) + " meshes no node places: not built");
        if (stats_.meshes_empty > 0) decide(std::to_string(stats_.meshes_empty) + " meshes without triangles: dropped");
        if (stats_.subtrees_empty > 0)
            decide(std::to_string(stats_.subtrees_empty) + " instances of subtrees without meshes: dropped");
        if (stats_.images_unused > 0)
            decide(std::to_string(stats_.images_unused) + " images no used material refers to: not converted");
        if (stats_.identity_placements > 0)
            decide(std::to_string(stats_.identity_placements) + " of " + std::to_string(stats_.placements) +
                   " placements have the identity transform: not applied");
        if (stats_.faces_fanned > 0)
            decide(std::to_string(stats_.faces_fanned) +
                   " polygon faces fanned, not ear-clipped (self-intersecting, collinear, or non-convex with more "
                   "than " + std::to_string(max_ear_clipped_corners) +
                   " corners): their triangles may cover more than the face; the first in " + first_fanned_);

        c.camera = camera_;
        c.lights = lights_;
        c.build(o_.bvh);
        stats_.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        c.statistics = std::move(stats_);
        return c;
    }

private:
    struct prototype {
        std::string name;
        std::vector<item> meshes; // in the subtree's frame, deeper nesting flattened
        bool done = false;
    };

    void decide(std::string line) { stats_.decisions.push_back(std::move(line)); }

    std::uint32_t compiled_mesh_of(std::uint32_t source) {
        return mesh_map_.try_emplace(source, std::uint32_t(mesh_map_.size())).first->second;
    }

    // Places scene mesh `source` (its compiled index is assigned on first use).
    void add_placement(std::vector<placement>& out, item const& m) {
        out.push_back({compiled_mesh_of(m.mesh), m.where.rounded(), m.id});
        ++stats_.placements;
        if (out.back().transform.is_identity()) ++stats_.identity_placements;
    }

    // Depth-first walk from `n`; top = whether cameras and lights here belong to the scene.
    void walk(node_id n, frame const& where, std::vector<item>& found, bool top) {
        node const& nd = s_.at(n);
        switch (nd.kind) {
        case node_kind::group:
        case node_kind::custom:
            if (nd.kind == node_kind::custom && nd.children.empty())
                throw scene_error(nd.source.empty() ? o_.name : nd.source, node_label(s_, n),
                                  "custom node of type '" + nd.custom_type + "' was not expanded (no plugin registry given)");
            for (node_id c : nd.children) walk(c, where, found, top);
            break;
        case node_kind::transform:
            if (nd.transform.is_identity()) ++stats_.identity_transform_nodes;
            for (node_id c : nd.children) walk(c, where.then(nd.transform), found, top);
            break;
        case node_kind::mesh:
            if (s_.meshes()[nd.mesh].triangles.empty()) {
                empty_meshes_.insert(nd.mesh);
                break;
            }
            found.push_back({nd.mesh, no_node, where, invalid_id});
            break;
        case node_kind::instance:
            found.push_back({0, nd.target, where.then(nd.transform), nd.instance_id});
            break;
        case node_kind::camera:
            ++stats_.cameras;
            if (top && !camera_) {
                camera_data c = nd.camera;
                if (!where.identity) {
                    auto const xf = where.xf;
                    c.eye = vec3<float>(xf.transform_point(vec3<double>(c.eye)));
                    c.target = vec3<float>(xf.transform_point(vec3<double>(c.target)));
                    c.up = vec3<float>(xf.transform_vector(vec3<double>(c.up)));
                }
                camera_ = c;
            }
            break;
        case node_kind::light:
            ++stats_.lights;
            if (top) {
                light_data l = nd.light;
                if (!where.identity) {
                    l.position = vec3<float>(where.xf.transform_point(vec3<double>(l.position)));
                    l.direction = vec3<float>(normalize(where.xf.transform_vector(vec3<double>(l.direction))));
                }
                lights_.push_back(l);
            }
            break;
        }
    }

    prototype const& prototype_of(node_id target) {
        auto& p = protos_[target];
        if (p.done) return p;
        p.name = s_.at(target).name;
        std::vector<item> found;
        walk(target, frame{}, found, false);
        std::vector<item> meshes;
        for (auto const& st : found) {
            if (st.target == no_node) {
                meshes.push_back(st);
                continue;
            }
            prototype const& inner = prototype_of(st.target);
            if (inner.meshes.empty()) ++stats_.subtrees_empty;
            for (auto const& m : inner.meshes) {
                meshes.push_back({m.mesh, no_node, st.where.then(m.where), inner.meshes.size() == 1 ? st.id : m.id});
                if (inner.meshes.size() > 1) ++stats_.flattened_placements;
            }
        }
        auto& q = protos_[target]; // (re-fetch: the map may not move, but keep it obvious)
        q.meshes = std::move(meshes);
        q.done = true;
        return q;
    }

    std::uint32_t group_of(node_id target) {
        auto [it, fresh] = group_index_.try_emplace(target, std::uint32_t(group_protos_.size()));
        if (fresh) {
            prototype const& p = prototype_of(target);
            group_protos_.push_back({p.name.empty() ? node_label(s_, target) : p.name, p.meshes, true});
        }
        return it->second;
    }

    // Children and instance targets must form no cycle: colour-marking depth-first search.
    void check_cycles() const {
        std::vector<std::uint8_t> colour(s_.nodes().size(), 0); // 0 new, 1 on the path, 2 done
        std::vector<node_id> path;
        std::vector<std::pair<node_id, std::size_t>> stack;     // (node, next edge)
        auto const edges = [&](node_id n) {
            std::vector<node_id> e = s_.at(n).children;
            if (s_.at(n).kind == node_kind::instance) e.push_back(s_.at(n).target);
            return e;
        };
        for (node_id start = 0; start < s_.nodes().size(); ++start) {
            if (colour[start] != 0) continue;
            stack.push_back({start, 0});
            colour[start] = 1;
            path.push_back(start);
            while (!stack.empty()) {
                auto& [n, next] = stack.back();
                auto const e = edges(n);
                if (next == e.size()) {
                    colour[n] = 2;
                    path.pop_back();
                    stack.pop_back();
                    continue;
                }
                node_id const m = e[next++];
                if (colour[m] == 1) {
                    std::string cycle;
                    auto const from = std::find(path.begin(), path.end(), m);
                    for (auto it = from; it != path.end(); ++it) cycle += node_label(s_, *it) + " → ";
                    cycle += node_label(s_, m);
                    throw scene_error(o_.name, "", "instance cycle: " + cycle);
                }
                if (colour[m] == 0) {
                    colour[m] = 1;
                    path.push_back(m);
                    stack.push_back({m, 0});
                }
            }
        }
    }

    scene const& s_;
    compile_options const& o_;
    compile_statistics stats_;
    std::string first_fanned_; // where the first fanned face of a built mesh is
    std::map<node_id, prototype> protos_;
    std::map<node_id, std::uint32_t> group_index_;
    std::vector<prototype> group_protos_;
    std::map<std::uint32_t, std::uint32_t> mesh_map_; // scene mesh → compiled mesh
    std::set<std::uint32_t> empty_meshes_;
    std::size_t direct_single_mesh_ = 0;
    std::optional<camera_data> camera_;
    std::vector<light_data> lights_;
};

} // namespace

compiled_scene compile(scene const& s, compile_options const& options) {
    bool has_custom = false;
    for (auto const& n : s.nodes()) has_custom |= n.kind == node_kind::custom;
    if (has_custom && options.plugins != nullptr) {
        scene expanded = s;
        std::size_t const before = expanded.nodes().size();
        options.plugins->expand_custom_nodes(expanded);
        compiled_scene c = compiler(expanded, options).run();
        std::size_t custom = 0;
        for (auto const& n : s.nodes()) custom += n.kind == node_kind::custom;
        c.statistics.custom_nodes_expanded = custom;
        c.statistics.decisions.push_back(std::to_string(custom) + " custom nodes expanded by their plugins (" +
                                         std::to_string(expanded.nodes().size() - before) + " nodes made)");
        return c;
    }
    return compiler(s, options).run();
}

} // namespace canopy
