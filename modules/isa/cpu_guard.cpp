// The start-up check of Canopy's programs (the canopy_cpu_guard object, linked into the CLI,
// the examples, the benchmarks and the tests; installed as canopy::canopy_cpu_guard). Before
// main() and before any static initialiser of default priority, so before any code compiled for
// the library's ISA, it checks that this CPU provides every feature of that ISA. If one is
// missing the program ends with status 1 and a message naming the ISA and the missing features,
// instead of dying of SIGILL somewhere later.
//
// CANOPY_ASSUME_CPU_FEATURES (space-separated feature names, as in canopy::simd::cpu_features)
// narrows what the CPU reports to the features it names: it lets the tests check the refusal on
// any machine.
//
// Compiled for the baseline x86-64 ISA.
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <string>
#include <string_view>
#include <unistd.h>
#include <vector>

#include "cpu_features.hpp"

namespace canopy::simd {
std::string_view build_isa() noexcept;
std::string_view build_isa_flags() noexcept;
std::vector<std::string_view> cpu_features();
std::vector<std::string_view> missing_isa_features(std::span<std::string_view const> cpu);
}  // namespace canopy::simd

namespace {

[[gnu::constructor(101)]] void canopy_check_cpu() {
  std::vector<std::string_view> cpu = canopy::simd::cpu_features();
  if (char const* assumed = std::getenv("CANOPY_ASSUME_CPU_FEATURES"))
    std::erase_if(cpu, [&](std::string_view n) { return !canopy::isa_detail::list_contains(assumed, n); });
  std::vector<std::string_view> const missing = canopy::simd::missing_isa_features(cpu);
  if (missing.empty()) return;
  std::string list;
  for (std::string_view m : missing) list.append(list.empty() ? "" : ", ").append(m);
  std::string_view const isa = canopy::simd::build_isa(), flags = canopy::simd::build_isa_flags();
  std::fprintf(stderr,
               "%s: this program was built for the x86-64 ISA %.*s (%.*s), but this CPU lacks %s.\n"
               "Build Canopy on this machine (its configure probe picks an ISA the CPU runs) or set "
               "-DCANOPY_ARCH to an ISA this CPU has (x86-64-v2, x86-64-v3, ...).\n",
               program_invocation_short_name, static_cast<int>(isa.size()), isa.data(),
               static_cast<int>(flags.size()), flags.data(), list.c_str());
  std::fflush(stderr);
  _exit(1);
}

}  // namespace
