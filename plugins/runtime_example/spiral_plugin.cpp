// canopy_plugin_spiral — an example of a plugin loaded at run time (a shared library), not built
// into any program: registry::load_plugin("canopy_plugin_spiral.so"), or list it (or its folder)
// in CANOPY_PLUGIN_PATH for builtin_registry().
//
// ### Plugins loaded at run time (shared libraries)
//
// Besides the built-in plugins, a registry loads plugins compiled as shared libraries:
//
// ```cpp
// canopy::registry r;                        // or canopy::builtin_registry()
// r.load_plugin("/opt/canopy/plugins/canopy_plugin_spiral.so");
// r.load_plugin_path("/opt/canopy/plugins:/home/me/extra.so");  // folders (every *.so, in name order) and files
// ```
//
// `builtin_registry()` loads, on its first call, the list in the environment variable
// **`CANOPY_PLUGIN_PATH`** (files and folders separated by `:`, empty entries skipped):
//
//     CANOPY_PLUGIN_PATH=build/release/plugins canopy info scene.json
//
// **The interface.** A plugin is a shared library exporting one C function, the only symbol the
// loader looks up:
//
// ```cpp
// extern "C" int canopy_plugin_register(unsigned abi_version, void* registry);
// ```
//
// - `abi_version` is `canopy::plugin_abi_version` of the loading program (`canopy.scene`, currently
//   3; raised on every incompatible change of the registry or the scene types). A plugin built
//   against another version must return non-zero without touching the registry.
// - `registry` points to the `canopy::registry` to register into: loaders (`add_loader`), image
//   loaders (`add_image_loader`), generators (`add_generator`) and node types (`add_node_type`).
//   A loader says how it ranks among the loaders of its extension (`canopy::loader_rank`:
//   `alternative`, `standard` by default, `preferred`): the extension's default is the loader of
//   highest rank (equal ranks: the plugin name that sorts first), never the last registered, so a
//   plugin that means to replace a built-in loader registers as `preferred`; the others are chosen
//   by plugin name.
// - It returns 0 on success. A non-zero result, or an exception it lets escape, is reported as a
//   `scene_error` naming the file, and the registry is left as it was (the plugin registers into a
//   copy that replaces the registry only on success).
// - A loaded library stays loaded for the life of the process: the registry holds functions that live
//   in it. Loading the same file twice is a no-op.
//
// A plugin links `canopy_scene` (a static library; the project builds everything
// position-independent) and so carries its own copy of it. Build it with hidden visibility
// (`-fvisibility=hidden`, and `-Wl,--exclude-libs,ALL` for the symbols of the static libraries) and
// give only the entry point default visibility: nothing of the plugin's copy can then interpose on
// the program's. Build it with the program's compiler, standard library and flags (the scene types
// cross the boundary by reference).
//
// Loading errors, each a `scene_error` naming the file:
//
//     plugins/notes.so: cannot load plugin: plugins/notes.so: file too short
//     plugins/libfoo.so: not a canopy plugin: it has no canopy_plugin_register entry point
//     /no/such/plugin.so: file not found
//     old_plugin.so: plugin refused to register (code 1; built for another plugin_abi_version than 3?)
//
// **A complete plugin** (`plugins/runtime_example/`, built as `build/<preset>/plugins/canopy_plugin_spiral.so`
// and never linked into a program): the generator and node type `spiral_staircase`, `steps` closed
// slabs winding about the y axis, 12 triangles each. Parameters: `steps` integer 16 [1, 100000];
// `step_angle` degrees 22.5 (0, 360]; `rise` 0.2, `thickness` 0.05, `inner_radius` 0.25 — numbers
// in (0, 1e6]; `outer_radius` 1.5 (inner_radius, 1e6].
//
// ```cmake
// add_library(canopy_plugin_spiral MODULE spiral_plugin.cpp)
// target_link_libraries(canopy_plugin_spiral PRIVATE canopy_scene)
// target_link_options(canopy_plugin_spiral PRIVATE "LINKER:--exclude-libs,ALL")
// set_target_properties(canopy_plugin_spiral PROPERTIES
//   PREFIX "" CXX_VISIBILITY_PRESET hidden VISIBILITY_INLINES_HIDDEN ON
//   LIBRARY_OUTPUT_DIRECTORY "${CMAKE_BINARY_DIR}/plugins")
// ```
//
// Using it:
//
// ```cpp
// canopy::registry r;
// r.load_plugin("build/release/plugins/canopy_plugin_spiral.so");
// canopy::scene s;
// r.generate(s, "spiral_staircase", {{"steps", "24"}, {"rise", "0.18"}});
// canopy::compiled_scene c = canopy::compile(s, {.plugins = &r});   // 288 triangles, levels 0
// ```
//
// Its source, `plugins/runtime_example/spiral_plugin.cpp` (this listing is made from the file):
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <string>
#include <utility>

import canopy.scene;

namespace {

using canopy::node_id;
using canopy::parameters;
using canopy::scene_error;

std::string const context = "generator 'spiral_staircase'";

// A number in (lo, hi].
double number_in(parameters const& p, std::string const& key, double fallback, double lo, double hi) {
    double const v = p.get_number(key, fallback, context);
    if (!(v > lo && v <= hi))
        throw scene_error(context, "parameter '" + key + "'",
                          "'" + p.get_string(key, "") + "' is not in (" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return v;
}

node_id spiral_staircase(canopy::scene& s, node_id parent, parameters const& p) {
    for (auto const& [key, value] : p.values())
        if (key != "steps" && key != "step_angle" && key != "rise" && key != "thickness" && key != "inner_radius" &&
            key != "outer_radius")
            throw scene_error(context, "parameter '" + key + "'", "is not a parameter of this generator");
    auto const steps = std::uint32_t(p.get_integer("steps", 16, 1, 100'000, context));
    double const step_angle = number_in(p, "step_angle", 22.5, 0.0, 360.0) * std::numbers::pi / 180.0;
    double const rise = number_in(p, "rise", 0.2, 0.0, 1e6);
    double const thickness = number_in(p, "thickness", 0.05, 0.0, 1e6);
    double const inner = number_in(p, "inner_radius", 0.25, 0.0, 1e6);
    double const outer = number_in(p, "outer_radius", 1.5, inner, 1e6);

    canopy::mesh_data m;
    m.name = "spiral_staircase";
    for (std::uint32_t k = 0; k < steps; ++k) {
        double const a0 = k * step_angle, a1 = (k + 1) * step_angle;
        double const top = (k + 1) * rise, bottom = top - thickness;
        // Corner c: bit 0 = outer radius, bit 1 = end angle, bit 2 = top.
        std::uint32_t const first = std::uint32_t(m.positions.size());
        for (int c = 0; c < 8; ++c) {
            double const r = (c & 1) ? outer : inner, a = (c & 2) ? a1 : a0, y = (c & 4) ? top : bottom;
            m.positions.emplace_back(float(r * std::cos(a)), float(y), float(-r * std::sin(a)));
        }
        // Six quads (corners listed clockwise seen from outside), each as two triangles wound
        // counter-clockwise seen from outside.
        constexpr std::array<std::array<std::uint32_t, 4>, 6> quads{{
            {0, 1, 3, 2}, // bottom
            {4, 6, 7, 5}, // top
            {0, 4, 5, 1}, // start side
            {2, 3, 7, 6}, // end side
            {0, 2, 6, 4}, // inner side
            {1, 5, 7, 3}, // outer side
        }};
        for (auto const& q : quads) {
            m.triangles.push_back({first + q[0], first + q[2], first + q[1]});
            m.triangles.push_back({first + q[0], first + q[3], first + q[2]});
        }
    }
    node_id const group = s.add_group(parent, "spiral_staircase");
    s.add_mesh_node(group, s.add_mesh(std::move(m)), "spiral_staircase");
    return group;
}

} // namespace

// The entry point the loader looks up (see canopy.scene:registry); the only exported symbol.
extern "C" [[gnu::visibility("default")]] int canopy_plugin_register(unsigned abi_version, void* registry) {
    if (abi_version != canopy::plugin_abi_version) return 1;
    auto& r = *static_cast<canopy::registry*>(registry);
    r.add_generator("spiral_staircase", "spiral", "a spiral staircase of closed slabs (steps, step_angle, rise, ...)",
                    spiral_staircase);
    r.add_node_type("spiral_staircase", "spiral", "a spiral staircase (the generator's parameters)", spiral_staircase);
    return 0;
}
