// canopy — the command-line program.
//
//   canopy render [SCENE] [-o OUT] [--size WxH] [--spp N] [--kernel primary|ao|path|heatmap]
//                 [--intersector none|alpha|procedural|costs] [--threads N]
//   canopy trace --scene FILE --rays FILE --query closest|any --out FILE
//                [--intersector none|alpha] [--threads N]
//   canopy info SCENE | --plugins
//
// `canopy render` without a scene renders the built-in demo (instanced alpha-masked billboards)
// into the four images of Figure 1 of the custom-intersector paper. With a scene, any file a
// registered plugin loads (built-in, in CANOPY_PLUGIN_PATH, or given with --plugin FILE), or
// gen:NAME[:KEY=VALUE,...] for a registered generator, is loaded into the scene graph, compiled
// (canopy.scene's skip rules) and rendered with the scene's camera and lights when it has them.
// `canopy trace` reads the benchmark formats (.obj subset: one BVH, no top level; .inst: one shared
// mesh instanced under a top-level BVH); rays and hits use the benchmark formats too.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>
#include <unistd.h>
#include <fmt/core.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
import canopy;
import canopy.bench_formats;
import canopy.billboard_forest;
import canopy.image_io;
import canopy.plugins;

namespace {

using clock_type = std::chrono::steady_clock;

double seconds_since(clock_type::time_point start) {
    return std::chrono::duration<double>(clock_type::now() - start).count();
}

struct usage_error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

constexpr char const* main_usage =
    "usage: canopy <command> [options]\n"
    "commands:\n"
    "  render  render the demo scene (no SCENE) or a scene file into PNG images\n"
    "  trace   trace a ray file against a scene, write a hit file\n"
    "  info    print scene statistics, compile decisions and BVH statistics\n"
    "run 'canopy <command> --help' for the options of a command\n";

constexpr char const* trace_usage =
    "usage: canopy trace --scene FILE --rays FILE --query closest|any --out FILE\n"
    "                    [--intersector none|alpha] [--threads N]\n"
    "  --scene FILE        .obj (single mesh) or .inst (instanced mesh)\n"
    "  --rays FILE         32-byte rays: origin, tmin, direction, tmax (float32)\n"
    "  --query KIND        closest: nearest accepted hit; any: first accepted hit\n"
    "  --out FILE          20-byte hits: t, prim, inst, u, v\n"
    "  --intersector KIND  none (default) or alpha: reject hits where floor(8u)+floor(8v) is odd\n"
    "  --threads N         worker threads (default: all cores)\n";

constexpr char const* render_usage =
    "usage: canopy render [SCENE] [-o OUT] [--size WxH] [--spp N] [--kernel KIND]\n"
    "                     [--intersector KIND] [--threads N] [--plugin FILE]\n"
    "  SCENE               a file any registered plugin loads (canopy info --plugins lists them),\n"
    "                      or gen:NAME[:KEY=VALUE,...] for a registered generator; without it, the\n"
    "                      built-in demo scene is rendered into the four images of the paper's\n"
    "                      Figure 1 (alpha ignored, texture alpha mask, procedural alpha mask, BVH\n"
    "                      cost heat map)\n"
    "  -o OUT              output folder (default: out)\n"
    "  --size WxH          image size (default 800x600)\n"
    "  --spp N             samples per pixel (default 1; 16 for ao and path)\n"
    "  --kernel KIND       primary (default), ao, path or heatmap\n"
    "  --intersector KIND  auto (default: alpha when the scene has masked materials, else none),\n"
    "                      none, alpha (texture alpha mask), procedural (ring mask on masked\n"
    "                      materials), bench (the alpha rule of the bench formats) or costs (heat map)\n"
    "  --threads N         worker threads (default: all cores)\n"
    "  --plugin FILE       load a shared-library plugin first (may be repeated)\n";

constexpr char const* info_usage =
    "usage: canopy info SCENE [--plugin FILE]...\n"
    "       canopy info --plugins [--plugin FILE]...\n"
    "  SCENE      a file any registered plugin loads, or gen:NAME[:KEY=VALUE,...]\n"
    "  --plugins  list the registered loaders, image loaders, generators and node types\n"
    "  --plugin FILE  load a shared-library plugin first (may be repeated)\n";

// --name value pairs after the command; "--help" alone.
std::map<std::string, std::string> parse_options(std::span<char*> args, std::vector<std::string> const& known,
                                                 char const* usage) {
    std::map<std::string, std::string> options;
    for (std::size_t i = 0; i < args.size(); ++i) {
        std::string const name = args[i];
        if (name == "--help" || name == "-h") {
            std::fputs(usage, stdout);
            std::exit(0);
        }
        if (std::find(known.begin(), known.end(), name) == known.end())
            throw usage_error("unknown option '" + name + "'");
        if (i + 1 >= args.size()) throw usage_error("option '" + name + "' needs a value");
        options[name] = args[++i];
    }
    return options;
}

std::string required(std::map<std::string, std::string> const& options, std::string const& name) {
    auto const it = options.find(name);
    if (it == options.end()) throw usage_error("missing " + name);
    return it->second;
}

// Either a single-level scene or a two-level instanced one.
struct loaded_scene {
    canopy::bvh<canopy::triangle> mesh;
    std::vector<canopy::instance<canopy::bvh<canopy::triangle>>> instances;
    canopy::bvh<canopy::instance<canopy::bvh<canopy::triangle>>> top;
    bool instanced = false;
    double build_seconds = 0.0;
};

std::unique_ptr<loaded_scene> load_bench_scene(std::filesystem::path const& path) {
    auto scene = std::make_unique<loaded_scene>();
    canopy::require_regular_file(path); // a folder or a device is named as such, whatever its extension
    auto const ext = path.extension().string();
    if (ext == ".obj") {
        auto const mesh = canopy::read_bench_obj(path);
        auto const start = clock_type::now();
        scene->mesh = canopy::build_binned_sah(mesh.triangles);
        scene->build_seconds = seconds_since(start);
    } else if (ext == ".inst") {
        auto const inst = canopy::read_bench_inst(path);
        auto const start = clock_type::now();
        scene->mesh = canopy::build_binned_sah(inst.mesh.triangles);
        for (std::size_t k = 0; k < inst.instances.size(); ++k)
            scene->instances.emplace_back(scene->mesh, inst.instances[k], std::uint32_t(k));
        scene->top = canopy::build_binned_sah(scene->instances);
        scene->build_seconds = seconds_since(start);
        scene->instanced = true;
    } else {
        throw canopy::format_error(path.string() + ": unknown scene extension '" + canopy::excerpt(ext) + "' (expected .obj or .inst)");
    }
    return scene;
}

template <typename Isect>
canopy::bench_hit trace_one(loaded_scene const& scene, canopy::ray const& r, bool closest, Isect& isect) {
    canopy::basic_hit_record<float> hr;
    if (scene.instanced) {
        hr = closest ? canopy::closest_hit(r, &scene.top, &scene.top + 1, isect)
                     : canopy::any_hit(r, &scene.top, &scene.top + 1, isect);
    } else {
        hr = closest ? canopy::closest_hit(r, &scene.mesh, &scene.mesh + 1, isect)
                     : canopy::any_hit(r, &scene.mesh, &scene.mesh + 1, isect);
    }
    if (!hr.hit) return {};
    return {hr.t, hr.prim_id, hr.inst_id, hr.u, hr.v};
}

int run_trace(std::span<char*> args) {
    auto const options = parse_options(
        args, {"--scene", "--rays", "--query", "--out", "--intersector", "--threads"}, trace_usage);
    std::string const query = required(options, "--query");
    if (query != "closest" && query != "any") throw usage_error("--query must be closest or any, not '" + query + "'");
    std::string const isect_name = options.contains("--intersector") ? options.at("--intersector") : "none";
    if (isect_name != "none" && isect_name != "alpha")
        throw usage_error("--intersector must be none or alpha, not '" + isect_name + "'");
    std::optional<tbb::global_control> threads;
    if (options.contains("--threads")) {
        int const n = std::atoi(options.at("--threads").c_str());
        if (n < 1) throw usage_error("--threads needs a positive number");
        threads.emplace(tbb::global_control::max_allowed_parallelism, std::size_t(n));
    }

    std::string const scene_path = required(options, "--scene");
    std::string const rays_path = required(options, "--rays");
    std::string const out_path = required(options, "--out");
    auto const scene = load_bench_scene(scene_path);
    auto const rays = canopy::read_bench_rays(rays_path);
    std::vector<canopy::bench_hit> hits(rays.size());
    bool const closest = query == "closest";

    auto const start = clock_type::now();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, rays.size(), 256), [&](auto const& range) {
        canopy::default_intersector none;
        canopy::bench_alpha_intersector alpha;
        for (std::size_t i = range.begin(); i != range.end(); ++i)
            hits[i] = isect_name == "alpha" ? trace_one(*scene, rays[i], closest, alpha)
                                            : trace_one(*scene, rays[i], closest, none);
    });
    double const trace_seconds = seconds_since(start);
    canopy::write_bench_hits(out_path, hits);

    std::size_t const hit_count = std::size_t(std::count_if(hits.begin(), hits.end(), [](auto const& h) {
        return h.prim != canopy::invalid_id;
    }));
    fmt::print("build {:.3f} ms, trace {} rays in {:.3f} ms: {:.2f} Mrays/s, {} hits\n", scene->build_seconds * 1e3,
               rays.size(), trace_seconds * 1e3, trace_seconds > 0 ? double(rays.size()) / trace_seconds * 1e-6 : 0.0,
               hit_count);
    return 0;
}

// ---- render ----------------------------------------------------------------------------------

canopy::light_options lights_of(canopy::compiled_scene const& scene);

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
    canopy::surface_sample surface(canopy::basic_hit_record<float> const& hr, canopy::ray const& r) const {
        return scene->surface(hr, r);
    }
    canopy::vec3<float> background(canopy::ray const& r) const { return scene->background(r); }
};

struct render_job {
    std::string kernel = "primary";
    std::string intersector = "none";
    int width = 800, height = 600, spp = 1;
    std::filesystem::path output;
    canopy::pinhole_camera camera;
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

canopy::rgba_image to_display(canopy::framebuffer const& fb, bool linear) {
    canopy::rgba_image img;
    img.width = fb.width;
    img.height = fb.height;
    img.pixels.resize(4 * fb.pixels.size());
    for (std::size_t i = 0; i < fb.pixels.size(); ++i) {
        auto const& p = fb.pixels[i];
        img.pixels[4 * i + 0] = linear ? canopy::to_srgb(p.x) : p.x;
        img.pixels[4 * i + 1] = linear ? canopy::to_srgb(p.y) : p.y;
        img.pixels[4 * i + 2] = linear ? canopy::to_srgb(p.z) : p.z;
        img.pixels[4 * i + 3] = 1.0f;
    }
    return img;
}

// Shades every pixel with kernel(ray, isect, rng) averaged over spp jittered samples.
template <typename I, typename Kernel>
canopy::framebuffer render_with(render_job const& job, I const& prototype, Kernel const& kernel, progress_bar& bar) {
    canopy::framebuffer fb(job.width, job.height);
    canopy::render_tiles(
        fb,
        [&](int x, int y) {
            canopy::vec4<float> sum;
            for (int s = 0; s < job.spp; ++s) {
                canopy::pixel_random rng(1u, x, y, s);
                float const jx = job.spp > 1 ? rng.next() : 0.5f, jy = job.spp > 1 ? rng.next() : 0.5f;
                I isect = prototype;
                sum = sum + kernel(job.camera.primary_ray(float(x) + jx, float(y) + jy, job.width, job.height), isect, rng);
            }
            return sum * (1.0f / float(job.spp));
        },
        {.tile_size = 16, .progress = [&](float f) { bar.update(f); }});
    return fb;
}

template <typename I>
canopy::framebuffer render_kernel(counting_scene const& scene, render_job const& job, I const& prototype,
                                  progress_bar& bar) {
    if (job.kernel == "ao")
        return render_with(job, prototype, [&](canopy::ray const& r, I& isect, canopy::pixel_random& rng) {
            return canopy::ao_kernel(scene, r, isect, rng, 8, 2.0f);
        }, bar);
    // The path kernel adds a point light (the scene's, or one above the middle of the scene) to
    // the sun and the sky.
    canopy::light_options const light = lights_of(*scene.scene);
    if (job.kernel == "path")
        return render_with(job, prototype, [&](canopy::ray const& r, I& isect, canopy::pixel_random& rng) {
            return canopy::path_kernel(scene, r, isect, rng, 3, light);
        }, bar);
    return render_with(job, prototype, [&](canopy::ray const& r, I& isect, canopy::pixel_random&) {
        return canopy::primary_kernel(scene, r, isect);
    }, bar);
}

// The paper's bvh_costs counter composed with the scene's texture alpha mask: counts every
// ray/box and ray/triangle test at every level while the mask decides the hits, so the heat map
// shows the extra traversal that alpha-masked holes cause.
struct masked_costs : canopy::basic_intersector<masked_costs> {
    using canopy::basic_intersector<masked_costs>::operator();

    template <typename Ray, typename... Args>
    auto operator()(Ray const& ray, canopy::aabb const& box, Args&&... args) {
        ++num_boxes;
        return intersect(ray, box, std::forward<Args>(args)...);
    }

    template <typename Ray>
    auto operator()(Ray const& ray, canopy::triangle const& tri) {
        ++num_tris;
        return intersect(ray, tri);
    }

    template <typename Ray>
    bool filter(Ray const&, canopy::basic_hit_record<float> const& hr) const {
        return mask.keeps(hr);
    }

    canopy::texture_alpha_mask mask;
    unsigned num_boxes = 0;
    unsigned num_tris = 0;
};

// Heat map: box + triangle tests of each primary ray, scaled so that the 99th percentile is red.
canopy::framebuffer render_heatmap(counting_scene const& scene, render_job const& job, progress_bar& bar) {
    masked_costs prototype;
    prototype.mask.scene = scene.scene;
    canopy::framebuffer fb = render_with(job, prototype, [&](canopy::ray const& r, masked_costs& isect,
                                                             canopy::pixel_random&) {
        scene.closest_hit(r, isect);
        return canopy::vec4<float>(float(isect.num_boxes + isect.num_tris), 0, 0, 1);
    }, bar);
    std::vector<float> costs;
    costs.reserve(fb.pixels.size());
    for (auto const& p : fb.pixels) costs.push_back(p.x);
    auto const p99 = costs.begin() + std::ptrdiff_t(costs.size() * 99 / 100);
    std::nth_element(costs.begin(), p99, costs.end());
    float const scale = std::max(1.0f, *p99);
    for (auto& p : fb.pixels) p = canopy::vec4<float>(canopy::heat_colour(p.x, scale), 1.0f);
    return fb;
}

render_result render_image(canopy::compiled_scene const& scene, render_job const& job) {
    std::atomic<std::uint64_t> rays{0};
    counting_scene const counted{&scene, &rays};
    progress_bar bar(job.output.filename().string());
    auto const start = clock_type::now();
    canopy::framebuffer fb;
    bool linear = true;
    if (job.kernel == "heatmap" || job.intersector == "costs") {
        fb = render_heatmap(counted, job, bar);
        linear = false;
    } else if (job.intersector == "bench") {
        fb = render_kernel(counted, job, canopy::bench_alpha_intersector{}, bar);
    } else if (job.intersector == "alpha") {
        canopy::texture_alpha_mask mask;
        mask.scene = &scene;
        fb = render_kernel(counted, job, mask, bar);
    } else if (job.intersector == "procedural") {
        canopy::procedural_alpha_mask mask;
        mask.scene = &scene;
        fb = render_kernel(counted, job, mask, bar);
    } else {
        fb = render_kernel(counted, job, canopy::default_intersector{}, bar);
    }
    render_result result{seconds_since(start), rays.load()};
    std::filesystem::create_directories(job.output.parent_path());
    canopy::write_image(job.output, to_display(fb, linear));
    return result;
}

canopy::texture2d<canopy::vec4<float>> load_texture(std::filesystem::path const& path) {
    auto const img = canopy::read_image(path);
    std::vector<canopy::vec4<float>> texels(std::size_t(img.width) * std::size_t(img.height));
    for (std::size_t i = 0; i < texels.size(); ++i)
        texels[i] = {img.pixels[4 * i], img.pixels[4 * i + 1], img.pixels[4 * i + 2], img.pixels[4 * i + 3]};
    return {img.width, img.height, std::move(texels), {canopy::filter_mode::bilinear, canopy::address_mode::clamp}};
}

// The registry of built-in plugins, plus shared-library plugins named on the command line.
canopy::registry& plugin_registry(std::vector<std::string> const& plugin_files) {
    canopy::registry& r = canopy::builtin_registry();
    for (auto const& f : plugin_files) r.load_plugin(f);
    return r;
}

// SCENE: a file, or gen:NAME[:KEY=VALUE,...].
struct loaded_graph {
    canopy::scene graph;
    canopy::compiled_scene compiled;
    double load_seconds = 0.0;
};

loaded_graph load_and_compile(std::string const& spec, canopy::registry const& r) {
    loaded_graph out;
    auto const start = clock_type::now();
    if (spec.starts_with("gen:")) {
        std::string_view rest = std::string_view(spec).substr(4);
        auto const colon = rest.find(':');
        std::string const name(rest.substr(0, colon));
        canopy::parameters params;
        if (colon != std::string_view::npos) {
            rest.remove_prefix(colon + 1);
            while (!rest.empty()) {
                auto const comma = std::min(rest.find(','), rest.size());
                std::string_view const item = rest.substr(0, comma);
                auto const eq = item.find('=');
                if (eq == std::string_view::npos || eq == 0)
                    throw usage_error("generator parameter '" + std::string(item) + "' is not KEY=VALUE");
                params.set(std::string(item.substr(0, eq)), std::string(item.substr(eq + 1)));
                rest.remove_prefix(std::min(comma + 1, rest.size()));
            }
        }
        r.generate(out.graph, name, params, out.graph.root());
    } else {
        r.load(out.graph, spec, out.graph.root());
    }
    out.load_seconds = seconds_since(start);
    out.compiled = canopy::compile(out.graph, {.plugins = &r, .name = spec});
    return out;
}

// The scene's own lights replace the default sun / point light where it has them.
canopy::light_options lights_of(canopy::compiled_scene const& scene) {
    canopy::light_options light;
    canopy::aabb const box = scene.bounds();
    float const extent = canopy::length(canopy::diagonal(box));
    light.point_position = canopy::center(box) + canopy::vec3<float>(0.0f, 0.35f * extent, 0.0f);
    light.point_intensity = canopy::vec3<float>(1.0f, 0.8f, 0.6f) * (0.05f * extent * extent);
    light.point_light = true;
    bool sun = false, point = false;
    for (auto const& l : scene.lights) {
        if (l.kind == canopy::light_data::directional && !sun) {
            light.sun_direction = canopy::normalize(l.direction);
            light.sun_colour = l.colour;
            sun = true;
        } else if (l.kind == canopy::light_data::point && !point) {
            light.point_position = l.position;
            light.point_intensity = l.colour;
            point = true;
        }
    }
    return light;
}

std::pair<int, int> parse_size(std::string const& text) {
    auto const x = text.find('x');
    int const w = x == std::string::npos ? 0 : std::atoi(text.substr(0, x).c_str());
    int const h = x == std::string::npos ? 0 : std::atoi(text.substr(x + 1).c_str());
    if (w < 1 || h < 1 || w > 16384 || h > 16384) throw usage_error("--size must be WxH, e.g. 800x600");
    return {w, h};
}

// Takes every `--plugin FILE` out of args (render and info accept it, repeated); the other
// arguments stay, in order, in `rest`.
std::vector<std::string> take_plugin_files(std::span<char*> args, std::vector<char*>& rest) {
    std::vector<std::string> files;
    for (std::size_t i = 0; i < args.size(); ++i) {
        if (std::string_view(args[i]) != "--plugin") {
            rest.push_back(args[i]);
            continue;
        }
        if (i + 1 >= args.size()) throw usage_error("option '--plugin' needs a value");
        files.emplace_back(args[++i]);
    }
    return files;
}

int run_render(std::span<char*> all_args) {
    std::vector<char*> args;
    std::vector<std::string> const plugin_files = take_plugin_files(all_args, args);
    std::optional<std::string> scene_path;
    std::vector<char*> option_args;
    for (std::size_t i = 0; i < args.size(); ++i) {
        std::string_view const a = args[i];
        if (!a.starts_with("-") && (i == 0 || !std::string_view(args[i - 1]).starts_with("-"))) {
            if (scene_path) throw usage_error("more than one scene given");
            scene_path = std::string(a);
        } else {
            option_args.push_back(args[i]);
        }
    }
    auto const options = parse_options(option_args, {"-o", "--size", "--spp", "--kernel", "--intersector", "--threads"},
                                       render_usage);
    render_job base;
    auto const [w, h] = parse_size(options.contains("--size") ? options.at("--size") : "800x600");
    base.width = w;
    base.height = h;
    if (options.contains("--kernel")) base.kernel = options.at("--kernel");
    if (base.kernel != "primary" && base.kernel != "ao" && base.kernel != "path" && base.kernel != "heatmap")
        throw usage_error("--kernel must be primary, ao, path or heatmap, not '" + base.kernel + "'");
    base.intersector = options.contains("--intersector") ? options.at("--intersector") : "auto";
    if (base.intersector != "auto" && base.intersector != "none" && base.intersector != "alpha" &&
        base.intersector != "procedural" && base.intersector != "bench" && base.intersector != "costs")
        throw usage_error("--intersector must be auto, none, alpha, procedural, bench or costs, not '" +
                          base.intersector + "'");
    base.spp = base.kernel == "ao" || base.kernel == "path" ? 16 : 1;
    if (options.contains("--spp")) {
        base.spp = std::atoi(options.at("--spp").c_str());
        if (base.spp < 1 || base.spp > 65536) throw usage_error("--spp needs a positive number");
    }
    std::optional<tbb::global_control> threads;
    if (options.contains("--threads")) {
        int const n = std::atoi(options.at("--threads").c_str());
        if (n < 1) throw usage_error("--threads needs a positive number");
        threads.emplace(tbb::global_control::max_allowed_parallelism, std::size_t(n));
    }
    std::filesystem::path const out = options.contains("-o") ? options.at("-o") : "out";
    float const aspect = float(base.width) / float(base.height);

    std::vector<std::pair<std::string, render_result>> results;
    auto const build_start = clock_type::now();
    if (!scene_path) {
        auto forest = canopy::make_billboard_forest(load_texture(std::filesystem::path(CANOPY_ASSET_DIR) / "tree.png"));
        double const build_seconds = seconds_since(build_start);
        base.camera = canopy::pinhole_camera::look_at(forest.camera_eye, forest.camera_target, {0, 1, 0},
                                                      forest.camera_fovy, aspect);
        fmt::print(stderr, "demo scene: {} instances of {} meshes, built in {:.1f} ms\n",
                   forest.scene.top_mesh_instances.size(), forest.scene.meshes.size(), build_seconds * 1e3);
        struct figure {
            char const* file;
            char const* kernel;
            char const* intersector;
        };
        figure const figures[] = {{"1_billboards_alpha_ignored.png", nullptr, "none"},
                                  {"2_texture_alpha_mask.png", nullptr, "alpha"},
                                  {"3_procedural_alpha_mask.png", nullptr, "procedural"},
                                  {"4_bvh_cost_heatmap.png", "heatmap", "costs"}};
        for (auto const& f : figures) {
            render_job job = base;
            if (f.kernel) job.kernel = f.kernel;
            job.intersector = f.intersector;
            job.output = out / f.file;
            results.emplace_back(job.output.string(), render_image(forest.scene, job));
        }
    } else {
        canopy::registry const& registry = plugin_registry(plugin_files);
        auto const loaded = load_and_compile(*scene_path, registry);
        canopy::compiled_scene const& scene = loaded.compiled;
        auto const& st = scene.statistics;
        fmt::print(stderr, "{}: {} triangles in {} meshes, {} placements, {} instance level{}; loaded in {:.1f} ms, "
                           "compiled in {:.1f} ms\n",
                   *scene_path, st.triangles_placed, st.meshes_built, st.placements, st.levels, st.levels == 1 ? "" : "s",
                   loaded.load_seconds * 1e3, st.build_seconds * 1e3);
        if (scene.camera) {
            base.camera = canopy::pinhole_camera::look_at(scene.camera->eye, scene.camera->target, scene.camera->up,
                                                          scene.camera->fovy_degrees, aspect);
        } else {
            canopy::aabb const box = scene.bounds();
            auto const c = canopy::center(box);
            float const extent = canopy::length(canopy::diagonal(box));
            base.camera = canopy::pinhole_camera::look_at(c + canopy::vec3<float>(0.35f, 0.45f, 1.0f) * extent, c,
                                                          {0, 1, 0}, 45.0f, aspect);
        }
        if (base.intersector == "auto") base.intersector = st.alpha_mask_needed ? "alpha" : "none";
        std::string stem = std::filesystem::path(*scene_path).stem().string();
        if (scene_path->starts_with("gen:")) stem = scene_path->substr(4, scene_path->find(':', 4) - 4);
        base.output = out / (stem + ".png");
        results.emplace_back(base.output.string(), render_image(scene, base));
    }
    double total_seconds = 0.0;
    std::uint64_t total_rays = 0;
    for (auto const& [file, r] : results) {
        fmt::print("{}: {:.1f} ms, {} rays, {:.2f} Mrays/s\n", file, r.seconds * 1e3, r.rays,
                   double(r.rays) / r.seconds * 1e-6);
        total_seconds += r.seconds;
        total_rays += r.rays;
    }
    fmt::print("rendered {} image{} ({}x{}, {} spp) in {:.2f} s: {} rays, {:.2f} Mrays/s\n", results.size(),
               results.size() == 1 ? "" : "s", base.width, base.height, base.spp, total_seconds, total_rays,
               double(total_rays) / total_seconds * 1e-6);
    return 0;
}

void print_stats(char const* name, canopy::bvh_stats const& s) {
    fmt::print("{}: {} primitives, {} nodes ({} leaves, largest {}), depth {}, SAH cost {:.2f}, {:.1f} bytes/primitive\n",
               name, s.primitive_count, s.node_count, s.leaf_count, s.max_leaf_size, s.depth, s.sah_cost,
               s.bytes_per_primitive);
}

void print_registered(char const* what, std::vector<canopy::registered> const& list) {
    fmt::print("{}:\n", what);
    if (list.empty()) fmt::print("  (none)\n");
    for (auto const& e : list)
        fmt::print("  {:<20} {:<12} {}\n", e.name, e.plugin, e.description);
}

int run_info(std::span<char*> all_args) {
    std::vector<char*> args;
    std::vector<std::string> const plugin_files = take_plugin_files(all_args, args);
    std::optional<std::string> scene_path;
    bool list_plugins = false;
    for (std::size_t i = 0; i < args.size(); ++i) {
        std::string_view const a = args[i];
        if (a == "--help" || a == "-h") {
            std::fputs(info_usage, stdout);
            return 0;
        }
        if (a == "--plugins") {
            list_plugins = true;
        } else if (a.starts_with("-")) {
            throw usage_error("unknown option '" + std::string(a) + "'");
        } else {
            if (scene_path) throw usage_error("info takes exactly one scene");
            scene_path = std::string(a);
        }
    }
    if (list_plugins == scene_path.has_value()) throw usage_error("info takes exactly one scene, or --plugins");
    canopy::registry const& registry = plugin_registry(plugin_files);
    if (list_plugins) {
        print_registered("file loaders (the first of an extension is its default)", registry.loaders());
        print_registered("image loaders", registry.image_loaders());
        print_registered("generators", registry.generators());
        print_registered("node types", registry.node_types());
        fmt::print("shared-library plugins loaded:{}\n", registry.plugins().empty() ? " none" : "");
        for (auto const& p : registry.plugins()) fmt::print("  {}\n", p);
        return 0;
    }
    auto const loaded = load_and_compile(*scene_path, registry);
    canopy::scene const& g = loaded.graph;
    canopy::compiled_scene const& c = loaded.compiled;
    auto const& st = c.statistics;
    fmt::print("scene {}: loaded in {:.3f} ms\n", *scene_path, loaded.load_seconds * 1e3);
    fmt::print("graph: {} nodes, {} meshes, {} materials, {} images, {} cameras, {} lights\n", g.nodes().size(),
               g.meshes().size(), g.materials().size(), g.images().size(), st.cameras, st.lights);
    fmt::print("compiled in {:.3f} ms: {} instance level{}, {} meshes built ({} triangles stored), {} placements "
               "({} triangles placed), {} groups, {} group instances\n",
               st.build_seconds * 1e3, st.levels, st.levels == 1 ? "" : "s", st.meshes_built, st.triangles_stored,
               st.placements, st.triangles_placed, st.groups, st.group_instances);
    fmt::print("decisions:\n");
    for (auto const& d : st.decisions) fmt::print("  - {}\n", d);
    std::size_t mesh_nodes = 0, mesh_prims = 0;
    double mesh_bytes = 0.0;
    for (auto const& m : c.meshes) {
        auto const ms = canopy::compute_stats(m.accel);
        mesh_nodes += ms.node_count;
        mesh_prims += ms.primitive_count;
        mesh_bytes += ms.bytes_per_primitive * double(ms.primitive_count);
    }
    if (c.meshes.size() == 1) {
        print_stats("mesh BVH", canopy::compute_stats(c.meshes[0].accel));
    } else {
        fmt::print("mesh BVHs: {} BVHs, {} primitives, {} nodes, {:.1f} bytes/primitive\n", c.meshes.size(), mesh_prims,
                   mesh_nodes, mesh_prims ? mesh_bytes / double(mesh_prims) : 0.0);
    }
    for (auto const& grp : c.groups) print_stats(fmt::format("group '{}' BVH", grp.name).c_str(), canopy::compute_stats(grp.accel));
    if (c.levels == 1) print_stats("top-level BVH", canopy::compute_stats(c.top1));
    if (c.levels == 2) print_stats("top-level BVH", canopy::compute_stats(c.top2));
    return 0;
}

} // namespace

int main(int argc, char** argv) {
    std::span<char*> const args(argv, std::size_t(argc));
    if (args.size() < 2) {
        std::fputs(main_usage, stderr);
        return 2;
    }
    std::string_view const command = args[1];
    try {
        if (command == "--help" || command == "-h") {
            std::fputs(main_usage, stdout);
            return 0;
        }
        if (command == "render") return run_render(args.subspan(2));
        if (command == "trace") return run_trace(args.subspan(2));
        if (command == "info") return run_info(args.subspan(2));
        throw usage_error("unknown command '" + std::string(command) + "'");
    } catch (usage_error const& e) {
        std::fprintf(stderr, "canopy %s: %s\n%s", std::string(command).c_str(), e.what(),
                     command == "trace"    ? trace_usage
                     : command == "render" ? render_usage
                     : command == "info"   ? info_usage
                                           : main_usage);
        return 2;
    } catch (std::exception const& e) {
        std::fprintf(stderr, "canopy: %s\n", e.what());
        return 1;
    }
}
