// libFuzzer target: canopy.plugins.openmesh's checks of PLY, OFF and STL files (and OBJ and OM)
// on arbitrary bytes, and OpenMesh's reading of what they let through.
//
// Every input is checked as each format. The checks claim that OpenMesh's readers cannot loop,
// allocate without bound or misread a file they accept, so an input a check accepts is written
// to a file of that extension and read: that must end in a mesh or a scene_error. Anything else
// (a crash, a sanitizer report, another exception, a leak, a slow input) is a finding.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <system_error>
#include <unistd.h>

import canopy.scene;
import canopy.plugins.openmesh;

namespace {

// A folder of this process's own for the files read, removed at exit.
struct work_folder {
    std::filesystem::path path =
        std::filesystem::temp_directory_path() / ("canopy_openmesh_fuzz_" + std::to_string(::getpid()));
    work_folder() { std::filesystem::create_directories(path); }
    ~work_folder() {
        std::error_code ignored;
        std::filesystem::remove_all(path, ignored);
    }
};

} // namespace

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
    std::string_view const bytes(reinterpret_cast<char const*>(data), size);
    static work_folder const folder;
    for (char const* ext : {".ply", ".off", ".stl", ".obj", ".om"}) {
        try {
            (void)canopy::check_openmesh_input(bytes, "input", ext);
        } catch (canopy::scene_error const&) {
            continue;
        }
        std::filesystem::path const file = folder.path / (std::string("input") + ext);
        std::ofstream(file, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
        try {
            (void)canopy::read_openmesh(file);
        } catch (canopy::scene_error const&) {
        }
    }
    return 0;
}
