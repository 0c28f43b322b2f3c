// canopy.scene:compile — scene graph → compiled_scene, skipping what the scene does not need.
//
//   compiled_scene c = compile(s, {.plugins = &registry});
//   for (auto const& line : c.statistics.decisions) std::puts(line.c_str());
//
// Rules, each counted in compile_statistics and stated in its decisions list:
//   - every mesh is built once, however often it is placed; meshes no node reaches are not built,
//     images no used material refers to are not converted;
//   - a scene that is one mesh with an identity transform gets no top-level BVH (levels 0), unless
//     an instance node placed it and compile_options::keep_single_instance asks to keep it
//     (levels 1: hits then report inst_id 0, as the bench formats' `inst` field requires);
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
//   - custom nodes are expanded by the plugins that registered their types;
//   - mesh BVHs are built at compile_options::bvh.quality (automatic unless asked: spatial splits
//     for meshes of long thin triangles; fast: never; high: always), stated in the decisions
//     (automatic: how many meshes it split) and kept in compile_statistics::quality with the
//     time the mesh builds took; each compiled_mesh's accel.quality is the quality it used.
// Placements keep the order of the graph (depth first, children in order), so the inst_id of a
// hit is the index of its placement in that order; placement::id keeps the instance node's own id.
//
// Hostile graphs. Nothing here recurses: every walk keeps its own stack, so a chain of 10^5
// nodes or instances costs memory in proportion, not stack frames. The work is linear in the
// graph plus the placements made (a node with 10^6 children, or 10^6 instances of one prototype,
// is one pass; chains of single-child nodes are composed once and reused). Before anything is
// allocated, counts are taken with saturating arithmetic and checked against
// compile_options::limits (resource_limits):
//   - depth: a node more than max_depth child or instance links below the root is refused, naming
//     that node (--max-depth);
//   - placements: the placements of each group after flattening, and of the whole scene, over
//     max_placements are refused, naming the group's node (--max-placements); so are more than
//     max_placements meshes, instances, cameras and lights at the top level (children shared by
//     several parents are counted once per path).
// Running out of memory all the same is reported as a scene_error naming the scene.
//
// Errors (scene_error, naming the file — the node's source, else compile_options::name — and the
// node): instance cycles (the message lists the nodes on the cycle), custom nodes of an
// unregistered type, children or targets that do not exist, the limits above, a transform or
// instance node whose transform is not finite or cannot be inverted in float, a placement whose
// composed transform (in double, then rounded) is not finite, cannot be inverted in float or puts
// the mesh's bounds outside float range, a camera or light placed where it is not finite, and a
// scene with nothing to trace.
module;
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <new>
#include <optional>
#include <set>
#include <stdexcept>
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
    bvh_build_options bvh{};           // the builder's options; bvh.quality: automatic (default), fast or high
    std::string name{};                // how errors name the scene (usually its file)
    resource_limits limits = default_limits(); // placements after flattening, nesting depth
    // A scene that is one identity instance of one mesh keeps its top level (levels 1, a BVH over
    // that instance), so that hits report the instance's inst_id (0) rather than none: what the
    // bench formats (`canopy trace`) require. A mesh placed without an instance node is still
    // traced directly (levels 0), as is everything when this is off (the default).
    bool keep_single_instance = false;
};


compiled_scene compile(scene const& s, compile_options const& options = {});

} // namespace canopy

namespace canopy {

namespace {

// Transforms composed in double (canopy.math's convert: widened exactly, rounded to float once).
using xf64 = affine_transform<double>;

// A double value that stays finite once rounded to float.
bool finite_in_float(vec3<double> v) { return all_finite(vec3<float>(v)); }

std::uint64_t saturating_add(std::uint64_t a, std::uint64_t b) {
    return a > std::numeric_limits<std::uint64_t>::max() - b ? std::numeric_limits<std::uint64_t>::max() : a + b;
}

// check_limit, for counts taken with saturating_add: one that saturated says so.
void check_count(std::string const& file, std::string const& where, std::uint64_t count, std::uint64_t limit,
                 char const* what, char const* option) {
    if (count == std::numeric_limits<std::uint64_t>::max() && count > limit)
        throw scene_error(file, where,
                          "at least " + std::to_string(count) + " " + what + " exceed the limit of " + std::to_string(limit) +
                              " (" + option + ")");
    check_limit(file, where, count, limit, what, option);
}

// A transform on the way down: `identity` is exact (no product was ever taken).
struct frame {
    xf64 xf = xf64::identity();
    bool identity = true;

    frame then(affine_transform<float> const& local) const {
        if (local.is_identity()) return *this;
        if (identity) return {convert<double>(local), false};
        return {xf * convert<double>(local), false};
    }
    frame then(frame const& inner) const {
        if (inner.identity) return *this;
        if (identity) return inner;
        return {xf * inner.xf, false};
    }
    affine_transform<float> rounded() const { return identity ? affine_transform<float>::identity() : convert<float>(xf); }
};

// Bounds in double (empty: lo > hi).
struct box64 {
    vec3<double> lo{std::numeric_limits<double>::infinity()};
    vec3<double> hi{-std::numeric_limits<double>::infinity()};

    void add(vec3<double> p) {
        lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
        hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
    }
    bool empty() const { return lo.x > hi.x; }
    // The box of the eight corners mapped by xf.
    box64 mapped(xf64 const& xf) const {
        box64 out;
        if (empty()) return out;
        for (int k = 0; k < 8; ++k)
            out.add(xf.transform_point(vec3<double>((k & 1) ? hi.x : lo.x, (k & 2) ? hi.y : lo.y, (k & 4) ? hi.z : lo.z)));
        return out;
    }
    bool finite_in_float() const { return empty() || (canopy::finite_in_float(lo) && canopy::finite_in_float(hi)); }
};

std::string node_label(scene const& s, node_id n) {
    node const& nd = s.at(n);
    return std::string(to_string(nd.kind)) + (nd.name.empty() ? " #" + std::to_string(n) : " '" + nd.name + "'");
}

// Whether a node's children are walked (the other kinds are leaves, or an instance's one link).
bool has_children(node const& nd) {
    return nd.kind == node_kind::group || nd.kind == node_kind::transform || nd.kind == node_kind::custom;
}

inline constexpr std::uint32_t no_slot = ~std::uint32_t(0);

class compiler {
public:
    compiler(scene const& s, compile_options const& o) : s_(s), o_(o), nodes_(s.nodes()) {}

    compiled_scene run() {
        auto const start = std::chrono::steady_clock::now();
        stats_.nodes = nodes_.size();
        stats_.meshes_in_scene = s_.meshes().size();
        order_nodes();
        check_depth();
        scan();
        top_.build(*this, false);
        full_.build(*this, true);
        for (node_id n : reachable_)
            if (nodes_[n].kind == node_kind::instance && full_.count[nodes_[n].target] == 0) ++stats_.subtrees_empty;

        // The top level, in graph order: meshes reached through children alone, and instances —
        // of one mesh: placed directly; of several: a group (made below, once per subtree).
        check_count(o_.name, "", top_.count[s_.root()], o_.limits.max_placements,
                    "meshes, instances, cameras and lights at the top level", "--max-placements");
        struct group_item {
            std::uint32_t group;
            frame where;
            std::uint32_t id;
            node_id node;
        };
        std::vector<group_item> groups_placed;
        std::vector<placement> loose; // placement::index is the scene's mesh until renumbered
        bool placed_by_instance = false; // loose[0] was placed by an instance node
        expand(top_, s_.root(), frame{}, [&](node_id leaf, frame const& where, std::uint32_t, bool) {
            node const& nd = nodes_[leaf];
            switch (nd.kind) {
            case node_kind::mesh: loose.push_back(make_placement(leaf, where, invalid_id, no_node, nullptr)); break;
            case node_kind::instance: {
                if (full_.count[nd.target] == 0) break;
                frame const at = compose(where, nd.transform, leaf);
                if (full_.count[nd.target] == 1) {
                    expand(full_, nd.target, at, [&](node_id mesh, frame const& placed, std::uint32_t, bool) {
                        loose.push_back(make_placement(mesh, placed, nd.instance_id, leaf, nullptr));
                    });
                    ++direct_single_mesh_;
                    placed_by_instance = loose.size() == 1;
                } else {
                    groups_placed.push_back({group_of(nd.target), at, nd.instance_id, leaf});
                }
                break;
            }
            case node_kind::camera: place_camera(leaf, where); break;
            case node_kind::light: place_light(leaf, where); break;
            default: break;
            }
        });

        // Every group's placements after flattening, then the scene's, before any is made.
        std::uint64_t placements = loose.size();
        for (node_id t : group_targets_) {
            check_count(file_of(t), node_label(s_, t), full_.count[t], o_.limits.max_placements,
                        "placements after flattening", "--max-placements");
            placements = saturating_add(placements, full_.count[t]);
        }
        check_count(o_.name, "", placements, o_.limits.max_placements, "placements after flattening", "--max-placements");
        for (node_id t : group_targets_) {
            prototype g{nodes_[t].name.empty() ? node_label(s_, t) : nodes_[t].name, t, {}, {}};
            g.placements.reserve(std::size_t(full_.count[t]));
            expand(full_, t, frame{}, [&](node_id mesh, frame const& where, std::uint32_t id, bool nested) {
                g.placements.push_back(make_placement(mesh, where, id, no_node, &g));
                if (nested) ++stats_.flattened_placements;
            });
            group_protos_.push_back(std::move(g));
        }

        if (loose.empty() && groups_placed.empty())
            throw scene_error(o_.name, "", "the scene has nothing to trace (no mesh with triangles is placed in it)");

        // Meshes: only those placed, numbered in order of first use.
        for (auto& p : loose) p.index = compiled_mesh_of(p.index);
        for (auto& g : group_protos_)
            for (auto& p : g.placements) p.index = compiled_mesh_of(p.index);

        // Levels and placements.
        compiled_scene c;
        if (groups_placed.empty()) {
            if (loose.size() == 1 && loose[0].transform.is_identity() && !(o_.keep_single_instance && placed_by_instance)) {
                c.levels = 0;
                decide("one mesh with an identity transform: traced directly, no top-level BVH (levels 0)");
            } else if (loose.size() == 1 && loose[0].transform.is_identity()) {
                c.levels = 1;
                c.top_meshes = std::move(loose);
                decide("one identity instance of one mesh: top-level BVH kept, so that hits report its inst_id "
                       "(keep_single_instance; levels 1)");
            } else {
                c.levels = 1;
                c.top_meshes = std::move(loose);
                decide("top-level BVH over " + std::to_string(c.top_meshes.size()) + " mesh placements (levels 1)");
            }
        } else if (groups_placed.size() == 1 && loose.empty() && groups_placed[0].where.identity) {
            c.levels = 1;
            c.top_meshes = std::move(group_protos_[groups_placed[0].group].placements);
            decide("one untransformed subtree: its placements form the top level (levels 1)");
        } else {
            c.levels = 2;
            for (auto& g : group_protos_) {
                compiled_group cg;
                cg.name = g.name;
                cg.placements = std::move(g.placements);
                c.groups.push_back(std::move(cg));
            }
            for (auto const& [g, where, id, node] : groups_placed) {
                check_group_instance(node, where, group_protos_[g].bounds);
                c.top_groups.push_back({g, where.rounded(), id});
                ++stats_.group_instances;
            }
            if (!loose.empty()) {
                // Meshes placed outside any multi-mesh subtree share one extra group, placed
                // with the identity (the traversal reuses the ray: no transform is applied).
                compiled_group extra;
                extra.name = "(meshes outside instanced subtrees)";
                std::size_t const count = loose.size();
                extra.placements = std::move(loose);
                c.top_groups.push_back({std::uint32_t(c.groups.size()), affine_transform<float>::identity(), invalid_id});
                c.groups.push_back(std::move(extra));
                decide(std::to_string(count) +
                       " mesh placements outside instanced subtrees: one extra group, placed with the identity");
            }
            decide("top-level BVH over " + std::to_string(c.top_groups.size()) + " instances of " +
                   std::to_string(c.groups.size()) + " groups (levels 2)");
        }
        group_protos_ = {};
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
            c.materials.push_back({.colour = md.colour, .alpha = md.alpha, .alpha_cutoff = md.alpha_cutoff});
        }
        stats_.materials = s_.materials().size();
        std::vector<bool> material_used(c.materials.size(), false);
        c.meshes.resize(meshes_built_);
        for (std::uint32_t source = 0; source < compiled_index_.size(); ++source) {
            std::uint32_t const index = compiled_index_[source];
            if (index == no_slot) continue;
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
        // Triangles in the world: every placement at every level (a group's sum taken once).
        auto const triangles_of = [&](std::vector<placement> const& ps) {
            std::uint64_t n = 0;
            for (auto const& p : ps) n = saturating_add(n, c.meshes[p.index].triangles.size());
            return n;
        };
        std::uint64_t placed = 0;
        if (c.levels == 0) placed = c.meshes[0].triangles.size();
        if (c.levels == 1) placed = triangles_of(c.top_meshes);
        std::vector<std::uint64_t> group_triangles;
        for (auto const& g : c.groups) group_triangles.push_back(triangles_of(g.placements));
        for (auto const& g : c.top_groups) placed = saturating_add(placed, group_triangles[g.index]);
        stats_.triangles_placed = std::size_t(std::min<std::uint64_t>(placed, std::numeric_limits<std::size_t>::max()));
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
            if (c.materials[i].alpha == alpha_mode::mask) {
                if (c.materials[i].texture < 0) c.materials[i].alpha = alpha_mode::opaque; // nothing to mask by
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
        c.camera_file = camera_file_;
        c.camera_node = camera_node_;
        c.lights = lights_;
        stats_.quality = o_.bvh.quality;
        c.build(o_.bvh);
        if (o_.bvh.quality == build_quality::automatic) {
            std::size_t high = 0;
            for (auto const& m : c.meshes) high += m.accel.quality == build_quality::high ? 1 : 0;
            decide("mesh BVHs built at quality automatic (the default): " + std::to_string(high) + " of " +
                   std::to_string(c.meshes.size()) +
                   " with spatial splits (long thin triangles hold at least 5 % of their box area), the others fast");
        } else {
            decide(o_.bvh.quality == build_quality::high
                       ? "mesh BVHs built at quality high: object and spatial splits (long thin triangles split between leaves)"
                       : "mesh BVHs built at quality fast: object splits only");
        }
        for (auto const& m : c.meshes) stats_.mesh_build_seconds += m.build_seconds;
        stats_.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        c.statistics = std::move(stats_);
        return c;
    }

private:
    // A subtree placed as a group: its placements in its own frame, deeper nesting flattened.
    struct prototype {
        std::string name;
        node_id node;
        std::vector<placement> placements;
        box64 bounds; // of the placed meshes, in the subtree's frame
    };

    // From a node down the only way on to the first leaf or fork (a node with several ways on):
    // the transforms on the way composed, and the id of the outermost instance of a single mesh.
    struct jump {
        node_id end;
        frame where;
        std::uint32_t id = invalid_id;
        bool nested = false; // passes through an instance of a multi-mesh subtree
    };

    // The graph as one kind of walk sees it. full: through children and instance targets down to
    // meshes with triangles (what a group holds once flattened). top: through children alone;
    // meshes, instances, cameras and lights are its leaves. Per node: how many leaves lie below
    // (paths counted, saturating), the links that lead to any (in order), and jumps, made lazily.
    struct reach {
        std::vector<std::uint64_t> count;
        std::vector<std::size_t> first;  // into ways
        std::vector<std::uint32_t> ways_of;
        std::vector<node_id> ways;
        std::vector<std::uint32_t> jump_slot;
        std::vector<jump> jumps;

        void build(compiler const& c, bool full) {
            std::size_t const n = c.nodes_.size();
            count.assign(n, 0);
            first.assign(n, 0);
            ways_of.assign(n, 0);
            jump_slot.assign(n, no_slot);
            ways.clear();
            jumps.clear();
            for (node_id v : c.order_) {
                node const& nd = c.nodes_[v];
                if (c.is_leaf(nd, full)) {
                    count[v] = 1;
                    continue;
                }
                first[v] = ways.size();
                auto const link = [&](node_id w) {
                    if (count[w] == 0) return;
                    ways.push_back(w);
                    count[v] = saturating_add(count[v], count[w]);
                };
                if (has_children(nd))
                    for (node_id w : nd.children) link(w);
                else if (nd.kind == node_kind::instance && full)
                    link(nd.target);
                ways_of[v] = std::uint32_t(ways.size() - first[v]);
            }
        }
    };

    bool is_leaf(node const& nd, bool full) const {
        switch (nd.kind) {
        case node_kind::mesh: return nd.mesh < s_.meshes().size() && !s_.meshes()[nd.mesh].triangles.empty();
        case node_kind::instance:
        case node_kind::camera:
        case node_kind::light: return !full;
        default: return false;
        }
    }

    std::string const& file_of(node_id n) const { return nodes_[n].source.empty() ? o_.name : nodes_[n].source; }

    [[noreturn]] void fail(node_id n, std::string const& problem) const {
        throw scene_error(file_of(n), node_label(s_, n), problem);
    }

    // outer ∘ inner, refused (naming `at`) when a value leaves double range.
    frame compose(frame const& outer, frame const& inner, node_id at) const {
        frame const f = outer.then(inner);
        if (!f.identity && !all_finite(f.xf)) fail(at, "the transforms composed through it leave double range (a value is not finite)");
        return f;
    }
    frame compose(frame const& outer, affine_transform<float> const& local, node_id at) const {
        frame const f = outer.then(local);
        if (!f.identity && !all_finite(f.xf)) fail(at, "the transforms composed through it leave double range (a value is not finite)");
        return f;
    }

    // The transform a fork applies to all its children.
    frame below(node_id fork, frame const& where) const {
        node const& nd = nodes_[fork];
        return nd.kind == node_kind::transform ? compose(where, nd.transform, fork) : where;
    }

    jump jump_of(reach& r, node_id v) {
        if (r.ways_of[v] != 1) return {v, frame{}, invalid_id, false};
        if (r.jump_slot[v] != no_slot) return r.jumps[r.jump_slot[v]];
        // Down the chain to a node that is not a link of one, or one already known; then back up.
        std::vector<node_id> chain;
        node_id u = v;
        while (r.ways_of[u] == 1 && r.jump_slot[u] == no_slot) {
            chain.push_back(u);
            u = r.ways[r.first[u]];
        }
        jump inner = r.ways_of[u] == 1 ? r.jumps[r.jump_slot[u]] : jump{u, frame{}, invalid_id, false};
        for (auto it = chain.rbegin(); it != chain.rend(); ++it) {
            node const& nd = nodes_[*it];
            jump j = inner;
            if (nd.kind == node_kind::transform || nd.kind == node_kind::instance)
                j.where = compose(frame{}.then(nd.transform), inner.where, *it);
            if (nd.kind == node_kind::instance) {
                if (r.count[*it] == 1) j.id = nd.instance_id;
                else j.nested = true;
            }
            r.jump_slot[*it] = std::uint32_t(r.jumps.size());
            r.jumps.push_back(j);
            inner = j;
        }
        return inner;
    }

    // Calls leaf(node, frame, id, nested) for every leaf of `r` below `start`, depth first,
    // children in order; `base` places start. Each call costs O(1) amortised: chains of single
    // links are crossed by their jumps, links without leaves are not kept.
    template <typename Leaf>
    void expand(reach& r, node_id start, frame const& base, Leaf&& leaf) {
        if (r.count[start] == 0) return;
        jump const j = jump_of(r, start);
        frame const at = compose(base, j.where, start);
        if (r.count[start] == 1) {
            leaf(j.end, at, j.id, j.nested);
            return;
        }
        struct entry {
            node_id fork;
            frame where; // of the fork's children
            std::uint32_t next;
            bool nested;
        };
        std::vector<entry> stack;
        stack.push_back({j.end, below(j.end, at), 0, j.nested});
        while (!stack.empty()) {
            entry& e = stack.back();
            if (e.next == r.ways_of[e.fork]) {
                stack.pop_back();
                continue;
            }
            node_id const c = r.ways[r.first[e.fork] + e.next++];
            jump const jc = jump_of(r, c);
            frame const where = compose(e.where, jc.where, c);
            bool const nested = e.nested || jc.nested;
            if (r.count[c] == 1) leaf(jc.end, where, jc.id, nested);
            else stack.push_back({jc.end, below(jc.end, where), 0, nested});
        }
    }

    void decide(std::string line) { stats_.decisions.push_back(std::move(line)); }

    std::uint32_t compiled_mesh_of(std::uint32_t source) {
        if (compiled_index_.empty()) compiled_index_.assign(s_.meshes().size(), no_slot);
        if (compiled_index_[source] == no_slot) compiled_index_[source] = meshes_built_++;
        return compiled_index_[source];
    }

    std::uint32_t group_of(node_id target) {
        auto [it, fresh] = group_index_.try_emplace(target, std::uint32_t(group_targets_.size()));
        if (fresh) group_targets_.push_back(target);
        return it->second;
    }

    box64 const& mesh_bounds(std::uint32_t mesh) {
        if (mesh_bounds_.empty()) mesh_bounds_.resize(s_.meshes().size());
        auto& b = mesh_bounds_[mesh];
        if (!b) {
            b.emplace();
            mesh_data const& md = s_.meshes()[mesh];
            for (auto const& t : md.triangles)
                for (std::uint32_t v : t) b->add(vec3<double>(md.positions[v]));
        }
        return *b;
    }

    // Where a placement is named: its mesh node, the group it is in, the instance that placed it.
    std::string placement_label(node_id mesh, node_id placed_by, prototype const* in) const {
        std::string where = node_label(s_, mesh);
        if (in != nullptr) where += " in " + node_label(s_, in->node);
        if (placed_by != no_node) where += " placed by " + node_label(s_, placed_by);
        return where;
    }

    // The placement of mesh node `mesh` (placement::index: the scene's mesh), counted; in a group,
    // its bounds are added to the group's. A placement that does not survive rounding to float is
    // refused by name.
    placement make_placement(node_id mesh, frame const& where, std::uint32_t id, node_id placed_by, prototype* in) {
        std::uint32_t const source = nodes_[mesh].mesh;
        placement const p{source, where.rounded(), id};
        ++stats_.placements;
        box64 bounds;
        if (p.transform.is_identity()) {
            ++stats_.identity_placements;
            bounds = mesh_bounds(source);
        } else {
            if (char const* problem = transform_problem(p.transform))
                throw scene_error(file_of(mesh), placement_label(mesh, placed_by, in),
                                  std::string("the transforms above it, composed and rounded to float: ") + problem);
            bounds = mesh_bounds(source).mapped(convert<double>(p.transform));
            if (!bounds.finite_in_float())
                throw scene_error(file_of(mesh), placement_label(mesh, placed_by, in),
                                  "placed by the transforms above it, its bounds are not finite in float");
        }
        if (in != nullptr && !bounds.empty()) {
            in->bounds.add(bounds.lo);
            in->bounds.add(bounds.hi);
        }
        return p;
    }

    void check_group_instance(node_id instance, frame const& where, box64 const& bounds) const {
        if (where.identity) return;
        affine_transform<float> const xf = where.rounded();
        if (char const* problem = transform_problem(xf))
            fail(instance, std::string("the transforms above it, composed and rounded to float: ") + problem);
        if (!bounds.mapped(convert<double>(xf)).finite_in_float())
            fail(instance, "placed by the transforms above it, the bounds of its subtree are not finite in float");
    }

    void place_camera(node_id n, frame const& where) {
        if (camera_) return;
        camera_data c = nodes_[n].camera;
        if (!where.identity) {
            vec3<double> const eye = where.xf.transform_point(vec3<double>(c.eye));
            vec3<double> const target = where.xf.transform_point(vec3<double>(c.target));
            vec3<double> const up = where.xf.transform_vector(vec3<double>(c.up));
            if (!finite_in_float(eye) || !finite_in_float(target) || !finite_in_float(up))
                fail(n, "placed by the transforms above it, the camera's eye, target or up is not finite in float");
            c.eye = vec3<float>(eye);
            c.target = vec3<float>(target);
            c.up = vec3<float>(up);
        }
        if (!all_finite(c.eye) || !all_finite(c.target) || !all_finite(c.up)) fail(n, "the camera's eye, target or up is not finite");
        if (c.eye.x == c.target.x && c.eye.y == c.target.y && c.eye.z == c.target.z)
            fail(n, "placed by the transforms above it, the camera's eye and target coincide in float");
        camera_ = c;
        camera_file_ = file_of(n);
        camera_node_ = node_label(s_, n);
    }

    void place_light(node_id n, frame const& where) {
        light_data l = nodes_[n].light;
        if (!where.identity) {
            vec3<double> const position = where.xf.transform_point(vec3<double>(l.position));
            vec3<double> const direction = where.xf.transform_vector(vec3<double>(l.direction));
            double const length = std::sqrt(dot(direction, direction));
            if (!finite_in_float(position) || !(length > 0.0) || !std::isfinite(length))
                fail(n, "placed by the transforms above it, the light's position or direction is not finite in float");
            l.position = vec3<float>(position);
            l.direction = vec3<float>(direction / length);
        }
        if (!all_finite(l.position) || !all_finite(l.direction) || !all_finite(l.colour)) fail(n, "the light has a value that is not finite");
        lights_.push_back(l);
    }

    // Children and instance targets must exist and form no cycle: colour-marking depth-first
    // search over every node, with its own stack. Leaves order_ children before parents.
    void order_nodes() {
        std::size_t const n = nodes_.size();
        std::vector<std::uint8_t> colour(n, 0); // 0 new, 1 on the path, 2 done
        order_.reserve(n);
        auto const degree = [&](node_id v) {
            return nodes_[v].children.size() + (nodes_[v].kind == node_kind::instance ? 1 : 0);
        };
        auto const link = [&](node_id v, std::size_t k) {
            node const& nd = nodes_[v];
            node_id const w = k < nd.children.size() ? nd.children[k] : nd.target;
            if (w >= n)
                fail(v, (k < nd.children.size() ? "child " : "instance target ") + std::to_string(w) + " does not exist");
            return w;
        };
        std::vector<std::pair<node_id, std::size_t>> stack; // (node, next link); also the path
        for (node_id start = 0; start < n; ++start) {
            if (colour[start] != 0) continue;
            stack.push_back({start, 0});
            colour[start] = 1;
            while (!stack.empty()) {
                auto& [v, next] = stack.back();
                if (next == degree(v)) {
                    colour[v] = 2;
                    order_.push_back(v);
                    stack.pop_back();
                    continue;
                }
                node_id const w = link(v, next++);
                if (colour[w] == 1) {
                    std::string cycle;
                    auto const from = std::find_if(stack.begin(), stack.end(), [&](auto const& e) { return e.first == w; });
                    for (auto it = from; it != stack.end(); ++it) cycle += node_label(s_, it->first) + " → ";
                    cycle += node_label(s_, w);
                    throw scene_error(o_.name, "", "instance cycle: " + cycle);
                }
                if (colour[w] == 0) {
                    colour[w] = 1;
                    stack.push_back({w, 0});
                }
            }
        }
    }

    // The links walks follow: a group's, transform's or custom node's children, an instance's target.
    template <typename F>
    void for_each_link(node const& nd, F&& f) const {
        if (has_children(nd))
            for (node_id w : nd.children) f(w);
        else if (nd.kind == node_kind::instance)
            f(nd.target);
    }

    // No node more than max_depth links below the root: heights (children before parents), then
    // down the deepest path to name the first node past the limit.
    void check_depth() const {
        std::vector<std::uint32_t> height(nodes_.size(), 0);
        for (node_id v : order_)
            for_each_link(nodes_[v], [&](node_id w) { height[v] = std::max(height[v], height[w] + 1); });
        std::uint64_t const depth = height[s_.root()];
        if (depth <= o_.limits.max_depth) return;
        node_id v = s_.root();
        for (std::uint64_t d = 0; d <= o_.limits.max_depth; ++d) {
            node_id next = v;
            for_each_link(nodes_[v], [&](node_id w) {
                if (next == v && height[w] + 1 == height[v]) next = w;
            });
            v = next;
        }
        check_limit(file_of(v), node_label(s_, v), depth, o_.limits.max_depth, "levels of nesting (children and instances)",
                    "--max-depth");
    }

    // Every node the root reaches, once: the checks on single nodes, and what is counted per node.
    void scan() {
        std::vector<bool> seen(nodes_.size(), false);
        std::vector<node_id> stack{s_.root()};
        seen[s_.root()] = true;
        while (!stack.empty()) {
            node_id const v = stack.back();
            stack.pop_back();
            reachable_.push_back(v);
            node const& nd = nodes_[v];
            switch (nd.kind) {
            case node_kind::custom:
                if (nd.children.empty())
                    fail(v, "custom node of type '" + nd.custom_type + "' was not expanded (no plugin registry given)");
                break;
            case node_kind::transform:
            case node_kind::instance:
                if (char const* problem = transform_problem(nd.transform)) fail(v, problem);
                if (nd.kind == node_kind::transform && nd.transform.is_identity()) ++stats_.identity_transform_nodes;
                break;
            case node_kind::mesh:
                if (nd.mesh >= s_.meshes().size()) fail(v, "mesh index " + std::to_string(nd.mesh) + " does not exist");
                if (s_.meshes()[nd.mesh].triangles.empty()) empty_meshes_.insert(nd.mesh);
                break;
            case node_kind::camera: ++stats_.cameras; break;
            case node_kind::light: ++stats_.lights; break;
            case node_kind::group: break;
            }
            for_each_link(nd, [&](node_id w) {
                if (!seen[w]) {
                    seen[w] = true;
                    stack.push_back(w);
                }
            });
        }
    }

    scene const& s_;
    compile_options const& o_;
    std::vector<node> const& nodes_;
    compile_statistics stats_;
    std::vector<node_id> order_;     // every node, children and targets before their parents
    std::vector<node_id> reachable_; // the nodes the root reaches
    reach top_, full_;
    std::string first_fanned_; // where the first fanned face of a built mesh is
    std::map<node_id, std::uint32_t> group_index_;
    std::vector<node_id> group_targets_;
    std::vector<prototype> group_protos_;
    std::vector<std::optional<box64>> mesh_bounds_;
    std::vector<std::uint32_t> compiled_index_; // scene mesh → compiled mesh, or no_slot
    std::uint32_t meshes_built_ = 0;
    std::set<std::uint32_t> empty_meshes_;
    std::size_t direct_single_mesh_ = 0;
    std::optional<camera_data> camera_;
    std::string camera_file_, camera_node_;
    std::vector<light_data> lights_;
};

compiled_scene compile_checked(scene const& s, compile_options const& options) {
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

} // namespace

compiled_scene compile(scene const& s, compile_options const& options) {
    try {
        return compile_checked(s, options);
    } catch (std::bad_alloc const&) {
        throw scene_error(options.name, "", "out of memory while compiling the scene (lower --max-placements or "
                                            "--max-triangles to be refused before allocating)");
    } catch (std::length_error const&) {
        throw scene_error(options.name, "", "out of memory while compiling the scene (a list grew past its maximum size)");
    }
}

} // namespace canopy
