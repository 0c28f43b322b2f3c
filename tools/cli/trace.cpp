// canopy trace: a ray file traced against a scene of the bench formats (FORMATS.md), the hits
// written in the bench hit format; one process, or the ray file's chunks shared out under mpirun.
// The intersectors are named in one table (trace_intersectors).
#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <tuple>
#include <utility>
#include <vector>
#include <fcntl.h>
#include <unistd.h>
#include <fmt/core.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include "commands.hpp"
#include "options.hpp"
#include "output.hpp"
#include "processes.hpp"
import canopy;
import canopy.plugins.bench;
import canopy.scene;

namespace cli {

namespace {

// A scene of the bench formats, loaded by the bench plugin and compiled: the BVH of the .obj's mesh,
// or the top-level BVH over the .inst's instances (each placement's inst_id is its matrix line).
struct loaded_bench_scene {
    canopy::compiled_scene compiled;
    double build_seconds = 0.0; // compile(): the BVHs and the instances
};

std::unique_ptr<loaded_bench_scene> load_bench_scene(std::filesystem::path const& path, canopy::build_quality quality) {
    auto scene = std::make_unique<loaded_bench_scene>();
    canopy::require_regular_file(path); // a folder or a device is named as such, whatever its extension
    auto const ext = path.extension().string();
    if (ext != ".obj" && ext != ".inst")
        throw canopy::scene_error(path.string(), "", "unknown scene extension " + quote(ext) + " (expected .obj or .inst)");
    step("loading " + path.string());
    canopy::registry bench;
    canopy::register_bench_plugin(bench);
    canopy::scene graph;
    bench.load(graph, path, graph.root(), "bench");
    step("building the BVHs of " + path.string());
    scene->compiled = canopy::compile(graph, {.bvh = {.quality = quality}, .name = path.string(), .keep_single_instance = true});
    scene->build_seconds = scene->compiled.statistics.build_seconds;
    return scene;
}

// Rays per chunk of `trace`: the unit in which processes share out a ray file under mpirun (a
// multiple of the batch queries' groups of 8).
constexpr std::size_t trace_chunk = 256;
// The grain of the threads' ranges of chunks, each range one batch query: oneTBB splits a range
// while it is longer than this, so a batch gets 16 to 32 chunks (but for a file's last), 4,096 to
// 8,192 rays: two rows or more of a camera's image up to 2,048 pixels wide, so that the batch can
// find the rows and trace squares of pixels (canopy.query:batch).
constexpr std::size_t trace_batch_chunks = 32;

canopy::bench_hit to_bench_hit(canopy::basic_hit_record<float> const& hr) {
    if (!hr.hit) return {};
    return {hr.t, hr.prim_id, hr.inst_id, hr.u, hr.v};
}

// Rays [first, first + out.size()) into out: one at a time, or through the batch queries
// (returning how many rays they traced in packets).
template <typename Isect>
std::size_t trace_rays(canopy::compiled_scene const& scene, std::span<canopy::ray const> rays, std::span<canopy::bench_hit> out,
                       bool closest, bool batch, Isect& isect) {
    if (!batch) {
        for (std::size_t i = 0; i < rays.size(); ++i)
            out[i] = to_bench_hit(scene.visit_root([&](auto const& root) {
                return closest ? canopy::closest_hit(rays[i], &root, &root + 1, isect)
                               : canopy::any_hit(rays[i], &root, &root + 1, isect);
            }));
        return 0;
    }
    thread_local std::vector<canopy::basic_hit_record<float>> records;
    records.resize(std::max(records.size(), rays.size()));
    std::span<canopy::basic_hit_record<float>> const got(records.data(), rays.size());
    auto const stats = scene.visit_root([&](auto const& root) {
        return closest ? canopy::closest_hit(rays, &root, &root + 1, got, isect)
                       : canopy::any_hit(rays, &root, &root + 1, got, isect);
    });
    for (std::size_t i = 0; i < rays.size(); ++i) out[i] = to_bench_hit(got[i]);
    return stats.packed_rays();
}

// The intersectors of --intersector: make() gives one for a task's rays.
template <typename Make>
struct intersector_row {
    std::string_view name, text;
    Make make;
};

constexpr std::tuple trace_intersectors{
    intersector_row{"none", " (default)", [] { return canopy::default_intersector{}; }},
    intersector_row{"alpha", ": reject hits where floor(8u)+floor(8v) is odd",
                    [] { return canopy::bench_alpha_intersector{}; }},
};

struct trace_setup {
    std::string scene_path, rays_path, out_path, mode, intersector;
    bool closest = true, batch = false;
    int reps = 0;
    canopy::build_quality quality = canopy::build_quality::automatic;
};

// Runs of chunks of trace_chunk rays (trace_batch_chunks), as many at once as the threads take,
// each run one batch query; returns the rays traced in packets. (The hits do not depend on how the
// rays are cut: a batch query's results are the single rays'.)
std::size_t trace_chunks(canopy::compiled_scene const& scene, std::span<canopy::ray const> rays, std::span<canopy::bench_hit> hits,
                         trace_setup const& setup) {
    std::size_t const chunks = (rays.size() + trace_chunk - 1) / trace_chunk;
    std::atomic<std::size_t> packed{0};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks, trace_batch_chunks), [&](auto const& range) {
        with_choice(trace_intersectors, setup.intersector, [&](auto const& row) {
            auto isect = row.make();
            std::size_t const first = range.begin() * trace_chunk;
            std::size_t const count = std::min(range.end() * trace_chunk, rays.size()) - first;
            std::span<canopy::ray const> const in(rays.data() + first, count);
            std::span<canopy::bench_hit> const out(hits.data() + first, count);
            packed += trace_rays(scene, in, out, setup.closest, setup.batch, isect);
        });
    });
    return packed;
}

// The seconds of one pass, or with --reps N the median of N passes after a warm-up pass.
template <typename Pass>
double timed_passes(int reps, Pass const& pass) {
    auto const timed = [&] {
        auto const start = clock_type::now();
        pass();
        return seconds_since(start);
    };
    if (reps == 0) return timed();
    timed(); // warm-up
    std::vector<double> times;
    for (int r = 0; r < reps; ++r) times.push_back(timed());
    std::sort(times.begin(), times.end());
    std::size_t const mid = times.size() / 2;
    return times.size() % 2 == 1 ? times[mid] : 0.5 * (times[mid - 1] + times[mid]);
}

void print_trace(loaded_bench_scene const& scene, trace_setup const& setup, std::uint64_t rays, std::uint64_t packed,
                 std::uint64_t hit_count, double trace_seconds) {
    std::string const timing =
        setup.reps == 0 ? std::string() : fmt::format(" (median of {} after a warm-up pass)", setup.reps);
    std::string const how =
        setup.batch ? fmt::format("batch: {} rays in packets, {} single rays", packed, rays - packed) : setup.mode;
    fmt::print("build {:.3f} ms at quality {}, trace {} rays ({}) in {:.3f} ms{}: {:.2f} Mrays/s, {} hits\n",
               scene.build_seconds * 1e3, quality_used(setup.quality, scene.compiled.meshes[0].accel.quality), rays, how,
               trace_seconds * 1e3, timing, trace_seconds > 0 ? double(rays) / trace_seconds * 1e-6 : 0.0, hit_count);
}

#if CANOPY_WITH_MPI
int trace_across_ranks(trace_setup const& setup);
#endif

#if CANOPY_WITH_MPI
// The hits file of a trace under mpirun, on rank 0: written at each range's offset into OUT.partial
// as the results arrive, renamed to OUT when all is written, so that a job that dies leaves no file
// under OUT's name (an OUT that is not a regular file, a device, is written in place). Removed
// when the trace fails.
class partial_output {
public:
    explicit partial_output(std::filesystem::path out) : out_(std::move(out)) {
        std::error_code ec;
        bool const regular = !std::filesystem::exists(out_, ec) || std::filesystem::is_regular_file(out_, ec);
        path_ = regular ? std::filesystem::path(out_.string() + ".partial") : out_;
        fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
        if (fd_ < 0) throw output_error(path_.string() + ": cannot be written: " + os_reason(errno));
    }
    partial_output(partial_output const&) = delete;
    partial_output& operator=(partial_output const&) = delete;
    ~partial_output() {
        if (fd_ >= 0) ::close(fd_);
        if (!done_ && path_ != out_) ::unlink(path_.c_str());
    }

    void write(std::uint64_t offset, std::span<std::byte const> bytes) {
        for (std::size_t done = 0; done < bytes.size();) {
            ssize_t const n = ::pwrite(fd_, bytes.data() + done, bytes.size() - done, off_t(offset + done));
            if (n < 0 && errno == EINTR) continue;
            if (n <= 0) throw output_error(out_.string() + ": cannot write: " + os_reason(n < 0 ? errno : ENOSPC));
            done += std::size_t(n);
        }
    }

    void commit() {
        int const fd = std::exchange(fd_, -1);
        if (::close(fd) != 0) throw output_error(out_.string() + ": cannot write: " + os_reason(errno));
        if (path_ != out_ && std::rename(path_.c_str(), out_.c_str()) != 0)
            throw output_error(out_.string() + ": cannot rename " + path_.string() + " to it: " + os_reason(errno));
        done_ = true;
    }

private:
    std::filesystem::path out_, path_;
    int fd_ = -1;
    bool done_ = false;
};

// canopy trace under mpirun: every rank loads the scene; the ray file's chunks (trace_chunk rays,
// the same chunks as one process traces) are dealt out in ranges; each rank reads only its ranges'
// rays, at their offset, and traces them with oneTBB; rank 0 writes the hits at their offset. The
// hits are the same, byte for byte, as one process's.
int trace_across_ranks(trace_setup const& setup) {
    std::optional<partial_output> output;
    std::unique_ptr<loaded_bench_scene> scene;
    std::uint64_t ray_count = 0;
    on_every_rank([&] {
        if (root_rank()) {
            check_writable(setup.out_path);
            output.emplace(setup.out_path);
        }
        scene = load_bench_scene(setup.scene_path, setup.quality);
        step("reading " + setup.rays_path);
        ray_count = canopy::count_bench_rays(setup.rays_path);
        if (ray_count == 0)
            throw canopy::scene_error(setup.rays_path, "", "holds no rays (the file is empty): nothing to trace");
    });
    step("tracing " + setup.rays_path);
    std::size_t const chunks = std::size_t((ray_count + trace_chunk - 1) / trace_chunk);
    std::uint64_t packed = 0, hit_count = 0;
    // A range's result: its rays traced in packets and its hits (two uint64), then its hits as the
    // hit file holds them.
    auto const work = [&](dist::item_range r) {
        std::uint64_t const first = r.first * trace_chunk;
        std::uint64_t const count = std::min<std::uint64_t>(r.count * trace_chunk, ray_count - first);
        std::vector<canopy::ray> const rays = canopy::read_bench_rays(setup.rays_path, first, count, ray_count);
        std::vector<canopy::bench_hit> hits(rays.size());
        std::uint64_t const counts[2] = {
            trace_chunks(scene->compiled, rays, hits, setup),
            std::uint64_t(std::count_if(hits.begin(), hits.end(), [](auto const& h) { return h.prim != canopy::invalid_id; }))};
        std::string const encoded = canopy::encode_bench_hits(hits);
        std::vector<std::byte> bytes(sizeof counts + encoded.size());
        std::memcpy(bytes.data(), counts, sizeof counts);
        std::memcpy(bytes.data() + sizeof counts, encoded.data(), encoded.size());
        return bytes;
    };
    auto const collect = [&](dist::item_range r, std::span<std::byte const> bytes) {
        std::uint64_t counts[2];
        std::memcpy(counts, bytes.data(), sizeof counts);
        packed += counts[0];
        hit_count += counts[1];
        output->write(20 * r.first * trace_chunk, bytes.subspan(sizeof counts));
    };
    dist::deal_report report;
    double const trace_seconds = timed_passes(setup.reps, [&] {
        packed = hit_count = 0;
        report = dist::deal(ranks, chunks, work, collect);
    });
    on_every_rank([&] {
        if (!root_rank()) return;
        step("writing " + setup.out_path);
        output->commit();
    });
    record_sharing(report);
    print_sharing("chunks of 256 rays");
    if (root_rank()) print_trace(*scene, setup, ray_count, packed, hit_count, trace_seconds);
    return 0;
}
#endif

// The options' usage; --intersector's from its table.
std::string trace_options_usage() {
    return "usage: canopy trace --scene FILE --rays FILE --query closest|any --out FILE\n"
           "                    [--intersector " + choice_bar(choices(trace_intersectors)) +
           "] [--mode single|batch] [--reps N]\n"
           "                    [--threads N] [--quality Q] [limits]\n"
           "  --scene FILE        .obj (single mesh) or .inst (instanced mesh)\n"
           "  --rays FILE         32-byte rays: origin, tmin, direction, tmax (float32); at least one\n"
           "  --query KIND        closest: nearest accepted hit; any: first accepted hit\n"
           "  --out FILE          20-byte hits: t, prim, inst, u, v (checked writable before tracing)\n" +
           option_usage("--intersector KIND", choice_list(choices(trace_intersectors), true)) +
           "  --mode MODE         single (default): one ray at a time; batch: the batch queries, which\n"
           "                      trace groups of 8 or 16 coherent rays as packets (same hits, byte for byte)\n"
           "  --reps N            one warm-up pass, then N timed passes, 1 to 1000; the median is\n"
           "                      printed (default: one timed pass, no warm-up)\n"
           "  --threads N         worker threads, 1 to 1024 (default: all cores)\n";
}

} // namespace

std::string trace_usage() { return trace_options_usage() + quality_usage + limits_usage; }

int run_trace(std::span<char*> all_args) {
    arguments const args = parse_arguments(all_args, {{"--scene"}, {"--rays"}, {"--query"}, {"--out"}, {"--intersector"},
                                                      {"--mode"}, {"--reps"}, {"--threads"}, {"--quality"}});
    if (args.help) {
        if (root_rank()) std::fputs(trace_usage().c_str(), stdout);
        return 0;
    }
    if (!args.positional.empty()) throw usage_error("unexpected argument " + quote(args.positional.front()));
    apply_limits(args);
    std::optional<tbb::global_control> threads;
    limit_threads(args, threads);
    std::string const scene_path = required(args, "--scene");
    std::string const rays_path = required(args, "--rays");
    std::string const out_path = required(args, "--out");
    std::string const query = required(args, "--query");
    if (query != "closest" && query != "any") throw usage_error("--query must be closest or any, not " + quote(query));
    std::string const isect_name = args.value_or("--intersector", "none");
    check_choice(choices(trace_intersectors), "--intersector", isect_name);
    canopy::build_quality const quality = quality_option(args);
    std::string const mode = args.value_or("--mode", "single");
    if (mode != "single" && mode != "batch") throw usage_error("--mode must be single or batch, not " + quote(mode));
    int const reps = args.has("--reps") ? int(whole_option(args, "--reps", 1, 1000)) : 0;
    trace_setup const setup{scene_path, rays_path, out_path, mode, isect_name, query == "closest", mode == "batch",
                            reps, quality};
#if CANOPY_WITH_MPI
    if (distributed()) return trace_across_ranks(setup);
#endif

    check_writable(out_path);
    auto const scene = load_bench_scene(scene_path, quality);
    step("reading " + rays_path);
    canopy::require_regular_file(rays_path, "ray file");
    auto const rays = canopy::read_bench_rays(rays_path);
    if (rays.empty()) throw canopy::scene_error(rays_path, "", "holds no rays (the file is empty): nothing to trace");
    step("tracing " + rays_path);
    std::vector<canopy::bench_hit> hits(rays.size());
    std::size_t packed = 0;
    double const trace_seconds = timed_passes(reps, [&] {
        packed = trace_chunks(scene->compiled, rays, hits, setup);
    });
    step("writing " + out_path);
    canopy::write_bench_hits(out_path, hits);

    std::size_t const hit_count = std::size_t(std::count_if(hits.begin(), hits.end(), [](auto const& h) {
        return h.prim != canopy::invalid_id;
    }));
    print_trace(*scene, setup, rays.size(), packed, hit_count, trace_seconds);
    return 0;
}

} // namespace cli
