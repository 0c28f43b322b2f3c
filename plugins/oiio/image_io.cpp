// Implementation of canopy.image_io on OpenImageIO 2.4.
module;
#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
module canopy.image_io;

namespace canopy {

namespace {
[[noreturn]] void fail(std::filesystem::path const& path, std::string const& what) {
    throw image_error(path.string() + ": " + what);
}

// The reason of the last failed system call.
std::string os_reason() { return errno != 0 ? std::strerror(errno) : "unknown error"; }
} // namespace

rgba_image read_image(std::filesystem::path const& path) {
    if (!std::filesystem::exists(path)) fail(path, "no such file");
    auto in = OIIO::ImageInput::open(path.string());
    if (!in) fail(path, "cannot read image: " + OIIO::geterror());
    OIIO::ImageSpec const& spec = in->spec();
    if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0) fail(path, "empty image");
    if (spec.depth > 1) fail(path, "volume images are not supported");
    int const channels = spec.nchannels;
    std::vector<float> data(std::size_t(spec.width) * std::size_t(spec.height) * std::size_t(channels));
    if (!in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, data.data()))
        fail(path, "cannot read pixels: " + in->geterror());
    in->close();

    rgba_image image;
    // Integer pixel data is sRGB by convention (PNG, JPEG, 8-bit TIFF, ...) unless the file says
    // otherwise; float data (EXR, HDR) is linear.
    bool const integer = spec.format.basetype == OIIO::TypeDesc::UINT8 || spec.format.basetype == OIIO::TypeDesc::UINT16;
    std::string const space = spec.get_string_attribute("oiio:ColorSpace");
    image.srgb = integer && space != "Linear" && space != "linear";
    image.width = spec.width;
    image.height = spec.height;
    image.pixels.resize(4 * std::size_t(spec.width) * std::size_t(spec.height));
    for (std::size_t i = 0, n = std::size_t(spec.width) * std::size_t(spec.height); i < n; ++i) {
        float const* src = data.data() + i * std::size_t(channels);
        float* dst = image.pixels.data() + 4 * i;
        if (channels >= 3) {
            dst[0] = src[0], dst[1] = src[1], dst[2] = src[2];
        } else {
            dst[0] = dst[1] = dst[2] = src[0];
        }
        dst[3] = channels == 4 ? src[3] : channels == 2 ? src[1] : 1.0f;
    }
    return image;
}

void write_image(std::filesystem::path const& path, rgba_image const& image) {
    if (image.width <= 0 || image.height <= 0 ||
        image.pixels.size() != 4 * std::size_t(image.width) * std::size_t(image.height))
        fail(path, "image to write has inconsistent size");
    auto out = OIIO::ImageOutput::create(path.string());
    if (!out) fail(path, "no image writer for this file type: " + OIIO::geterror());
    std::string const ext = path.extension().string();
    bool const eight_bit = ext == ".png" || ext == ".jpg" || ext == ".jpeg";
    OIIO::ImageSpec spec(image.width, image.height, 4, eight_bit ? OIIO::TypeDesc::UINT8 : OIIO::TypeDesc::FLOAT);
    std::vector<float> clamped(image.pixels);
    if (eight_bit)
        for (float& v : clamped) v = std::clamp(v, 0.0f, 1.0f);
    // Encoded in memory when the format allows (OpenImageIO's file writers do not report a full
    // disk), then written and checked after closing here.
    std::vector<unsigned char> encoded;
    OIIO::Filesystem::IOVecOutput memory(encoded);
    bool const in_memory = out->supports("ioproxy") && out->set_ioproxy(&memory);
    if (!out->open(path.string(), spec)) fail(path, "cannot open for writing: " + out->geterror());
    if (!out->write_image(OIIO::TypeDesc::FLOAT, clamped.data())) fail(path, "cannot write: " + out->geterror());
    if (!out->close()) fail(path, "cannot finish writing: " + out->geterror());
    if (!in_memory) return;
    errno = 0;
    std::ofstream file(path, std::ios::binary | std::ios::trunc);
    if (!file) fail(path, "cannot open for writing: " + os_reason());
    file.write(reinterpret_cast<char const*>(encoded.data()), std::streamsize(encoded.size()));
    file.close();
    if (!file) fail(path, "cannot write: " + os_reason());
}

} // namespace canopy
