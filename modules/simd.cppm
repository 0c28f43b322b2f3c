module;
#include <string_view>
export module canopy.simd;
export namespace canopy::simd {
constexpr std::string_view isa_name() { return "scalar"; }
}
