# A broken precondition stops the program with CANOPY_DCHECK's message (tests/CMakeLists.txt).
#   -DPROGRAM=... -DCASE=... -DMESSAGE=...   PROGRAM CASE must fail, its output containing MESSAGE;
#                                             with CASE=valid it must succeed
execute_process(COMMAND "${PROGRAM}" "${CASE}" OUTPUT_VARIABLE out ERROR_VARIABLE out RESULT_VARIABLE rc)
if(CASE STREQUAL "valid")
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${PROGRAM} valid: a check fired where every precondition holds (${rc}):\n${out}")
  endif()
  return()
endif()
if(rc EQUAL 0)
  message(FATAL_ERROR "${PROGRAM} ${CASE} succeeded, but its precondition is broken:\n${out}")
endif()
string(FIND "${out}" "${MESSAGE}" at)
if(at EQUAL -1)
  message(FATAL_ERROR "${PROGRAM} ${CASE} stopped (${rc}) without saying '${MESSAGE}':\n${out}")
endif()
message(STATUS "${CASE}: ${out}")
