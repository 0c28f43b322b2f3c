// canopy.image — reading and writing images through OpenImageIO (PNG, JPEG, EXR, TIFF, …:
// whatever the installed OpenImageIO reads and writes, chosen by file extension). Library code:
// the oiio plugin (canopy.plugins.oiio) registers read_texture as the scene registry's image
// loader.
//
//   read_texture(path, texels_held)  any image → image_data (RGBA float, row 0 at the top; grey
//                             → RGB, missing alpha → 1; 8/16-bit data scaled to [0, 1] and
//                             marked srgb unless the file tags it linear), decoded straight into
//                             its storage; the limits are canopy::default_limits()'s
//   read_image(path[, limits])  the same reading path into an rgba_image (interleaved floats)
//   write_image(path, image)  RGBA float → the file's format; values are clamped to [0, 1] and
//                             quantised for 8-bit formats (PNG, JPEG); the file is checked after
//                             closing (a full disk or /dev/full is an error, with the OS reason)
//   write_framebuffer(path, fb, display)  a rendered framebuffer through its display values
//                             (canopy.render:film: exposure, tone curve, sRGB, or heat colours as
//                             they are) into write_image; returns the NaN pixels, written black
//
// Every read goes through one path (image.cpp): a file is read only when it is a regular file
// within the size limit (a device such as /dev/zero, a FIFO or a folder is refused before it is
// opened), only by the reader of its extension (a file that is not what its extension says is
// refused, not tried with every format OpenImageIO knows), and only after its header: an image of
// more than max_texels texels (width × height; --max-texels, canopy::default_limits() by
// default), or one that would bring the texels of a scene's images over max_total_texels
// (texels_held: those loaded before it; --max-total-texels), is refused before any pixel is
// decoded (GIF, WebP and BMP headers are read here, since OpenImageIO decodes those images as it
// opens them), as are images without pixels or channels, volumes and deep images.
//
// Failures throw canopy::scene_error (canopy.scene:error) naming the file and the problem
// (missing file, unknown format, truncated data, a limit), as "tree.png: image is 16384 × 16384
// (268435456 texels), over the limit of 67108864 texels (--max-texels)". OpenImageIO's headers
// stay in the implementation unit.
module;
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <vector>
export module canopy.image;
import canopy.render;
import canopy.scene;

export namespace canopy {

// What a read accepts; by default canopy::default_limits()'s values.
struct image_read_limits {
    std::uint64_t max_file_bytes;   // bytes of the file (--max-file-bytes)
    std::uint64_t max_texels;       // width × height (--max-texels)
    std::uint64_t max_total_texels; // texels_held + width × height (--max-total-texels)
    std::uint64_t texels_held;      // of the images loaded before this one (0: none)
};
// default_limits()'s values as they are now, with texels_held.
image_read_limits default_image_read_limits(std::uint64_t texels_held = 0);

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

// A texture for a scene (its image_loader: texels_held are the texels of the images the scene
// holds already, see registry::load_image); image_data::source is the path.
image_data read_texture(std::filesystem::path const& path, std::uint64_t texels_held = 0);

rgba_image read_image(std::filesystem::path const& path);
rgba_image read_image(std::filesystem::path const& path, image_read_limits const& limits);

void write_image(std::filesystem::path const& path, rgba_image const& image);

// Writes fb's display values (display_values, canopy.render:film); returns how many pixels were
// not a number (written black), for the caller to report.
std::size_t write_framebuffer(std::filesystem::path const& path, framebuffer const& fb, display_options const& display = {});

} // namespace canopy
