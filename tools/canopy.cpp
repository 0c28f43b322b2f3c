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
//
// The commands are rows of one table below; each lives in its own file (tools/cli/render.cpp,
// trace.cpp, info.cpp) over the shared options parser (tools/cli/options.hpp).
#include <cerrno>
#include <cstdio>
#include <exception>
#include <span>
#include <string>
#include <string_view>
#include <fmt/core.h>
#include "cli/commands.hpp"
#include "cli/options.hpp"
#include "cli/output.hpp"
#include "cli/processes.hpp"
#if CANOPY_WITH_MPI
import canopy.distributed;
#endif

namespace {

using namespace cli;

// The commands: name, what it does (the main usage), its usage, how it runs; `root_only`: under
// mpirun, rank 0 alone runs it.
struct command_row {
    std::string_view name, text;
    std::string (*usage)();
    int (*run)(std::span<char*>);
    bool root_only = false;
};

constexpr command_row commands[] = {
    {"render", "render the demo scene (no SCENE) or a scene file into PNG images", render_usage, run_render},
    {"trace", "trace a ray file against a scene, write a hit file", trace_usage, run_trace},
    {"info", "print scene statistics, compile decisions and BVH statistics", info_usage, run_info, true},
};

command_row const* find_command(std::string_view name) {
    for (command_row const& c : commands)
        if (c.name == name) return &c;
    return nullptr;
}

std::string main_usage() {
    std::string out = "usage: canopy <command> [options]\ncommands:\n";
    for (command_row const& c : commands) out += fmt::format("  {:<6}  {}\n", c.name, c.text);
    return out + "run 'canopy <command> --help' for the options of a command\n"
                 "exit status: 0 success, 1 error (the message names the file), 2 usage error\n";
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
    command_row const* const chosen = find_command(command);
    try {
        if (command == "--help" || command == "-h") {
            if (root_rank()) std::fputs(main_usage().c_str(), stdout);
            return 0;
        }
        if (!chosen) throw usage_error("unknown command " + quote(command));
        if (chosen->root_only && !root_rank()) return 0;
        return chosen->run(args);
    } catch (usage_error const& e) {
        if (!root_rank()) return 2; // every rank has the same arguments, hence the same error
        std::fprintf(stderr, "canopy%s%s: %s\n%s", chosen ? " " : "", chosen ? std::string(command).c_str() : "",
                     e.what(), chosen ? chosen->usage().c_str() : main_usage().c_str());
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
        std::fputs(main_usage().c_str(), stderr);
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
