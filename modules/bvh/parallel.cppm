// canopy.bvh:parallel — the two parallel primitives the builder needs, on oneTBB.
//
// They are ordinary (non-template) functions compiled into this module's object file, so
// importers instantiate no oneTBB templates themselves; they are the builder's own, not exported.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <cstddef>
#include <functional>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_group.h>
export module canopy.bvh:parallel;

namespace canopy {

// Runs a and b, possibly in parallel; returns when both are done.
void parallel_invoke(std::function<void()> const& a, std::function<void()> const& b) {
    tbb::task_group group;
    group.run([&] { a(); });
    b();
    group.wait();
}

// Calls body(begin, end) on disjoint chunks covering [0, n), in parallel.
void parallel_for_chunks(std::size_t n, std::size_t grain, std::function<void(std::size_t, std::size_t)> const& body) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, grain),
                      [&](tbb::blocked_range<std::size_t> const& r) { body(r.begin(), r.end()); });
}

} // namespace canopy
