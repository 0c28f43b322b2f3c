// canopy.render: the tile scheduler (oneTBB), compiled once here.
module;
// No a·b + c → FMA contraction in this file, whatever -ffp-contract says: every build and
// every path (scalar, SIMD, packet) rounds the same way.
#pragma STDC FP_CONTRACT OFF
#include <algorithm>
#include <atomic>
#include <functional>
#include <mutex>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
module canopy.render;

namespace canopy {

void render_tiles(framebuffer& fb, std::function<vec4<float>(int, int)> const& shade, tile_options const& options) {
    int const tile = std::max(1, options.tile_size);
    int const tiles_x = (fb.width + tile - 1) / tile;
    int const tiles_y = (fb.height + tile - 1) / tile;
    int const total = tiles_x * tiles_y;
    std::atomic<int> done{0};
    std::mutex progress_mutex;
    tbb::parallel_for(tbb::blocked_range<int>(0, total, 1), [&](tbb::blocked_range<int> const& range) {
        for (int t = range.begin(); t != range.end(); ++t) {
            int const x0 = (t % tiles_x) * tile, y0 = (t / tiles_x) * tile;
            for (int y = y0; y < std::min(y0 + tile, fb.height); ++y)
                for (int x = x0; x < std::min(x0 + tile, fb.width); ++x) fb.at(x, y) = shade(x, y);
            int const finished = ++done;
            if (options.progress) {
                std::lock_guard lock(progress_mutex);
                options.progress(float(finished) / float(total));
            }
        }
    });
}

} // namespace canopy
