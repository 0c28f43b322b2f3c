// scene_graph — the scene graph and its plugins: a JSON scene, a mesh file loaded once as a
// prototype and instanced, a generated sphere, compiled (printing each decision), then one ray.
//
//   canopy_scene_graph [SCENE.json] [MESH]   (defaults: examples/scenes/forest.json, the bunny of
//                                              glmark2-data)
#include <cstdio>
#include <exception>
#include <string>
import canopy.plugins;

int main(int argc, char** argv) {
    std::string const scene_file = argc > 1 ? argv[1] : CANOPY_SOURCE_DIR "/examples/scenes/forest.json";
    std::string const mesh_file = argc > 2 ? argv[2] : "/usr/share/glmark2/models/bunny.obj";
    try {
        canopy::registry& r = canopy::builtin_registry(); // built-ins + CANOPY_PLUGIN_PATH
        canopy::scene s = canopy::load_scene(scene_file, r);

        // A file loaded once, outside the tree (a prototype), placed twice by instance nodes.
        canopy::node_id const bunny = r.load(s, mesh_file, canopy::no_node);
        using affine = canopy::affine_transform<float>;
        s.add_instance(s.root(), bunny, affine::from_rows({20, 0, 0, 5, 0, 20, 0, -0.7f, 0, 0, 20, 6}), 7, "bunny 7");
        s.add_instance(s.root(), bunny, affine::from_rows({0, 0, 20, -5, 0, 20, 0, -0.7f, -20, 0, 0, 6}), 8, "bunny 8");
        // Procedural content from a generator, under a transform.
        canopy::node_id const up = s.add_transform(s.root(), affine::from_rows({1, 0, 0, 0, 0, 1, 0, 6, 0, 0, 1, 0}), "sky");
        r.generate(s, "sphere", {{"subdivisions", "4"}, {"radius", "0.5"}}, up);

        canopy::compiled_scene const c = canopy::compile(s, {.plugins = &r, .name = scene_file});
        auto const& st = c.statistics;
        std::printf("%zu triangles stored, %zu placed, %d instance levels, alpha mask %s\n", st.triangles_stored,
                    st.triangles_placed, st.levels, st.alpha_mask_needed ? "needed" : "not needed");
        for (auto const& d : st.decisions) std::printf("  - %s\n", d.c_str());

        // One ray down onto the first bunny, through the scene's texture alpha mask.
        canopy::texture_alpha_mask mask;
        mask.scene = &c;
        canopy::ray const down{{5.0f, 10.0f, 6.0f}, 0.0f, {0.0f, -1.0f, 0.0f}, 100.0f};
        auto const hit = c.closest_hit(down, mask);
        std::printf("ray down at (5, 6): hit=%d t=%g mesh '%s' instance id %u\n", int(hit.hit), double(hit.t),
                    hit.hit ? c.meshes[hit.geom_id].name.c_str() : "-", hit.hit ? c.instance_id(hit) : 0u);
        return hit.hit ? 0 : 1;
    } catch (std::exception const& e) {
        std::fprintf(stderr, "scene_graph: %s\n", e.what());
        return 1;
    }
}
