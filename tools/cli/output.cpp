// The output files of `canopy` (output.hpp).
#include "output.hpp"
#include <cerrno>
#include <cstring>
#include <system_error>
#include <fcntl.h>
#include <unistd.h>

namespace cli {

std::string os_reason(int error) { return error != 0 ? std::strerror(error) : "unknown error"; }

void check_writable(std::filesystem::path const& file) {
    int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NONBLOCK | O_CLOEXEC, 0666);
    bool const created = fd >= 0;
    if (fd < 0 && errno == EEXIST) fd = ::open(file.c_str(), O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0 && errno == ENXIO) throw output_error(file.string() + ": cannot be written: a FIFO with no reader");
    if (fd < 0) throw output_error(file.string() + ": cannot be written: " + os_reason(errno));
    ::close(fd);
    if (created) ::unlink(file.c_str());
}

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

} // namespace cli
