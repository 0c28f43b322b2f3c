// Broken preconditions of the API (tests/CMakeLists.txt: built with CANOPY_DCHECKS only, as in the
// debug and asan presets). `dcheck_probe CASE` breaks one precondition, which must stop the
// program with CANOPY_DCHECK's message; `dcheck_probe valid` keeps them all and must run through.
#include <cstdio>
#include <string_view>
import canopy.geometry;

int main(int argc, char** argv) {
    std::string_view const name = argc > 1 ? argv[1] : "";
    bool const valid = name == "valid";
    int volatile const bad = 99; // out of every range, and unknown to the optimiser
    canopy::vec3<float> const v(1.0f, 2.0f, 3.0f);
    if (valid || name == "permute")
        std::printf("%g\n", double(canopy::permute(v, 2, 0, valid ? 1 : bad).z));
    if (valid || name == "get_lane") {
        canopy::vec3<canopy::simd::float8> const packet(canopy::simd::float8(4.0f));
        std::printf("%g\n", double(canopy::get_lane(packet, valid ? 7 : bad).x));
    }
    if (valid || name == "enter_instance") {
        canopy::instance_path path;
        for (int k = 0; k < canopy::max_instance_depth + (valid ? 0 : 1); ++k) path.enter_instance(std::uint32_t(k));
        std::printf("%d\n", path.depth);
    }
    if (valid || name == "leave_instance") {
        canopy::instance_path path;
        if (valid) path.enter_instance(5);
        path.leave_instance();
        std::printf("%d\n", path.depth);
    }
    if (valid || name == "triangle_at") {
        canopy::triangle_block block{};
        std::printf("%u\n", block.triangle_at(valid ? canopy::triangle_block_width - 1 : bad).prim_id);
    }
    std::puts(valid ? "every precondition kept" : "no check fired");
    return valid ? 0 : 3;
}
