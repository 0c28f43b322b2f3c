// canopy.testing:files — what the tests need that involves no Canopy type: a temporary folder per
// test, the special files loaders must refuse, the message of an expected exception, and running
// a shell command.
module;
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
export module canopy.testing:files;

export namespace test_support {

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

// The kinds of file that are not regular files, as every reader must refuse them by name before
// opening them: `name` is the stem make_special_files gives them, `kind` the words of the message
// ("is a FIFO, not a regular file").
struct special_file {
    std::string name;
    std::string kind;
};

inline std::vector<special_file> const& special_files() {
    static std::vector<special_file> const all{{"folder", "a folder"}, {"zero", "a character device"}, {"fifo", "a FIFO"}};
    return all;
}

// Makes in `folder`, for each extension (".obj"; "" for none), the folder "folder<ext>", the
// symbolic link "zero<ext>" to /dev/zero and the FIFO "fifo<ext>". Returns false when one
// cannot be made.
inline bool make_special_files(std::filesystem::path const& folder, std::initializer_list<std::string_view> extensions) {
    std::error_code ec;
    for (std::string_view ext : extensions) {
        std::filesystem::create_directory(folder / ("folder" + std::string(ext)), ec);
        if (ec) return false;
        std::filesystem::create_symlink("/dev/zero", folder / ("zero" + std::string(ext)), ec);
        if (ec) return false;
        if (::mkfifo((folder / ("fifo" + std::string(ext))).c_str(), 0600) != 0) return false;
    }
    return true;
}

// The message (what()) of the exception f throws when it is one of the types E..., or
// "(no exception)" when f returns; an exception of another type propagates.
template <typename... E>
std::string what_of(auto&& f) {
    try {
        f();
    } catch (std::exception const& e) {
        if ((... || (dynamic_cast<E const*>(&e) != nullptr))) return e.what();
        throw;
    }
    return "(no exception)";
}

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
