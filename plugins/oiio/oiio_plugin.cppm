// canopy.plugins.oiio — textures through OpenImageIO.
//
// Loads: images (.png .jpg .jpeg .exr .hdr .tif .tiff .bmp .tga .ppm .pgm .pnm .gif .webp) into
// image_data: RGBA float as stored in the file, row 0 at the top; grey → RGB, missing alpha → 1;
// 8/16-bit data scaled to [0, 1] and marked srgb (unless the file tags it linear), float data
// linear. Parameters: none. The file must be a regular file within the size limit, and its
// header is checked against canopy::default_limits().max_texels (--max-texels), and with the
// texels the scene holds already against max_total_texels (--max-total-texels), before a pixel is
// decoded (canopy.image_io). Errors name the file and the problem, or OpenImageIO's reason.
module;
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <new>
#include <string>
#include <utility>
#include <vector>
export module canopy.plugins.oiio;
import canopy.scene;
import canopy.image_io;
import canopy.math;

export namespace canopy {

// The texels are decoded straight into image_data's storage (one copy of the image in memory).
// texels_held: those of the images the scene holds already (the total budget, see
// registry::load_image).
inline image_data read_texture_image(std::filesystem::path const& file, std::uint64_t texels_held = 0) {
    static_assert(sizeof(vec4<float>) == 4 * sizeof(float));
    image_data out;
    out.source = file.string();
    image_read_limits limits = default_image_read_limits();
    limits.texels_held = texels_held;
    try {
        read_image_into(file, limits, [&](image_header const& h) {
            out.width = h.width;
            out.height = h.height;
            out.srgb = h.srgb;
            out.texels.resize(std::size_t(h.width) * std::size_t(h.height));
            return &out.texels.data()->x;
        });
    } catch (std::bad_alloc const&) {
        throw scene_error(file.string(), "", "out of memory while reading the image");
    }
    return out;
}

inline void register_oiio_plugin(registry& r) {
    for (char const* ext : {".png", ".jpg", ".jpeg", ".exr", ".hdr", ".tif", ".tiff", ".bmp", ".tga", ".ppm", ".pgm",
                            ".pnm", ".gif", ".webp"})
        r.add_image_loader(ext, "oiio", read_texture_image);
}

} // namespace canopy
