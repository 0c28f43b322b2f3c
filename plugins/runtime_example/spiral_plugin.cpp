// canopy_plugin_spiral — an example of a plugin loaded at run time (a shared library), not built
// into any program: registry::load_plugin("canopy_plugin_spiral.so"), or list it (or its folder)
// in CANOPY_PLUGIN_PATH for builtin_registry().
//
// Generator and node type "spiral_staircase": `steps` closed slabs (annular sectors) winding
// about the y axis, step k spanning the angles [k·step_angle, (k+1)·step_angle] (degrees,
// counter-clockwise seen from +y, starting on +x) and the heights [(k+1)·rise − thickness,
// (k+1)·rise]. 12 triangles and 8 vertices per step, in step order.
//     steps         integer  16     [1, 100000]
//     step_angle    number   22.5   (0, 360]
//     rise          number   0.2    (0, 1e6]
//     thickness     number   0.05   (0, 1e6]
//     inner_radius  number   0.25   (0, 1e6]
//     outer_radius  number   1.5    (inner_radius, 1e6]
// Bad values are errors naming the generator and the parameter.
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
