// The main of distributed_test: MPI for the whole run when started by mpirun (every rank runs
// every test case), none otherwise.
#define CATCH_CONFIG_RUNNER
#include <catch2/catch.hpp>

import canopy.distributed;

int main(int argc, char** argv) {
    canopy::distributed::session mpi(argc, argv);
    return Catch::Session().run(argc, argv);
}
