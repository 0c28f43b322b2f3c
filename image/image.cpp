// Implementation of canopy.image: the one reading path (read_into) and the writer, on OpenImageIO
// through its backend (oiio_backend.hpp), loaded on first use.
module;
#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <new>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>
#include <dlfcn.h>
#include "oiio_backend.hpp"
module canopy.image;
import canopy.render;
import canopy.scene;

namespace canopy {

namespace {

[[noreturn]] void fail(std::filesystem::path const& path, std::string const& what) {
    throw scene_error(path.string(), "", what);
}

// The OpenImageIO backend, loaded once (thread-safe), from CANOPY_IMAGE_BACKEND when set, else
// from where the build put it (CANOPY_IMAGE_BACKEND_PATH); `path` names the image in the error
// when it cannot be loaded.
canopy_image_backend const& backend(std::filesystem::path const& path) {
    // The backend, or why there is none.
    struct loaded_backend {
        canopy_image_backend const* io = nullptr;
        std::string problem;
    };
    static loaded_backend const loaded = []() -> loaded_backend {
        char const* from_environment = std::getenv("CANOPY_IMAGE_BACKEND");
        std::string const file = from_environment != nullptr && *from_environment != '\0' ? from_environment
                                                                                          : CANOPY_IMAGE_BACKEND_PATH;
        void* const handle = dlopen(file.c_str(), RTLD_NOW | RTLD_LOCAL);
        if (handle == nullptr) {
            char const* const why = dlerror();
            return {nullptr, "image support is unavailable: cannot load its OpenImageIO backend (" +
                                 std::string(why != nullptr ? why : file) + ")"};
        }
        auto const entry = reinterpret_cast<canopy_image_backend_entry>(dlsym(handle, "canopy_image_backend_v1"));
        canopy_image_backend const* const io = entry != nullptr ? entry() : nullptr;
        if (io == nullptr || io->version != canopy_image_backend_version)
            return {nullptr, "image support is unavailable: " + file + " is not a canopy image backend of version " +
                                 std::to_string(canopy_image_backend_version)};
        return {io, {}}; // never unloaded: OpenImageIO keeps threads and static state
    }();
    if (loaded.io == nullptr) fail(path, loaded.problem);
    return *loaded.io;
}

// A message of the backend (error_buffer), as reason() below takes it.
struct error_buffer {
    char text[512] = {};
    std::string str() const { return std::string(text); }
};

// OpenImageIO's message, on one line and at most a few hundred characters.
std::string reason(std::string message) {
    std::replace(message.begin(), message.end(), '\n', ' ');
    while (!message.empty() && message.back() == ' ') message.pop_back();
    constexpr std::size_t longest = 200;
    if (message.size() > longest) message = message.substr(0, longest) + "…";
    return message.empty() ? std::string("no reason given") : message;
}

// The reason of the last failed system call.
std::string os_reason() { return errno != 0 ? std::strerror(errno) : "unknown error"; }

std::string size_text(std::int64_t width, std::int64_t height) {
    return std::to_string(width) + " × " + std::to_string(height);
}

// Width and height from the header of a GIF, WebP or BMP file: OpenImageIO's readers of these
// formats allocate (and fill) the whole image when they open the file (GIF: its canvas; WebP:
// the decoded image; BMP: an RLE image), before its size can be checked. nullopt for other
// formats and for headers not understood here (OpenImageIO then reports them).
std::optional<std::pair<std::uint64_t, std::uint64_t>> size_before_open(std::filesystem::path const& path,
                                                                        std::string const& extension) {
    if (extension != "gif" && extension != "webp" && extension != "bmp") return std::nullopt;
    unsigned char b[32] = {};
    std::ifstream in(path, std::ios::binary);
    in.read(reinterpret_cast<char*>(b), sizeof b);
    std::size_t const n = std::size_t(in.gcount());
    auto const le16 = [&](std::size_t i) { return std::uint64_t(b[i]) | std::uint64_t(b[i + 1]) << 8; };
    auto const le24 = [&](std::size_t i) { return le16(i) | std::uint64_t(b[i + 2]) << 16; };
    auto const le32 = [&](std::size_t i) { return le16(i) | le16(i + 2) << 16; };
    if (n >= 10 && std::memcmp(b, "GIF8", 4) == 0) return std::pair(le16(6), le16(8));
    if (n >= 26 && b[0] == 'B' && b[1] == 'M') {
        if (le32(14) == 12) return std::pair(le16(18), le16(20));
        auto const magnitude = [](std::uint64_t v) { return v >= 0x80000000u ? 0x100000000u - v : v; };
        return std::pair(magnitude(le32(18)), magnitude(le32(22)));
    }
    if (n >= 30 && std::memcmp(b, "RIFF", 4) == 0 && std::memcmp(b + 8, "WEBP", 4) == 0) {
        if (std::memcmp(b + 12, "VP8X", 4) == 0) return std::pair(le24(24) + 1, le24(27) + 1);
        if (std::memcmp(b + 12, "VP8L", 4) == 0 && b[20] == 0x2f) {
            std::uint64_t const bits = le32(21);
            return std::pair((bits & 0x3fff) + 1, (bits >> 14 & 0x3fff) + 1);
        }
        if (std::memcmp(b + 12, "VP8 ", 4) == 0) return std::pair(le16(26) & 0x3fff, le16(28) & 0x3fff);
    }
    return std::nullopt;
}

// A PNG file (by its signature) must hold its IEND chunk (type and CRC) in its last 64 KiB: image
// readers stop once the pixels are decoded, so a file cut in its last chunks would load silently.
bool png_without_end(std::filesystem::path const& path, std::uint64_t size) {
    static constexpr char signature[] = "\x89PNG\r\n\x1a\n";
    static constexpr char end[] = "IEND\xAE\x42\x60\x82";
    std::ifstream in(path, std::ios::binary);
    char head[8] = {};
    in.read(head, sizeof head);
    if (in.gcount() != 8 || std::memcmp(head, signature, 8) != 0) return false;
    std::uint64_t const tail = std::min<std::uint64_t>(size, 65536);
    std::string last(std::size_t(tail), '\0');
    in.seekg(std::streamoff(size - tail));
    in.read(last.data(), std::streamsize(tail));
    return std::string_view(last.data(), std::size_t(in.gcount())).find(std::string_view(end, 8)) == std::string_view::npos;
}

// An image's size and encoding, known from its header before its pixels are decoded.
struct image_header {
    int width = 0;
    int height = 0;
    bool srgb = false; // as rgba_image::srgb
};

void check_texels(std::filesystem::path const& path, std::uint64_t width, std::uint64_t height,
                  image_read_limits const& limits) {
    std::string const problem = texel_problem(width, height, limits.texels_held, limits.max_texels, limits.max_total_texels);
    if (!problem.empty()) fail(path, problem);
}

// The one reading path: reads the header, checks it, then calls allocate(header) once for the
// storage of the pixels (4 · width · height floats, RGBA, row 0 first) and decodes into it.
void read_into(std::filesystem::path const& path, image_read_limits const& limits,
               std::function<float*(image_header const&)> const& allocate) {
    std::uint64_t size = 0;
    try {
        size = require_regular_file(path, limits.max_file_bytes);
    } catch (scene_error const& e) {
        fail(path, e.problem());
    }
    // The reader of the file's extension only: given a file name, OpenImageIO tries every format
    // it knows on a file its extension's reader refuses; given the extension, it makes that reader.
    std::string extension = path.extension().string();
    if (!extension.empty()) extension.erase(0, 1);
    for (char& c : extension) c = char(std::tolower(static_cast<unsigned char>(c)));
    if (auto const dims = size_before_open(path, extension)) check_texels(path, dims->first, dims->second, limits);
    if (png_without_end(path, size)) fail(path, "PNG file without its IEND chunk at the end (truncated?)");
    auto const no_reader = [&] {
        fail(path, "no image reader for this file type (" +
                       (extension.empty() ? std::string("no extension") : "'." + extension + "'") + ")");
    };
    if (extension.empty()) no_reader();
    canopy_image_backend const& io = backend(path);
    canopy_image_header spec{};
    error_buffer error;
    int stage = 0;
    std::unique_ptr<void, void (*)(void*)> in(
        io.open_reader(extension.c_str(), path.c_str(), &spec, &stage, error.text, sizeof error.text), io.close_reader);
    if (!in) {
        if (stage == canopy_image_no_codec) no_reader();
        fail(path, "cannot read image: " + reason(error.str()));
    }

    // The header, checked before anything is allocated for the pixels.
    if (spec.deep) fail(path, "deep images are not supported");
    if (spec.depth > 1) fail(path, "volume images are not supported");
    if (spec.width <= 0 || spec.height <= 0) fail(path, "image has no pixels (" + size_text(spec.width, spec.height) + ")");
    if (spec.channels <= 0) fail(path, "image has no channels");
    std::uint64_t const texels = std::uint64_t(spec.width) * std::uint64_t(spec.height);
    check_texels(path, std::uint64_t(spec.width), std::uint64_t(spec.height), limits);
    if (texels > std::numeric_limits<std::size_t>::max() / (4 * sizeof(float)))
        fail(path, "image is " + size_text(spec.width, spec.height) + ", too large to address");

    // Integer pixel data is sRGB by convention (PNG, JPEG, 8-bit TIFF, ...) unless the file says
    // otherwise; float data (EXR, HDR) is linear.
    image_header header;
    header.width = spec.width;
    header.height = spec.height;
    bool const integer = spec.integer_data != 0;
    std::string const space = spec.color_space;
    header.srgb = integer && space != "Linear" && space != "linear";

    try {
        float* const pixels = allocate(header);
        // The first four channels at most, each texel 4 floats apart; then grey → RGB and the
        // missing alpha → 1.
        int const channels = std::min(spec.channels, 4);
        if (io.read_pixels(in.get(), channels, pixels, error.text, sizeof error.text) == 0)
            fail(path, "cannot read pixels: " + reason(error.str()));
        for (std::size_t i = 0; i < std::size_t(texels); ++i) {
            float* p = pixels + 4 * i;
            if (channels < 3) {
                float const alpha = channels == 2 ? p[1] : 1.0f;
                p[1] = p[2] = p[0];
                p[3] = alpha;
            } else if (channels == 3) {
                p[3] = 1.0f;
            }
        }
    } catch (std::bad_alloc const&) {
        fail(path, "out of memory for an image of " + size_text(spec.width, spec.height) + " texels");
    }
}

} // namespace

image_read_limits default_image_read_limits(std::uint64_t texels_held) {
    return {default_limits().max_file_bytes, default_limits().max_texels, default_limits().max_total_texels, texels_held};
}

image_data read_texture(std::filesystem::path const& path, std::uint64_t texels_held) {
    static_assert(sizeof(vec4<float>) == 4 * sizeof(float));
    image_data out;
    out.source = path.string();
    read_into(path, default_image_read_limits(texels_held), [&](image_header const& h) {
        out.width = h.width;
        out.height = h.height;
        out.srgb = h.srgb;
        out.texels.resize(std::size_t(h.width) * std::size_t(h.height));
        return &out.texels.data()->x;
    });
    return out;
}

rgba_image read_image(std::filesystem::path const& path, image_read_limits const& limits) {
    rgba_image image;
    read_into(path, limits, [&](image_header const& h) {
        image.width = h.width;
        image.height = h.height;
        image.srgb = h.srgb;
        image.pixels.resize(4 * std::size_t(h.width) * std::size_t(h.height));
        return image.pixels.data();
    });
    return image;
}

rgba_image read_image(std::filesystem::path const& path) { return read_image(path, default_image_read_limits()); }

void write_image(std::filesystem::path const& path, rgba_image const& image) {
    if (image.width <= 0 || image.height <= 0 ||
        image.pixels.size() != 4 * std::size_t(image.width) * std::size_t(image.height))
        fail(path, "image to write has inconsistent size");
    canopy_image_backend const& io = backend(path);
    std::string const ext = path.extension().string();
    bool const eight_bit = ext == ".png" || ext == ".jpg" || ext == ".jpeg";
    std::vector<float> clamped(image.pixels);
    if (eight_bit)
        for (float& v : clamped) v = std::clamp(v, 0.0f, 1.0f);
    // Encoded in memory when the format allows (OpenImageIO's file writers do not report a full
    // disk), then written and checked after closing here.
    std::vector<unsigned char> encoded;
    auto const keep = [](void* context, unsigned char const* data, std::size_t size) {
        static_cast<std::vector<unsigned char>*>(context)->assign(data, data + size);
    };
    error_buffer error;
    int in_memory = 0, stage = 0;
    if (io.write_image(path.c_str(), image.width, image.height, eight_bit ? 1 : 0, clamped.data(), &encoded, keep,
                       &in_memory, &stage, error.text, sizeof error.text) == 0) {
        switch (stage) {
        case canopy_image_no_codec: fail(path, "no image writer for this file type: " + reason(error.str()));
        case canopy_image_open: fail(path, "cannot open for writing: " + reason(error.str()));
        case canopy_image_pixels: fail(path, "cannot write: " + reason(error.str()));
        default: fail(path, "cannot finish writing: " + reason(error.str()));
        }
    }
    if (!in_memory) return;
    errno = 0;
    std::ofstream file(path, std::ios::binary | std::ios::trunc);
    if (!file) fail(path, "cannot open for writing: " + os_reason());
    file.write(reinterpret_cast<char const*>(encoded.data()), std::streamsize(encoded.size()));
    file.close();
    if (!file) fail(path, "cannot write: " + os_reason());
}

std::size_t write_framebuffer(std::filesystem::path const& path, framebuffer const& fb, display_options const& display) {
    rgba_image image;
    image.width = fb.width;
    image.height = fb.height;
    std::size_t nan_pixels = 0;
    image.pixels = display_values(fb, display, nan_pixels);
    write_image(path, image);
    return nan_pixels;
}

} // namespace canopy
