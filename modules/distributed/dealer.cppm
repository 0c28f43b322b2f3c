// canopy.distributed:dealer — the dynamic work dealer. `items` work items (image tiles, chunks
// of a ray file) are handed out in ranges on request: a rank asks rank 0 for work, computes the
// range, sends the result back with its next request, and so on until nothing is left, so that
// fast ranks take more. The range sizes shrink as the work runs out (guided scheduling: a
// quarter of what is left per rank, at most max_batch items, at least one), so the last ranges
// are single items and the ranks finish together.
//
// Rank 0 works too: its main thread serves the requests (MPI_Iprobe, then a 50 µs sleep when no
// message waits, so it takes little CPU) while one extra thread of rank 0 takes ranges from the
// same counter and computes them. Only the main threads call MPI (MPI_THREAD_FUNNELED); the work
// may use oneTBB inside a range.
//
// A rank other than 0 keeps one request ahead: it asks for its next range before it computes
// the current one, so the answer's latency (rank 0's polling, the network) hides behind the work.
//
// Results are gathered on rank 0: collect(range, bytes) is called there for every range, in the
// order the results arrive, serialised (never two at once). A range's bytes are whatever work()
// returned for it on the rank that computed it. The ranges are the same whatever the rank count
// only in their union: a result must depend on the item, not on the range.
//
// Errors: work() or collect() throwing stops the dealing (ranks still working finish their
// current range, then receive no more), and deal() throws remote_failure on every rank with the
// message of the lowest failing rank (agreement). A rank that dies (a crash, a kill) cannot
// answer: mpirun then aborts the whole job.
module;
#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <functional>
#include <limits>
#include <mutex>
#include <span>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>
#include <mpi.h>
export module canopy.distributed:dealer;
import :communicator;
import :agreement;

namespace canopy::distributed {

export struct item_range {
    std::size_t first = 0, count = 0; // items [first, first + count)
};

export struct deal_options {
    std::size_t max_batch = 64; // most items in one range
    // Rank 0: called with the items gathered so far and the total, after each collect.
    std::function<void(std::size_t done, std::size_t total)> progress;
};

// What this rank did (rank 0's report also has every rank's share).
export struct deal_report {
    std::size_t items = 0, ranges = 0;     // computed by this rank
    std::uint64_t result_bytes = 0;        // of this rank's results (sent to rank 0, or kept there)
    double wait_seconds = 0.0;             // waiting for an answer of rank 0 (ranks other than 0)
    double seconds = 0.0;                  // deal() from start to end on this rank
    std::vector<std::size_t> items_per_rank; // rank 0 only: every rank's items
    std::uint64_t messages = 0;            // rank 0 only: requests and results received
    double serve_seconds = 0.0;            // rank 0 only: its main thread receiving and answering
                                           // them (the serial part of the dealing)
};

enum tag : int { request_tag = 1, result_tag = 2, error_tag = 3, assign_tag = 4 };

// The next range of a counter: guided, shrinking to single items.
struct counter {
    std::size_t next = 0, total = 0, ranks = 1, max_batch = 64;
    bool stopped = false;
    std::mutex mutex;

    item_range take() {
        std::lock_guard lock(mutex);
        if (stopped || next >= total) return {next, 0};
        std::size_t const left = total - next;
        std::size_t const n = std::clamp<std::size_t>(left / (4 * ranks), 1, std::max<std::size_t>(1, max_batch));
        item_range const r{next, std::min(n, left)};
        next += r.count;
        return r;
    }
    void stop() {
        std::lock_guard lock(mutex);
        stopped = true;
    }
};

std::string what(std::exception_ptr e) {
    try {
        std::rethrow_exception(e);
    } catch (std::exception const& x) {
        return *x.what() ? x.what() : "an error without a message";
    } catch (...) {
        return "an unknown error";
    }
}

double since(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

export using work_function = std::function<std::vector<std::byte>(item_range)>;
export using collect_function = std::function<void(item_range, std::span<std::byte const>)>;

// Collective: every rank of `comm` calls it with the same `items`. work() runs on every rank;
// collect() and options.progress on rank 0 only.
export deal_report deal(communicator const& comm, std::size_t items, work_function const& work,
                        collect_function const& collect, deal_options const& options = {}) {
    auto const start = std::chrono::steady_clock::now();
    deal_report report;
    counter dealer;
    dealer.total = items;
    dealer.ranks = std::size_t(comm.size());
    dealer.max_batch = options.max_batch;
    std::string error; // this rank's
    std::mutex collect_mutex;
    std::size_t gathered = 0;
    if (comm.root()) report.items_per_rank.assign(std::size_t(comm.size()), 0);

    // Rank 0's results, and the remote ones its main thread receives.
    auto const gather = [&](int from, item_range r, std::span<std::byte const> bytes) {
        std::lock_guard lock(collect_mutex);
        collect(r, bytes);
        gathered += r.count;
        report.items_per_rank[std::size_t(from)] += r.count;
        if (options.progress) options.progress(gathered, items);
    };
    // Rank 0's failures (its work, or collect): the first is its error; the dealing stops.
    auto const record_failure = [&] {
        dealer.stop();
        std::lock_guard lock(collect_mutex);
        if (error.empty()) error = what(std::current_exception());
    };
    // Rank 0's own share: takes ranges until none is left or something failed.
    auto const local_worker = [&] {
        try {
            for (item_range r = dealer.take(); r.count > 0; r = dealer.take()) {
                std::vector<std::byte> const bytes = work(r);
                report.items += r.count;
                ++report.ranges;
                report.result_bytes += bytes.size();
                gather(0, r, bytes);
            }
        } catch (...) {
            record_failure();
        }
    };

    if (!comm.uses_mpi() || comm.size() == 1) {
        local_worker();
    } else if (comm.root()) {
        std::thread worker(local_worker);
        // Per rank: ranges dealt and not yet gathered, and whether it has been told "no more"
        // (or has stopped on an error).
        std::vector<std::size_t> outstanding(std::size_t(comm.size()), 0);
        std::vector<char> finished(std::size_t(comm.size()), 0);
        int active = comm.size() - 1;
        std::vector<std::byte> buffer;
        try {
            while (active > 0) {
                int flag = 0;
                MPI_Status status;
                check(MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, comm.handle(), &flag, &status), "MPI_Iprobe");
                if (!flag) {
                    std::this_thread::sleep_for(std::chrono::microseconds(50));
                    continue;
                }
                auto const served = std::chrono::steady_clock::now();
                int bytes = 0;
                check(MPI_Get_count(&status, MPI_BYTE, &bytes), "MPI_Get_count");
                buffer.resize(std::size_t(bytes));
                int const from = status.MPI_SOURCE;
                check(MPI_Recv(buffer.data(), bytes, MPI_BYTE, from, status.MPI_TAG, comm.handle(), MPI_STATUS_IGNORE),
                      "MPI_Recv");
                ++report.messages;
                std::size_t const r = std::size_t(from);
                bool const was_done = finished[r] && outstanding[r] == 0;
                if (status.MPI_TAG == error_tag) { // that rank stopped; agree() brings its message
                    dealer.stop();
                    finished[r] = 1;
                    outstanding[r] = 0;
                } else if (status.MPI_TAG == result_tag) {
                    std::uint64_t header[2];
                    if (buffer.size() < sizeof header) throw std::runtime_error("a malformed result from a rank");
                    std::memcpy(header, buffer.data(), sizeof header);
                    if (outstanding[r] > 0) --outstanding[r];
                    bool stopped;
                    {
                        std::lock_guard lock(dealer.mutex);
                        stopped = dealer.stopped;
                    }
                    if (!stopped) try {
                            gather(from, {header[0], header[1]},
                                   std::span<std::byte const>(buffer).subspan(sizeof header));
                        } catch (...) { // collect() failed: stop, and agree() below carries it
                            record_failure();
                        }
                } else { // a request: the next range, or none
                    item_range const next = dealer.take();
                    std::uint64_t const answer[2] = {next.first, next.count};
                    check(MPI_Send(answer, 2, MPI_UINT64_T, from, assign_tag, comm.handle()), "MPI_Send");
                    if (next.count > 0) ++outstanding[r];
                    else finished[r] = 1;
                }
                if (!was_done && finished[r] && outstanding[r] == 0) --active;
                report.serve_seconds += since(served);
            }
        } catch (...) {
            // An MPI failure here leaves ranks waiting for an answer: end the job.
            dealer.stop();
            worker.join();
            std::fprintf(stderr, "canopy: rank 0 cannot deal out work: %s\n", what(std::current_exception()).c_str());
            comm.abort(1);
        }
        worker.join();
    } else {
        // One range ahead: the request for the next range goes out before this one is computed,
        // so the answer's latency hides behind the work.
        std::uint64_t current[2] = {0, 0}, next[2] = {0, 0};
        std::vector<std::byte> message;
        MPI_Request pending = MPI_REQUEST_NULL;
        auto const wait_for_next = [&] {
            auto const asked = std::chrono::steady_clock::now();
            check(MPI_Wait(&pending, MPI_STATUS_IGNORE), "MPI_Wait");
            report.wait_seconds += since(asked);
            current[0] = next[0];
            current[1] = next[1];
        };
        auto const request = [&] {
            check(MPI_Irecv(next, 2, MPI_UINT64_T, 0, assign_tag, comm.handle(), &pending), "MPI_Irecv");
            check(MPI_Send(nullptr, 0, MPI_BYTE, 0, request_tag, comm.handle()), "MPI_Send");
        };
        request();
        wait_for_next();
        try {
            while (current[1] > 0) {
                request();
                std::vector<std::byte> const bytes = work({current[0], current[1]});
                report.items += current[1];
                ++report.ranges;
                report.result_bytes += bytes.size();
                message.resize(sizeof current + bytes.size());
                if (message.size() > std::size_t(std::numeric_limits<int>::max()))
                    throw std::runtime_error("the result of items " + std::to_string(current[0]) + " to " +
                                             std::to_string(current[0] + current[1] - 1) +
                                             " is over 2 GiB: too large for one message");
                std::memcpy(message.data(), current, sizeof current);
                std::memcpy(message.data() + sizeof current, bytes.data(), bytes.size());
                check(MPI_Send(message.data(), int(message.size()), MPI_BYTE, 0, result_tag, comm.handle()), "MPI_Send");
                wait_for_next();
            }
        } catch (...) {
            error = what(std::current_exception());
            check(MPI_Send(error.data(), int(std::min<std::size_t>(error.size(), 1u << 20)), MPI_CHAR, 0, error_tag,
                           comm.handle()),
                  "MPI_Send");
            if (pending != MPI_REQUEST_NULL) check(MPI_Wait(&pending, MPI_STATUS_IGNORE), "MPI_Wait");
        }
    }
    report.seconds = since(start);
    agree(comm, error);
    return report;
}

} // namespace canopy::distributed
