// canopy.distributed:tiles — canopy::render_tiles across the ranks of a job: the tiles of
// canopy.render's tile_grid dealt out by the dealer, each rank shading its ranges with oneTBB
// across its cores, the pixels gathered into rank 0's framebuffer. shade(x, y) must depend on
// the pixel alone (the kernels of canopy.render do: their random streams are seeded by the
// pixel and the sample), so the image is bit-identical to one process's, whatever the ranks.
module;
#include <cstddef>
#include <cstring>
#include <functional>
#include <span>
#include <stdexcept>
#include <utility>
#include <vector>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
export module canopy.distributed:tiles;
import canopy.render;
import :communicator;
import :dealer;

export namespace canopy::distributed {

// Collective. On rank 0, fb (of the image's size) receives every pixel and options.progress the
// fraction gathered; on the other ranks fb is left as it is. Pixels travel as float RGBA (16
// bytes each), the tiles of a range one after the other.
// A tile_shader shades a whole tile at a time (canopy.render:scheduling); shade(x, y) one pixel.
deal_report render_tiles(communicator const& comm, framebuffer& fb, tile_shader const& shade,
                         tile_options const& options = {}, deal_options dealing = {}) {
    tile_grid const grid(fb.width, fb.height, options.tile_size);
    std::size_t const tile_bytes = std::size_t(grid.tile) * std::size_t(grid.tile) * sizeof(vec4<float>);
    auto const work = [&](item_range r) {
        // Tile k of the range at k · tile_bytes (the last row and column of tiles leave a gap).
        std::vector<std::byte> bytes(r.count * tile_bytes);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, r.count, 1), [&](auto const& tiles) {
            std::vector<vec4<float>> pixels;
            for (std::size_t k = tiles.begin(); k != tiles.end(); ++k) {
                tile_grid::rect const t = grid.bounds(int(r.first + k));
                pixels.resize(std::size_t(t.pixels()));
                shade(t, pixels);
                std::memcpy(bytes.data() + k * tile_bytes, pixels.data(), pixels.size() * sizeof(vec4<float>));
            }
        });
        return bytes;
    };
    auto const collect = [&](item_range r, std::span<std::byte const> bytes) {
        if (bytes.size() != r.count * tile_bytes) throw std::runtime_error("a tile result of the wrong size");
        for (std::size_t k = 0; k < r.count; ++k) {
            tile_grid::rect const t = grid.bounds(int(r.first + k));
            std::byte const* in = bytes.data() + k * tile_bytes;
            for (int y = t.y0; y < t.y1; ++y)
                for (int x = t.x0; x < t.x1; ++x) {
                    std::memcpy(&fb.at(x, y), in, sizeof(vec4<float>));
                    in += sizeof(vec4<float>);
                }
        }
    };
    if (options.progress && !dealing.progress)
        dealing.progress = [&](std::size_t done, std::size_t total) { options.progress(float(done) / float(total)); };
    return deal(comm, std::size_t(grid.count()), work, collect, dealing);
}

deal_report render_tiles(communicator const& comm, framebuffer& fb, std::function<vec4<float>(int, int)> const& shade,
                         tile_options const& options = {}, deal_options dealing = {}) {
    return render_tiles(comm, fb, pixel_by_pixel(shade), options, std::move(dealing));
}

} // namespace canopy::distributed
