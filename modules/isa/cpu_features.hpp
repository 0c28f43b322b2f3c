// x86-64 instruction-set features: which ones a translation unit was compiled for (the
// compiler's predefined macros) and which ones the running CPU and operating system provide
// (cpuid and xgetbv). Shared by the configure-time ISA probe (cmake/isa_probe.cpp), the
// library's ISA functions (modules/isa/isa.cpp) and the start-up check of every program
// (modules/isa/cpu_guard.cpp).
//
// Contract: a feature counts as present only when the CPU reports it *and* the operating system
// saves the register state it needs (XCR0: SSE/AVX state for AVX, opmask/ZMM state for
// AVX-512), as Intel SDM vol. 1 §13.3 and §15.2 require before such instructions may run.
// The code here is plain integer code: it may be compiled for the baseline x86-64 ISA and run
// on any x86-64 CPU.
//
// Features are named as the compilers name them in -m flags (sse4.2, avx512vl, ...). The list
// covers the instructions a compiler may emit on its own (vector ISA, bit manipulation, FMA,
// conversions); instructions reachable only through their intrinsics (crc32, rdrnd, xsave, ...)
// are not checked, since the library uses none of them.
#pragma once

#include <cpuid.h>

#include <cstdint>
#include <string_view>

namespace canopy::isa_detail {

enum class cpuid_reg : std::uint8_t { eax, ebx, ecx, edx };

// Which OS-saved register state a feature needs before its instructions may run.
enum class os_state : std::uint8_t { none, avx, avx512 };

struct feature {
  std::string_view name;
  std::uint32_t leaf;
  std::uint32_t subleaf;
  cpuid_reg reg;
  std::uint8_t bit;
  os_state state;
};

// Intel SDM vol. 2A, CPUID; AMD APM vol. 3, appendix E (leaves 0x80000001 and 0x80000008).
inline constexpr feature features[] = {
    {"sse3", 1, 0, cpuid_reg::ecx, 0, os_state::none},
    {"pclmul", 1, 0, cpuid_reg::ecx, 1, os_state::none},
    {"ssse3", 1, 0, cpuid_reg::ecx, 9, os_state::none},
    {"fma", 1, 0, cpuid_reg::ecx, 12, os_state::avx},
    {"cx16", 1, 0, cpuid_reg::ecx, 13, os_state::none},
    {"sse4.1", 1, 0, cpuid_reg::ecx, 19, os_state::none},
    {"sse4.2", 1, 0, cpuid_reg::ecx, 20, os_state::none},
    {"movbe", 1, 0, cpuid_reg::ecx, 22, os_state::none},
    {"popcnt", 1, 0, cpuid_reg::ecx, 23, os_state::none},
    {"aes", 1, 0, cpuid_reg::ecx, 25, os_state::none},
    {"avx", 1, 0, cpuid_reg::ecx, 28, os_state::avx},
    {"f16c", 1, 0, cpuid_reg::ecx, 29, os_state::avx},
    {"bmi", 7, 0, cpuid_reg::ebx, 3, os_state::none},
    {"avx2", 7, 0, cpuid_reg::ebx, 5, os_state::avx},
    {"bmi2", 7, 0, cpuid_reg::ebx, 8, os_state::none},
    {"avx512f", 7, 0, cpuid_reg::ebx, 16, os_state::avx512},
    {"avx512dq", 7, 0, cpuid_reg::ebx, 17, os_state::avx512},
    {"adx", 7, 0, cpuid_reg::ebx, 19, os_state::none},
    {"avx512ifma", 7, 0, cpuid_reg::ebx, 21, os_state::avx512},
    {"avx512cd", 7, 0, cpuid_reg::ebx, 28, os_state::avx512},
    {"sha", 7, 0, cpuid_reg::ebx, 29, os_state::none},
    {"avx512bw", 7, 0, cpuid_reg::ebx, 30, os_state::avx512},
    {"avx512vl", 7, 0, cpuid_reg::ebx, 31, os_state::avx512},
    {"avx512vbmi", 7, 0, cpuid_reg::ecx, 1, os_state::avx512},
    {"avx512vbmi2", 7, 0, cpuid_reg::ecx, 6, os_state::avx512},
    {"gfni", 7, 0, cpuid_reg::ecx, 8, os_state::none},
    {"vaes", 7, 0, cpuid_reg::ecx, 9, os_state::avx},
    {"vpclmulqdq", 7, 0, cpuid_reg::ecx, 10, os_state::avx},
    {"avx512vnni", 7, 0, cpuid_reg::ecx, 11, os_state::avx512},
    {"avx512bitalg", 7, 0, cpuid_reg::ecx, 12, os_state::avx512},
    {"avx512vpopcntdq", 7, 0, cpuid_reg::ecx, 14, os_state::avx512},
    {"avx512vp2intersect", 7, 0, cpuid_reg::edx, 8, os_state::avx512},
    {"avx512fp16", 7, 0, cpuid_reg::edx, 23, os_state::avx512},
    {"avxvnni", 7, 1, cpuid_reg::eax, 4, os_state::avx},
    {"avx512bf16", 7, 1, cpuid_reg::eax, 5, os_state::avx512},
    {"avxifma", 7, 1, cpuid_reg::eax, 23, os_state::avx},
    {"lzcnt", 0x80000001u, 0, cpuid_reg::ecx, 5, os_state::none},
    {"sse4a", 0x80000001u, 0, cpuid_reg::ecx, 6, os_state::none},
    {"xop", 0x80000001u, 0, cpuid_reg::ecx, 11, os_state::avx},
    {"fma4", 0x80000001u, 0, cpuid_reg::ecx, 16, os_state::avx},
    {"tbm", 0x80000001u, 0, cpuid_reg::ecx, 21, os_state::none},
};

// The features of the table that the including translation unit is compiled for (its -march
// and -m flags), as a space-separated list in table order.
inline constexpr std::string_view compiled_features =
#if defined(__SSE3__)
    "sse3 "
#endif
#if defined(__PCLMUL__)
    "pclmul "
#endif
#if defined(__SSSE3__)
    "ssse3 "
#endif
#if defined(__FMA__)
    "fma "
#endif
#if defined(__GCC_HAVE_SYNC_COMPARE_AND_SWAP_16)
    "cx16 "
#endif
#if defined(__SSE4_1__)
    "sse4.1 "
#endif
#if defined(__SSE4_2__)
    "sse4.2 "
#endif
#if defined(__MOVBE__)
    "movbe "
#endif
#if defined(__POPCNT__)
    "popcnt "
#endif
#if defined(__AES__)
    "aes "
#endif
#if defined(__AVX__)
    "avx "
#endif
#if defined(__F16C__)
    "f16c "
#endif
#if defined(__BMI__)
    "bmi "
#endif
#if defined(__AVX2__)
    "avx2 "
#endif
#if defined(__BMI2__)
    "bmi2 "
#endif
#if defined(__AVX512F__)
    "avx512f "
#endif
#if defined(__AVX512DQ__)
    "avx512dq "
#endif
#if defined(__ADX__)
    "adx "
#endif
#if defined(__AVX512IFMA__)
    "avx512ifma "
#endif
#if defined(__AVX512CD__)
    "avx512cd "
#endif
#if defined(__SHA__)
    "sha "
#endif
#if defined(__AVX512BW__)
    "avx512bw "
#endif
#if defined(__AVX512VL__)
    "avx512vl "
#endif
#if defined(__AVX512VBMI__)
    "avx512vbmi "
#endif
#if defined(__AVX512VBMI2__)
    "avx512vbmi2 "
#endif
#if defined(__GFNI__)
    "gfni "
#endif
#if defined(__VAES__)
    "vaes "
#endif
#if defined(__VPCLMULQDQ__)
    "vpclmulqdq "
#endif
#if defined(__AVX512VNNI__)
    "avx512vnni "
#endif
#if defined(__AVX512BITALG__)
    "avx512bitalg "
#endif
#if defined(__AVX512VPOPCNTDQ__)
    "avx512vpopcntdq "
#endif
#if defined(__AVX512VP2INTERSECT__)
    "avx512vp2intersect "
#endif
#if defined(__AVX512FP16__)
    "avx512fp16 "
#endif
#if defined(__AVXVNNI__)
    "avxvnni "
#endif
#if defined(__AVX512BF16__)
    "avx512bf16 "
#endif
#if defined(__AVXIFMA__)
    "avxifma "
#endif
#if defined(__LZCNT__)
    "lzcnt "
#endif
#if defined(__SSE4A__)
    "sse4a "
#endif
#if defined(__XOP__)
    "xop "
#endif
#if defined(__FMA4__)
    "fma4 "
#endif
#if defined(__TBM__)
    "tbm "
#endif
    "";

// Register state the operating system saves (XCR0), or 0 when XGETBV is not enabled (OSXSAVE).
inline std::uint64_t os_saved_state() {
  unsigned eax = 0, ebx = 0, ecx = 0, edx = 0;
  if (!__get_cpuid(1, &eax, &ebx, &ecx, &edx) || !(ecx & (1u << 27))) return 0;
  unsigned lo = 0, hi = 0;
  __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0u));
  return (std::uint64_t(hi) << 32) | lo;
}

// Whether the running CPU and operating system provide `f`.
inline bool cpu_has(feature const& f) {
  unsigned max_leaf = __get_cpuid_max(f.leaf & 0x80000000u, nullptr);
  if (max_leaf < f.leaf) return false;
  unsigned regs[4] = {0, 0, 0, 0};
  __cpuid_count(f.leaf, f.subleaf, regs[0], regs[1], regs[2], regs[3]);
  if (!(regs[static_cast<int>(f.reg)] & (1u << f.bit))) return false;
  std::uint64_t const xcr0 = f.state == os_state::none ? 0 : os_saved_state();
  std::uint64_t constexpr avx_state = 0x6;     // XMM and YMM state
  std::uint64_t constexpr avx512_state = 0xe6; // XMM, YMM, opmask, ZMM_Hi256, Hi16_ZMM state
  switch (f.state) {
  case os_state::none:
    return true;
  case os_state::avx:
    return (xcr0 & avx_state) == avx_state;
  case os_state::avx512:
    return (xcr0 & avx512_state) == avx512_state;
  }
  return false;
}

// Calls `visit(name)` for each feature of the list `names` (space-separated) in order.
template <typename Visit>
void for_each_name(std::string_view names, Visit&& visit) {
  while (!names.empty()) {
    std::size_t const start = names.find_first_not_of(' ');
    if (start == std::string_view::npos) return;
    names.remove_prefix(start);
    std::size_t const end = names.find(' ');
    visit(names.substr(0, end));
    if (end == std::string_view::npos) return;
    names.remove_prefix(end);
  }
}

// Whether the space-separated list `names` contains `name`.
inline bool list_contains(std::string_view names, std::string_view name) {
  bool found = false;
  for_each_name(names, [&](std::string_view n) { found = found || n == name; });
  return found;
}

}  // namespace canopy::isa_detail
