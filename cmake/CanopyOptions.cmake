# Compile options shared by every Canopy target.
#
# canopy_isa      PUBLIC on the module targets: ISA and floating-point semantics must be identical
#                 for a module and its importers (a BMI built with -march=X cannot be imported
#                 without it, and templates are instantiated with the importer's flags).
# Warnings: CMAKE_CXX_FLAGS of this project only (never exported).

add_library(canopy_isa INTERFACE)
if(CANOPY_ARCH)
  target_compile_options(canopy_isa INTERFACE "-march=${CANOPY_ARCH}")
endif()
# Watertight triangle tests depend on the exact evaluation order: pin contraction, never fast-math.
target_compile_options(canopy_isa INTERFACE "-ffp-contract=${CANOPY_FP_CONTRACT}" -fno-fast-math)
if(CANOPY_SANITIZE)
  list(JOIN CANOPY_SANITIZE "," canopy_sanitizers)
  target_compile_options(canopy_isa INTERFACE "-fsanitize=${canopy_sanitizers}" -fno-omit-frame-pointer
                         -fno-sanitize-recover=all)
  target_link_options(canopy_isa INTERFACE "-fsanitize=${canopy_sanitizers}")
endif()

# Warnings for everything this project compiles, through CMAKE_CXX_FLAGS so that no target
# property (which installed module targets export to their importers) carries them.
string(APPEND CMAKE_CXX_FLAGS " -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wno-sign-conversion")
if(CANOPY_WARNINGS_AS_ERRORS)
  string(APPEND CMAKE_CXX_FLAGS " -Werror")
endif()
# Kept for the project's executables that name it; the flags above already apply to them.
add_library(canopy_warnings INTERFACE)
