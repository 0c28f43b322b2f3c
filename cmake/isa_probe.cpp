// The configure-time ISA probe (cmake/CanopyIsa.cmake): compiled with one candidate's -march
// and the project's warning flags (-Werror included), then run. It passes when it compiles
// cleanly, when this CPU and OS provide every feature the candidate enables, and when the
// families of SIMD intrinsics that canopy.simd uses at that level compute the right values.
// Output: "features: <the candidate's features>" or "missing: <feature>".
//
// CANOPY_ASSUME_CPU_FEATURES (space-separated feature names) narrows what this CPU is taken to
// have, as in the programs' start-up check: the tests use it to make candidates fail here.
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "../modules/isa/cpu_features.hpp"

#if defined(__SSE4_2__)
#include <immintrin.h>
#endif

namespace {

// Lanes of a, b as canopy.simd's kernels combine them: min(a * b + 1, a) by compare and blend,
// plus round(g) - round(g) = 0 of a gathered g. Every level must reproduce the scalar reference
// bit for bit.
float reference(float a, float b) {
  float const p = a * b + 1.0f;
  return p < a ? p : a;
}

bool run_simd_families() {
  alignas(64) float a[16], b[16], out[16];
  alignas(64) int index[16];
  for (int i = 0; i < 16; ++i) {
    a[i] = static_cast<float>(i) * 0.5f - 3.0f;
    b[i] = static_cast<float>(15 - i) * 0.25f;
    index[i] = 15 - i;
  }
  std::memset(out, 0, sizeof out);
#if defined(__AVX512F__)
  __m512 const va = _mm512_load_ps(a), vb = _mm512_load_ps(b);
  __m512 const p = _mm512_add_ps(_mm512_mul_ps(va, vb), _mm512_set1_ps(1.0f));
  __mmask16 const less = _mm512_cmp_ps_mask(p, va, _CMP_LT_OQ);
  __m512 const g = _mm512_roundscale_ps(_mm512_i32gather_ps(_mm512_load_si512(index), a, 4), _MM_FROUND_CUR_DIRECTION);
  _mm512_store_ps(out, _mm512_add_ps(_mm512_mask_blend_ps(less, va, p), _mm512_sub_ps(g, g)));
#elif defined(__AVX2__)
  for (int h = 0; h < 16; h += 8) {
    __m256 const va = _mm256_load_ps(a + h), vb = _mm256_load_ps(b + h);
    __m256 const p = _mm256_add_ps(_mm256_mul_ps(va, vb), _mm256_set1_ps(1.0f));
    __m256 const r = _mm256_blendv_ps(va, p, _mm256_cmp_ps(p, va, _CMP_LT_OQ));
    __m256i const idx = _mm256_load_si256(reinterpret_cast<__m256i const*>(index + h));
    __m256 const g = _mm256_round_ps(_mm256_i32gather_ps(a, idx, 4), _MM_FROUND_CUR_DIRECTION);
    _mm256_store_ps(out + h, _mm256_add_ps(r, _mm256_sub_ps(g, g)));
  }
#elif defined(__SSE4_2__)
  for (int h = 0; h < 16; h += 4) {
    __m128 const va = _mm_load_ps(a + h), vb = _mm_load_ps(b + h);
    __m128 const p = _mm_add_ps(_mm_mul_ps(va, vb), _mm_set1_ps(1.0f));
    __m128 const r = _mm_blendv_ps(va, p, _mm_cmplt_ps(p, va));
    __m128 const g = _mm_round_ps(_mm_load_ps(a + 15 - h - 3), _MM_FROUND_CUR_DIRECTION);
    __m128i const m = _mm_mullo_epi32(_mm_min_epi32(_mm_set1_epi32(1), _mm_set1_epi32(2)), _mm_set1_epi32(0));
    _mm_store_ps(out + h, _mm_add_ps(_mm_add_ps(r, _mm_sub_ps(g, g)), _mm_cvtepi32_ps(m)));
  }
#else
  for (int i = 0; i < 16; ++i) out[i] = reference(a[i], b[i]);
#endif
  for (int i = 0; i < 16; ++i) {
    float const expected = reference(a[i], b[i]);
    if (std::memcmp(&out[i], &expected, sizeof expected) != 0) {
      std::printf("wrong: lane %d\n", i);
      return false;
    }
  }
  return true;
}

}  // namespace

int main() {
  namespace d = canopy::isa_detail;
  // Every compiled-for feature first: running the intrinsics without one would end in SIGILL.
  char const* const assumed = std::getenv("CANOPY_ASSUME_CPU_FEATURES");
  bool complete = true;
  d::for_each_name(d::compiled_features, [&](std::string_view name) {
    for (auto const& f : d::features)
      if (f.name == name && (!d::cpu_has(f) || (assumed && !d::list_contains(assumed, name)))) {
        std::printf("missing: %.*s\n", static_cast<int>(name.size()), name.data());
        complete = false;
      }
  });
  if (!complete || !run_simd_families()) return 1;
  std::printf("features: %.*s\n", static_cast<int>(d::compiled_features.size()), d::compiled_features.data());
  return 0;
}
