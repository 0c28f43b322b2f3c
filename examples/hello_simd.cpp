// hello_simd — which SIMD backend this build selected, and vec3<float8> math in action:
// eight ray directions normalised at once, checked against the scalar path lane by lane.
#include <cmath>
#include <cstdio>
import canopy.simd;
import canopy.math;

int main() {
    namespace simd = canopy::simd;
    std::printf("canopy.simd: widest native ISA %s\n", simd::isa_name().data());
    std::printf("  float4  -> %s\n  float8  -> %s\n  float16 -> %s\n", simd::backend_name<simd::float4>().data(),
                simd::backend_name<simd::float8>().data(), simd::backend_name<simd::float16>().data());

    canopy::vec3<simd::float8> dirs;
    for (int i = 0; i < 8; ++i)
        canopy::set_lane(dirs, i, canopy::vec3<float>(float(i) - 3.5f, 1.0f + float(i), 2.0f * float(i) - 7.0f));
    auto const unit = canopy::normalize(dirs);

    int mismatches = 0;
    for (int i = 0; i < 8; ++i) {
        auto const lane = canopy::get_lane(unit, i);
        auto const scalar = canopy::normalize(canopy::get_lane(dirs, i));
        mismatches += lane.x != scalar.x || lane.y != scalar.y || lane.z != scalar.z;
        std::printf("  lane %d: (%+.6f, %+.6f, %+.6f)  |d| = %.7f\n", i, double(lane.x), double(lane.y),
                    double(lane.z), double(canopy::length(lane)));
    }
    std::printf("vec3<float8> vs vec3<float>: %d lane mismatches\n", mismatches);
    return mismatches == 0 ? 0 : 1;
}
