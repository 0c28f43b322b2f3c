// libFuzzer target: canopy.plugins.obj's OBJ and MTL parsers on arbitrary bytes.
//
// Every input is parsed as an OBJ file (no registry: texture statements are checked, not loaded;
// material libraries are looked up next to a file in a folder that does not exist) and as an MTL
// file. Bad input must end in a scene_error and leave the scene as it was; anything else (a
// crash, a sanitizer report, another exception, a leak, a slow input) is a finding.
#include <cstddef>
#include <cstdint>
#include <string_view>

import canopy.scene;
import canopy.plugins.obj;

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
    std::string_view const text(reinterpret_cast<char const*>(data), size);
    canopy::scene s;
    try {
        canopy::parse_obj(text, "/nonexistent-canopy-fuzz/input.obj", nullptr, s, s.root());
    } catch (canopy::scene_error const&) {
        // Rolled back: only the root is left.
        if (s.nodes().size() != 1 || !s.meshes().empty() || !s.materials().empty() || !s.images().empty())
            __builtin_trap();
    }
    try {
        (void)canopy::parse_mtl(text, "input.mtl");
    } catch (canopy::scene_error const&) {
    }
    return 0;
}
