// canopy.scene:limits — resource limits on loading and compiling, and the checked way to open
// an input file.
//
// A scene file is data from anywhere. Before anything is allocated in proportion to what a file
// claims (a texel count, a vertex count, a number of placements after flattening), the claim is
// checked against a limit, and a claim over it is refused with a scene_error naming the file, the
// element and the limit, e.g.
//   "forest.json: node 'trees': 10000000 placements after flattening exceed the limit of
//    4194304 (--max-placements)"
// The defaults let every real scene through on a machine with a few GiB and keep a hostile file
// from taking the machine down; a user with bigger data raises them (resource_limits fields, or
// the CLI options named in each field's comment).
//
// Only regular files are read (scenes, meshes, textures, ray files, plugins): a folder, a device
// (/dev/zero), a FIFO or a socket is refused by name, before it is opened, so a read can neither
// hang nor grow without end.
module;
#include <cstdint>
#include <filesystem>
#include <string>
#include <system_error>
export module canopy.scene:limits;
import :error;

export namespace canopy {

struct resource_limits {
    // Bytes of one input file (scene, mesh, texture, ray file). --max-file-bytes
    std::uint64_t max_file_bytes = std::uint64_t(4) << 30;
    // Texels of one image (width × height); 2^26 texels is 1 GiB as float RGBA. --max-texels
    std::uint64_t max_texels = std::uint64_t(1) << 26;
    // Triangles held by the scene's meshes together (each mesh counted once, however often it is
    // placed), and vertices likewise. --max-triangles
    std::uint64_t max_triangles = std::uint64_t(1) << 28;
    // Placements of meshes after instances are flattened (compile()'s placements); a placement
    // costs about 400 bytes once compiled, so the default is about 1.7 GB. --max-placements
    std::uint64_t max_placements = std::uint64_t(1) << 22;
    // Nesting depth of the graph: children below children and instances of instances, and the
    // nesting of a scene file's own structures (JSON arrays, glTF node hierarchies).
    // Nothing recurses in proportion to it, but deeper input is refused. --max-depth
    std::uint64_t max_depth = 4096;
};

// The one process-wide default, used where no limits are given explicitly (the registry's
// loaders, compile() without options). Set it once at start-up, before loading.
inline resource_limits& default_limits() {
    static resource_limits l;
    return l;
}

// The kinds of file the checks below tell apart, for messages.
inline char const* file_kind_name(std::filesystem::file_type t) {
    switch (t) {
    case std::filesystem::file_type::directory: return "a folder";
    case std::filesystem::file_type::block: return "a block device";
    case std::filesystem::file_type::character: return "a character device";
    case std::filesystem::file_type::fifo: return "a FIFO";
    case std::filesystem::file_type::socket: return "a socket";
    case std::filesystem::file_type::not_found: return "missing";
    default: return "not a regular file";
    }
}

// Throws scene_error unless `file` (after following symbolic links) is an existing regular file
// of at most `max_bytes` bytes; returns its size. `what` names the role in messages ("texture",
// "ray file"), and is empty for the file being loaded itself.
inline std::uint64_t require_regular_file(std::filesystem::path const& file, std::uint64_t max_bytes,
                                          std::string const& what = {}) {
    std::error_code ec;
    auto const st = std::filesystem::status(file, ec);
    std::string const role = what.empty() ? std::string() : " (" + what + ")";
    if (st.type() == std::filesystem::file_type::not_found || st.type() == std::filesystem::file_type::none)
        throw scene_error(file.string(), "", "file not found" + role);
    if (st.type() != std::filesystem::file_type::regular)
        throw scene_error(file.string(), "", "is " + std::string(file_kind_name(st.type())) + ", not a regular file" + role);
    std::uint64_t const size = std::filesystem::file_size(file, ec);
    if (ec) throw scene_error(file.string(), "", "cannot be read: " + ec.message() + role);
    if (size > max_bytes)
        throw scene_error(file.string(), "",
                          "is " + std::to_string(size) + " bytes, over the limit of " + std::to_string(max_bytes) +
                              " bytes per file (--max-file-bytes)" + role);
    return size;
}

// The same check against the default limits.
inline std::uint64_t require_regular_file(std::filesystem::path const& file, std::string const& what = {}) {
    return require_regular_file(file, default_limits().max_file_bytes, what);
}

// Throws scene_error(file, where, ...) when `count` of `what` exceeds `limit`; the message names
// the CLI option that raises it.
inline void check_limit(std::string const& file, std::string const& where, std::uint64_t count, std::uint64_t limit,
                        char const* what, char const* option) {
    if (count > limit)
        throw scene_error(file, where,
                          std::to_string(count) + " " + what + " exceed the limit of " + std::to_string(limit) + " (" +
                              option + ")");
}

} // namespace canopy
