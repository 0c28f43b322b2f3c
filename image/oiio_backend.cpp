// The OpenImageIO 2.4 backend of canopy.image (see oiio_backend.hpp): a shared library loaded by
// image.cpp on first use; every symbol but canopy_image_backend_v1 is hidden.
#include "oiio_backend.hpp"
#include <algorithm>
#include <cstring>
#include <memory>
#include <string>
#include <vector>
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace {

void copy_message(std::string const& message, char* error, std::size_t error_size) {
    if (error == nullptr || error_size == 0) return;
    std::size_t const n = std::min(message.size(), error_size - 1);
    std::memcpy(error, message.data(), n);
    error[n] = '\0';
}

int failed(int* stage, int which, std::string const& message, char* error, std::size_t error_size) {
    *stage = which;
    copy_message(message, error, error_size);
    return 0;
}

void* open_reader(char const* extension, char const* path, canopy_image_header* header, int* stage, char* error,
                  std::size_t error_size) {
    auto in = OIIO::ImageInput::create(extension, false);
    if (!in) {
        failed(stage, canopy_image_no_codec, OIIO::geterror(), error, error_size);
        return nullptr;
    }
    OIIO::ImageSpec spec;
    if (!in->open(path, spec)) {
        failed(stage, canopy_image_open, in->geterror(), error, error_size);
        return nullptr;
    }
    header->width = spec.width;
    header->height = spec.height;
    header->depth = spec.depth;
    header->channels = spec.nchannels;
    header->deep = spec.deep ? 1 : 0;
    header->integer_data =
        spec.format.basetype == OIIO::TypeDesc::UINT8 || spec.format.basetype == OIIO::TypeDesc::UINT16 ? 1 : 0;
    copy_message(spec.get_string_attribute("oiio:ColorSpace"), header->color_space, sizeof header->color_space);
    return in.release();
}

int read_pixels(void* reader, int channels, float* pixels, char* error, std::size_t error_size) {
    auto* in = static_cast<OIIO::ImageInput*>(reader);
    if (in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, pixels, OIIO::stride_t(4 * sizeof(float)))) return 1;
    copy_message(in->geterror(), error, error_size);
    return 0;
}

void close_reader(void* reader) {
    std::unique_ptr<OIIO::ImageInput> in(static_cast<OIIO::ImageInput*>(reader));
    in->close();
}

int write_image(char const* path, int width, int height, int eight_bit, float const* pixels, void* context,
                void (*sink)(void*, unsigned char const*, std::size_t), int* in_memory, int* stage, char* error,
                std::size_t error_size) {
    *in_memory = 0;
    auto out = OIIO::ImageOutput::create(path);
    if (!out) return failed(stage, canopy_image_no_codec, OIIO::geterror(), error, error_size);
    OIIO::ImageSpec spec(width, height, 4, eight_bit != 0 ? OIIO::TypeDesc::UINT8 : OIIO::TypeDesc::FLOAT);
    // Encoded in memory when the format allows (OpenImageIO's file writers do not report a full
    // disk): the caller writes the bytes and checks the file.
    std::vector<unsigned char> encoded;
    OIIO::Filesystem::IOVecOutput memory(encoded);
    bool const proxy = out->supports("ioproxy") && out->set_ioproxy(&memory);
    if (!out->open(path, spec)) return failed(stage, canopy_image_open, out->geterror(), error, error_size);
    if (!out->write_image(OIIO::TypeDesc::FLOAT, pixels))
        return failed(stage, canopy_image_pixels, out->geterror(), error, error_size);
    if (!out->close()) return failed(stage, canopy_image_close, out->geterror(), error, error_size);
    if (proxy) {
        *in_memory = 1;
        sink(context, encoded.data(), encoded.size());
    }
    return 1;
}

constexpr canopy_image_backend backend{canopy_image_backend_version, open_reader, read_pixels, close_reader,
                                       write_image};

} // namespace

extern "C" __attribute__((visibility("default"))) canopy_image_backend const* canopy_image_backend_v1() {
    return &backend;
}
