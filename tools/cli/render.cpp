// canopy render: the demo's four Figure-1 images, or one image of a scene, with a kernel and a
// custom intersector named in one table each (render_kernels, render_intersectors).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <limits>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>
#include <unistd.h>
#include <fmt/core.h>
#include <tbb/global_control.h>
#include "commands.hpp"
#include "options.hpp"
#include "output.hpp"
#include "processes.hpp"
#include "scenes.hpp"
import canopy;
import canopy.image;
import canopy.plugins.bench;

namespace cli {

namespace {

// The scene as the kernels see it, counting the rays traced.
struct counting_scene {
    canopy::compiled_scene const* scene;
    mutable std::atomic<std::uint64_t>* rays;

    template <typename I>
    canopy::basic_hit_record<float> closest_hit(canopy::ray const& r, I& isect) const {
        rays->fetch_add(1, std::memory_order_relaxed);
        return scene->closest_hit(r, isect);
    }
    template <typename I>
    canopy::basic_hit_record<float> any_hit(canopy::ray const& r, I& isect) const {
        rays->fetch_add(1, std::memory_order_relaxed);
        return scene->any_hit(r, isect);
    }
    template <typename I>
    canopy::batch_stats closest_hit(std::span<canopy::ray const> rs, std::span<canopy::basic_hit_record<float>> out,
                                    I& isect) const {
        rays->fetch_add(rs.size(), std::memory_order_relaxed);
        return scene->closest_hit(rs, out, isect);
    }
    template <typename I>
    canopy::batch_stats any_hit(std::span<canopy::ray const> rs, std::span<bool> out, I& isect) const {
        rays->fetch_add(rs.size(), std::memory_order_relaxed);
        return scene->any_hit(rs, out, isect);
    }
    canopy::surface_sample surface(canopy::basic_hit_record<float> const& hr, canopy::ray const& r) const {
        return scene->surface(hr, r);
    }
    canopy::vec3<float> background(canopy::ray const& r) const { return scene->background(r); }
};

struct render_job {
    std::string kernel = "primary";
    std::string intersector = "none";
    bool batch = true;                  // --mode: each tile's samples traced as waves, or one by one
    int width = 800, height = 600, spp = 1;
    std::filesystem::path output;
    canopy::pinhole_camera camera;
    std::string scene_name;             // how messages name the scene (its file, or gen:...)
    float ao_radius = 0.0f;             // absolute (scene units), or
    float ao_radius_fraction = 0.05f;   // of the bounding-box diagonal when ao_radius is 0
    canopy::tone_curve tone = canopy::tone_curve::none;
    float exposure_scale = 1.0f;        // 2^EV
};

struct render_result {
    double seconds = 0.0;
    std::uint64_t rays = 0;
};

class progress_bar {
public:
    explicit progress_bar(std::string label) : label_(std::move(label)), enabled_(isatty(STDERR_FILENO) != 0) {}
    void update(float fraction) {
        if (!enabled_) return;
        int const filled = int(fraction * 40.0f);
        std::fprintf(stderr, "\r%-28s [%s%s] %3d%%", label_.c_str(), std::string(std::size_t(filled), '#').c_str(),
                     std::string(std::size_t(40 - filled), ' ').c_str(), int(fraction * 100.0f));
        if (fraction >= 1.0f) std::fputc('\n', stderr);
    }

private:
    std::string label_;
    bool enabled_;
};

// The AO radius of a job: absolute, or a fraction of the scene's bounding-box diagonal.
float ao_radius(canopy::compiled_scene const& scene, render_job const& job) {
    if (job.ao_radius > 0.0f) return job.ao_radius;
    float const diagonal = canopy::length(canopy::diagonal(scene.bounds()));
    float const radius = job.ao_radius_fraction * diagonal;
    if (!(radius > 0.0f && std::isfinite(radius)))
        throw canopy::scene_error(job.scene_name, "",
                                  fmt::format("the AO radius, {:g}% of the bounding-box diagonal ({:g}), is not a "
                                              "positive finite length: give --ao-radius in scene units",
                                              double(job.ao_radius_fraction) * 100.0, double(diagonal)));
    return radius;
}

// canopy::render_tiles, or across the ranks under mpirun: the image on rank 0 (the other ranks'
// framebuffers stay black).
void tiles(canopy::framebuffer& fb, canopy::tile_shader const& shade, canopy::tile_options const& options) {
#if CANOPY_WITH_MPI
    if (distributed()) {
        record_sharing(dist::render_tiles(ranks, fb, shade, options));
        return;
    }
#endif
    canopy::render_tiles(fb, shade, options);
}

// The camera ray of a sample of pixel (x, y): jittered by the sample's first two random numbers
// when the job takes several samples per pixel, else through the pixel's centre. render_with and
// render_waves_with draw their rays here, so that their images agree bit for bit.
canopy::ray sample_ray(render_job const& job, int x, int y, canopy::pixel_random& rng) {
    float const jx = job.spp > 1 ? rng.next() : 0.5f, jy = job.spp > 1 ? rng.next() : 0.5f;
    return job.camera.primary_ray(float(x) + jx, float(y) + jy, job.width, job.height);
}

// Shades every pixel with kernel(ray, isect, rng) averaged over spp jittered samples.
template <typename I, typename Kernel>
canopy::framebuffer render_with(render_job const& job, I const& prototype, Kernel const& kernel, progress_bar& bar) {
    canopy::framebuffer fb(job.width, job.height);
    tiles(
        fb,
        canopy::pixel_by_pixel([&](int x, int y) {
            canopy::vec4<float> sum;
            for (int s = 0; s < job.spp; ++s) {
                canopy::pixel_random rng(1u, x, y, s);
                canopy::ray const r = sample_ray(job, x, y, rng);
                I isect = prototype;
                sum = sum + kernel(r, isect, rng);
            }
            return sum * (1.0f / float(job.spp));
        }),
        {.tile_size = 16, .progress = [&](float f) { bar.update(f); }});
    return fb;
}

// The same image as render_with, bit for bit, with wave(rays, rngs, isect, colours) shading a
// tile's pixels one sample at a time (a wave of canopy.render:waves; the tile's camera rays row by
// row, so that runs of 8 along a row trace as packets).
template <typename I, typename Wave>
canopy::framebuffer render_waves_with(render_job const& job, I const& prototype, Wave const& wave, progress_bar& bar) {
    canopy::framebuffer fb(job.width, job.height);
    tiles(
        fb,
        [&](canopy::tile_grid::rect const& r, std::span<canopy::vec4<float>> sums) {
            std::size_t const n = std::size_t(r.pixels());
            std::vector<canopy::ray> rays(n);
            std::vector<canopy::pixel_random> rngs;
            std::vector<canopy::vec4<float>> colours(n);
            std::fill(sums.begin(), sums.end(), canopy::vec4<float>());
            for (int s = 0; s < job.spp; ++s) {
                rngs.clear();
                std::size_t i = 0;
                for (int y = r.y0; y < r.y1; ++y)
                    for (int x = r.x0; x < r.x1; ++x, ++i) {
                        rays[i] = sample_ray(job, x, y, rngs.emplace_back(1u, x, y, s));
                    }
                I isect = prototype;
                wave(std::span<canopy::ray const>(rays), std::span(rngs), isect, std::span(colours));
                for (std::size_t k = 0; k < n; ++k) sums[k] = sums[k] + colours[k];
            }
            for (auto& sum : sums) sum = sum * (1.0f / float(job.spp));
        },
        {.tile_size = 16, .progress = [&](float f) { bar.update(f); }});
    return fb;
}

// render_waves_with or render_with, as the job's --mode says; kernel(ray, isect, rng) → colour,
// wave(rays, rngs, isect, colours).
template <typename I, typename Kernel, typename Wave>
canopy::framebuffer render_in_mode(render_job const& job, I const& prototype, Kernel const& kernel, Wave const& wave,
                                   progress_bar& bar) {
    if (job.batch) return render_waves_with(job, prototype, wave, bar);
    return render_with(job, prototype, kernel, bar);
}

// ---- the tables ----------------------------------------------------------------------------

// A kernel of --kernel: render(scene, job, prototype, bar) renders the image with intersector
// prototype I; `shaded`: its pixels are radiance (exposure, tone curve, sRGB), else colours.
template <typename Render>
struct kernel_row {
    std::string_view name, text;
    bool shaded;
    Render render;
};

constexpr std::tuple render_kernels{
    kernel_row{"primary", " (default)", true,
               []<typename I>(counting_scene const& scene, render_job const& job, I const& prototype, progress_bar& bar) {
                   return render_in_mode(
                       job, prototype,
                       [&](canopy::ray const& r, I& isect, canopy::pixel_random&) {
                           return canopy::primary_kernel(scene, r, isect);
                       },
                       [&](auto rays, auto, I& isect, auto colours) { canopy::primary_wave(scene, rays, isect, colours); },
                       bar);
               }},
    kernel_row{"ao", "", true,
               []<typename I>(counting_scene const& scene, render_job const& job, I const& prototype, progress_bar& bar) {
                   canopy::ao_options const ao{.samples = 8, .radius = ao_radius(*scene.scene, job)};
                   return render_in_mode(
                       job, prototype,
                       [&](canopy::ray const& r, I& isect, canopy::pixel_random& rng) {
                           return canopy::ao_kernel(scene, r, isect, rng, ao);
                       },
                       [&](auto rays, auto rngs, I& isect, auto colours) {
                           canopy::ao_wave(scene, rays, rngs, isect, colours, ao);
                       },
                       bar);
               }},
    // The path kernel adds a point light (the scene's, or one above the middle of the scene) to
    // the sun and the sky.
    kernel_row{"path", "", true,
               []<typename I>(counting_scene const& scene, render_job const& job, I const& prototype, progress_bar& bar) {
                   canopy::path_options const path{.bounces = 3, .light = scene.scene->render_lights(job.scene_name)};
                   return render_in_mode(
                       job, prototype,
                       [&](canopy::ray const& r, I& isect, canopy::pixel_random& rng) {
                           return canopy::path_kernel(scene, r, isect, rng, path);
                       },
                       [&](auto rays, auto rngs, I& isect, auto colours) {
                           canopy::path_wave(scene, rays, rngs, isect, colours, path);
                       },
                       bar);
               }},
    // Box + triangle tests of each primary ray through counting<I> (I: the costs intersector, the
    // texture alpha mask), as a heat map whose 99th percentile is red. Pixel by pixel: each pixel
    // counts through its own copy of the counter. The options allow it with that intersector
    // alone, so it is compiled for that one.
    kernel_row{"heatmap", "", false,
               []<typename I>(counting_scene const& scene, render_job const& job, I const& prototype,
                              progress_bar& bar) -> canopy::framebuffer {
                   if constexpr (!std::is_same_v<I, canopy::texture_alpha_mask>)
                       throw std::logic_error("the heat map counts through the costs intersector only");
                   else {
                       using counter = canopy::counting<I>;
                       counter costs;
                       costs.inner = prototype;
                       canopy::framebuffer fb = render_with(job, costs, [&](canopy::ray const& r, counter& isect,
                                                                            canopy::pixel_random&) {
                           scene.closest_hit(r, isect);
                           return canopy::vec4<float>(float(isect.num_boxes + isect.num_tris), 0, 0, 1);
                       }, bar);
                       canopy::heat_map(fb);
                       return fb;
                   }
               }},
};

// An intersector of --intersector (besides auto): make(scene) gives the prototype each pixel copies.
template <typename Make>
struct intersector_row {
    std::string_view name, text;
    Make make;
};

// A mask of the scene's masked materials (canopy.scene's texture_alpha_mask, procedural_alpha_mask).
template <typename Mask>
Mask scene_mask(canopy::compiled_scene const& scene) {
    Mask mask;
    mask.scene = &scene;
    return mask;
}

template <typename I>
I plain(canopy::compiled_scene const&) {
    return I{};
}

constexpr std::tuple render_intersectors{
    intersector_row{"none", "", plain<canopy::default_intersector>},
    intersector_row{"alpha", " (texture alpha mask)", scene_mask<canopy::texture_alpha_mask>},
    intersector_row{"procedural", " (ring mask on masked materials)", scene_mask<canopy::procedural_alpha_mask>},
    intersector_row{"bench", " (the alpha rule of the bench formats)", plain<canopy::bench_alpha_intersector>},
    // The heat map's: the heatmap kernel counts through counting<texture_alpha_mask> (the paper's
    // bvh_costs over the texture alpha mask), so that the heat map shows the extra traversal that
    // alpha-masked holes cause.
    intersector_row{"costs", " (the heat map)", scene_mask<canopy::texture_alpha_mask>},
};

// Renders and writes one image. An image with NaN pixels is written (black there) and reported
// as an error: radiance that is not a number is a fault of the scene or of the renderer.
render_result render_image(canopy::compiled_scene const& scene, render_job const& job) {
    step("rendering " + job.output.string());
    std::atomic<std::uint64_t> rays{0};
    counting_scene const counted{&scene, &rays};
    progress_bar bar(job.output.filename().string());
    auto const start = clock_type::now();
    canopy::framebuffer fb;
    bool shaded = true;
    with_choice(render_intersectors, job.intersector, [&](auto const& intersector) {
        auto const prototype = intersector.make(scene);
        with_choice(render_kernels, job.kernel, [&](auto const& kernel) {
            fb = kernel.render(counted, job, prototype, bar);
            shaded = kernel.shaded;
        });
    });
    render_result result{seconds_since(start), rays.load()};
#if CANOPY_WITH_MPI
    if (distributed()) result.rays = ranks.sum(result.rays);
#endif
    print_sharing("tiles");
    on_every_rank([&] {
        if (!root_rank()) return;
        step("writing " + job.output.string());
        std::size_t const nan_pixels = canopy::write_framebuffer(
            job.output, fb, {.linear = shaded, .tone = job.tone, .exposure_scale = job.exposure_scale});
        if (nan_pixels > 0)
            throw std::runtime_error(fmt::format("{}: {} of {} pixels are not a number (NaN radiance, written black)",
                                                 job.output.string(), nan_pixels, fb.pixels.size()));
    });
    return result;
}

// --size WxH: both whole numbers from 1 to 16384, W·H within the texel limit (the framebuffer
// holds float RGBA per pixel, as a texture of that size would).
std::pair<int, int> parse_size(std::string const& text) {
    auto const x = text.find('x');
    auto const w = x == std::string::npos ? std::nullopt : whole_number(std::string_view(text).substr(0, x), 1, 16384);
    auto const h = x == std::string::npos ? std::nullopt : whole_number(std::string_view(text).substr(x + 1), 1, 16384);
    if (!w || !h)
        throw usage_error("--size must be WxH with W and H whole numbers from 1 to 16384 (e.g. 800x600), not " +
                          quote(text));
    std::uint64_t const limit = canopy::default_limits().max_texels;
    if (*w * *h > limit)
        throw usage_error(fmt::format("--size {}x{} is {} pixels, over the limit of {} (--max-texels)", *w, *h,
                                      *w * *h, limit));
    return {int(*w), int(*h)};
}

// The options' usage; --kernel's and --intersector's from their tables.
std::string render_options_usage() {
    return std::string("usage: canopy render [SCENE] [-o OUT] [--size WxH] [--spp N] [--kernel KIND]\n"
                       "                     [--intersector KIND] [--ao-radius R[%]] [--exposure EV]\n"
                       "                     [--tonemap CURVE] [--threads N] [--mode MODE] [--plugin FILE]...\n"
                       "                     [--quality Q] [limits]\n"
                       "  SCENE               a file any registered plugin loads (canopy info --plugins lists them),\n"
                       "                      or gen:NAME[:KEY=VALUE,...] for a registered generator; without it, the\n"
                       "                      built-in demo scene is rendered into the four images of the paper's\n"
                       "                      Figure 1 (alpha ignored, texture alpha mask, procedural alpha mask, BVH\n"
                       "                      cost heat map; --kernel applies to the first three)\n"
                       "  -o OUT              output folder (default: out), created if missing; OUT/SCENE-STEM.png\n"
                       "  --size WxH          image size, W and H from 1 to 16384, W*H at most --max-texels\n"
                       "                      (default 800x600)\n"
                       "  --spp N             samples per pixel, 1 to 65536 (default 1; 16 for ao and path)\n") +
           option_usage("--kernel KIND", choice_list(choices(render_kernels), true)) +
           option_usage("--intersector KIND", "auto (default: alpha when the scene has masked materials, else none), " +
                                                  choice_list(choices(render_intersectors), true) +
                                                  "; a SCENE only (the demo's figures have their own)") +
           "  --ao-radius R[%]    ao: length of the occlusion rays, in scene units, or with % in percent\n"
           "                      of the scene's bounding-box diagonal (default 5%)\n"
           "  --exposure EV       scale radiance by 2^EV before the tone curve, -30 to 30 (default 0)\n"
           "  --tonemap CURVE     none (clip at 1), reinhard (x/(1+x)) or aces (filmic); default aces\n"
           "                      for the path kernel, none for primary and ao; not for the heat map\n"
           "  --threads N         worker threads, 1 to 1024 (default: all cores)\n"
           "  --mode MODE         batch (default): each tile's samples traced together, coherent rays\n"
           "                      as packets; single: one ray at a time. The images are identical.\n"
           "                      The heat map is always single\n"
           "  --plugin FILE       load a shared-library plugin first (may be repeated)\n";
}

} // namespace

std::string render_usage() {
    return render_options_usage() + quality_usage + limits_usage;
}

int run_render(std::span<char*> all_args) {
    arguments const args = parse_arguments(all_args, {{"-o"},
                                                      {"--size"},
                                                      {"--spp"},
                                                      {"--kernel"},
                                                      {"--intersector"},
                                                      {"--ao-radius"},
                                                      {"--exposure"},
                                                      {"--tonemap"},
                                                      {"--threads"},
                                                      {"--mode"},
                                                      {"--plugin", true, true},
                                                      {"--quality"}});
    if (args.help) {
        if (root_rank()) std::fputs(render_usage().c_str(), stdout);
        return 0;
    }
    if (args.positional.size() > 1)
        throw usage_error("more than one scene given (" + quote(args.positional[0]) + ", " + quote(args.positional[1]) +
                          ")");
    std::optional<std::string> const scene_path =
        args.positional.empty() ? std::nullopt : std::optional<std::string>(args.positional[0]);
    auto const generator = scene_path ? parse_generator(*scene_path) : std::nullopt;
    apply_limits(args);

    render_job base;
    auto const [w, h] = parse_size(args.value_or("--size", "800x600"));
    base.width = w;
    base.height = h;
    base.kernel = args.value_or("--kernel", "primary");
    check_choice(choices(render_kernels), "--kernel", base.kernel);
    base.intersector = args.value_or("--intersector", "auto");
    check_choice(choices(render_intersectors), "--intersector", base.intersector, "auto");
    bool const heatmap = base.kernel == "heatmap" || base.intersector == "costs";
    if (!scene_path && args.has("--intersector"))
        throw usage_error("--intersector applies to a SCENE: the demo renders each figure with its own intersector");
    canopy::build_quality const quality = quality_option(args);
    if (!scene_path && args.has("--quality"))
        throw usage_error("--quality applies to a SCENE: the demo scene is built at the default quality");
    if (!scene_path && base.kernel == "heatmap")
        throw usage_error("--kernel heatmap applies to a SCENE: the demo's fourth figure is the heat map");
    if (base.intersector == "costs" && args.has("--kernel") && base.kernel != "heatmap")
        throw usage_error("--intersector costs draws the heat map: it goes with --kernel heatmap, not " +
                          quote(base.kernel));
    if (base.kernel == "heatmap" && base.intersector != "auto" && base.intersector != "costs")
        throw usage_error("--kernel heatmap counts the tests of the texture alpha mask's traversal: --intersector " +
                          quote(base.intersector) + " does not apply");
    if (heatmap && (args.has("--exposure") || args.has("--tonemap")))
        throw usage_error("--exposure and --tonemap apply to shaded images, not to the heat map");
    if (heatmap) { // the costs intersector draws the heat map, and the heat map is its image
        base.kernel = "heatmap";
        base.intersector = "costs";
    }
    std::string const mode = args.value_or("--mode", heatmap ? "single" : "batch");
    if (mode != "single" && mode != "batch")
        throw usage_error("--mode must be single or batch, not " + quote(mode));
    if (heatmap && mode == "batch")
        throw usage_error("--mode batch does not apply to the heat map: each pixel counts the tests of its own ray");
    base.batch = mode == "batch";
    if (args.has("--ao-radius")) {
        if (base.kernel != "ao") throw usage_error("--ao-radius applies to --kernel ao");
        std::string_view text = args.value("--ao-radius");
        bool const percent = text.ends_with('%');
        if (percent) text.remove_suffix(1);
        double const r = real_option("--ao-radius", text, 0.0,
                                     percent ? 1e6 : double(std::numeric_limits<float>::max()),
                                     "over 0: a length in scene units, or a percentage of the bounding-box diagonal "
                                     "(e.g. 5%)");
        if (!(float(r) > 0.0f))
            throw usage_error("--ao-radius must be over 0, not " + quote(args.value("--ao-radius")));
        if (percent) {
            base.ao_radius_fraction = float(r / 100.0);
        } else {
            base.ao_radius = float(r);
        }
    }
    if (args.has("--exposure"))
        base.exposure_scale =
            float(std::exp2(real_option("--exposure", args.value("--exposure"), -30.0, 30.0, "of stops from -30 to 30")));
    std::string const tone = args.value_or("--tonemap", base.kernel == "path" ? "aces" : "none");
    if (tone == "none") {
        base.tone = canopy::tone_curve::none;
    } else if (tone == "reinhard") {
        base.tone = canopy::tone_curve::reinhard;
    } else if (tone == "aces") {
        base.tone = canopy::tone_curve::aces;
    } else {
        throw usage_error("--tonemap must be none, reinhard or aces, not " + quote(tone));
    }
    base.spp = base.kernel == "ao" || base.kernel == "path" ? 16 : 1;
    if (args.has("--spp")) base.spp = int(whole_option(args, "--spp", 1, 65536));
    std::optional<tbb::global_control> threads;
    limit_threads(args, threads);
    std::filesystem::path const out = args.value_or("-o", "out");
    float const aspect = float(base.width) / float(base.height);

    // The output files, checked before anything is loaded or rendered.
    struct figure {
        char const* file;
        char const* kernel;
        char const* intersector;
    };
    figure const figures[] = {{"1_billboards_alpha_ignored.png", nullptr, "none"},
                              {"2_texture_alpha_mask.png", nullptr, "alpha"},
                              {"3_procedural_alpha_mask.png", nullptr, "procedural"},
                              {"4_bvh_cost_heatmap.png", "heatmap", "costs"}};
    if (scene_path) {
        std::string stem = generator ? generator->name : std::filesystem::path(*scene_path).stem().string();
        if (stem.empty()) stem = "scene";
        base.output = out / (stem + ".png");
    }
    // Under mpirun, rank 0 alone writes the images, and each rank loads the scene: a failure on any
    // rank stops every rank with its message.
    on_every_rank([&] {
        if (!root_rank()) return;
        prepare_folder(out);
        if (!scene_path) {
            for (auto const& f : figures) check_writable(out / f.file);
        } else {
            check_writable(base.output);
        }
    });

    canopy::registry const* registry = nullptr;
    on_every_rank([&] { registry = &plugin_registry(args.values("--plugin")); });
    std::vector<std::pair<std::string, render_result>> results;
    auto const build_start = clock_type::now();
    if (!scene_path) {
        // The demo: the procedural plugin's billboard_forest, compiled like any scene.
        std::optional<loaded_graph> loaded_forest;
        on_every_rank([&] {
            loaded_forest.emplace(load_and_compile(demo_scene, *registry, canopy::build_quality::automatic));
            base.camera = loaded_forest->compiled.render_camera(aspect, demo_scene);
        });
        canopy::compiled_scene const& forest = loaded_forest->compiled;
        double const build_seconds = seconds_since(build_start);
        base.scene_name = "demo scene";
        if (root_rank())
            fmt::print(stderr, "demo scene: {} instances of {} meshes, built in {:.1f} ms\n",
                       forest.top_mesh_instances.size(), forest.meshes.size(), build_seconds * 1e3);
        for (auto const& f : figures) {
            render_job job = base;
            if (f.kernel) job.kernel = f.kernel;
            job.intersector = f.intersector;
            job.output = out / f.file;
            results.emplace_back(job.output.string(), render_image(forest, job));
        }
    } else {
        std::optional<loaded_graph> loaded_scene;
        on_every_rank([&] {
            loaded_scene.emplace(load_and_compile(*scene_path, *registry, quality));
            base.camera = loaded_scene->compiled.render_camera(aspect, *scene_path);
        });
        loaded_graph const& loaded = *loaded_scene;
        canopy::compiled_scene const& scene = loaded.compiled;
        auto const& st = scene.statistics;
        if (root_rank()) fmt::print(stderr, "{}: {} triangles in {} meshes, {} placements, {} instance level{}; loaded in {:.1f} ms, "
                           "compiled in {:.1f} ms (mesh BVHs at quality {})\n",
                   *scene_path, st.triangles_placed, st.meshes_built, st.placements, st.levels, st.levels == 1 ? "" : "s",
                   loaded.load_seconds * 1e3, st.build_seconds * 1e3, quality_name(st.quality));
        base.scene_name = *scene_path;
        if (base.intersector == "auto") base.intersector = st.alpha_mask_needed ? "alpha" : "none";
        results.emplace_back(base.output.string(), render_image(scene, base));
    }
    if (!root_rank()) return 0;
    double total_seconds = 0.0;
    std::uint64_t total_rays = 0;
    auto const mrays = [](std::uint64_t rays, double seconds) { return seconds > 0.0 ? double(rays) / seconds * 1e-6 : 0.0; };
    for (auto const& [file, r] : results) {
        fmt::print("{}: {:.1f} ms, {} rays, {:.2f} Mrays/s\n", file, r.seconds * 1e3, r.rays, mrays(r.rays, r.seconds));
        total_seconds += r.seconds;
        total_rays += r.rays;
    }
    fmt::print("rendered {} image{} ({}x{}, {} spp) in {:.2f} s: {} rays, {:.2f} Mrays/s\n", results.size(),
               results.size() == 1 ? "" : "s", base.width, base.height, base.spp, total_seconds, total_rays,
               mrays(total_rays, total_seconds));
    return 0;
}

} // namespace cli
