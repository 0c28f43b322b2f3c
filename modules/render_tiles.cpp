// canopy.render:scheduling: the tile scheduler (oneTBB), compiled once here.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <atomic>
#include <functional>
#include <mutex>
#include <span>
#include <vector>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
module canopy.render;

namespace canopy {

void render_tiles(framebuffer& fb, std::function<vec4<float>(int, int)> const& shade, tile_options const& options) {
    render_tiles(fb, pixel_by_pixel(shade), options);
}

void render_tiles(framebuffer& fb, tile_shader const& shade, tile_options const& options) {
    tile_grid const grid(fb.width, fb.height, options.tile_size);
    int const total = grid.count();
    std::atomic<int> done{0};
    std::mutex progress_mutex;
    tbb::parallel_for(tbb::blocked_range<int>(0, total, 1), [&](tbb::blocked_range<int> const& range) {
        std::vector<vec4<float>> pixels(std::size_t(grid.tile) * std::size_t(grid.tile));
        for (int t = range.begin(); t != range.end(); ++t) {
            tile_grid::rect const r = grid.bounds(t);
            std::span<vec4<float>> const out(pixels.data(), std::size_t(r.pixels()));
            shade(r, out);
            std::size_t i = 0;
            for (int y = r.y0; y < r.y1; ++y)
                for (int x = r.x0; x < r.x1; ++x) fb.at(x, y) = out[i++];
            int const finished = ++done;
            if (options.progress) {
                std::lock_guard lock(progress_mutex);
                options.progress(float(finished) / float(total));
            }
        }
    });
}

} // namespace canopy
