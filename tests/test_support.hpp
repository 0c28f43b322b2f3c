// Helpers shared by the test files that need no Canopy type: a temporary folder per test.
//
// Self-contained (standard headers only): include it with the test file's standard headers,
// before its `import` lines.
#pragma once

#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <system_error>
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

} // namespace test_support
