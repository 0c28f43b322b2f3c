// The C interface between canopy.image (image.cpp) and its OpenImageIO backend
// (oiio_backend.cpp, the shared library canopy_image_oiio), which image.cpp loads with dlopen
// the first time an image is read or written. OpenImageIO pulls in some 260 shared libraries
// (its format readers: video, DICOM, HEIF, ...) whose loading and symbol binding took about
// 0.35 s at the start of every program linked with it, including `canopy --help` and every
// `canopy trace`; programs now pay it only when they touch an image.
//
// Plain C types only: no exception and no C++ object crosses the boundary. A failing call returns
// 0 (or a null reader), says in *stage which step failed and copies OpenImageIO's message into
// error (error_size bytes, NUL-terminated); image.cpp turns that into its canopy::scene_error.
#pragma once
#include <cstddef>

extern "C" {

// An image file's header as the reader of its extension sees it.
struct canopy_image_header {
    int width, height, depth, channels;
    int deep;         // deep (multi-sample) image
    int integer_data; // 8- or 16-bit unsigned integer pixels
    char color_space[32]; // OpenImageIO's "oiio:ColorSpace" attribute (truncated), or empty
};

// Steps that can fail.
enum canopy_image_stage { canopy_image_no_codec = 0, canopy_image_open = 1, canopy_image_pixels = 2, canopy_image_close = 3 };

struct canopy_image_backend {
    int version; // canopy_image_backend_version
    // Makes the reader of `extension` (lower case, no dot) and opens path with it, filling
    // header; null on failure (stage: no_codec or open).
    void* (*open_reader)(char const* extension, char const* path, canopy_image_header* header, int* stage, char* error,
                         std::size_t error_size);
    // Decodes the first `channels` channels of every pixel as floats, pixel i at pixels + 4 i.
    int (*read_pixels)(void* reader, int channels, float* pixels, char* error, std::size_t error_size);
    void (*close_reader)(void* reader); // closes and frees the reader
    // Encodes width × height RGBA float pixels in the format of path's extension (8-bit when
    // eight_bit, else float). When the format's writer can encode in memory, the bytes go to
    // sink(context, data, size) once and *in_memory is 1 (the caller writes and checks the file);
    // else the writer writes path itself and *in_memory is 0.
    int (*write_image)(char const* path, int width, int height, int eight_bit, float const* pixels, void* context,
                       void (*sink)(void* context, unsigned char const* data, std::size_t size), int* in_memory,
                       int* stage, char* error, std::size_t error_size);
};

inline constexpr int canopy_image_backend_version = 1;

// The backend's one exported symbol.
canopy_image_backend const* canopy_image_backend_v1();
using canopy_image_backend_entry = canopy_image_backend const* (*)();

} // extern "C"
