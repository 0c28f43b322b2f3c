# MPI for canopy.distributed and `mpirun ... canopy` (CANOPY_WITH_MPI: ON, AUTO or OFF).
# Sets CANOPY_MPI (ON when the MPI parts are built) and, then, the target MPI::MPI_CXX (the C API
# from C++: the project enables no C compiler; MPI_CXX_SKIP_MPICXX leaves out the old C++ bindings).
# ON and no MPI: a configure error. AUTO and no MPI: a warning, and the build goes on without.
set(CANOPY_MPI OFF)
string(TOUPPER "${CANOPY_WITH_MPI}" canopy_with_mpi)
if(NOT canopy_with_mpi MATCHES "^(ON|OFF|AUTO|TRUE|FALSE|YES|NO|1|0)$")
  message(FATAL_ERROR "canopy: CANOPY_WITH_MPI must be ON, OFF or AUTO, not '${CANOPY_WITH_MPI}'")
endif()
if(NOT canopy_with_mpi MATCHES "^(OFF|FALSE|NO|0)$")
  set(MPI_CXX_SKIP_MPICXX ON CACHE BOOL "MPI: the C API only (no deprecated C++ bindings)")
  find_package(MPI COMPONENTS CXX QUIET)
  if(MPI_CXX_FOUND)
    set(CANOPY_MPI ON)
    find_program(CANOPY_MPIEXEC NAMES mpirun mpiexec )
    message(STATUS "canopy: MPI ${MPI_CXX_VERSION} found (${MPI_CXX_LIBRARIES}): building canopy.distributed; "
                   "canopy runs under ${CANOPY_MPIEXEC}")
  elseif(canopy_with_mpi STREQUAL "AUTO")
    message(WARNING "canopy: no MPI found: building WITHOUT canopy.distributed and without mpirun support in "
                    "canopy (install libopenmpi-dev and openmpi-bin, e.g. with scripts/setup.sh; "
                    "-DCANOPY_WITH_MPI=OFF builds without MPI and silences this warning)")
  else()
    message(FATAL_ERROR "canopy: CANOPY_WITH_MPI=${CANOPY_WITH_MPI} but no MPI was found: install libopenmpi-dev "
                        "and openmpi-bin (scripts/setup.sh does), or configure with -DCANOPY_WITH_MPI=OFF")
  endif()
endif()
