// canopy.image_io — reading and writing images through OpenImageIO (PNG, JPEG, EXR, TIFF, …:
// whatever the installed OpenImageIO reads and writes, chosen by file extension).
//
//   read_image(path)          any image → RGBA float, row 0 at the top; grey → RGB, missing
//                             alpha → 1; 8/16-bit data scaled to [0, 1]
//   write_image(path, image)  RGBA float → the file's format; values are clamped to [0, 1] and
//                             quantised for 8-bit formats (PNG, JPEG); the file is checked after
//                             closing (a full disk or /dev/full is an error, with the OS reason)
//
// Failures throw image_error naming the file and OpenImageIO's reason (missing file, unknown
// format, truncated data). OpenImageIO's headers stay in the implementation unit.
module;
#include <cstddef>
#include <filesystem>
#include <stdexcept>
#include <vector>
export module canopy.image_io;

export namespace canopy {

struct image_error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

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

rgba_image read_image(std::filesystem::path const& path);
void write_image(std::filesystem::path const& path, rgba_image const& image);

} // namespace canopy
