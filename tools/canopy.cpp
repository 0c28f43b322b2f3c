// canopy — the command-line program.
//
//   canopy trace --scene FILE --rays FILE --query closest|any --out FILE
//                [--intersector none|alpha] [--threads N]
//   canopy info SCENE
//
// Scenes: .obj (the benchmark OBJ subset: one BVH, no top level) or .inst (one shared mesh,
// instanced: a top-level BVH over instances). Rays and hits use the benchmark formats.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>
#include <fmt/core.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
import canopy;
import canopy.bench_formats;

namespace {

using clock_type = std::chrono::steady_clock;

double seconds_since(clock_type::time_point start) {
    return std::chrono::duration<double>(clock_type::now() - start).count();
}

struct usage_error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

constexpr char const* main_usage =
    "usage: canopy <command> [options]\n"
    "commands:\n"
    "  trace   trace a ray file against a scene, write a hit file\n"
    "  info    print scene and BVH statistics\n"
    "run 'canopy <command> --help' for the options of a command\n";

constexpr char const* trace_usage =
    "usage: canopy trace --scene FILE --rays FILE --query closest|any --out FILE\n"
    "                    [--intersector none|alpha] [--threads N]\n"
    "  --scene FILE        .obj (single mesh) or .inst (instanced mesh)\n"
    "  --rays FILE         32-byte rays: origin, tmin, direction, tmax (float32)\n"
    "  --query KIND        closest: nearest accepted hit; any: first accepted hit\n"
    "  --out FILE          20-byte hits: t, prim, inst, u, v\n"
    "  --intersector KIND  none (default) or alpha: reject hits where floor(8u)+floor(8v) is odd\n"
    "  --threads N         worker threads (default: all cores)\n";

constexpr char const* info_usage = "usage: canopy info SCENE\n  SCENE: .obj or .inst\n";

// --name value pairs after the command; "--help" alone.
std::map<std::string, std::string> parse_options(std::span<char*> args, std::vector<std::string> const& known,
                                                 char const* usage) {
    std::map<std::string, std::string> options;
    for (std::size_t i = 0; i < args.size(); ++i) {
        std::string const name = args[i];
        if (name == "--help" || name == "-h") {
            std::fputs(usage, stdout);
            std::exit(0);
        }
        if (std::find(known.begin(), known.end(), name) == known.end())
            throw usage_error("unknown option '" + name + "'");
        if (i + 1 >= args.size()) throw usage_error("option '" + name + "' needs a value");
        options[name] = args[++i];
    }
    return options;
}

std::string required(std::map<std::string, std::string> const& options, std::string const& name) {
    auto const it = options.find(name);
    if (it == options.end()) throw usage_error("missing " + name);
    return it->second;
}

// Either a single-level scene or a two-level instanced one.
struct loaded_scene {
    canopy::bvh<canopy::triangle> mesh;
    std::vector<canopy::instance<canopy::bvh<canopy::triangle>>> instances;
    canopy::bvh<canopy::instance<canopy::bvh<canopy::triangle>>> top;
    bool instanced = false;
    double build_seconds = 0.0;
};

std::unique_ptr<loaded_scene> load_scene(std::filesystem::path const& path) {
    auto scene = std::make_unique<loaded_scene>();
    auto const ext = path.extension().string();
    if (ext == ".obj") {
        auto const mesh = canopy::read_bench_obj(path);
        auto const start = clock_type::now();
        scene->mesh = canopy::build_binned_sah(mesh.triangles);
        scene->build_seconds = seconds_since(start);
    } else if (ext == ".inst") {
        auto const inst = canopy::read_bench_inst(path);
        auto const start = clock_type::now();
        scene->mesh = canopy::build_binned_sah(inst.mesh.triangles);
        for (std::size_t k = 0; k < inst.instances.size(); ++k)
            scene->instances.emplace_back(scene->mesh, inst.instances[k], std::uint32_t(k));
        scene->top = canopy::build_binned_sah(scene->instances);
        scene->build_seconds = seconds_since(start);
        scene->instanced = true;
    } else {
        throw canopy::format_error(path.string() + ": unknown scene extension '" + ext + "' (expected .obj or .inst)");
    }
    return scene;
}

template <typename Isect>
canopy::bench_hit trace_one(loaded_scene const& scene, canopy::ray const& r, bool closest, Isect& isect) {
    canopy::basic_hit_record<float> hr;
    if (scene.instanced) {
        hr = closest ? canopy::closest_hit(r, &scene.top, &scene.top + 1, isect)
                     : canopy::any_hit(r, &scene.top, &scene.top + 1, isect);
    } else {
        hr = closest ? canopy::closest_hit(r, &scene.mesh, &scene.mesh + 1, isect)
                     : canopy::any_hit(r, &scene.mesh, &scene.mesh + 1, isect);
    }
    if (!hr.hit) return {};
    return {hr.t, hr.prim_id, hr.inst_id, hr.u, hr.v};
}

int run_trace(std::span<char*> args) {
    auto const options = parse_options(
        args, {"--scene", "--rays", "--query", "--out", "--intersector", "--threads"}, trace_usage);
    std::string const query = required(options, "--query");
    if (query != "closest" && query != "any") throw usage_error("--query must be closest or any, not '" + query + "'");
    std::string const isect_name = options.contains("--intersector") ? options.at("--intersector") : "none";
    if (isect_name != "none" && isect_name != "alpha")
        throw usage_error("--intersector must be none or alpha, not '" + isect_name + "'");
    std::optional<tbb::global_control> threads;
    if (options.contains("--threads")) {
        int const n = std::atoi(options.at("--threads").c_str());
        if (n < 1) throw usage_error("--threads needs a positive number");
        threads.emplace(tbb::global_control::max_allowed_parallelism, std::size_t(n));
    }

    auto const scene = load_scene(required(options, "--scene"));
    auto const rays = canopy::read_bench_rays(required(options, "--rays"));
    std::vector<canopy::bench_hit> hits(rays.size());
    bool const closest = query == "closest";

    auto const start = clock_type::now();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, rays.size(), 256), [&](auto const& range) {
        canopy::default_intersector none;
        canopy::bench_alpha_intersector alpha;
        for (std::size_t i = range.begin(); i != range.end(); ++i)
            hits[i] = isect_name == "alpha" ? trace_one(*scene, rays[i], closest, alpha)
                                            : trace_one(*scene, rays[i], closest, none);
    });
    double const trace_seconds = seconds_since(start);
    canopy::write_bench_hits(required(options, "--out"), hits);

    std::size_t const hit_count = std::size_t(std::count_if(hits.begin(), hits.end(), [](auto const& h) {
        return h.prim != canopy::invalid_id;
    }));
    fmt::print("build {:.3f} ms, trace {} rays in {:.3f} ms: {:.2f} Mrays/s, {} hits\n", scene->build_seconds * 1e3,
               rays.size(), trace_seconds * 1e3, trace_seconds > 0 ? double(rays.size()) / trace_seconds * 1e-6 : 0.0,
               hit_count);
    return 0;
}

void print_stats(char const* name, canopy::bvh_stats const& s) {
    fmt::print("{}: {} primitives, {} nodes ({} leaves, largest {}), depth {}, SAH cost {:.2f}, {:.1f} bytes/primitive\n",
               name, s.primitive_count, s.node_count, s.leaf_count, s.max_leaf_size, s.depth, s.sah_cost,
               s.bytes_per_primitive);
}

int run_info(std::span<char*> args) {
    if (args.size() == 1 && (std::string_view(args[0]) == "--help" || std::string_view(args[0]) == "-h")) {
        std::fputs(info_usage, stdout);
        return 0;
    }
    if (args.size() != 1) throw usage_error("info takes exactly one scene file");
    auto const scene = load_scene(args[0]);
    fmt::print("scene {}: {} (built in {:.3f} ms)\n", args[0],
               scene->instanced ? fmt::format("{} instances of one mesh, two levels", scene->instances.size())
                                : std::string("one mesh, single level (no top-level BVH)"),
               scene->build_seconds * 1e3);
    print_stats("mesh BVH", canopy::compute_stats(scene->mesh));
    if (scene->instanced) print_stats("top-level BVH", canopy::compute_stats(scene->top));
    return 0;
}

} // namespace

int main(int argc, char** argv) {
    std::span<char*> const args(argv, std::size_t(argc));
    if (args.size() < 2) {
        std::fputs(main_usage, stderr);
        return 2;
    }
    std::string_view const command = args[1];
    try {
        if (command == "--help" || command == "-h") {
            std::fputs(main_usage, stdout);
            return 0;
        }
        if (command == "trace") return run_trace(args.subspan(2));
        if (command == "info") return run_info(args.subspan(2));
        throw usage_error("unknown command '" + std::string(command) + "'");
    } catch (usage_error const& e) {
        std::fprintf(stderr, "canopy %s: %s\n%s", std::string(command).c_str(), e.what(),
                     command == "trace" ? trace_usage : command == "info" ? info_usage : main_usage);
        return 2;
    } catch (std::exception const& e) {
        std::fprintf(stderr, "canopy: %s\n", e.what());
        return 1;
    }
}
