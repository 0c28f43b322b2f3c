// The ISA the library was built for, and whether this CPU runs it (canopy.simd exports the
// declarations). Compiled for the baseline x86-64 ISA, with no module imported, so that it can
// run on any x86-64 CPU before code built for the library's ISA does.
//
// CANOPY_BUILD_ISA, CANOPY_BUILD_ISA_FLAGS and CANOPY_BUILD_ISA_FEATURES are set by the
// configure-time probe (cmake/CanopyIsa.cmake).
#include <span>
#include <string_view>
#include <vector>

#include "cpu_features.hpp"

namespace canopy::simd {

std::string_view build_isa() noexcept { return CANOPY_BUILD_ISA; }

std::string_view build_isa_flags() noexcept { return CANOPY_BUILD_ISA_FLAGS; }

std::vector<std::string_view> build_isa_features() {
  std::vector<std::string_view> names;
  isa_detail::for_each_name(CANOPY_BUILD_ISA_FEATURES, [&](std::string_view n) { names.push_back(n); });
  return names;
}

std::vector<std::string_view> cpu_features() {
  std::vector<std::string_view> names;
  for (auto const& f : isa_detail::features)
    if (isa_detail::cpu_has(f)) names.push_back(f.name);
  return names;
}

std::vector<std::string_view> missing_isa_features(std::span<std::string_view const> cpu) {
  std::vector<std::string_view> missing;
  isa_detail::for_each_name(CANOPY_BUILD_ISA_FEATURES, [&](std::string_view n) {
    bool found = false;
    for (std::string_view c : cpu) found = found || c == n;
    if (!found) missing.push_back(n);
  });
  return missing;
}

bool cpu_supports_build_isa() noexcept {
  bool supported = true;
  isa_detail::for_each_name(CANOPY_BUILD_ISA_FEATURES, [&](std::string_view n) {
    for (auto const& f : isa_detail::features)
      if (f.name == n) supported = supported && isa_detail::cpu_has(f);
  });
  return supported;
}

}  // namespace canopy::simd
