// distributed_render — canopy.distributed in a program of its own: every process builds the same
// BVH, the image's tiles are dealt out across the processes, rank 0 gets the whole image.
//   canopy_distributed_render                     one process (MPI untouched)
//   mpirun -np 4 canopy_distributed_render        four processes, the same image
#include <cstdint>
#include <cstdio>
#include <vector>
import canopy;
import canopy.distributed;

int main(int argc, char** argv) {
    canopy::distributed::session mpi(argc, argv); // MPI only when started by mpirun
    canopy::distributed::communicator const comm = mpi.world();

    // Replicated data: every rank builds the scene, a fan of triangles.
    std::vector<canopy::triangle> tris;
    for (int i = 0; i < 64; ++i) {
        float const x = float(i % 8) - 4.0f, y = float(i / 8) - 4.0f;
        tris.push_back({{x, y, 0.0f}, {x + 0.9f, y, 0.2f}, {x, y + 0.9f, 0.4f}});
    }
    auto const bvh = canopy::build_binned_sah(tris);
    auto const camera = canopy::pinhole_camera::look_at({0, 0, 10}, {0, 0, 0}, {0, 1, 0}, 60.0f, 4.0f / 3.0f);

    // Distributed work: the tiles, dealt out on request; shade(x, y) depends on the pixel alone.
    canopy::framebuffer fb(320, 240);
    auto const report = canopy::distributed::render_tiles(comm, fb, [&](int x, int y) {
        auto const hit = canopy::closest_hit(camera.primary_ray(float(x) + 0.5f, float(y) + 0.5f, fb.width, fb.height),
                                             &bvh, &bvh + 1);
        float const shade = hit.hit ? 1.0f - hit.t / 12.0f : 0.0f;
        return canopy::vec4<float>(shade, shade, shade, 1.0f);
    });

    if (comm.root()) { // the image is complete here
        std::uint64_t sum = 0;
        for (auto const& p : fb.pixels) sum = sum * 31 + std::uint64_t(p.x * 1000.0f);
        std::printf("%d process(es); rank 0 rendered %zu of %d tiles; image checksum %016llx\n", comm.size(),
                    report.items_per_rank[0], canopy::tile_grid(fb.width, fb.height, 16).count(),
                    static_cast<unsigned long long>(sum));
    }
    return 0;
}
