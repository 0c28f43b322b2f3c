// canopy_bench_distributed — the dealer's cost per range: `ranges` ranges of one item each, each
// item "computed" by sleeping `work` microseconds (no CPU used, so that oversubscribed ranks do not
// distort it), each result `bytes` long (a 16×16 tile of float RGBA is 4096 bytes, 64 tiles
// 262144), dealt across the processes of mpirun. Prints, on rank 0, the wall time per range, the
// overhead per range against perfect sharing (wall · ranks / ranges − work), the time the ranks
// other than 0 waited for an answer per range (zero when the one-ahead request hides it), and
// the time rank 0's main thread spent per message received (receiving it and answering).
//   mpirun -np 2 canopy_bench_distributed [ranges [work-us [bytes...]]]
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <thread>
#include <vector>
import canopy.distributed;

int main(int argc, char** argv) {
    canopy::distributed::session mpi(argc, argv);
    auto const comm = mpi.world();
    std::size_t const ranges = argc > 1 ? std::size_t(std::strtoull(argv[1], nullptr, 10)) : 2000;
    long const work_us = argc > 2 ? std::strtol(argv[2], nullptr, 10) : 500;
    std::vector<std::size_t> sizes;
    for (int i = 3; i < argc; ++i) sizes.push_back(std::size_t(std::strtoull(argv[i], nullptr, 10)));
    if (sizes.empty()) sizes = {16, 4096, 65536, 262144, 1048576};
    if (comm.root()) std::printf("%d ranks, %zu ranges of one item, %ld us of work each\n", comm.size(), ranges, work_us);
    for (std::size_t bytes : sizes) {
        auto const report = canopy::distributed::deal(
            comm, ranges,
            [&](canopy::distributed::item_range) {
                std::this_thread::sleep_for(std::chrono::microseconds(work_us));
                return std::vector<std::byte>(bytes);
            },
            [](canopy::distributed::item_range, std::span<std::byte const>) {}, {.max_batch = 1, .progress = {}});
        double const waited = double(comm.sum(std::uint64_t(report.wait_seconds * 1e9))) * 1e-9;
        std::uint64_t const remote = comm.sum(comm.root() ? 0 : report.ranges);
        if (comm.root()) {
            double const per_range = report.seconds / double(ranges) * 1e6;
            std::printf("result of %8zu bytes: %7.1f us per range (wall), overhead %6.1f us per range, "
                        "%6.1f us waited per range away from rank 0 (%llu of %zu ranges there), rank 0 busy %.1f us "
                        "per message (%llu)\n",
                        bytes, per_range, per_range * comm.size() - double(work_us),
                        remote ? waited / double(remote) * 1e6 : 0.0, static_cast<unsigned long long>(remote), ranges,
                        report.messages ? report.serve_seconds / double(report.messages) * 1e6 : 0.0,
                        static_cast<unsigned long long>(report.messages));
        }
    }
    return 0;
}
