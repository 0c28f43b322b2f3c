// The output files of `canopy`: checked before any work, and again after closing.
#pragma once
#include <filesystem>
#include <stdexcept>
#include <string>

namespace cli {

// An output that cannot be written (exit status 1).
struct output_error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// The text of errno value `error` ("unknown error" for 0).
std::string os_reason(int error);

// Checks, before any work, that `file` can be written: it is opened for writing (not truncated;
// non-blocking, so a FIFO without a reader is an error, not a hang). A file that was not there is
// removed again.
void check_writable(std::filesystem::path const& file);

// Creates the output folder (and its parents) when missing; refuses a path that is not a folder.
void prepare_folder(std::filesystem::path const& folder);

} // namespace cli
