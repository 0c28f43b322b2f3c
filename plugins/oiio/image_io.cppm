// canopy.image_io — reading and writing images through OpenImageIO (PNG, JPEG, EXR, TIFF, …:
// whatever the installed OpenImageIO reads and writes, chosen by file extension).
//
//   read_image(path)          any image → RGBA float, row 0 at the top; grey → RGB, missing
//                             alpha → 1; 8/16-bit data scaled to [0, 1]
//   read_image_into(path, limits, allocate)
//                             the same, decoded straight into the caller's storage
//   write_image(path, image)  RGBA float → the file's format; values are clamped to [0, 1] and
//                             quantised for 8-bit formats (PNG, JPEG); the file is checked after
//                             closing (a full disk or /dev/full is an error, with the OS reason)
//
// A file is read only when it is a regular file within the size limit (a device such as
// /dev/zero, a FIFO or a folder is refused before it is opened), only by the reader of its
// extension (a file that is not what its extension says is refused, not tried with every
// format OpenImageIO knows), and only after its header: an image of more than max_texels texels
// (width × height; --max-texels, canopy::default_limits() by default), or one that would bring the
// texels of a scene's images over max_total_texels (texels_held: those loaded before it;
// --max-total-texels), is refused before any pixel is decoded (GIF, WebP and BMP headers are read here, since OpenImageIO decodes those images as
// it opens them), as are images without pixels or channels, volumes and deep images.
//
// Failures throw canopy::scene_error (canopy.scene:error) naming the file and the problem
// (missing file, unknown format, truncated data, a limit), as "tree.png: image is 16384 × 16384 (268435456 texels), over the
// limit of 67108864 texels (--max-texels)". OpenImageIO's headers stay in the implementation unit.
module;
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>
export module canopy.image_io;

export namespace canopy {

// What read_image accepts; by default canopy::default_limits()'s values.
struct image_read_limits {
    std::uint64_t max_file_bytes;   // bytes of the file (--max-file-bytes)
    std::uint64_t max_texels;       // width × height (--max-texels)
    std::uint64_t max_total_texels; // texels_held + width × height (--max-total-texels)
    std::uint64_t texels_held;      // of the images loaded before this one (0: none)
};
image_read_limits default_image_read_limits();

// Interleaved RGBA pixels, width × height, row-major, row 0 at the top.
struct rgba_image {
    int width = 0;
    int height = 0;
    std::vector<float> pixels; // 4 · width · height values
    bool srgb = false;         // read from 8/16-bit integer data not tagged linear: RGB is sRGB-encoded

    float* at(int x, int y) { return pixels.data() + 4 * (std::size_t(y) * std::size_t(width) + std::size_t(x)); }
    float const* at(int x, int y) const {
        return pixels.data() + 4 * (std::size_t(y) * std::size_t(width) + std::size_t(x));
    }
};

// An image's size and encoding, known from its header before its pixels are decoded.
struct image_header {
    int width = 0;
    int height = 0;
    bool srgb = false; // as rgba_image::srgb
};

rgba_image read_image(std::filesystem::path const& path);
rgba_image read_image(std::filesystem::path const& path, image_read_limits const& limits);

// Reads the header, checks it, then calls allocate(header) once for the storage of the pixels
// (4 · width · height floats, RGBA, row 0 first) and decodes into it.
void read_image_into(std::filesystem::path const& path, image_read_limits const& limits,
                     std::function<float*(image_header const&)> const& allocate);

void write_image(std::filesystem::path const& path, rgba_image const& image);

} // namespace canopy
