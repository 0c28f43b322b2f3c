// The processes of `canopy` and what they are doing (processes.hpp).
#include "processes.hpp"
#include <new>
#include <stdexcept>
#include <fmt/core.h>

namespace cli {

namespace {

std::string current_step = "starting";

// How the ranks shared the last job out (printed by rank 0 under mpirun).
struct sharing_report {
    std::size_t rank_count = 1;
    std::uint64_t messages = 0, bytes = 0;
    std::vector<std::size_t> items_per_rank;
    std::vector<double> wait_seconds, ranges_per_rank;
};
sharing_report last_sharing;

} // namespace

void step(std::string what) { current_step = std::move(what); }

#if CANOPY_WITH_MPI
dist::communicator ranks;

void record_sharing(dist::deal_report const& r) {
    last_sharing = {std::size_t(ranks.size()), r.messages, ranks.sum(r.result_bytes), r.items_per_rank,
                    ranks.gather(r.wait_seconds), ranks.gather(double(r.ranges))};
}
#endif

// Under mpirun: how the work was shared (rank 0, standard error).
void print_sharing(char const* what) {
    if (!distributed() || !root_rank()) return;
    sharing_report const& r = last_sharing;
    std::string shares;
    double ranges = 0.0, waited = 0.0;
    for (std::size_t k = 0; k < r.items_per_rank.size(); ++k) {
        shares += fmt::format("{}{}", k ? "/" : "", r.items_per_rank[k]);
        ranges += r.ranges_per_rank[k];
        if (k > 0) waited += r.wait_seconds[k];
    }
    double const remote_ranges = ranges - (r.ranges_per_rank.empty() ? 0.0 : r.ranges_per_rank[0]);
    fmt::print(stderr, "{} ranks: {} per rank {}, {} ranges, {} messages to rank 0, {:.2f} MB gathered, {:.3f} ms "
                       "waited per range away from rank 0\n",
               r.rank_count, what, shares, ranges, r.messages, double(r.bytes) * 1e-6,
               remote_ranges > 0 ? waited / remote_ranges * 1e3 : 0.0);
}

// The message of an exception, as the program prints it after "canopy: ".
std::string error_text(std::exception_ptr error) {
    try {
        std::rethrow_exception(error);
    } catch (std::bad_alloc const&) {
        return "out of memory while " + current_step;
    } catch (std::length_error const& e) {
        return "an allocation too large for memory while " + current_step + " (" + e.what() + ")";
    } catch (std::exception const& e) {
        return e.what();
    } catch (...) {
        return "unexpected error while " + current_step;
    }
}

} // namespace cli
