# Compile options shared by every Canopy target.
#
# canopy_isa      PUBLIC on the module targets: ISA and floating-point semantics must be identical
#                 for a module and its importers (a BMI built with -march=X cannot be imported
#                 without it, and templates are instantiated with the importer's flags). The ISA
#                 flags are the ones the configure-time probe chose (cmake/CanopyIsa.cmake).
# canopy_program  linked by every executable of the project: the start-up CPU check
#                 (modules/isa/cpu_guard.cpp), which ends the program with a clear message on a
#                 CPU without the library's ISA.
# Warnings: CMAKE_CXX_FLAGS of this project only (never exported).

# Warnings for everything this project compiles, through CMAKE_CXX_FLAGS so that no target
# property (which installed module targets export to their importers) carries them. The ISA
# probe compiles with them too.
string(APPEND CMAKE_CXX_FLAGS " -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wno-sign-conversion")
if(CANOPY_WARNINGS_AS_ERRORS)
  string(APPEND CMAKE_CXX_FLAGS " -Werror")
endif()

include(CanopyIsa)

add_library(canopy_isa INTERFACE)
target_compile_options(canopy_isa INTERFACE ${CANOPY_ISA_FLAGS})
# Watertight triangle tests depend on the exact evaluation order: pin contraction, never fast-math.
target_compile_options(canopy_isa INTERFACE "-ffp-contract=${CANOPY_FP_CONTRACT}" -fno-fast-math)
# CANOPY_DCHECK (modules/include/canopy/check.hpp): PUBLIC, so that the package records whether its
# preconditions are checked.
target_include_directories(canopy_isa INTERFACE $<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}/modules/include>
                                                $<INSTALL_INTERFACE:include>)
if(CANOPY_DCHECKS)
  target_compile_definitions(canopy_isa INTERFACE CANOPY_DCHECKS=1)
endif()
if(CANOPY_SANITIZE)
  list(JOIN CANOPY_SANITIZE "," canopy_sanitizers)
  target_compile_options(canopy_isa INTERFACE "-fsanitize=${canopy_sanitizers}" -fno-omit-frame-pointer
                         -fno-sanitize-recover=all)
  target_link_options(canopy_isa INTERFACE "-fsanitize=${canopy_sanitizers}")
  if(CANOPY_NO_SANITIZE)
    list(JOIN CANOPY_NO_SANITIZE "," canopy_no_sanitizers)
    target_compile_options(canopy_isa INTERFACE "-fno-sanitize=${canopy_no_sanitizers}")
  endif()
endif()
