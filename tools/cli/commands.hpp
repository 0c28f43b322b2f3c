// The commands of `canopy`, one file each (render.cpp, trace.cpp, info.cpp): each runs with the
// arguments after its name and returns the exit status; its usage is printed for --help and after
// a usage error.
#pragma once
#include <span>
#include <string>

namespace cli {

int run_render(std::span<char*> args);
std::string render_usage();

int run_trace(std::span<char*> args);
std::string trace_usage();

int run_info(std::span<char*> args);
std::string info_usage();

} // namespace cli
