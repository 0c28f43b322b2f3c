# The instruction set the library and every importer are compiled for, chosen by a probe.
#
# CANOPY_ARCH empty (the default): each -march value of CANOPY_ARCH_CANDIDATES is tried in order
# (default: native, x86-64-v4, x86-64-v3, x86-64-v2). A candidate is kept when cmake/isa_probe.cpp
# compiles with it and the project's warning flags (-Werror included) and then runs on this CPU:
# every feature the candidate enables is present (cpuid, and the OS saves its registers), and the
# SIMD intrinsic families canopy.simd uses at that level compute the right values. The first
# candidate kept wins; configure prints it with the reason each earlier candidate was rejected.
# CANOPY_ARCH=X: X alone is probed, and a failure is a configure error saying why.
#
# 'native' is never recorded as such: once the probe keeps it, it is resolved to the CPU name it
# stands for (clang's -target-cpu) plus -m/-mno- flags for the features in which this host differs
# from that CPU (virtual machines hide some), and kept only if those flags define exactly the same
# feature macros as -march=native and pass the probe too. Otherwise native is resolved to the
# highest x86-64-vN level whose features it has. The library is compiled with the resolved flags,
# so what the package records is what its code uses.
#
# CANOPY_ASSUME_CPU_FEATURES in the environment (space-separated feature names) narrows what the
# probe takes this CPU to have; the probe-logic test uses it to reject candidates on any machine.
#
# Results (cache, INTERNAL):
#   CANOPY_ISA            the ISA's name: a CPU name (znver5, sapphirerapids) or x86-64-vN
#   CANOPY_ISA_FLAGS      the flags the library and its importers are compiled with (a list)
#   CANOPY_ISA_FEATURES   the features a program checks at start-up (space-separated)

set(CANOPY_ARCH_CANDIDATES "native;x86-64-v4;x86-64-v3;x86-64-v2" CACHE STRING
    "-march values the ISA probe tries in order when CANOPY_ARCH is empty")

# Runs the probe with `flags` (a list). Sets <prefix>_OK, <prefix>_REASON (why it was rejected)
# and <prefix>_FEATURES.
function(canopy_isa_probe flags prefix)
  try_run(run_result compile_ok
          SOURCES "${PROJECT_SOURCE_DIR}/cmake/isa_probe.cpp"
          COMPILE_DEFINITIONS -O2 -ffp-contract=off ${flags}
          CXX_STANDARD 20 CXX_STANDARD_REQUIRED ON CXX_EXTENSIONS OFF
          NO_CACHE
          COMPILE_OUTPUT_VARIABLE compile_output
          RUN_OUTPUT_VARIABLE run_output)
  set(ok FALSE)
  set(reason "")
  set(features "")
  if(NOT compile_ok)
    string(REGEX MATCH "error: [^\n]*" reason "${compile_output}")
    if(NOT reason)
      set(reason "the probe does not compile")
    endif()
    set(reason "does not compile cleanly: ${reason}")
  elseif(NOT run_result STREQUAL "0")
    string(REGEX MATCHALL "missing: [^\n]*" missing "${run_output}")
    if(missing)
      string(REPLACE "missing: " "" missing "${missing}")
      list(JOIN missing ", " missing)
      set(reason "compiles, but this CPU lacks ${missing}")
    else()
      set(reason "compiles, but the probe fails when run (${run_result}): ${run_output}")
    endif()
  else()
    string(REGEX MATCH "features: ([^\n]*)" line "${run_output}")
    string(STRIP "${CMAKE_MATCH_1}" features)
    set(ok TRUE)
  endif()
  set(${prefix}_OK ${ok} PARENT_SCOPE)
  set(${prefix}_REASON "${reason}" PARENT_SCOPE)
  set(${prefix}_FEATURES "${features}" PARENT_SCOPE)
endfunction()

# The feature macros (#define __X__ 1) the compiler defines with `flags`, as a sorted list.
function(canopy_isa_feature_macros flags out)
  execute_process(COMMAND ${CMAKE_CXX_COMPILER} ${flags} -dM -E -x c++ /dev/null
                  OUTPUT_VARIABLE macros ERROR_QUIET RESULT_VARIABLE status)
  set(names "")
  if(status EQUAL 0)
    string(REGEX MATCHALL "#define __[A-Z0-9_]+__ 1\n" lines "${macros}")
    foreach(line IN LISTS lines)
      string(REGEX REPLACE "#define __([A-Z0-9_]+)__ 1\n" "\\1" name "${line}")
      list(APPEND names "${name}")
    endforeach()
    list(SORT names)
  endif()
  set(${out} "${names}" PARENT_SCOPE)
endfunction()

# The -m flag name of a feature macro: SSE4_2 -> sse4.2, AVX512VL -> avx512vl, AVX10_1_512 ->
# avx10.1-512, AMX_BF16 -> amx-bf16. A wrong guess is caught by the comparison that follows.
function(canopy_isa_flag_name macro out)
  string(TOLOWER "${macro}" name)
  if(name MATCHES "[0-9]_[0-9]_[0-9]+$")
    string(REGEX REPLACE "([0-9])_([0-9])_([0-9]+)$" "\\1.\\2-\\3" name "${name}")
  else()
    string(REGEX REPLACE "([0-9])_([0-9]+)$" "\\1.\\2" name "${name}")
  endif()
  string(REPLACE "_" "-" dotted "${name}")
  set(${out} "${dotted}" PARENT_SCOPE)
endfunction()

# Resolves the probed 'native' into portable flags; sets <prefix>_NAME, <prefix>_FLAGS,
# <prefix>_HOW (one line for the report).
function(canopy_isa_resolve_native prefix)
  canopy_isa_feature_macros("-march=native" native_macros)
  execute_process(COMMAND ${CMAKE_CXX_COMPILER} -march=native "-###" -c -x c++ /dev/null -o /dev/null
                  ERROR_VARIABLE driver OUTPUT_QUIET)
  string(REGEX MATCH "\"-target-cpu\" \"([^\"]+)\"" found "${driver}")
  set(cpu "${CMAKE_MATCH_1}")
  if(cpu)
    canopy_isa_feature_macros("-march=${cpu}" cpu_macros)
    set(flags "-march=${cpu}")
    set(only_cpu ${cpu_macros})
    list(REMOVE_ITEM only_cpu ${native_macros})
    set(only_native ${native_macros})
    list(REMOVE_ITEM only_native ${cpu_macros})
    foreach(m IN LISTS only_native)
      canopy_isa_flag_name("${m}" f)
      list(APPEND flags "-m${f}")
    endforeach()
    foreach(m IN LISTS only_cpu)
      canopy_isa_flag_name("${m}" f)
      list(APPEND flags "-mno-${f}")
    endforeach()
    canopy_isa_feature_macros("${flags}" resolved_macros)
    if(resolved_macros STREQUAL native_macros)
      canopy_isa_probe("${flags}" resolved)
      if(resolved_OK)
        list(JOIN flags " " shown)
        set(${prefix}_NAME "${cpu}" PARENT_SCOPE)
        set(${prefix}_FLAGS "${flags}" PARENT_SCOPE)
        set(${prefix}_HOW "kept, resolved to ${shown} (the same feature macros)" PARENT_SCOPE)
        return()
      endif()
    endif()
  endif()
  foreach(level x86-64-v4 x86-64-v3 x86-64-v2 x86-64)
    canopy_isa_feature_macros("-march=${level}" level_macros)
    set(extra ${level_macros})
    list(REMOVE_ITEM extra ${native_macros})
    if(level_macros AND NOT extra)
      set(${prefix}_NAME "${level}" PARENT_SCOPE)
      set(${prefix}_FLAGS "-march=${level}" PARENT_SCOPE)
      set(${prefix}_HOW "kept, resolved to ${level}, the highest x86-64 level it covers (no flag set names '${cpu}' as this host exactly)" PARENT_SCOPE)
      return()
    endif()
  endforeach()
  message(FATAL_ERROR "canopy: ISA probe: -march=native passed the probe, but no portable flags describe it")
endfunction()

# The probe runs again only when what it depends on changes.
execute_process(COMMAND ${CMAKE_CXX_COMPILER} --version OUTPUT_VARIABLE canopy_compiler_version ERROR_QUIET)
file(SHA256 "${PROJECT_SOURCE_DIR}/cmake/isa_probe.cpp" canopy_probe_hash)
file(SHA256 "${PROJECT_SOURCE_DIR}/modules/isa/cpu_features.hpp" canopy_features_hash)
file(SHA256 "${CMAKE_CURRENT_LIST_FILE}" canopy_isa_cmake_hash)
cmake_host_system_information(RESULT canopy_host_cpu QUERY PROCESSOR_DESCRIPTION)
string(SHA256 canopy_isa_key "${CMAKE_CXX_COMPILER}|${canopy_compiler_version}|${CMAKE_CXX_FLAGS}|${CANOPY_ARCH}|\
${CANOPY_ARCH_CANDIDATES}|$ENV{CANOPY_ASSUME_CPU_FEATURES}|${canopy_probe_hash}|${canopy_features_hash}|${canopy_isa_cmake_hash}|${canopy_host_cpu}")

if(NOT CANOPY_ISA_KEY STREQUAL canopy_isa_key)
  if(CANOPY_ARCH)
    set(candidates "${CANOPY_ARCH}")
  else()
    set(candidates ${CANOPY_ARCH_CANDIDATES})
  endif()
  set(report "")
  set(chosen "")
  foreach(candidate IN LISTS candidates)
    canopy_isa_probe("-march=${candidate}" probe)
    if(probe_OK)
      set(chosen "${candidate}")
      if(candidate STREQUAL "native")
        canopy_isa_resolve_native(native)
        set(name "${native_NAME}")
        set(flags "${native_FLAGS}")
        list(APPEND report "native: ${native_HOW}")
        canopy_isa_probe("${flags}" probe)
      else()
        set(name "${candidate}")
        set(flags "-march=${candidate}")
      endif()
      break()
    endif()
    list(APPEND report "${candidate}: rejected, ${probe_REASON}")
  endforeach()
  if(NOT chosen)
    list(JOIN report "\n  " why)
    if(CANOPY_ARCH)
      message(FATAL_ERROR "canopy: CANOPY_ARCH=${CANOPY_ARCH} cannot be used on this machine:\n  ${why}")
    endif()
    message(FATAL_ERROR "canopy: no ISA candidate passed the probe (CANOPY_ARCH_CANDIDATES):\n  ${why}")
  endif()
  set(CANOPY_ISA "${name}" CACHE INTERNAL "ISA the library is compiled for")
  set(CANOPY_ISA_FLAGS "${flags}" CACHE INTERNAL "ISA flags of the library and its importers")
  set(CANOPY_ISA_FEATURES "${probe_FEATURES}" CACHE INTERNAL "features checked at start-up")
  set(CANOPY_ISA_REPORT "${report}" CACHE INTERNAL "what the ISA probe tried")
  set(CANOPY_ISA_KEY "${canopy_isa_key}" CACHE INTERNAL "inputs of the last ISA probe")
endif()

foreach(line IN LISTS CANOPY_ISA_REPORT)
  message(STATUS "canopy: ISA probe: ${line}")
endforeach()
list(JOIN CANOPY_ISA_FLAGS " " canopy_isa_flags_shown)
message(STATUS "canopy: ISA ${CANOPY_ISA} (${canopy_isa_flags_shown}), features: ${CANOPY_ISA_FEATURES}")
