// libFuzzer target: canopy.plugins.json's scene parser on arbitrary bytes.
//
// The registry holds one generator and one node type (so params are exercised) and no file or
// image loaders: mesh files and textures fail by extension without touching the disk. Bad input
// must end in a scene_error and leave the scene as it was; anything else (a crash, a sanitizer
// report, another exception, a leak, a slow input) is a finding.
#include <cstddef>
#include <cstdint>
#include <string_view>
#include <utility>

import canopy.scene;
import canopy.plugins.json;

namespace {

canopy::registry const& fuzz_registry() {
    static canopy::registry const r = [] {
        canopy::registry out;
        out.add_generator("triangle", "fuzz", "one triangle", [](canopy::scene& s, canopy::node_id parent,
                                                                 canopy::parameters const& p) {
            auto const size = float(p.get_number("size", 1.0, "triangle"));
            auto const copies = p.get_integer("copies", 1, 1, 4, "triangle");
            canopy::mesh_data m;
            m.positions = {{0, 0, 0}, {size, 0, 0}, {0, size, 0}};
            m.triangles = {{0, 1, 2}};
            auto const mesh = s.add_mesh(std::move(m));
            auto const group = s.add_group(parent, p.get_string("name", "triangle"));
            for (long long k = 0; k < copies; ++k) s.add_mesh_node(group, mesh);
            return group;
        });
        out.add_node_type("marker", "fuzz", "an empty group", [](canopy::scene& s, canopy::node_id parent,
                                                                 canopy::parameters const& p) {
            return s.add_group(parent, p.get_string("label", ""));
        });
        return out;
    }();
    return r;
}

} // namespace

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
    std::string_view const text(reinterpret_cast<char const*>(data), size);
    canopy::registry const& r = fuzz_registry();
    canopy::scene s;
    try {
        canopy::parse_json_scene(text, "/nonexistent-canopy-fuzz/input.json", &r, s, s.root());
    } catch (canopy::scene_error const&) {
        // Rolled back: only the root is left.
        if (s.nodes().size() != 1 || !s.meshes().empty() || !s.materials().empty() || !s.images().empty())
            __builtin_trap();
        return 0;
    }
    try {
        r.expand_custom_nodes(s);
    } catch (canopy::scene_error const&) {
    }
    return 0;
}
