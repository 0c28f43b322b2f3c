// canopy.render:scheduling — the image cut into tiles, and the parallel tile scheduler
// (render_tiles, oneTBB, compiled once in render_tiles.cpp).
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <cstddef>
#include <functional>
#include <span>
#include <utility>
export module canopy.render:scheduling;
import canopy.query;
import :film;

export namespace canopy {

// The image cut into square tiles of `tile` pixels (the last row and column may be narrower),
// numbered row by row from the top left: the unit of work of render_tiles, also across processes
// (canopy.distributed).
struct tile_grid {
    int width = 0, height = 0, tile = 16;

    struct rect {
        int x0, y0, x1, y1; // pixels [x0, x1) × [y0, y1)
        int pixels() const { return (x1 - x0) * (y1 - y0); }
    };

    tile_grid(int w, int h, int tile_size) : width(w), height(h), tile(std::max(1, tile_size)) {}
    int columns() const { return (width + tile - 1) / tile; }
    int rows() const { return (height + tile - 1) / tile; }
    int count() const { return columns() * rows(); }
    rect bounds(int t) const {
        int const x0 = (t % columns()) * tile, y0 = (t / columns()) * tile;
        return {x0, y0, std::min(x0 + tile, width), std::min(y0 + tile, height)};
    }
};

struct tile_options {
    int tile_size = 16;
    // Called with the fraction done, from the worker that finished a tile (serialised).
    std::function<void(float)> progress;
};

// What a tile shader computes: every pixel of the tile `r`, row by row from the top left, into
// out[(y - r.y0) * (r.x1 - r.x0) + (x - r.x0)] (out.size() == r.pixels()). A pixel's value must
// depend on the pixel alone, not on the tile it falls in nor on the thread that shades it.
using tile_shader = std::function<void(tile_grid::rect const&, std::span<vec4<float>>)>;

// Runs shade(x, y) → vec4 for every pixel, tiles in parallel on all cores (oneTBB).
void render_tiles(framebuffer& fb, std::function<vec4<float>(int, int)> const& shade, tile_options const& options = {});

// The same with a whole tile shaded at a time (the batch kernels of canopy.render:waves trace a
// tile's rays together).
void render_tiles(framebuffer& fb, tile_shader const& shade, tile_options const& options = {});

// A per-pixel shader as a tile shader.
inline tile_shader pixel_by_pixel(std::function<vec4<float>(int, int)> shade) {
    return [shade = std::move(shade)](tile_grid::rect const& r, std::span<vec4<float>> out) {
        std::size_t i = 0;
        for (int y = r.y0; y < r.y1; ++y)
            for (int x = r.x0; x < r.x1; ++x) out[i++] = shade(x, y);
    };
}

} // namespace canopy
