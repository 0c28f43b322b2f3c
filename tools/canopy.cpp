// canopy — the command-line program.
//
//   canopy render [SCENE] [-o OUT] [--size WxH] [--spp N] [--kernel primary|ao|path|heatmap]
//                 [--intersector auto|none|alpha|procedural|bench|costs] [--ao-radius R[%]]
//                 [--exposure EV] [--tonemap none|reinhard|aces] [--threads N] [--plugin FILE]...
//                 [--quality automatic|fast|high] [LIMITS]
//   canopy trace --scene FILE --rays FILE --query closest|any --out FILE
//                [--intersector none|alpha] [--mode single|batch] [--reps N] [--threads N]
//                [--quality automatic|fast|high] [LIMITS]
//   canopy info SCENE [--plugin FILE]... [--quality automatic|fast|high] [LIMITS]
//   canopy info --plugins [--plugin FILE]... [LIMITS]
//   --quality: the build quality of the mesh BVHs (canopy::build_quality; default automatic).
//   LIMITS: [--max-file-bytes N] [--max-texels N] [--max-total-texels N] [--max-triangles N]
//           [--max-placements N] [--max-depth N]  (canopy::resource_limits, set before anything
//           is loaded)
//
// `canopy render` without a scene renders the built-in demo (instanced alpha-masked billboards)
// into the four images of Figure 1 of the custom-intersector paper. With a scene, any file a
// registered plugin loads (built-in, in CANOPY_PLUGIN_PATH, or given with --plugin FILE), or
// gen:NAME[:KEY=VALUE,...] for a registered generator, is loaded into the scene graph, compiled
// (canopy.scene's skip rules) and rendered with the scene's camera and lights when it has them.
// `canopy trace` loads the benchmark formats through the bench plugin (canopy.plugins.bench) and
// compiles them like any scene (.obj subset: one mesh BVH, no top level; .inst: one shared mesh
// instanced under a top-level BVH, kept for a single instance so that hits report its inst 0:
// compile_options::keep_single_instance); rays and hits use the benchmark formats too. It traces one
// ray at a time (--mode single, the default: counted in SIMD operations, the batch queries' packets
// do more work than their rays alone on most bench scenes, see the README) or through the batch
// queries (--mode batch: groups of 8 coherent rays as packets); the hit files are the same byte
// for byte.
//
// Under mpirun (a build with CANOPY_WITH_MPI, more than one process), `render` and `trace` share
// their work out across the processes (canopy.distributed: tiles, or chunks of the ray file, dealt
// out by rank 0), with the same outputs byte for byte; rank 0 alone writes and prints, and a
// failure on any rank stops all with its message. Without mpirun, MPI is never touched.
//
// Exit status: 0 success; 1 an error in an input, an output or a limit (the message names the
// file and the problem); 2 a usage error (unknown, missing, repeated or malformed option, followed
// by the command's usage). Numbers are read whole and range-checked. Output files are checked
// before any work (the folder is created, each file opened for writing) and again after closing;
// standard output is checked at exit.
#include <algorithm>
#include <array>
#include <atomic>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <new>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>
#include <cerrno>
#include <fcntl.h>
#include <unistd.h>
#include <fmt/core.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
import canopy;
import canopy.image_io;
import canopy.plugins;
import canopy.plugins.bench;
#if CANOPY_WITH_MPI
import canopy.distributed;
#endif

namespace {

using clock_type = std::chrono::steady_clock;

double seconds_since(clock_type::time_point start) {
    return std::chrono::duration<double>(clock_type::now() - start).count();
}

struct usage_error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// What the program is doing, for the message when memory runs out ("loading scene.obj").
std::string current_step = "starting";

void step(std::string what) { current_step = std::move(what); }

// ---- processes (mpirun) ------------------------------------------------------------------------
// Started by mpirun, with more than one process: `render` and `trace` share their work out
// (canopy.distributed); rank 0 writes the outputs and prints, the other ranks print nothing.
// Started without mpirun, the program never touches MPI.
#if CANOPY_WITH_MPI
namespace dist = canopy::distributed;
dist::communicator ranks; // solo (rank 0 of 1) unless under mpirun
bool distributed() { return ranks.size() > 1; }
bool root_rank() { return ranks.root(); }
#else
bool distributed() { return false; }
bool root_rank() { return true; }
#endif

// How the ranks shared the last job out (printed by rank 0 under mpirun).
struct sharing_report {
    std::size_t rank_count = 1;
    std::uint64_t messages = 0, bytes = 0;
    std::vector<std::size_t> items_per_rank;
    std::vector<double> wait_seconds, ranges_per_rank;
};
sharing_report last_sharing;

#if CANOPY_WITH_MPI
// Collective: every rank's share of a deal, on rank 0.
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

constexpr char const* main_usage =
    "usage: canopy <command> [options]\n"
    "commands:\n"
    "  render  render the demo scene (no SCENE) or a scene file into PNG images\n"
    "  trace   trace a ray file against a scene, write a hit file\n"
    "  info    print scene statistics, compile decisions and BVH statistics\n"
    "run 'canopy <command> --help' for the options of a command\n"
    "exit status: 0 success, 1 error (the message names the file), 2 usage error\n";

// The resource-limit options of every command; defaults from canopy::resource_limits.
constexpr char const* limits_usage =
    "limits (checked before anything is allocated; a file over a limit is refused, naming it):\n"
    "  --max-file-bytes N  bytes of one input file (default 4294967296 = 4 GiB)\n"
    "  --max-texels N      texels of one image, and pixels of a rendered image (default 67108864\n"
    "                      = 2^26, 1 GiB as float RGBA)\n"
    "  --max-total-texels N\n"
    "                      texels of all the scene's images together (default 268435456 = 2^28,\n"
    "                      4 GiB as float RGBA)\n"
    "  --max-triangles N   triangles (and vertices) of the scene's meshes together, each mesh\n"
    "                      counted once (default 268435456 = 2^28)\n"
    "  --max-placements N  mesh placements after instances are flattened (default 4194304 = 2^22)\n"
    "  --max-depth N       nesting depth of the scene graph and of a file's structures (default 4096)\n";

constexpr char const* trace_options_usage =
    "usage: canopy trace --scene FILE --rays FILE --query closest|any --out FILE\n"
    "                    [--intersector none|alpha] [--mode single|batch] [--reps N]\n"
    "                    [--threads N] [--quality Q] [limits]\n"
    "  --scene FILE        .obj (single mesh) or .inst (instanced mesh)\n"
    "  --rays FILE         32-byte rays: origin, tmin, direction, tmax (float32); at least one\n"
    "  --query KIND        closest: nearest accepted hit; any: first accepted hit\n"
    "  --out FILE          20-byte hits: t, prim, inst, u, v (checked writable before tracing)\n"
    "  --intersector KIND  none (default) or alpha: reject hits where floor(8u)+floor(8v) is odd\n"
    "  --mode MODE         single (default): one ray at a time; batch: the batch queries, which\n"
    "                      trace groups of 8 coherent rays as packets (same hits, byte for byte)\n"
    "  --reps N            one warm-up pass, then N timed passes, 1 to 1000; the median is\n"
    "                      printed (default: one timed pass, no warm-up)\n"
    "  --threads N         worker threads, 1 to 1024 (default: all cores)\n";

constexpr char const* render_options_usage =
    "usage: canopy render [SCENE] [-o OUT] [--size WxH] [--spp N] [--kernel KIND]\n"
    "                     [--intersector KIND] [--ao-radius R[%]] [--exposure EV]\n"
    "                     [--tonemap CURVE] [--threads N] [--plugin FILE]... [--quality Q]\n"
    "                     [limits]\n"
    "  SCENE               a file any registered plugin loads (canopy info --plugins lists them),\n"
    "                      or gen:NAME[:KEY=VALUE,...] for a registered generator; without it, the\n"
    "                      built-in demo scene is rendered into the four images of the paper's\n"
    "                      Figure 1 (alpha ignored, texture alpha mask, procedural alpha mask, BVH\n"
    "                      cost heat map; --kernel applies to the first three)\n"
    "  -o OUT              output folder (default: out), created if missing; OUT/SCENE-STEM.png\n"
    "  --size WxH          image size, W and H from 1 to 16384, W*H at most --max-texels\n"
    "                      (default 800x600)\n"
    "  --spp N             samples per pixel, 1 to 65536 (default 1; 16 for ao and path)\n"
    "  --kernel KIND       primary (default), ao, path or heatmap\n"
    "  --intersector KIND  auto (default: alpha when the scene has masked materials, else none),\n"
    "                      none, alpha (texture alpha mask), procedural (ring mask on masked\n"
    "                      materials), bench (the alpha rule of the bench formats) or costs (the\n"
    "                      heat map); a SCENE only (the demo's figures have their own)\n"
    "  --ao-radius R[%]    ao: length of the occlusion rays, in scene units, or with % in percent\n"
    "                      of the scene's bounding-box diagonal (default 5%)\n"
    "  --exposure EV       scale radiance by 2^EV before the tone curve, -30 to 30 (default 0)\n"
    "  --tonemap CURVE     none (clip at 1), reinhard (x/(1+x)) or aces (filmic); default aces\n"
    "                      for the path kernel, none for primary and ao; not for the heat map\n"
    "  --threads N         worker threads, 1 to 1024 (default: all cores)\n"
    "  --plugin FILE       load a shared-library plugin first (may be repeated)\n";

constexpr char const* info_options_usage =
    "usage: canopy info SCENE [--plugin FILE]... [--quality Q] [limits]\n"
    "       canopy info --plugins [--plugin FILE]...\n"
    "  SCENE      a file any registered plugin loads, or gen:NAME[:KEY=VALUE,...]\n"
    "  --plugins  list the registered loaders, image loaders, generators and node types\n"
    "  --plugin FILE  load a shared-library plugin first (may be repeated)\n";

// --quality, for the commands that build BVHs of a scene's meshes.
constexpr char const* quality_usage =
    "  --quality Q         build quality of the mesh BVHs: automatic (default: high for meshes of\n"
    "                      long thin triangles, else fast), fast (object splits) or high (spatial\n"
    "                      splits too: faster tracing of long thin triangles, slower builds, more\n"
    "                      memory)\n";

std::string const trace_usage = std::string(trace_options_usage) + quality_usage + limits_usage;
std::string const render_usage = std::string(render_options_usage) + quality_usage + limits_usage;
std::string const info_usage = std::string(info_options_usage) + quality_usage + limits_usage;

// ---- arguments ---------------------------------------------------------------------------

// At most 40 characters of an argument in quotes, bytes that are not printable as '?'.
std::string quote(std::string_view text) {
    std::string out = "'";
    for (char c : text.substr(0, 40)) out += c >= 0x20 && c < 0x7f ? c : '?';
    return out + (text.size() > 40 ? "...'" : "'");
}

struct option_spec {
    std::string_view name;
    bool takes_value = true;
    bool repeatable = false;
};

// Every command's limit options.
constexpr option_spec limit_options[] = {
    {"--max-file-bytes"}, {"--max-texels"},     {"--max-total-texels"},
    {"--max-triangles"},  {"--max-placements"}, {"--max-depth"}};

struct arguments {
    std::map<std::string, std::vector<std::string>, std::less<>> options;
    std::vector<std::string> positional;
    bool help = false;

    bool has(std::string_view name) const { return options.find(name) != options.end(); }
    std::string const& value(std::string_view name) const { return options.find(name)->second.front(); }
    std::string value_or(std::string_view name, std::string fallback) const {
        return has(name) ? value(name) : std::move(fallback);
    }
    std::vector<std::string> values(std::string_view name) const {
        return has(name) ? options.find(name)->second : std::vector<std::string>{};
    }
};

// Options (given once, unless repeatable; a value is the next argument, non-empty, not an option)
// and positional arguments ("--" ends the options). "--help" or "-h" anywhere stops parsing.
arguments parse_arguments(std::span<char*> args, std::vector<option_spec> specs) {
    specs.insert(specs.end(), std::begin(limit_options), std::end(limit_options));
    arguments out;
    bool options_ended = false;
    for (std::size_t i = 0; i < args.size(); ++i) {
        std::string const a = args[i];
        if (options_ended || a.size() < 2 || a[0] != '-') {
            if (a.empty()) throw usage_error("an empty argument (a file name was expected)");
            out.positional.push_back(a);
            continue;
        }
        if (a == "--") {
            options_ended = true;
            continue;
        }
        if (a == "--help" || a == "-h") {
            out.help = true;
            return out;
        }
        auto const spec = std::find_if(specs.begin(), specs.end(), [&](option_spec const& o) { return o.name == a; });
        if (spec == specs.end()) throw usage_error("unknown option " + quote(a));
        if (!spec->repeatable && out.has(a)) throw usage_error("option " + a + " given more than once");
        if (!spec->takes_value) {
            out.options[a].emplace_back();
            continue;
        }
        if (i + 1 >= args.size()) throw usage_error("option " + a + " needs a value");
        std::string const value = args[++i];
        if (value.empty()) throw usage_error("option " + a + " has an empty value");
        if (value.starts_with("--")) throw usage_error("option " + a + " needs a value, not the option " + quote(value));
        out.options[a].push_back(value);
    }
    return out;
}

std::string required(arguments const& args, std::string_view name) {
    if (!args.has(name)) throw usage_error("missing " + std::string(name));
    return args.value(name);
}

// The whole text as a number in [lo, hi], or nothing.
std::optional<std::uint64_t> whole_number(std::string_view text, std::uint64_t lo, std::uint64_t hi) {
    std::uint64_t v = 0;
    auto const [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size() || v < lo || v > hi) return std::nullopt;
    return v;
}

std::uint64_t whole_option(arguments const& args, std::string_view name, std::uint64_t lo, std::uint64_t hi) {
    std::string const& text = args.value(name);
    auto const v = whole_number(text, lo, hi);
    if (!v)
        throw usage_error(std::string(name) + " must be a whole number from " + std::to_string(lo) + " to " +
                          std::to_string(hi) + ", not " + quote(text));
    return *v;
}

// A finite decimal number in [lo, hi], the whole text.
double real_option(std::string_view name, std::string_view text, double lo, double hi, std::string const& range) {
    double v = 0.0;
    auto const [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(v) || v < lo || v > hi)
        throw usage_error(std::string(name) + " must be a number " + range + ", not " + quote(text));
    return v;
}

// Sets canopy::default_limits() from the limit options, before anything is loaded.
void apply_limits(arguments const& args) {
    canopy::resource_limits& limits = canopy::default_limits();
    std::uint64_t const most = std::numeric_limits<std::uint64_t>::max();
    if (args.has("--max-file-bytes")) limits.max_file_bytes = whole_option(args, "--max-file-bytes", 1, most);
    if (args.has("--max-texels")) limits.max_texels = whole_option(args, "--max-texels", 1, most);
    if (args.has("--max-total-texels")) limits.max_total_texels = whole_option(args, "--max-total-texels", 1, most);
    if (args.has("--max-triangles")) limits.max_triangles = whole_option(args, "--max-triangles", 1, most);
    if (args.has("--max-placements")) limits.max_placements = whole_option(args, "--max-placements", 1, most);
    if (args.has("--max-depth")) limits.max_depth = whole_option(args, "--max-depth", 1, most);
}

// --quality automatic|fast|high: the build quality of the mesh BVHs (default automatic, the
// library's: spatial splits only for meshes of long thin triangles).
canopy::build_quality quality_option(arguments const& args) {
    std::string const q = args.value_or("--quality", "automatic");
    if (q == "high") return canopy::build_quality::high;
    if (q == "fast") return canopy::build_quality::fast;
    if (q != "automatic") throw usage_error("--quality must be automatic, fast or high, not " + quote(q));
    return canopy::build_quality::automatic;
}

char const* quality_name(canopy::build_quality q) {
    return q == canopy::build_quality::high ? "high" : q == canopy::build_quality::fast ? "fast" : "automatic";
}

// The quality asked for and, when automatic, the one a build used: "automatic (high)".
std::string quality_used(canopy::build_quality asked, canopy::build_quality used) {
    if (asked != canopy::build_quality::automatic) return quality_name(asked);
    return std::string("automatic (") + quality_name(used) + ")";
}

// --threads N: the worker limit, kept in `control` (constructed in place: a global_control must
// not be copied) for as long as the caller keeps it.
void limit_threads(arguments const& args, std::optional<tbb::global_control>& control) {
    if (args.has("--threads"))
        control.emplace(tbb::global_control::max_allowed_parallelism, std::size_t(whole_option(args, "--threads", 1, 1024)));
}

// ---- output files ----------------------------------------------------------------------------

struct output_error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

std::string os_reason(int error) { return error != 0 ? std::strerror(error) : "unknown error"; }

// Checks, before any work, that `file` can be written: it is opened for writing (not truncated;
// non-blocking, so a FIFO without a reader is an error, not a hang). A file that was not there is
// removed again.
void check_writable(std::filesystem::path const& file) {
    int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NONBLOCK | O_CLOEXEC, 0666);
    bool const created = fd >= 0;
    if (fd < 0 && errno == EEXIST) fd = ::open(file.c_str(), O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0 && errno == ENXIO) throw output_error(file.string() + ": cannot be written: a FIFO with no reader");
    if (fd < 0) throw output_error(file.string() + ": cannot be written: " + os_reason(errno));
    ::close(fd);
    if (created) ::unlink(file.c_str());
}

// Creates the output folder (and its parents) when missing; refuses a path that is not a folder.
void prepare_folder(std::filesystem::path const& folder) {
    if (folder.empty()) return;
    std::error_code ec;
    if (std::filesystem::exists(folder, ec) && !std::filesystem::is_directory(folder, ec))
        throw output_error(folder.string() + ": the output folder exists and is not a folder");
    std::filesystem::create_directories(folder, ec);
    if (ec) throw output_error(folder.string() + ": cannot create the output folder: " + ec.message());
    if (!std::filesystem::is_directory(folder, ec))
        throw output_error(folder.string() + ": the output folder exists and is not a folder");
}

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

// Rays per task of `trace` (a multiple of the batch queries' groups of 8).
constexpr std::size_t trace_chunk = 256;

canopy::bench_hit to_bench_hit(canopy::basic_hit_record<float> const& hr) {
    if (!hr.hit) return {};
    return {hr.t, hr.prim_id, hr.inst_id, hr.u, hr.v};
}

// Rays [first, first + out.size()) into out: one at a time, or through the batch queries
// (returning how many packets they traced).
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
    std::array<canopy::basic_hit_record<float>, trace_chunk> records;
    std::span<canopy::basic_hit_record<float>> const got(records.data(), rays.size());
    auto const stats = scene.visit_root([&](auto const& root) {
        return closest ? canopy::closest_hit(rays, &root, &root + 1, got, isect)
                       : canopy::any_hit(rays, &root, &root + 1, got, isect);
    });
    for (std::size_t i = 0; i < rays.size(); ++i) out[i] = to_bench_hit(got[i]);
    return stats.packets;
}

struct trace_setup {
    std::string scene_path, rays_path, out_path, mode;
    bool closest = true, batch = false, alpha = false;
    int reps = 0;
    canopy::build_quality quality = canopy::build_quality::automatic;
};

// Chunks of trace_chunk rays (a multiple of 8: the batch queries' groups are the same whatever
// the threads and processes), as many at once as the threads take; returns the packets traced.
std::size_t trace_chunks(canopy::compiled_scene const& scene, std::span<canopy::ray const> rays, std::span<canopy::bench_hit> hits,
                         trace_setup const& setup) {
    std::size_t const chunks = (rays.size() + trace_chunk - 1) / trace_chunk;
    std::atomic<std::size_t> packets{0};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks), [&](auto const& range) {
        canopy::default_intersector none;
        canopy::bench_alpha_intersector alpha;
        std::size_t n = 0;
        for (std::size_t c = range.begin(); c != range.end(); ++c) {
            std::size_t const first = c * trace_chunk, count = std::min(trace_chunk, rays.size() - first);
            std::span<canopy::ray const> const in(rays.data() + first, count);
            std::span<canopy::bench_hit> const out(hits.data() + first, count);
            n += setup.alpha ? trace_rays(scene, in, out, setup.closest, setup.batch, alpha)
                             : trace_rays(scene, in, out, setup.closest, setup.batch, none);
        }
        packets += n;
    });
    return packets;
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

void print_trace(loaded_bench_scene const& scene, trace_setup const& setup, std::uint64_t rays, std::uint64_t packets,
                 std::uint64_t hit_count, double trace_seconds) {
    std::string const timing =
        setup.reps == 0 ? std::string() : fmt::format(" (median of {} after a warm-up pass)", setup.reps);
    std::string const how =
        setup.batch ? fmt::format("batch: {} packets of 8, {} single rays", packets, rays - 8 * packets) : setup.mode;
    fmt::print("build {:.3f} ms at quality {}, trace {} rays ({}) in {:.3f} ms{}: {:.2f} Mrays/s, {} hits\n",
               scene.build_seconds * 1e3, quality_used(setup.quality, scene.compiled.meshes[0].accel.quality), rays, how,
               trace_seconds * 1e3, timing, trace_seconds > 0 ? double(rays) / trace_seconds * 1e-6 : 0.0, hit_count);
}

#if CANOPY_WITH_MPI
int trace_across_ranks(trace_setup const& setup);
#endif

int run_trace(std::span<char*> all_args) {
    arguments const args = parse_arguments(all_args, {{"--scene"}, {"--rays"}, {"--query"}, {"--out"}, {"--intersector"},
                                                      {"--mode"}, {"--reps"}, {"--threads"}, {"--quality"}});
    if (args.help) {
        if (root_rank()) std::fputs(trace_usage.c_str(), stdout);
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
    if (isect_name != "none" && isect_name != "alpha")
        throw usage_error("--intersector must be none or alpha, not " + quote(isect_name));
    canopy::build_quality const quality = quality_option(args);
    std::string const mode = args.value_or("--mode", "single");
    if (mode != "single" && mode != "batch") throw usage_error("--mode must be single or batch, not " + quote(mode));
    int const reps = args.has("--reps") ? int(whole_option(args, "--reps", 1, 1000)) : 0;
    trace_setup const setup{scene_path, rays_path, out_path, mode, query == "closest", mode == "batch",
                            isect_name == "alpha", reps, quality};
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
    std::size_t packets = 0;
    double const trace_seconds = timed_passes(reps, [&] {
        packets = trace_chunks(scene->compiled, rays, hits, setup);
    });
    step("writing " + out_path);
    canopy::write_bench_hits(out_path, hits);

    std::size_t const hit_count = std::size_t(std::count_if(hits.begin(), hits.end(), [](auto const& h) {
        return h.prim != canopy::invalid_id;
    }));
    print_trace(*scene, setup, rays.size(), packets, hit_count, trace_seconds);
    return 0;
}

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
    std::uint64_t packets = 0, hit_count = 0;
    // A range's result: its packets and hits (two uint64), then its hits as the hit file holds them.
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
        packets += counts[0];
        hit_count += counts[1];
        output->write(20 * r.first * trace_chunk, bytes.subspan(sizeof counts));
    };
    dist::deal_report report;
    double const trace_seconds = timed_passes(setup.reps, [&] {
        packets = hit_count = 0;
        report = dist::deal(ranks, chunks, work, collect);
    });
    on_every_rank([&] {
        if (!root_rank()) return;
        step("writing " + setup.out_path);
        output->commit();
    });
    record_sharing(report);
    print_sharing("chunks of 256 rays");
    if (root_rank()) print_trace(*scene, setup, ray_count, packets, hit_count, trace_seconds);
    return 0;
}
#endif

// ---- render ----------------------------------------------------------------------------------

// The scene as the kernels see it, counting the rays traced.
struct counting_scene {
    canopy::compiled_scene const* scene;
    mutable std::atomic<std::uint64_t>* rays;

    template <typename I>
    canopy::basic_hit_record<float> closest_hit(canopy::ray const& r, I& isect) const {
        rays->fetch_add(1, std::memory_order_relaxed);
        return scene->closest_hit(r, isect);
    }
    template <typename I>
    canopy::basic_hit_record<float> any_hit(canopy::ray const& r, I& isect) const {
        rays->fetch_add(1, std::memory_order_relaxed);
        return scene->any_hit(r, isect);
    }
    canopy::surface_sample surface(canopy::basic_hit_record<float> const& hr, canopy::ray const& r) const {
        return scene->surface(hr, r);
    }
    canopy::vec3<float> background(canopy::ray const& r) const { return scene->background(r); }
};

struct render_job {
    std::string kernel = "primary";
    std::string intersector = "none";
    int width = 800, height = 600, spp = 1;
    std::filesystem::path output;
    canopy::pinhole_camera camera;
    std::string scene_name;             // how messages name the scene (its file, or gen:...)
    float ao_radius = 0.0f;             // absolute (scene units), or
    float ao_radius_fraction = 0.05f;   // of the bounding-box diagonal when ao_radius is 0
    canopy::tone_curve tone = canopy::tone_curve::none;
    float exposure_scale = 1.0f;        // 2^EV
};

struct render_result {
    double seconds = 0.0;
    std::uint64_t rays = 0;
};

class progress_bar {
public:
    explicit progress_bar(std::string label) : label_(std::move(label)), enabled_(isatty(STDERR_FILENO) != 0) {}
    void update(float fraction) {
        if (!enabled_) return;
        int const filled = int(fraction * 40.0f);
        std::fprintf(stderr, "\r%-28s [%s%s] %3d%%", label_.c_str(), std::string(std::size_t(filled), '#').c_str(),
                     std::string(std::size_t(40 - filled), ' ').c_str(), int(fraction * 100.0f));
        if (fraction >= 1.0f) std::fputc('\n', stderr);
    }

private:
    std::string label_;
    bool enabled_;
};

// Linear radiance → display values: exposure, tone curve, sRGB encoding (`linear`), or the
// colours as they are (heat map). NaN pixels are written black and counted in `nan_pixels`.
canopy::rgba_image to_display(canopy::framebuffer const& fb, bool linear, render_job const& job,
                              std::size_t& nan_pixels) {
    canopy::rgba_image img;
    img.width = fb.width;
    img.height = fb.height;
    img.pixels.resize(4 * fb.pixels.size());
    nan_pixels = 0;
    auto const display = [&](float v) {
        return linear ? canopy::to_srgb(canopy::tone_map(v, job.tone, job.exposure_scale)) : v;
    };
    for (std::size_t i = 0; i < fb.pixels.size(); ++i) {
        auto const& p = fb.pixels[i];
        bool const nan = std::isnan(p.x) || std::isnan(p.y) || std::isnan(p.z);
        nan_pixels += nan;
        img.pixels[4 * i + 0] = nan ? 0.0f : display(p.x);
        img.pixels[4 * i + 1] = nan ? 0.0f : display(p.y);
        img.pixels[4 * i + 2] = nan ? 0.0f : display(p.z);
        img.pixels[4 * i + 3] = 1.0f;
    }
    return img;
}

// The AO radius of a job: absolute, or a fraction of the scene's bounding-box diagonal.
float ao_radius(canopy::compiled_scene const& scene, render_job const& job) {
    if (job.ao_radius > 0.0f) return job.ao_radius;
    float const diagonal = canopy::length(canopy::diagonal(scene.bounds()));
    float const radius = job.ao_radius_fraction * diagonal;
    if (!(radius > 0.0f && std::isfinite(radius)))
        throw canopy::scene_error(job.scene_name, "",
                                  fmt::format("the AO radius, {:g}% of the bounding-box diagonal ({:g}), is not a "
                                              "positive finite length: give --ao-radius in scene units",
                                              double(job.ao_radius_fraction) * 100.0, double(diagonal)));
    return radius;
}

// canopy::render_tiles, or across the ranks under mpirun: the image on rank 0 (the other ranks'
// framebuffers stay black).
void tiles(canopy::framebuffer& fb, std::function<canopy::vec4<float>(int, int)> const& shade,
           canopy::tile_options const& options) {
#if CANOPY_WITH_MPI
    if (distributed()) {
        record_sharing(dist::render_tiles(ranks, fb, shade, options));
        return;
    }
#endif
    canopy::render_tiles(fb, shade, options);
}

// Shades every pixel with kernel(ray, isect, rng) averaged over spp jittered samples.
template <typename I, typename Kernel>
canopy::framebuffer render_with(render_job const& job, I const& prototype, Kernel const& kernel, progress_bar& bar) {
    canopy::framebuffer fb(job.width, job.height);
    tiles(
        fb,
        [&](int x, int y) {
            canopy::vec4<float> sum;
            for (int s = 0; s < job.spp; ++s) {
                canopy::pixel_random rng(1u, x, y, s);
                float const jx = job.spp > 1 ? rng.next() : 0.5f, jy = job.spp > 1 ? rng.next() : 0.5f;
                I isect = prototype;
                sum = sum + kernel(job.camera.primary_ray(float(x) + jx, float(y) + jy, job.width, job.height), isect, rng);
            }
            return sum * (1.0f / float(job.spp));
        },
        {.tile_size = 16, .progress = [&](float f) { bar.update(f); }});
    return fb;
}

template <typename I>
canopy::framebuffer render_kernel(counting_scene const& scene, render_job const& job, I const& prototype,
                                  progress_bar& bar) {
    if (job.kernel == "ao") {
        float const radius = ao_radius(*scene.scene, job);
        return render_with(job, prototype, [&](canopy::ray const& r, I& isect, canopy::pixel_random& rng) {
            return canopy::ao_kernel(scene, r, isect, rng, 8, radius);
        }, bar);
    }
    // The path kernel adds a point light (the scene's, or one above the middle of the scene) to
    // the sun and the sky.
    canopy::light_options const light = scene.scene->render_lights(job.scene_name);
    if (job.kernel == "path")
        return render_with(job, prototype, [&](canopy::ray const& r, I& isect, canopy::pixel_random& rng) {
            return canopy::path_kernel(scene, r, isect, rng, 3, light);
        }, bar);
    return render_with(job, prototype, [&](canopy::ray const& r, I& isect, canopy::pixel_random&) {
        return canopy::primary_kernel(scene, r, isect);
    }, bar);
}

// The paper's bvh_costs counter composed with the scene's texture alpha mask: counts every
// ray/box and ray/triangle test at every level while the mask decides the hits, so the heat map
// shows the extra traversal that alpha-masked holes cause.
struct masked_costs : canopy::basic_intersector<masked_costs> {
    using canopy::basic_intersector<masked_costs>::operator();

    template <typename Ray, typename... Args>
    auto operator()(Ray const& ray, canopy::aabb const& box, Args&&... args) {
        ++num_boxes;
        return intersect(ray, box, std::forward<Args>(args)...);
    }

    template <typename Ray>
    auto operator()(Ray const& ray, canopy::triangle const& tri) {
        ++num_tris;
        return intersect(ray, tri);
    }

    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) const {
        return mask.keeps(hr);
    }

    canopy::texture_alpha_mask mask;
    unsigned num_boxes = 0;
    unsigned num_tris = 0;
};

// Heat map: box + triangle tests of each primary ray, scaled so that the 99th percentile is red.
canopy::framebuffer render_heatmap(counting_scene const& scene, render_job const& job, progress_bar& bar) {
    masked_costs prototype;
    prototype.mask.scene = scene.scene;
    canopy::framebuffer fb = render_with(job, prototype, [&](canopy::ray const& r, masked_costs& isect,
                                                             canopy::pixel_random&) {
        scene.closest_hit(r, isect);
        return canopy::vec4<float>(float(isect.num_boxes + isect.num_tris), 0, 0, 1);
    }, bar);
    std::vector<float> costs;
    costs.reserve(fb.pixels.size());
    for (auto const& p : fb.pixels) costs.push_back(p.x);
    auto const p99 = costs.begin() + std::ptrdiff_t(costs.size() * 99 / 100);
    std::nth_element(costs.begin(), p99, costs.end());
    float const scale = std::max(1.0f, *p99);
    for (auto& p : fb.pixels) p = canopy::vec4<float>(canopy::heat_colour(p.x, scale), 1.0f);
    return fb;
}

// Renders and writes one image. An image with NaN pixels is written (black there) and reported
// as an error: radiance that is not a number is a fault of the scene or of the renderer.
render_result render_image(canopy::compiled_scene const& scene, render_job const& job) {
    step("rendering " + job.output.string());
    std::atomic<std::uint64_t> rays{0};
    counting_scene const counted{&scene, &rays};
    progress_bar bar(job.output.filename().string());
    auto const start = clock_type::now();
    canopy::framebuffer fb;
    bool linear = true;
    if (job.kernel == "heatmap" || job.intersector == "costs") {
        fb = render_heatmap(counted, job, bar);
        linear = false;
    } else if (job.intersector == "bench") {
        fb = render_kernel(counted, job, canopy::bench_alpha_intersector{}, bar);
    } else if (job.intersector == "alpha") {
        canopy::texture_alpha_mask mask;
        mask.scene = &scene;
        fb = render_kernel(counted, job, mask, bar);
    } else if (job.intersector == "procedural") {
        canopy::procedural_alpha_mask mask;
        mask.scene = &scene;
        fb = render_kernel(counted, job, mask, bar);
    } else {
        fb = render_kernel(counted, job, canopy::default_intersector{}, bar);
    }
    render_result result{seconds_since(start), rays.load()};
#if CANOPY_WITH_MPI
    if (distributed()) result.rays = ranks.sum(result.rays);
#endif
    print_sharing("tiles");
    on_every_rank([&] {
        if (!root_rank()) return;
        step("writing " + job.output.string());
        std::size_t nan_pixels = 0;
        canopy::write_image(job.output, to_display(fb, linear, job, nan_pixels));
        if (nan_pixels > 0)
            throw std::runtime_error(fmt::format("{}: {} of {} pixels are not a number (NaN radiance, written black)",
                                                 job.output.string(), nan_pixels, fb.pixels.size()));
    });
    return result;
}

// The registry of built-in plugins, plus shared-library plugins named on the command line.
canopy::registry& plugin_registry(std::vector<std::string> const& plugin_files) {
    step("loading the plugins of CANOPY_PLUGIN_PATH");
    canopy::registry& r = canopy::builtin_registry();
    for (auto const& f : plugin_files) {
        step("loading plugin " + f);
        r.load_plugin(f);
    }
    return r;
}

// The scene `canopy render` renders without a SCENE: the paper's Figure 1 forest.
constexpr char const* demo_scene = "gen:billboard_forest";

// SCENE: a file, or gen:NAME[:KEY=VALUE,...].
struct loaded_graph {
    canopy::scene graph;
    canopy::compiled_scene compiled;
    double load_seconds = 0.0;
};

// gen:NAME[:KEY=VALUE,...] read into the generator's name and parameters (usage errors: an item
// that is not KEY=VALUE, a key given twice); nothing for a file.
struct generator_call {
    std::string name;
    canopy::parameters params;
};

std::optional<generator_call> parse_generator(std::string const& spec) {
    if (!spec.starts_with("gen:")) return std::nullopt;
    std::string_view rest = std::string_view(spec).substr(4);
    auto const colon = rest.find(':');
    generator_call call{std::string(rest.substr(0, colon)), {}};
    if (call.name.empty()) throw usage_error("gen: needs a generator name (gen:NAME[:KEY=VALUE,...])");
    if (colon == std::string_view::npos) return call;
    rest.remove_prefix(colon + 1);
    while (!rest.empty()) {
        auto const comma = std::min(rest.find(','), rest.size());
        std::string_view const item = rest.substr(0, comma);
        auto const eq = item.find('=');
        if (eq == std::string_view::npos || eq == 0)
            throw usage_error("generator parameter " + quote(item) + " is not KEY=VALUE");
        std::string key(item.substr(0, eq));
        if (call.params.has(key)) throw usage_error("generator parameter " + quote(key) + " given more than once");
        call.params.set(std::move(key), std::string(item.substr(eq + 1)));
        rest.remove_prefix(std::min(comma + 1, rest.size()));
    }
    return call;
}

loaded_graph load_and_compile(std::string const& spec, canopy::registry const& r, canopy::build_quality quality) {
    loaded_graph out;
    step("loading " + spec);
    auto const start = clock_type::now();
    if (auto const call = parse_generator(spec)) {
        r.generate(out.graph, call->name, call->params, out.graph.root());
    } else {
        r.load(out.graph, spec, out.graph.root());
    }
    out.load_seconds = seconds_since(start);
    step("compiling " + spec);
    out.compiled = canopy::compile(out.graph, {.plugins = &r, .bvh = {.quality = quality}, .name = spec});
    return out;
}

// --size WxH: both whole numbers from 1 to 16384, W·H within the texel limit (the framebuffer
// holds float RGBA per pixel, as a texture of that size would).
std::pair<int, int> parse_size(std::string const& text) {
    auto const x = text.find('x');
    auto const w = x == std::string::npos ? std::nullopt : whole_number(std::string_view(text).substr(0, x), 1, 16384);
    auto const h = x == std::string::npos ? std::nullopt : whole_number(std::string_view(text).substr(x + 1), 1, 16384);
    if (!w || !h)
        throw usage_error("--size must be WxH with W and H whole numbers from 1 to 16384 (e.g. 800x600), not " +
                          quote(text));
    std::uint64_t const limit = canopy::default_limits().max_texels;
    if (*w * *h > limit)
        throw usage_error(fmt::format("--size {}x{} is {} pixels, over the limit of {} (--max-texels)", *w, *h,
                                      *w * *h, limit));
    return {int(*w), int(*h)};
}

int run_render(std::span<char*> all_args) {
    arguments const args = parse_arguments(all_args, {{"-o"},
                                                      {"--size"},
                                                      {"--spp"},
                                                      {"--kernel"},
                                                      {"--intersector"},
                                                      {"--ao-radius"},
                                                      {"--exposure"},
                                                      {"--tonemap"},
                                                      {"--threads"},
                                                      {"--plugin", true, true},
                                                      {"--quality"}});
    if (args.help) {
        if (root_rank()) std::fputs(render_usage.c_str(), stdout);
        return 0;
    }
    if (args.positional.size() > 1)
        throw usage_error("more than one scene given (" + quote(args.positional[0]) + ", " + quote(args.positional[1]) +
                          ")");
    std::optional<std::string> const scene_path =
        args.positional.empty() ? std::nullopt : std::optional<std::string>(args.positional[0]);
    auto const generator = scene_path ? parse_generator(*scene_path) : std::nullopt;
    apply_limits(args);

    render_job base;
    auto const [w, h] = parse_size(args.value_or("--size", "800x600"));
    base.width = w;
    base.height = h;
    base.kernel = args.value_or("--kernel", "primary");
    if (base.kernel != "primary" && base.kernel != "ao" && base.kernel != "path" && base.kernel != "heatmap")
        throw usage_error("--kernel must be primary, ao, path or heatmap, not " + quote(base.kernel));
    base.intersector = args.value_or("--intersector", "auto");
    if (base.intersector != "auto" && base.intersector != "none" && base.intersector != "alpha" &&
        base.intersector != "procedural" && base.intersector != "bench" && base.intersector != "costs")
        throw usage_error("--intersector must be auto, none, alpha, procedural, bench or costs, not " +
                          quote(base.intersector));
    bool const heatmap = base.kernel == "heatmap" || base.intersector == "costs";
    if (!scene_path && args.has("--intersector"))
        throw usage_error("--intersector applies to a SCENE: the demo renders each figure with its own intersector");
    canopy::build_quality const quality = quality_option(args);
    if (!scene_path && args.has("--quality"))
        throw usage_error("--quality applies to a SCENE: the demo scene is built at the default quality");
    if (!scene_path && base.kernel == "heatmap")
        throw usage_error("--kernel heatmap applies to a SCENE: the demo's fourth figure is the heat map");
    if (base.intersector == "costs" && args.has("--kernel") && base.kernel != "heatmap")
        throw usage_error("--intersector costs draws the heat map: it goes with --kernel heatmap, not " +
                          quote(base.kernel));
    if (base.kernel == "heatmap" && base.intersector != "auto" && base.intersector != "costs")
        throw usage_error("--kernel heatmap counts the tests of the texture alpha mask's traversal: --intersector " +
                          quote(base.intersector) + " does not apply");
    if (heatmap && (args.has("--exposure") || args.has("--tonemap")))
        throw usage_error("--exposure and --tonemap apply to shaded images, not to the heat map");
    if (args.has("--ao-radius")) {
        if (base.kernel != "ao") throw usage_error("--ao-radius applies to --kernel ao");
        std::string_view text = args.value("--ao-radius");
        bool const percent = text.ends_with('%');
        if (percent) text.remove_suffix(1);
        double const r = real_option("--ao-radius", text, 0.0,
                                     percent ? 1e6 : double(std::numeric_limits<float>::max()),
                                     "over 0: a length in scene units, or a percentage of the bounding-box diagonal "
                                     "(e.g. 5%)");
        if (!(float(r) > 0.0f))
            throw usage_error("--ao-radius must be over 0, not " + quote(args.value("--ao-radius")));
        if (percent) {
            base.ao_radius_fraction = float(r / 100.0);
        } else {
            base.ao_radius = float(r);
        }
    }
    if (args.has("--exposure"))
        base.exposure_scale =
            float(std::exp2(real_option("--exposure", args.value("--exposure"), -30.0, 30.0, "of stops from -30 to 30")));
    std::string const tone = args.value_or("--tonemap", base.kernel == "path" ? "aces" : "none");
    if (tone == "none") {
        base.tone = canopy::tone_curve::none;
    } else if (tone == "reinhard") {
        base.tone = canopy::tone_curve::reinhard;
    } else if (tone == "aces") {
        base.tone = canopy::tone_curve::aces;
    } else {
        throw usage_error("--tonemap must be none, reinhard or aces, not " + quote(tone));
    }
    base.spp = base.kernel == "ao" || base.kernel == "path" ? 16 : 1;
    if (args.has("--spp")) base.spp = int(whole_option(args, "--spp", 1, 65536));
    std::optional<tbb::global_control> threads;
    limit_threads(args, threads);
    std::filesystem::path const out = args.value_or("-o", "out");
    float const aspect = float(base.width) / float(base.height);

    // The output files, checked before anything is loaded or rendered.
    struct figure {
        char const* file;
        char const* kernel;
        char const* intersector;
    };
    figure const figures[] = {{"1_billboards_alpha_ignored.png", nullptr, "none"},
                              {"2_texture_alpha_mask.png", nullptr, "alpha"},
                              {"3_procedural_alpha_mask.png", nullptr, "procedural"},
                              {"4_bvh_cost_heatmap.png", "heatmap", "costs"}};
    if (scene_path) {
        std::string stem = generator ? generator->name : std::filesystem::path(*scene_path).stem().string();
        if (stem.empty()) stem = "scene";
        base.output = out / (stem + ".png");
    }
    // Under mpirun, rank 0 alone writes the images, and each rank loads the scene: a failure on any
    // rank stops every rank with its message.
    on_every_rank([&] {
        if (!root_rank()) return;
        prepare_folder(out);
        if (!scene_path) {
            for (auto const& f : figures) check_writable(out / f.file);
        } else {
            check_writable(base.output);
        }
    });

    canopy::registry const* registry = nullptr;
    on_every_rank([&] { registry = &plugin_registry(args.values("--plugin")); });
    std::vector<std::pair<std::string, render_result>> results;
    auto const build_start = clock_type::now();
    if (!scene_path) {
        // The demo: the procedural plugin's billboard_forest, compiled like any scene.
        std::optional<loaded_graph> loaded_forest;
        on_every_rank([&] {
            loaded_forest.emplace(load_and_compile(demo_scene, *registry, canopy::build_quality::automatic));
            base.camera = loaded_forest->compiled.render_camera(aspect, demo_scene);
        });
        canopy::compiled_scene const& forest = loaded_forest->compiled;
        double const build_seconds = seconds_since(build_start);
        base.scene_name = "demo scene";
        if (root_rank())
            fmt::print(stderr, "demo scene: {} instances of {} meshes, built in {:.1f} ms\n",
                       forest.top_mesh_instances.size(), forest.meshes.size(), build_seconds * 1e3);
        for (auto const& f : figures) {
            render_job job = base;
            if (f.kernel) job.kernel = f.kernel;
            job.intersector = f.intersector;
            job.output = out / f.file;
            results.emplace_back(job.output.string(), render_image(forest, job));
        }
    } else {
        std::optional<loaded_graph> loaded_scene;
        on_every_rank([&] {
            loaded_scene.emplace(load_and_compile(*scene_path, *registry, quality));
            base.camera = loaded_scene->compiled.render_camera(aspect, *scene_path);
        });
        loaded_graph const& loaded = *loaded_scene;
        canopy::compiled_scene const& scene = loaded.compiled;
        auto const& st = scene.statistics;
        if (root_rank()) fmt::print(stderr, "{}: {} triangles in {} meshes, {} placements, {} instance level{}; loaded in {:.1f} ms, "
                           "compiled in {:.1f} ms (mesh BVHs at quality {})\n",
                   *scene_path, st.triangles_placed, st.meshes_built, st.placements, st.levels, st.levels == 1 ? "" : "s",
                   loaded.load_seconds * 1e3, st.build_seconds * 1e3, quality_name(st.quality));
        base.scene_name = *scene_path;
        if (base.intersector == "auto") base.intersector = st.alpha_mask_needed ? "alpha" : "none";
        results.emplace_back(base.output.string(), render_image(scene, base));
    }
    if (!root_rank()) return 0;
    double total_seconds = 0.0;
    std::uint64_t total_rays = 0;
    auto const mrays = [](std::uint64_t rays, double seconds) { return seconds > 0.0 ? double(rays) / seconds * 1e-6 : 0.0; };
    for (auto const& [file, r] : results) {
        fmt::print("{}: {:.1f} ms, {} rays, {:.2f} Mrays/s\n", file, r.seconds * 1e3, r.rays, mrays(r.rays, r.seconds));
        total_seconds += r.seconds;
        total_rays += r.rays;
    }
    fmt::print("rendered {} image{} ({}x{}, {} spp) in {:.2f} s: {} rays, {:.2f} Mrays/s\n", results.size(),
               results.size() == 1 ? "" : "s", base.width, base.height, base.spp, total_seconds, total_rays,
               mrays(total_rays, total_seconds));
    return 0;
}

void print_stats(char const* name, canopy::bvh_stats const& s) {
    fmt::print("{}: {} primitives, {} nodes ({} leaves, largest {}), depth {}, SAH cost {:.2f}, {:.1f} bytes/primitive\n",
               name, s.primitive_count, s.node_count, s.leaf_count, s.max_leaf_size, s.depth, s.sah_cost,
               s.bytes_per_primitive);
}

void print_registered(char const* what, std::vector<canopy::registered> const& list) {
    fmt::print("{}:\n", what);
    if (list.empty()) fmt::print("  (none)\n");
    for (auto const& e : list)
        fmt::print("  {:<20} {:<12} {}\n", e.name, e.plugin, e.description);
}

int run_info(std::span<char*> all_args) {
    arguments const args = parse_arguments(all_args, {{"--plugins", false}, {"--plugin", true, true}, {"--quality"}});
    if (args.help) {
        std::fputs(info_usage.c_str(), stdout);
        return 0;
    }
    if (args.positional.size() > 1)
        throw usage_error("info takes one scene, not " + std::to_string(args.positional.size()) + " (" +
                          quote(args.positional[0]) + ", " + quote(args.positional[1]) + ", ...)");
    bool const list_plugins = args.has("--plugins");
    if (list_plugins == !args.positional.empty()) throw usage_error("info takes exactly one scene, or --plugins");
    if (!list_plugins) parse_generator(args.positional.front()); // usage errors before any work
    canopy::build_quality const quality = quality_option(args);
    if (list_plugins && args.has("--quality")) throw usage_error("--quality applies to a SCENE, not to --plugins");
    apply_limits(args);
    canopy::registry const& registry = plugin_registry(args.values("--plugin"));
    if (list_plugins) {
        print_registered("file loaders (the first of an extension is its default)", registry.loaders());
        print_registered("image loaders", registry.image_loaders());
        print_registered("generators", registry.generators());
        print_registered("node types", registry.node_types());
        fmt::print("shared-library plugins loaded:{}\n", registry.plugins().empty() ? " none" : "");
        for (auto const& p : registry.plugins()) fmt::print("  {}\n", p);
        return 0;
    }
    std::string const scene_path = args.positional.front();
    auto const loaded = load_and_compile(scene_path, registry, quality);
    canopy::scene const& g = loaded.graph;
    canopy::compiled_scene const& c = loaded.compiled;
    auto const& st = c.statistics;
    fmt::print("scene {}: loaded in {:.3f} ms\n", scene_path, loaded.load_seconds * 1e3);
    fmt::print("graph: {} nodes, {} meshes, {} materials, {} images, {} cameras, {} lights\n", g.nodes().size(),
               g.meshes().size(), g.materials().size(), g.images().size(), st.cameras, st.lights);
    fmt::print("compiled in {:.3f} ms: {} instance level{}, {} meshes built ({} triangles stored), {} placements "
               "({} triangles placed), {} groups, {} group instances\n",
               st.build_seconds * 1e3, st.levels, st.levels == 1 ? "" : "s", st.meshes_built, st.triangles_stored,
               st.placements, st.triangles_placed, st.groups, st.group_instances);
    fmt::print("decisions:\n");
    for (auto const& d : st.decisions) fmt::print("  - {}\n", d);
    std::size_t mesh_nodes = 0, mesh_prims = 0;
    double mesh_bytes = 0.0, mesh_sah = 0.0;
    for (auto const& m : c.meshes) {
        auto const ms = canopy::compute_stats(m.accel);
        mesh_nodes += ms.node_count;
        mesh_prims += ms.primitive_count;
        mesh_bytes += double(ms.bytes);
        mesh_sah += ms.sah_cost * double(ms.primitive_count);
    }
    double const per_triangle = mesh_prims ? 1.0 / double(mesh_prims) : 0.0;
    std::size_t meshes_high = 0;
    for (auto const& m : c.meshes) meshes_high += m.accel.quality == canopy::build_quality::high ? 1 : 0;
    std::string quality_text = quality_name(st.quality);
    if (st.quality == canopy::build_quality::automatic)
        quality_text += fmt::format(" (high for {} of {} mesh{})", meshes_high, c.meshes.size(),
                                    c.meshes.size() == 1 ? "" : "es");
    fmt::print("mesh BVH build: quality {}, {:.3f} ms, SAH cost {:.2f}{}, {:.1f} bytes/triangle\n",
               quality_text, st.mesh_build_seconds * 1e3, mesh_sah * per_triangle,
               c.meshes.size() == 1 ? "" : " (mean over triangles)", mesh_bytes * per_triangle);
    if (c.meshes.size() == 1) {
        print_stats("mesh BVH", canopy::compute_stats(c.meshes[0].accel));
    } else {
        fmt::print("mesh BVHs: {} BVHs, {} primitives, {} nodes, {:.1f} bytes/primitive\n", c.meshes.size(), mesh_prims,
                   mesh_nodes, mesh_bytes * per_triangle);
    }
    for (auto const& grp : c.groups) print_stats(fmt::format("group '{}' BVH", grp.name).c_str(), canopy::compute_stats(grp.accel));
    if (c.levels > 0) c.visit_root([](auto const& root) { print_stats("top-level BVH", canopy::compute_stats(root)); });
    return 0;
}

// Standard output is checked at exit: output lost to a full disk is an error, not a success.
int finish_standard_output(int status) {
    errno = 0;
    if (std::fflush(stdout) != 0 || std::ferror(stdout)) {
        std::fprintf(stderr, "canopy: cannot write to standard output: %s\n", os_reason(errno).c_str());
        return 1;
    }
    return status;
}

int run(std::string_view command, std::span<char*> args) {
    try {
        if (command == "--help" || command == "-h") {
            if (root_rank()) std::fputs(main_usage, stdout);
            return 0;
        }
        if (command == "render") return run_render(args);
        if (command == "trace") return run_trace(args);
        if (command == "info") return root_rank() ? run_info(args) : 0; // info: rank 0 alone
        throw usage_error("unknown command " + quote(command));
    } catch (usage_error const& e) {
        if (!root_rank()) return 2; // every rank has the same arguments, hence the same error
        bool const known = command == "trace" || command == "render" || command == "info";
        std::fprintf(stderr, "canopy%s%s: %s\n%s", known ? " " : "", known ? std::string(command).c_str() : "",
                     e.what(),
                     command == "trace"    ? trace_usage.c_str()
                     : command == "render" ? render_usage.c_str()
                     : command == "info"   ? info_usage.c_str()
                                           : main_usage);
        return 2;
#if CANOPY_WITH_MPI
    } catch (dist::remote_failure const& e) {
        // Every rank has it: rank 0 prints it, naming the rank when it is another one.
        if (root_rank())
            std::fprintf(stderr, "canopy: %s%s\n", e.rank == 0 ? "" : fmt::format("rank {}: ", e.rank).c_str(), e.what());
        return 1;
#endif
    } catch (...) {
        // Under mpirun, errors outside on_every_rank are the same on every rank: rank 0 prints.
        if (root_rank()) std::fprintf(stderr, "canopy: %s\n", error_text(std::current_exception()).c_str());
        return 1;
    }
}

} // namespace

int main(int argc, char** argv) {
    std::span<char*> const args(argv, std::size_t(argc));
    if (args.size() < 2) {
        std::fputs(main_usage, stderr);
        return 2;
    }
#if CANOPY_WITH_MPI
    if (dist::launched_by_mpirun()) {
        dist::session mpi(argc, argv);
        ranks = mpi.world();
        return finish_standard_output(run(args[1], args.subspan(2)));
    }
#endif
    return finish_standard_output(run(args[1], args.subspan(2)));
}
