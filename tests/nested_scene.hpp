// A random three-level instanced scene shared by the intersector and query tests: two triangle
// soups and their BVHs, eight instances of them (ids 10 + k) in a two-level BVH, and three
// instances of that (ids 100 + j) in a three-level BVH. The same seed gives the same scene.
//
// Include it after random_support.hpp, in a test file that imports canopy.query.
#pragma once

namespace test_support {

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

} // namespace test_support
