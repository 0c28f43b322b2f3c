// The ISA record and the CPU check of canopy.simd, and the start-up refusal of the programs.
#include <catch2/catch.hpp>

#include <algorithm>
#include <string>
#include <string_view>
#include <vector>

#include "../modules/isa/cpu_features.hpp"

import canopy.simd;
import canopy.testing;

namespace {

std::vector<std::string_view> split(std::string_view names) {
  std::vector<std::string_view> out;
  canopy::isa_detail::for_each_name(names, [&](std::string_view n) { out.push_back(n); });
  return out;
}

bool contains(std::vector<std::string_view> const& list, std::string_view name) {
  return std::find(list.begin(), list.end(), name) != list.end();
}

// The compiler's own detection (libgcc's __cpu_indicator_init, which also checks the OS state
// for AVX and AVX-512), for the features it has known for years.
std::vector<std::pair<std::string_view, bool>> compiler_detected_features() {
  __builtin_cpu_init();
  return {{"sse3", __builtin_cpu_supports("sse3")},
          {"ssse3", __builtin_cpu_supports("ssse3")},
          {"sse4.1", __builtin_cpu_supports("sse4.1")},
          {"sse4.2", __builtin_cpu_supports("sse4.2")},
          {"popcnt", __builtin_cpu_supports("popcnt")},
          {"pclmul", __builtin_cpu_supports("pclmul")},
          {"aes", __builtin_cpu_supports("aes")},
          {"avx", __builtin_cpu_supports("avx")},
          {"avx2", __builtin_cpu_supports("avx2")},
          {"fma", __builtin_cpu_supports("fma")},
          {"bmi", __builtin_cpu_supports("bmi")},
          {"bmi2", __builtin_cpu_supports("bmi2")},
          {"sse4a", __builtin_cpu_supports("sse4a")},
          {"xop", __builtin_cpu_supports("xop")},
          {"fma4", __builtin_cpu_supports("fma4")},
          {"avx512f", __builtin_cpu_supports("avx512f")},
          {"avx512dq", __builtin_cpu_supports("avx512dq")},
          {"avx512cd", __builtin_cpu_supports("avx512cd")},
          {"avx512bw", __builtin_cpu_supports("avx512bw")},
          {"avx512vl", __builtin_cpu_supports("avx512vl")},
          {"avx512ifma", __builtin_cpu_supports("avx512ifma")},
          {"avx512vbmi", __builtin_cpu_supports("avx512vbmi")},
          {"avx512vbmi2", __builtin_cpu_supports("avx512vbmi2")},
          {"avx512vnni", __builtin_cpu_supports("avx512vnni")},
          {"avx512bitalg", __builtin_cpu_supports("avx512bitalg")},
          {"avx512vpopcntdq", __builtin_cpu_supports("avx512vpopcntdq")},
          {"gfni", __builtin_cpu_supports("gfni")},
          {"vaes", __builtin_cpu_supports("vaes")},
          {"vpclmulqdq", __builtin_cpu_supports("vpclmulqdq")}};
}

// Runs `command` through the shell with CANOPY_ASSUME_CPU_FEATURES set to `assumed`.
test_support::command_result run_assuming(std::string const& assumed, std::string const& command) {
    return test_support::run_command("CANOPY_ASSUME_CPU_FEATURES='" + assumed + "' " + command);
}

std::string join(std::vector<std::string_view> const& names, std::string_view skip = {}) {
  std::string out;
  for (std::string_view n : names)
    if (n != skip) out.append(out.empty() ? "" : " ").append(n);
  return out;
}

}  // namespace

TEST_CASE("the recorded ISA features are the ones this importer was compiled with") {
  // Tests are importers of canopy.simd: the package's flags must give them the same macros.
  CHECK(canopy::simd::build_isa_features() == split(canopy::isa_detail::compiled_features));
  CHECK(!canopy::simd::build_isa().empty());
  CHECK(canopy::simd::build_isa().find("native") == std::string_view::npos);
  std::string const march = "-march=" + std::string(canopy::simd::build_isa());
  CHECK(canopy::simd::build_isa_flags().substr(0, march.size()) == march);
  // canopy.simd's SIMD backends follow the same flags.
  CHECK(contains(canopy::simd::build_isa_features(), "sse4.2"));
#if defined(__AVX2__)
  CHECK(contains(canopy::simd::build_isa_features(), "avx2"));
#endif
#if defined(__AVX512F__)
  CHECK(contains(canopy::simd::build_isa_features(), "avx512f"));
#endif
}

TEST_CASE("cpu_features agrees with the compiler's own CPU detection") {
  std::vector<std::string_view> const cpu = canopy::simd::cpu_features();
  for (auto const& [name, supported] : compiler_detected_features()) {
    INFO(name);
    CHECK(contains(cpu, name) == supported);
  }
}

TEST_CASE("this CPU runs the build ISA: nothing is missing") {
  CHECK(canopy::simd::cpu_supports_build_isa());
  std::vector<std::string_view> const cpu = canopy::simd::cpu_features();
  CHECK(canopy::simd::missing_isa_features(cpu).empty());
}

TEST_CASE("a CPU that lacks one feature of the build ISA is refused, naming that feature") {
  std::vector<std::string_view> const build = canopy::simd::build_isa_features();
  REQUIRE(!build.empty());
  for (std::string_view feature : build) {
    std::vector<std::string_view> cpu = canopy::simd::cpu_features();
    std::erase(cpu, feature);
    INFO(feature);
    CHECK(canopy::simd::missing_isa_features(cpu) == std::vector<std::string_view>{feature});
  }
  CHECK(canopy::simd::missing_isa_features({}) == build);
}

TEST_CASE("programs refuse to start on a CPU without their ISA, with a message naming the feature") {
  std::vector<std::string_view> const build = canopy::simd::build_isa_features();
  std::string const programs[] = {"'" CANOPY_CLI "' info --plugins", "'" CANOPY_SELF "' 'this CPU runs the build ISA: nothing is missing'"};
  for (std::string const& program : programs) {
    INFO(program);
    auto const full = run_assuming(join(build), program);
    CHECK(full.exit_code == 0);
    for (std::string_view feature : {build.front(), build.back()}) {
      auto const lacking = run_assuming(join(build, feature), program);
      INFO(lacking.output);
      CHECK(lacking.exit_code == 1);
      CHECK(lacking.output.find("this CPU lacks " + std::string(feature) + ".") != std::string::npos);
      CHECK(lacking.output.find("built for the x86-64 ISA " + std::string(canopy::simd::build_isa())) !=
            std::string::npos);
    }
  }
}
