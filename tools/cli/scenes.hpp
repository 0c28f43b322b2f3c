// The scenes of `canopy render` and `canopy info`: a file any registered plugin loads, or
// gen:NAME[:KEY=VALUE,...] for a registered generator, loaded into the scene graph and compiled
// (canopy.scene's skip rules).
#pragma once
#include <optional>
#include <string>
#include <vector>
import canopy;
import canopy.scene;

namespace cli {

// The registry of built-in plugins, plus shared-library plugins named on the command line.
canopy::registry& plugin_registry(std::vector<std::string> const& plugin_files);

// The scene `canopy render` renders without a SCENE: the paper's Figure 1 forest.
inline constexpr char const* demo_scene = "gen:billboard_forest";

struct loaded_graph {
    canopy::scene graph;
    canopy::compiled_scene compiled;
    double load_seconds = 0.0;
};

// gen:NAME[:KEY=VALUE,...] read into the generator's name and parameters (usage errors: an item
// that is not KEY=VALUE, a key given twice); nothing for a file.
struct generator_call {
    std::string name;
    canopy::parameters params;
};
std::optional<generator_call> parse_generator(std::string const& spec);

// SCENE (a file, or gen:...) loaded and compiled with mesh BVHs of `quality`.
loaded_graph load_and_compile(std::string const& spec, canopy::registry const& r, canopy::build_quality quality);

} // namespace cli
