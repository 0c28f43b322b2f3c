// canopy.distributed:session — MPI for the lifetime of a session object, and only when the
// program was started by mpirun (or another launcher setting the PMIx/PMI variables): a plain
// run never initialises MPI (no "singleton" MPI_Init, which is slow and fails in some containers).
module;
#include <cstdlib>
#include <initializer_list>
#include <mpi.h>
export module canopy.distributed:session;
import :communicator;

namespace canopy::distributed {

// True when the environment says that an MPI launcher started this process: Open MPI's
// OMPI_COMM_WORLD_SIZE, PMIx's PMIX_RANK, or PMI's PMI_RANK (MPICH, Slurm).
export bool launched_by_mpirun() {
    for (char const* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK"})
        if (char const* v = std::getenv(name); v && *v) return true;
    return false;
}

// MPI_Init_thread(MPI_THREAD_FUNNELED) when launched_by_mpirun(), MPI_Finalize at the end; nothing
// otherwise. At most one per program, constructed on the main thread (which alone calls MPI).
export class session {
public:
    session(int& argc, char**& argv) {
        if (!launched_by_mpirun()) return;
        int provided = 0;
        check(MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided), "MPI_Init_thread");
        mpi_running() = true;
        active_ = true;
    }
    session(session const&) = delete;
    session& operator=(session const&) = delete;
    ~session() {
        if (!active_) return;
        mpi_running() = false;
        MPI_Finalize();
    }

    bool active() const { return active_; }
    communicator world() const { return communicator::world(); }

private:
    bool active_ = false;
};

} // namespace canopy::distributed
