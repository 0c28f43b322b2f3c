// Helpers shared by the test files that need no Canopy type: a temporary folder per test, and
// running a shell command.
//
// Self-contained (standard headers only): include it with the test file's standard headers,
// before its `import` lines.
#pragma once

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <system_error>
#include <sys/wait.h>
#include <unistd.h>

namespace test_support {

// A folder of its own, <temp>/<prefix>_<process id>_<n>: unique per test binary (the prefix
// names it), per process and per object. Created empty; removed, with all it holds, when the
// object goes.
struct temp_folder {
    std::filesystem::path path;

    explicit temp_folder(std::string_view prefix)
        : path(std::filesystem::temp_directory_path() /
               (std::string(prefix) + "_" + std::to_string(::getpid()) + "_" + std::to_string(++made()))) {
        std::filesystem::remove_all(path);
        std::filesystem::create_directories(path);
    }
    ~temp_folder() {
        std::error_code ignored;
        std::filesystem::remove_all(path, ignored);
    }
    temp_folder(temp_folder const&) = delete;
    temp_folder& operator=(temp_folder const&) = delete;

    // Writes `text` (bytes as given) to `name`, a path relative to the folder whose missing
    // parent folders are created; returns the file's path.
    std::filesystem::path write(std::string const& name, std::string const& text) const {
        std::filesystem::path const file = path / name;
        std::filesystem::create_directories(file.parent_path());
        std::ofstream(file, std::ios::binary) << text;
        return file;
    }

private:
    static unsigned& made() {
        static unsigned count = 0;
        return count;
    }
};

// What a shell command did: its exit status (128 + the signal when a signal ended it; -1 when
// it could not be started) and what it wrote to stdout and stderr.
struct command_result {
    int exit_code = -1;
    std::string output;
};

inline command_result run_command(std::string const& command) {
    command_result result;
    FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
    if (pipe == nullptr) return result;
    char buffer[4096];
    while (std::size_t const n = std::fread(buffer, 1, sizeof buffer, pipe)) result.output.append(buffer, n);
    int const status = ::pclose(pipe);
    result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    return result;
}

} // namespace test_support
