// libFuzzer target: canopy.plugins.gltf on arbitrary bytes (.gltf JSON text, or .glb).
//
// Every input is loaded as a glTF file in a folder that does not exist (external buffers and
// images are missing; data: URIs are decoded), through a registry without image loaders (an
// image by uri fails by extension without touching the disk). Bad input must end in a
// scene_error and leave the scene as it was; anything else (a crash, a sanitizer report, another
// exception, a leak, a slow input) is a finding.
#include <cstddef>
#include <cstdint>
#include <string_view>

import canopy.scene;
import canopy.plugins.gltf;

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
    std::string_view const bytes(reinterpret_cast<char const*>(data), size);
    static canopy::registry const no_images;
    canopy::scene s;
    try {
        canopy::parse_gltf(bytes, "/nonexistent-canopy-fuzz/input.gltf", s, s.root(), no_images);
    } catch (canopy::scene_error const&) {
        // Rolled back: only the root is left.
        if (s.nodes().size() != 1 || !s.meshes().empty() || !s.materials().empty() || !s.images().empty())
            __builtin_trap();
    }
    return 0;
}
