// The processes of `canopy` and what they are doing: the step for error messages, and under
// mpirun (a build with CANOPY_WITH_MPI, more than one process) the ranks that share `render` and
// `trace` out (canopy.distributed). Started without mpirun, the program never touches MPI.
#pragma once
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <string>
#include <vector>
#if CANOPY_WITH_MPI
import canopy.distributed;
#endif

namespace cli {

using clock_type = std::chrono::steady_clock;

inline double seconds_since(clock_type::time_point start) {
    return std::chrono::duration<double>(clock_type::now() - start).count();
}

// What the program is doing, for the message when memory runs out ("loading scene.obj").
void step(std::string what);

// The message of an exception, as the program prints it after "canopy: ".
std::string error_text(std::exception_ptr error);

// ---- processes (mpirun) ------------------------------------------------------------------------
// Started by mpirun, with more than one process: `render` and `trace` share their work out
// (canopy.distributed); rank 0 writes the outputs and prints, the other ranks print nothing.
#if CANOPY_WITH_MPI
namespace dist = canopy::distributed;
extern dist::communicator ranks; // solo (rank 0 of 1) unless under mpirun
inline bool distributed() { return ranks.size() > 1; }
inline bool root_rank() { return ranks.root(); }
// Collective: every rank's share of a deal, on rank 0 (for print_sharing).
void record_sharing(dist::deal_report const& r);
#else
inline bool distributed() { return false; }
inline bool root_rank() { return true; }
#endif

// Under mpirun: how the last job's work was shared (rank 0, standard error).
void print_sharing(char const* what);

// Runs step() on every rank; under mpirun every rank then learns whether any rank failed, and
// all stop with the message of the lowest failing one (canopy::distributed::agree), instead of
// waiting for a rank that gave up.
template <typename Step>
void on_every_rank(Step&& step) {
#if CANOPY_WITH_MPI
    if (distributed()) return dist::checked(ranks, step, error_text);
#endif
    step();
}

} // namespace cli
