// canopy.plugins.oiio — textures through OpenImageIO.
//
// Loads: images (.png .jpg .jpeg .exr .hdr .tif .tiff .bmp .tga .ppm .pgm .pnm .gif .webp) into
// image_data: RGBA float as stored in the file, row 0 at the top; grey → RGB, missing alpha → 1;
// 8/16-bit data scaled to [0, 1] and marked srgb (unless the file tags it linear), float data
// linear. Parameters: none. Errors name the file and OpenImageIO's reason.
module;
#include <filesystem>
#include <string>
#include <utility>
#include <vector>
export module canopy.plugins.oiio;
import canopy.scene;
import canopy.image_io;

export namespace canopy {

inline image_data read_texture_image(std::filesystem::path const& file) {
    rgba_image img;
    try {
        img = read_image(file);
    } catch (image_error const& e) {
        throw scene_error(file.string(), "", e.what());
    }
    image_data out;
    out.source = file.string();
    out.width = img.width;
    out.height = img.height;
    out.srgb = img.srgb;
    out.texels.resize(std::size_t(img.width) * std::size_t(img.height));
    for (std::size_t i = 0; i < out.texels.size(); ++i)
        out.texels[i] = {img.pixels[4 * i], img.pixels[4 * i + 1], img.pixels[4 * i + 2], img.pixels[4 * i + 3]};
    return out;
}

inline void register_oiio_plugin(registry& r) {
    for (char const* ext : {".png", ".jpg", ".jpeg", ".exr", ".hdr", ".tif", ".tiff", ".bmp", ".tga", ".ppm", ".pgm",
                            ".pnm", ".gif", ".webp"})
        r.add_image_loader(ext, "oiio", read_texture_image);
}

} // namespace canopy
