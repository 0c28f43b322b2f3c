// canopy.render — cameras (refusing degenerate ones), ray generation, a parallel tile scheduler,
// rendering kernels, cost counting and tone curves, one partition each:
//
//   :camera      pinhole_camera (look_at, look_at_problem, primary_ray)
//   :film        framebuffer, tone curves, sRGB, heat colours, heat_map, display_values
//   :scheduling  tile_grid, render_tiles per pixel or per tile (oneTBB; render_tiles.cpp)
//   :kernels     pixel_random, surface sampling, light_options, primary/ao/path kernels with
//                ao_options and path_options
//   :waves       the same kernels over a wave of samples, traced in batches (primary_wave,
//                ao_wave, path_wave), bit-identical
//   :costs       counting<Inner> (the paper's bvh_costs over any intersector), cost_counter
//
// Every kernel is a function template over the scene and the custom intersector (the paper's
// "scheduling parameters"): the same kernel runs with no intersector, an alpha mask or a cost
// counter. Each pixel owns a copy of the intersector prototype (counters are per pixel) and a
// random sequence seeded by (seed, x, y, sample): images do not depend on the thread count or the
// tile order.
export module canopy.render;
export import canopy.query;
export import :camera;
export import :film;
export import :scheduling;
export import :kernels;
export import :waves;
export import :costs;
