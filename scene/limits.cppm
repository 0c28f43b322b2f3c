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
// hang nor grow without end. read_regular_file reads such a file whole (or fails naming it), and
// require_text refuses binary data where a loader reads text.
module;
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <ios>
#include <limits>
#include <new>
#include <string>
#include <string_view>
#include <system_error>
export module canopy.scene:limits;
import :error;

export namespace canopy {

struct resource_limits {
    // Bytes of one input file (scene, mesh, texture, ray file). --max-file-bytes
    std::uint64_t max_file_bytes = std::uint64_t(4) << 30;
    // Texels of one image (width × height); 2^26 texels is 1 GiB as float RGBA. --max-texels
    std::uint64_t max_texels = std::uint64_t(1) << 26;
    // Texels of all the images one scene holds together (each image counted once, however many
    // materials use it, and a file's embedded images from when they are decoded); 2^28 texels is
    // 4 GiB as float RGBA. --max-total-texels
    std::uint64_t max_total_texels = std::uint64_t(1) << 28;
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

// The whole of `file`, checked first by require_regular_file, read into a string of exactly its
// size. A file that cannot be opened, a read that fails or comes up short, a file that grows while
// it is read, and a buffer that cannot be allocated are scene_errors naming the file: a partial
// read is never taken for the file.
inline std::string read_regular_file(std::filesystem::path const& file, std::uint64_t max_bytes,
                                     std::string const& what = {}) {
    std::uint64_t const size = require_regular_file(file, max_bytes, what);
    std::string const role = what.empty() ? std::string() : " (" + what + ")";
    std::ifstream in(file, std::ios::binary);
    if (!in) throw scene_error(file.string(), "", std::string("cannot be opened: ") + std::strerror(errno) + role);
    std::string content;
    try {
        content.resize(std::size_t(size));
    } catch (std::bad_alloc const&) {
        throw scene_error(file.string(), "", "out of memory for its " + std::to_string(size) + " bytes" + role);
    }
    in.read(content.data(), std::streamsize(size));
    if (in.bad() || std::uint64_t(in.gcount()) != size)
        throw scene_error(file.string(), "", "read " + std::to_string(in.gcount()) + " of its " + std::to_string(size) +
                                                 " bytes: the file cannot be read whole" + role);
    if (in.peek() != std::ifstream::traits_type::eof())
        throw scene_error(file.string(), "", "grew while it was being read" + role);
    return content;
}

inline std::string read_regular_file(std::filesystem::path const& file, std::string const& what = {}) {
    return read_regular_file(file, default_limits().max_file_bytes, what);
}

// Throws scene_error(file, line, "not a text FORMAT file: ...") unless `text` is text: a UTF-16 or
// UTF-32 byte-order mark, a NUL byte or another control byte (any below 0x20 but tab, line feed,
// vertical tab, form feed and carriage return; and 0x7F) is refused, named with its offset (and
// its line). Bytes from 0x80 up are let through (UTF-8, Latin-1 comments and names).
inline void require_text(std::string_view text, std::string const& file, std::string const& format) {
    std::string const head = "not a text " + format + " file: ";
    if (text.starts_with(std::string_view("\xFF\xFE\0\0", 4)) || text.starts_with(std::string_view("\0\0\xFE\xFF", 4)))
        throw scene_error(file, "", head + "UTF-32 byte-order mark (only ASCII or UTF-8 text is read)");
    if (text.starts_with("\xFF\xFE") || text.starts_with("\xFE\xFF"))
        throw scene_error(file, "", head + "UTF-16 byte-order mark (only ASCII or UTF-8 text is read)");
    std::size_t line = 1;
    for (std::size_t i = 0; i < text.size(); ++i) {
        auto const c = static_cast<unsigned char>(text[i]);
        if (c >= 0x20 && c != 0x7F) continue;
        if (c == '\n') {
            ++line;
            continue;
        }
        if (c == '\t' || c == '\r' || c == '\v' || c == '\f') continue;
        char hex[8];
        std::snprintf(hex, sizeof hex, "0x%02X", unsigned(c));
        throw scene_error(file, std::to_string(line),
                          head + (c == 0 ? std::string("NUL byte") : std::string("control byte ") + hex) + " at offset " +
                              std::to_string(i));
    }
}

// The byte offset in JSON `text` where arrays and objects first nest deeper than `limit`, or
// std::string_view::npos: one linear pass over the text (strings skipped), before any parser
// (whose recursion, or whose callbacks, it bounds).
inline std::size_t json_nesting_over(std::string_view text, std::uint64_t limit) {
    std::uint64_t depth = 0;
    bool in_string = false, escaped = false;
    for (std::size_t i = 0; i < text.size(); ++i) {
        char const c = text[i];
        if (in_string) {
            if (escaped) escaped = false;
            else if (c == '\\') escaped = true;
            else if (c == '"') in_string = false;
        } else if (c == '"') {
            in_string = true;
        } else if (c == '[' || c == '{') {
            if (++depth > limit) return i;
        } else if ((c == ']' || c == '}') && depth > 0) {
            --depth;
        }
    }
    return std::string_view::npos;
}

// What is wrong with an image of width × height texels, from its header, before it is decoded,
// or "" when nothing is: over max_texels (--max-texels), or bringing the texels held — `held`,
// those of the images the scene already holds or has decoded — over max_total_texels
// (--max-total-texels). Image loaders call it with the header's size before allocating (the
// registry passes them `held`: see registry::load_image).
inline std::string texel_problem(std::uint64_t width, std::uint64_t height, std::uint64_t held, std::uint64_t max_texels,
                                 std::uint64_t max_total_texels) {
    std::string const size = std::to_string(width) + " × " + std::to_string(height);
    // Each side is below 2^32 in every header read, so the product does not wrap.
    std::uint64_t const texels = width * height;
    if (texels > max_texels)
        return "image is " + size + " (" + std::to_string(texels) + " texels), over the limit of " +
               std::to_string(max_texels) + " texels (--max-texels)";
    if (held > max_total_texels || texels > max_total_texels - held)
        return "image is " + size + " (" + std::to_string(texels) + " texels): with the " + std::to_string(held) +
               " texels of the images loaded before it, " +
               (held > std::numeric_limits<std::uint64_t>::max() - texels ? std::string("more than 2^64")
                                                                          : std::to_string(held + texels)) +
               " texels in all exceed the limit of " + std::to_string(max_total_texels) + " (--max-total-texels)";
    return {};
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
