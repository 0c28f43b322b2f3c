// libFuzzer target: the bench plugin's format readers (canopy.plugins.bench:formats) on arbitrary bytes: the OBJ subset, the .inst
// text (its mesh is not read: parse_bench_inst), ray files and hit files.
//
// Bad input must end in a scene_error; anything else (a crash, a sanitizer report, another
// exception, a leak, a slow input) is a finding. What the readers return is checked against the
// input: one triangle per `f` line at most, one instance per line at most, one ray per 32 bytes,
// one hit per 20 bytes, every vertex and matrix entry finite.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string_view>

import canopy.math;
import canopy.scene;
import canopy.plugins.bench;

namespace {

bool finite(canopy::vec3<float> v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

std::size_t lines_of(std::string_view text) {
    std::size_t n = 1;
    for (char c : text) n += c == '\n';
    return n;
}

} // namespace

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
    std::string_view const bytes(reinterpret_cast<char const*>(data), size);
    try {
        auto const mesh = canopy::parse_bench_obj(bytes, "/nonexistent-canopy-fuzz/input.obj");
        if (mesh.triangles.empty() || mesh.triangles.size() > lines_of(bytes)) __builtin_trap();
        for (auto const& t : mesh.triangles)
            if (!finite(t.v0) || !finite(t.v1) || !finite(t.v2)) __builtin_trap();
    } catch (canopy::scene_error const&) {
    }
    try {
        auto const inst = canopy::parse_bench_inst(bytes, "/nonexistent-canopy-fuzz/input.inst");
        if (inst.instances.empty() || inst.instances.size() > lines_of(bytes) || inst.mesh_path.empty()) __builtin_trap();
        for (auto const& m : inst.instances)
            if (!finite(m.linear.col0) || !finite(m.linear.col1) || !finite(m.linear.col2) || !finite(m.translation))
                __builtin_trap();
    } catch (canopy::scene_error const&) {
    }
    try {
        if (canopy::parse_bench_rays(bytes, "input.rays").size() * 32 != size) __builtin_trap();
    } catch (canopy::scene_error const&) {
        if (size % 32 == 0) __builtin_trap();
    }
    try {
        if (canopy::parse_bench_hits(bytes, "input.hits").size() * 20 != size) __builtin_trap();
    } catch (canopy::scene_error const&) {
        if (size % 20 == 0) __builtin_trap();
    }
    return 0;
}
