// canopy_bench_distributed — the dealer's cost per message, without any work: `ranges` ranges of
// one item each, each result `bytes` long (a 16×16 tile of float RGBA is 4096 bytes, 64 tiles
// 262144), dealt across the processes of mpirun. Prints, on rank 0, the wall time per range and
// the time a rank other than 0 waits between sending a result and receiving its next range.
//   mpirun -np 2 canopy_bench_distributed [ranges] [bytes...]
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <vector>
import canopy.distributed;

int main(int argc, char** argv) {
    canopy::distributed::session mpi(argc, argv);
    auto const comm = mpi.world();
    std::size_t const ranges = argc > 1 ? std::size_t(std::strtoull(argv[1], nullptr, 10)) : 2000;
    std::vector<std::size_t> sizes;
    for (int i = 2; i < argc; ++i) sizes.push_back(std::size_t(std::strtoull(argv[i], nullptr, 10)));
    if (sizes.empty()) sizes = {16, 4096, 65536, 262144, 1048576};
    if (comm.root()) std::printf("%d ranks, %zu ranges of one item each\n", comm.size(), ranges);
    for (std::size_t bytes : sizes) {
        auto const report = canopy::distributed::deal(
            comm, ranges, [&](canopy::distributed::item_range) { return std::vector<std::byte>(bytes); },
            [](canopy::distributed::item_range, std::span<std::byte const>) {}, {.max_batch = 1, .progress = {}});
        double const waited = comm.sum(std::uint64_t(report.wait_seconds * 1e9)) * 1e-9;
        std::uint64_t const remote = comm.sum(comm.root() ? 0 : report.ranges);
        if (comm.root())
            std::printf("result of %8zu bytes: %7.1f us per range (wall), %7.1f us waited per range away from rank 0 "
                        "(%llu of %zu ranges)\n",
                        bytes, report.seconds / double(ranges) * 1e6, remote ? waited / double(remote) * 1e6 : 0.0,
                        static_cast<unsigned long long>(remote), ranges);
    }
    return 0;
}
