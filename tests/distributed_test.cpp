// Tests of canopy.distributed. The same executable runs alone (each test case registered with
// ctest: a solo communicator, no MPI) and under mpirun with 2 and 3 processes (label `mpi`), where
// every rank runs every test case. References: every item's result is a function of the item
// written out here, counted on rank 0; the image across ranks is compared with canopy::render_tiles
// in one process; failures carry the exact text of the failing rank.
#include <catch2/catch.hpp>

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <span>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

import canopy;
import canopy.distributed;

namespace {

namespace dist = canopy::distributed;

// What work() returns for item i: three uint64, i * 7 + 1 repeated i % 3 + 1 times.
std::vector<std::uint64_t> expected_words(std::size_t i) { return std::vector<std::uint64_t>(i % 3 + 1, i * 7 + 1); }

std::vector<std::byte> result_of(dist::item_range r) {
    std::vector<std::byte> out;
    for (std::size_t i = r.first; i < r.first + r.count; ++i) {
        auto const words = expected_words(i);
        std::size_t const at = out.size();
        out.resize(at + words.size() * sizeof(std::uint64_t));
        std::memcpy(out.data() + at, words.data(), words.size() * sizeof(std::uint64_t));
    }
    return out;
}

} // namespace

TEST_CASE("dealer: every item is dealt exactly once and its result gathered on rank 0, whatever the ranks") {
    dist::communicator const comm = dist::communicator::world();
    for (std::size_t items : {std::size_t(0), std::size_t(1), std::size_t(2), std::size_t(7), std::size_t(1000)})
        for (std::size_t batch : {std::size_t(1), std::size_t(5), std::size_t(64)}) {
            CAPTURE(items, batch, comm.rank(), comm.size());
            std::vector<int> seen(items, 0);
            std::vector<std::uint64_t> words(items, 0);
            std::size_t last_progress = 0, progress_calls = 0;
            bool sizes_right = true;
            dist::deal_report const report = dist::deal(
                comm, items, [](dist::item_range r) { return result_of(r); },
                [&](dist::item_range r, std::span<std::byte const> bytes) {
                    std::size_t at = 0;
                    for (std::size_t i = r.first; i < r.first + r.count; ++i) {
                        ++seen[i];
                        auto const expected = expected_words(i);
                        std::size_t const n = expected.size() * sizeof(std::uint64_t);
                        if (at + n > bytes.size() || std::memcmp(bytes.data() + at, expected.data(), n) != 0)
                            sizes_right = false;
                        else
                            words[i] = expected.front();
                        at += n;
                    }
                    if (at != bytes.size()) sizes_right = false;
                },
                {.max_batch = batch, .progress = [&](std::size_t done, std::size_t total) {
                     if (done <= last_progress || total != items) sizes_right = false;
                     last_progress = done;
                     ++progress_calls;
                 }});
            // Every rank: the items computed add up to all of them.
            CHECK(comm.sum(report.items) == items);
            if (comm.root()) {
                CHECK(sizes_right);
                CHECK(last_progress == items);
                CHECK(progress_calls >= (items + batch - 1) / batch);
                std::size_t dealt = 0;
                for (std::size_t k = 0; k < report.items_per_rank.size(); ++k) dealt += report.items_per_rank[k];
                CHECK(dealt == items);
                CHECK(report.items_per_rank.size() == std::size_t(comm.size()));
                for (std::size_t i = 0; i < items; ++i) {
                    INFO("item " << i);
                    CHECK(seen[i] == 1);
                    CHECK(words[i] == i * 7 + 1);
                }
            }
        }
}

TEST_CASE("dealer: a range is at most max_batch items, and ranges shrink to single items at the end") {
    dist::communicator const comm = dist::communicator::world();
    std::vector<std::size_t> sizes;
    dist::deal(comm, 500, [](dist::item_range r) { return result_of(r); },
               [&](dist::item_range r, std::span<std::byte const>) { sizes.push_back(r.count); }, {.max_batch = 16, .progress = {}});
    if (comm.root()) {
        REQUIRE(!sizes.empty());
        for (std::size_t n : sizes) CHECK((n >= 1 && n <= 16));
        CHECK(*std::min_element(sizes.begin(), sizes.end()) == 1);
        CHECK(*std::max_element(sizes.begin(), sizes.end()) == 16);
    }
}

TEST_CASE("dealer: a rank whose work fails stops every rank with its message") {
    dist::communicator const comm = dist::communicator::world();
    int const failing = comm.size() - 1; // the last rank; rank 0 when alone
    // The failing rank fails on whatever item it takes, the others never.
    auto const work = [&](dist::item_range r) -> std::vector<std::byte> {
        if (comm.rank() == failing) throw std::runtime_error("rank " + std::to_string(failing) + " cannot read item " + std::to_string(r.first));
        return result_of(r);
    };
    bool thrown = false;
    try {
        // Rank 0 would take everything before a slow rank starts if the work were fast: make it
        // slow enough per item that every rank gets work.
        dist::deal(comm, 400, [&](dist::item_range r) {
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
            return work(r);
        }, [](dist::item_range, std::span<std::byte const>) {}, {.max_batch = 1, .progress = {}});
    } catch (dist::remote_failure const& e) {
        thrown = true;
        CHECK(e.rank == failing);
        CHECK(e.local == (comm.rank() == failing));
        CHECK(std::string(e.what()).starts_with("rank " + std::to_string(failing) + " cannot read item "));
    }
    CHECK(thrown);
}

TEST_CASE("agreement: every rank gets the lowest failing rank's message, and nothing when none failed") {
    dist::communicator const comm = dist::communicator::world();
    CHECK_NOTHROW(dist::agree(comm, ""));
    std::string const mine = comm.rank() == 0 ? "" : "rank " + std::to_string(comm.rank()) + " failed";
    if (comm.size() == 1) {
        CHECK_NOTHROW(dist::agree(comm, mine));
    } else {
        try {
            dist::agree(comm, mine);
            FAIL("agree did not throw");
        } catch (dist::remote_failure const& e) {
            CHECK(e.rank == 1);
            CHECK(std::string(e.what()) == "rank 1 failed");
            CHECK(e.local == (comm.rank() == 1));
        }
    }
    // checked(): the exception's text is the rank's error.
    try {
        dist::checked(comm, [&] {
            if (comm.rank() == comm.size() - 1) throw std::invalid_argument("the last rank's error");
        });
        FAIL("checked did not throw");
    } catch (dist::remote_failure const& e) {
        CHECK(e.rank == comm.size() - 1);
        CHECK(std::string(e.what()) == "the last rank's error");
    }
}

TEST_CASE("tiles: the image rendered across the ranks is the one process's image, bit for bit") {
    dist::communicator const comm = dist::communicator::world();
    auto const shade = [](int x, int y) {
        auto const h = canopy::pixel_random::hash(std::uint32_t(x) * 92821u ^ std::uint32_t(y));
        return canopy::vec4<float>(float(x) / 37.0f, float(y) * 0.25f, float(h >> 8) * 0x1p-24f, 1.0f);
    };
    for (int tile : {1, 8, 16, 64}) {
        CAPTURE(tile);
        canopy::framebuffer one(37, 23), across(37, 23);
        canopy::render_tiles(one, shade, {.tile_size = tile, .progress = {}});
        float last = 0.0f;
        bool increasing = true;
        dist::render_tiles(comm, across, shade, {.tile_size = tile, .progress = [&](float f) {
                                                     increasing = increasing && f > last;
                                                     last = f;
                                                 }});
        if (comm.root()) {
            CHECK(increasing);
            CHECK(last == 1.0f);
            CHECK(std::memcmp(one.pixels.data(), across.pixels.data(), one.pixels.size() * sizeof(one.pixels[0])) == 0);
        } else {
            std::vector<canopy::vec4<float>> const zeros(across.pixels.size());
            CHECK(std::memcmp(zeros.data(), across.pixels.data(), zeros.size() * sizeof(zeros[0])) == 0); // untouched
        }
    }
}

TEST_CASE("session: launched_by_mpirun() reads the launcher's environment") {
    // Under ctest alone the variables are absent; under mpirun Open MPI sets them.
    bool const launched = std::getenv("OMPI_COMM_WORLD_SIZE") || std::getenv("PMIX_RANK") || std::getenv("PMI_RANK");
    CHECK(dist::launched_by_mpirun() == launched);
    dist::communicator const comm = dist::communicator::world();
    CHECK(comm.uses_mpi() == launched);
    if (!launched) {
        CHECK(comm.size() == 1);
        CHECK(comm.rank() == 0);
    }
}

TEST_CASE("dealer: rank 0 failing to collect a result stops every rank with its message") {
    dist::communicator const comm = dist::communicator::world();
    bool thrown = false;
    try {
        dist::deal(comm, 300, [](dist::item_range r) {
            std::this_thread::sleep_for(std::chrono::microseconds(200));
            return result_of(r);
        }, [](dist::item_range r, std::span<std::byte const>) {
            if (r.first + r.count > 100) throw std::runtime_error("disk full after item 100");
        }, {.max_batch = 4, .progress = {}});
    } catch (dist::remote_failure const& e) {
        thrown = true;
        CHECK(e.rank == 0);
        CHECK(std::string(e.what()) == "disk full after item 100");
    }
    CHECK(thrown);
}
