// canopy.testing:nested — a random three-level instanced scene shared by the intersector, query
// and stress tests: two triangle soups and their BVHs, eight instances of them (ids 10 + k) in a
// two-level BVH, and three instances of that (ids 100 + j) in a three-level BVH. The same seed
// gives the same scene. Also the brute-force hits of a ray on instances of one mesh.
module;
#include <algorithm>
#include <cstdint>
#include <tuple>
#include <vector>
export module canopy.testing:nested;
import canopy.query;
import :random;

export namespace test_support {

using mesh_bvh = canopy::bvh<canopy::triangle>;
using mesh_instance = canopy::instance<mesh_bvh>;
using two_level = canopy::bvh<mesh_instance>;
using two_level_instance = canopy::instance<two_level>;
using three_level = canopy::bvh<two_level_instance>;

struct nested_scene {
    std::vector<std::vector<canopy::triangle>> soups;
    std::vector<mesh_bvh> meshes;
    std::vector<mesh_instance> level1;
    two_level middle;
    std::vector<two_level_instance> level2;
    three_level top;

    explicit nested_scene(std::uint32_t seed) {
        random_source rng(seed);
        soups.push_back(triangle_soup(rng, 150, 1.0f, 0.4f));
        soups.push_back(triangle_soup(rng, 120, 1.0f, 0.4f));
        for (auto const& soup : soups) meshes.push_back(canopy::build_binned_sah(soup));
        for (std::uint32_t k = 0; k < 8; ++k) level1.emplace_back(meshes[k % 2], random_transform(rng, 4.0f), 10 + k);
        middle = canopy::build_binned_sah(level1);
        for (std::uint32_t j = 0; j < 3; ++j) level2.emplace_back(middle, random_transform(rng, 6.0f), 100 + j);
        top = canopy::build_binned_sah(level2);
    }
    // Instances point into this object: no copies.
    nested_scene(nested_scene const&) = delete;
    nested_scene& operator=(nested_scene const&) = delete;
};

// The hits of a plain loop over every instance and triangle, each instance's ray taken into object
// space with the instance's own stored inverse (as traversal does), sorted by (t, inst_id,
// prim_id).
inline std::vector<canopy::hit_record<canopy::ray, canopy::triangle>> instanced_brute_force_hits(
    canopy::ray const& r, std::vector<mesh_instance> const& instances, std::vector<canopy::triangle> const& mesh) {
    std::vector<canopy::hit_record<canopy::ray, canopy::triangle>> hits;
    for (mesh_instance const& inst : instances) {
        canopy::ray local = r;
        if (!inst.identity) {
            local.origin = inst.world_to_object.transform_point(r.origin);
            local.direction = inst.world_to_object.transform_vector(r.direction);
        }
        for (canopy::triangle const& tri : mesh) {
            auto h = canopy::intersect(local, tri);
            if (!h.hit) continue;
            h.inst_id = inst.inst_id;
            hits.push_back(h);
        }
    }
    std::sort(hits.begin(), hits.end(), [](auto const& a, auto const& b) {
        return std::tuple(a.t, a.inst_id, a.prim_id) < std::tuple(b.t, b.inst_id, b.prim_id);
    });
    return hits;
}

} // namespace test_support
