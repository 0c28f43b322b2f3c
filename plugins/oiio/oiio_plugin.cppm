// canopy.plugins.oiio — textures through OpenImageIO.
//
// Loads: images (.png .jpg .jpeg .exr .hdr .tif .tiff .bmp .tga .ppm .pgm .pnm .gif .webp) into
// image_data: RGBA float as stored in the file, row 0 at the top; grey → RGB, missing alpha → 1;
// 8/16-bit data scaled to [0, 1] and marked srgb (unless the file tags it linear), float data
// linear. Parameters: none. The file must be a regular file within the size limit, and its
// header is checked against canopy::default_limits().max_texels (--max-texels), and with the
// texels the scene holds already against max_total_texels (--max-total-texels), before a pixel is
// decoded. The reading is the library's canopy::read_texture (canopy.image, image/); this plugin
// registers it. Errors name the file and the problem, or OpenImageIO's reason.
module;
#include <initializer_list>
export module canopy.plugins.oiio;
import canopy.image;
import canopy.scene;

export namespace canopy {

inline void register_oiio_plugin(registry& r) {
    for (char const* ext : {".png", ".jpg", ".jpeg", ".exr", ".hdr", ".tif", ".tiff", ".bmp", ".tga", ".ppm", ".pgm",
                            ".pnm", ".gif", ".webp"})
        r.add_image_loader(ext, "oiio", read_texture);
}

} // namespace canopy
