// canopy.distributed:agreement — error propagation. After a step that may fail on some ranks
// (loading a scene, writing an output), every rank calls agree() with its own error (empty when
// it succeeded): one MPI_Allreduce of the lowest failing rank, then a broadcast of that rank's
// message. Every rank then stops with the same message, and none waits for a rank that has
// given up.
module;
#include <exception>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <mpi.h>
export module canopy.distributed:agreement;
import :communicator;

export namespace canopy::distributed {

// The error of the lowest failing rank, thrown on every rank.
struct remote_failure : std::runtime_error {
    remote_failure(int failed_rank, std::string const& message, bool here)
        : std::runtime_error(message), rank(failed_rank), local(here) {}
    int rank;   // the failing rank
    bool local; // true on that rank itself
};

// Collective: every rank calls it. Throws remote_failure on every rank when any rank passed an
// error (a non-empty message), with the message of the lowest such rank.
void agree(communicator const& comm, std::string const& local_error) {
    int first = comm.size();
    if (comm.uses_mpi()) {
        int const mine = local_error.empty() ? comm.size() : comm.rank();
        check(MPI_Allreduce(&mine, &first, 1, MPI_INT, MPI_MIN, comm.handle()), "MPI_Allreduce");
    } else if (!local_error.empty()) {
        first = 0;
    }
    if (first == comm.size()) return;
    std::string const message = comm.broadcast(comm.rank() == first ? local_error : std::string(), first);
    throw remote_failure(first, message.empty() ? "an error without a message" : message, comm.rank() == first);
}

// Runs step() on this rank, then agree()s: the text of an exception step() threw (what(), or
// `describe` of it when given) is this rank's error.
void checked(communicator const& comm, std::function<void()> const& step,
             std::function<std::string(std::exception_ptr)> const& describe = {}) {
    std::string error;
    try {
        step();
    } catch (...) {
        if (describe) {
            error = describe(std::current_exception());
        } else {
            try {
                throw;
            } catch (std::exception const& e) {
                error = e.what();
            } catch (...) {
                error = "an unknown error";
            }
        }
        if (error.empty()) error = "an error without a message";
    }
    agree(comm, error);
}

} // namespace canopy::distributed
