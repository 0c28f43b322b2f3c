# The configure-time ISA probe's logic, on any CPU (run by ctest in script mode):
#   cmake -DSOURCE_DIR=... -DWORK_DIR=... -DCXX=... -DGENERATOR=... -P isa_probe_test.cmake
# configures the project three times and checks what the probe printed and chose:
#  1. a candidate that does not compile is rejected with the compiler's reason, and the next is kept;
#  2. with the CPU taken to have only x86-64-v2's features (CANOPY_ASSUME_CPU_FEATURES), native,
#     x86-64-v4 and x86-64-v3 are rejected at run time, each naming what the CPU lacks, and
#     x86-64-v2 is kept: the case of a native that does not run falls through;
#  3. a CANOPY_ARCH that fails the probe is a configure error that says why.
set(common -G "${GENERATOR}" -DCMAKE_CXX_COMPILER=${CXX} -DCANOPY_BUILD_TESTS=OFF -DCANOPY_BUILD_EXAMPLES=OFF)

function(configure name expect_success)
  file(REMOVE_RECURSE "${WORK_DIR}/${name}")
  execute_process(COMMAND ${CMAKE_COMMAND} -E env ${ARGN} -- ${CMAKE_COMMAND} -S "${SOURCE_DIR}"
                          -B "${WORK_DIR}/${name}" ${common} ${configure_args}
                  OUTPUT_VARIABLE out ERROR_VARIABLE err RESULT_VARIABLE status)
  set(output "${out}${err}" PARENT_SCOPE)
  if(expect_success AND NOT status EQUAL 0)
    message(FATAL_ERROR "${name}: configure failed:\n${out}${err}")
  elseif(NOT expect_success AND status EQUAL 0)
    message(FATAL_ERROR "${name}: configure succeeded, an error was expected:\n${out}${err}")
  endif()
endfunction()

function(expect name text)
  string(FIND "${output}" "${text}" at)
  if(at EQUAL -1)
    message(FATAL_ERROR "${name}: expected \"${text}\" in:\n${output}")
  endif()
endfunction()

# One of several texts: where more than one outcome is right on some machine.
function(expect_one_of name)
  foreach(text IN LISTS ARGN)
    string(FIND "${output}" "${text}" at)
    if(NOT at EQUAL -1)
      return()
    endif()
  endforeach()
  list(JOIN ARGN "\" or \"" texts)
  message(FATAL_ERROR "${name}: expected \"${texts}\" in:\n${output}")
endfunction()

set(configure_args "-DCANOPY_ARCH_CANDIDATES=no-such-cpu\;x86-64-v2")
configure(uncompilable TRUE)
expect(uncompilable "canopy: ISA probe: no-such-cpu: rejected, does not compile cleanly: error: unknown target CPU 'no-such-cpu'")
expect(uncompilable "canopy: ISA x86-64-v2 (-march=x86-64-v2), features: sse3 ssse3 cx16 sse4.1 sse4.2 popcnt")

set(configure_args "")
configure(native_rejected TRUE "CANOPY_ASSUME_CPU_FEATURES=sse3 ssse3 cx16 sse4.1 sse4.2 popcnt")
# Native falls through either way: at run time, or where clang's -march=native does not even
# compile cleanly (some Intel Xeons: "invalid feature combination: +avx10.1-256").
expect_one_of(native_rejected "canopy: ISA probe: native: rejected, compiles, but this CPU lacks "
              "canopy: ISA probe: native: rejected, does not compile cleanly: ")
expect(native_rejected "canopy: ISA probe: x86-64-v4: rejected, compiles, but this CPU lacks fma, movbe, avx, f16c, bmi, avx2, bmi2, avx512f, avx512dq, avx512cd, avx512bw, avx512vl, lzcnt")
expect(native_rejected "canopy: ISA probe: x86-64-v3: rejected, compiles, but this CPU lacks fma, movbe, avx, f16c, bmi, avx2, bmi2, lzcnt")
expect(native_rejected "canopy: ISA x86-64-v2 (-march=x86-64-v2)")

set(configure_args "-DCANOPY_ARCH=no-such-cpu")
configure(bad_arch FALSE)
expect(bad_arch "canopy: CANOPY_ARCH=no-such-cpu cannot be used on this machine")
expect(bad_arch "no-such-cpu: rejected, does not compile cleanly: error: unknown target CPU 'no-such-cpu'")

file(REMOVE_RECURSE "${WORK_DIR}")
message(STATUS "isa probe: falls through rejected candidates (compile and run), refuses a bad CANOPY_ARCH")
