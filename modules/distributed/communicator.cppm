// canopy.distributed:communicator — a process's place in the job (rank, size) and the few
// collectives the library needs. A default-constructed communicator is "solo": rank 0 of 1, and
// it never calls MPI (a program started without mpirun).
module;
#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <vector>
#include <mpi.h>
export module canopy.distributed:communicator;

namespace canopy::distributed {

// Set by session while MPI is initialised.
bool& mpi_running() {
    static bool running = false;
    return running;
}

void check(int code, char const* what) {
    if (code == MPI_SUCCESS) return;
    char text[MPI_MAX_ERROR_STRING];
    int length = 0;
    MPI_Error_string(code, text, &length);
    throw std::runtime_error(std::string("MPI: ") + what + " failed: " + std::string(text, std::size_t(length)));
}

export class communicator {
public:
    // Solo: rank 0 of 1, no MPI.
    communicator() = default;

    // MPI_COMM_WORLD when MPI is running (a session exists), else solo.
    static communicator world() {
        communicator c;
        if (!mpi_running()) return c;
        c.mpi_ = true;
        check(MPI_Comm_rank(MPI_COMM_WORLD, &c.rank_), "MPI_Comm_rank");
        check(MPI_Comm_size(MPI_COMM_WORLD, &c.size_), "MPI_Comm_size");
        return c;
    }

    int rank() const { return rank_; }
    int size() const { return size_; }
    bool root() const { return rank_ == 0; }
    // False for a solo communicator: then no member calls MPI.
    bool uses_mpi() const { return mpi_; }
    MPI_Comm handle() const { return MPI_COMM_WORLD; }

    void barrier() const {
        if (mpi_) check(MPI_Barrier(MPI_COMM_WORLD), "MPI_Barrier");
    }

    // The sum over all ranks, on every rank.
    std::uint64_t sum(std::uint64_t value) const {
        if (!mpi_) return value;
        unsigned long long in = value, out = 0;
        check(MPI_Allreduce(&in, &out, 1, MPI_UNSIGNED_LONG_LONG, MPI_SUM, MPI_COMM_WORLD), "MPI_Allreduce");
        return out;
    }

    // Every rank's value, in rank order, on rank 0 (empty on the others).
    std::vector<double> gather(double value) const {
        if (!mpi_) return {value};
        std::vector<double> all(root() ? std::size_t(size_) : 0);
        check(MPI_Gather(&value, 1, MPI_DOUBLE, all.data(), 1, MPI_DOUBLE, 0, MPI_COMM_WORLD), "MPI_Gather");
        return all;
    }

    // Rank `from`'s text, on every rank.
    std::string broadcast(std::string text, int from) const {
        if (!mpi_) return text;
        unsigned long long length = text.size();
        check(MPI_Bcast(&length, 1, MPI_UNSIGNED_LONG_LONG, from, MPI_COMM_WORLD), "MPI_Bcast");
        text.resize(std::size_t(length));
        for (std::size_t done = 0; done < text.size();) {
            int const piece = int(std::min<std::size_t>(text.size() - done, 1u << 30));
            check(MPI_Bcast(text.data() + done, piece, MPI_CHAR, from, MPI_COMM_WORLD), "MPI_Bcast");
            done += std::size_t(piece);
        }
        return text;
    }

    // Ends every process of the job at once (mpirun reports it): for failures after which the
    // ranks can no longer meet.
    [[noreturn]] void abort(int status) const {
        if (mpi_) MPI_Abort(MPI_COMM_WORLD, status);
        std::exit(status);
    }

private:
    bool mpi_ = false;
    int rank_ = 0;
    int size_ = 1;
};

} // namespace canopy::distributed
