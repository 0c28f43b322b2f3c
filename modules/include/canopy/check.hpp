// canopy/check.hpp — CANOPY_DCHECK(condition, message): a documented precondition of the public
// API, checked where the library is built with CANOPY_DCHECKS=ON (the CMake option: on by
// default for Debug builds and with sanitizers, so in the debug and asan presets) and compiled
// out otherwise, condition unevaluated. A failed check prints the message, the condition and the
// place to standard error and aborts. Modules include this header in their global module fragment
// (a module exports no macros).
#pragma once

#if defined(CANOPY_DCHECKS) && CANOPY_DCHECKS
#include <cstdio>
#include <cstdlib>

[[noreturn, gnu::cold]] inline void canopy_dcheck_failed(char const* message, char const* condition, char const* file,
                                                         int line) {
    std::fprintf(stderr, "canopy: precondition failed: %s (%s, %s:%d)\n", message, condition, file, line);
    std::abort();
}

#define CANOPY_DCHECK(condition, message)                                                                             \
    ((condition) ? void(0) : canopy_dcheck_failed(message, #condition, __FILE__, __LINE__))
#else
#define CANOPY_DCHECK(condition, message) void(0)
#endif
