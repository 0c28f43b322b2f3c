// embree_compare — Canopy and Embree 3 side by side on the same scenes and rays.
//
//   canopy_bench_embree [--scene FILE.obj|FILE.inst] [--threads-list 1,2] [--repeat N]
//                       [--rays primary,random,shadow]
//
// Without --scene it generates two scenes: a closed icosphere (327,680 triangles) and a
// two-level scene (64 instances of a 20,480-triangle icosphere). For each: build time and
// memory, then closest-hit and any-hit Mrays/s for primary, random and shadow rays, with no
// intersector and with the alpha rule of the bench formats (Embree: an intersection filter
// function), at each thread count. Every figure is printed with the ratio Canopy / Embree
// (> 1: Canopy faster or larger). Results are also compared ray by ray (hit/miss agreement).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>
#include <embree3/rtcore.h>
#include <fmt/core.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
import canopy;
import canopy.bench_formats;
import canopy.procedural;

namespace {

using clock_type = std::chrono::steady_clock;
double seconds_since(clock_type::time_point t) { return std::chrono::duration<double>(clock_type::now() - t).count(); }

struct scene_input {
    std::string name;
    std::vector<canopy::triangle> mesh;
    std::vector<canopy::affine_transform<float>> instances; // empty: single level
};

// ---- Canopy -------------------------------------------------------------------------------

struct canopy_scene {
    canopy::bvh<canopy::triangle> mesh;
    std::vector<canopy::instance<canopy::bvh<canopy::triangle>>> instances;
    canopy::bvh<canopy::instance<canopy::bvh<canopy::triangle>>> top;
    bool instanced = false;
    std::size_t bytes = 0;
};

std::unique_ptr<canopy_scene> build_canopy(scene_input const& in) {
    auto s = std::make_unique<canopy_scene>();
    s->mesh = canopy::build_binned_sah(in.mesh);
    s->bytes = canopy::compute_stats(s->mesh).bytes;
    if (!in.instances.empty()) {
        for (std::size_t k = 0; k < in.instances.size(); ++k)
            s->instances.emplace_back(s->mesh, in.instances[k], std::uint32_t(k));
        s->top = canopy::build_binned_sah(s->instances);
        s->bytes += canopy::compute_stats(s->top).bytes;
        s->instanced = true;
    }
    return s;
}

template <typename Isect>
canopy::bench_hit canopy_trace(canopy_scene const& s, canopy::ray const& r, bool closest, Isect& isect) {
    canopy::basic_hit_record<float> hr;
    if (s.instanced)
        hr = closest ? canopy::closest_hit(r, &s.top, &s.top + 1, isect) : canopy::any_hit(r, &s.top, &s.top + 1, isect);
    else
        hr = closest ? canopy::closest_hit(r, &s.mesh, &s.mesh + 1, isect) : canopy::any_hit(r, &s.mesh, &s.mesh + 1, isect);
    if (!hr.hit) return {};
    return {hr.t, hr.prim_id, hr.inst_id, hr.u, hr.v};
}

// ---- Embree -------------------------------------------------------------------------------

std::atomic<long long> embree_bytes{0};

bool memory_monitor(void*, ssize_t bytes, bool) {
    embree_bytes += bytes;
    return true;
}

void alpha_filter(RTCFilterFunctionNArguments const* args) {
    for (unsigned i = 0; i < args->N; ++i) {
        if (args->valid[i] == 0) continue;
        float const u = RTCHitN_u(args->hit, args->N, i);
        float const v = RTCHitN_v(args->hit, args->N, i);
        if (canopy::bench_alpha_intersector::rejects(u, v)) args->valid[i] = 0;
    }
}

struct embree_scene {
    RTCDevice device = nullptr;
    RTCScene mesh = nullptr;
    RTCScene top = nullptr;
    bool instanced = false;
    ~embree_scene() {
        if (top) rtcReleaseScene(top);
        if (mesh) rtcReleaseScene(mesh);
    }
    RTCScene root() const { return instanced ? top : mesh; }
};

std::unique_ptr<embree_scene> build_embree(RTCDevice device, scene_input const& in, bool alpha) {
    auto s = std::make_unique<embree_scene>();
    s->device = device;
    s->mesh = rtcNewScene(device);
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                          3 * sizeof(float), 3 * in.mesh.size()));
    auto* idx = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                               3 * sizeof(unsigned), in.mesh.size()));
    for (std::size_t i = 0; i < in.mesh.size(); ++i) {
        auto const& t = in.mesh[i];
        canopy::vec3<float> const p[3] = {t.v0, t.v1, t.v2};
        for (int k = 0; k < 3; ++k) {
            v[9 * i + 3 * std::size_t(k) + 0] = p[k].x;
            v[9 * i + 3 * std::size_t(k) + 1] = p[k].y;
            v[9 * i + 3 * std::size_t(k) + 2] = p[k].z;
            idx[3 * i + std::size_t(k)] = unsigned(3 * i + std::size_t(k));
        }
    }
    if (alpha) {
        rtcSetGeometryIntersectFilterFunction(geom, alpha_filter);
        rtcSetGeometryOccludedFilterFunction(geom, alpha_filter);
    }
    rtcCommitGeometry(geom);
    rtcAttachGeometry(s->mesh, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(s->mesh);
    if (!in.instances.empty()) {
        s->instanced = true;
        s->top = rtcNewScene(device);
        for (auto const& m : in.instances) {
            RTCGeometry inst = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
            rtcSetGeometryInstancedScene(inst, s->mesh);
            float rows[12] = {m.linear.col0.x, m.linear.col1.x, m.linear.col2.x, m.translation.x,
                              m.linear.col0.y, m.linear.col1.y, m.linear.col2.y, m.translation.y,
                              m.linear.col0.z, m.linear.col1.z, m.linear.col2.z, m.translation.z};
            // Embree's FLOAT3X4_ROW_MAJOR: three rows of (linear | translation).
            rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, rows);
            rtcCommitGeometry(inst);
            rtcAttachGeometry(s->top, inst);
            rtcReleaseGeometry(inst);
        }
        rtcCommitScene(s->top);
    }
    return s;
}

canopy::bench_hit embree_trace(embree_scene const& s, canopy::ray const& r, bool closest) {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    if (closest) {
        RTCRayHit rh{};
        rh.ray.org_x = r.origin.x, rh.ray.org_y = r.origin.y, rh.ray.org_z = r.origin.z;
        rh.ray.dir_x = r.direction.x, rh.ray.dir_y = r.direction.y, rh.ray.dir_z = r.direction.z;
        rh.ray.tnear = r.tmin, rh.ray.tfar = r.tmax, rh.ray.mask = ~0u;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(s.root(), &context, &rh);
        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return {};
        return {rh.ray.tfar, rh.hit.primID, s.instanced ? rh.hit.instID[0] : canopy::invalid_id, rh.hit.u, rh.hit.v};
    }
    RTCRay ray{};
    ray.org_x = r.origin.x, ray.org_y = r.origin.y, ray.org_z = r.origin.z;
    ray.dir_x = r.direction.x, ray.dir_y = r.direction.y, ray.dir_z = r.direction.z;
    ray.tnear = r.tmin, ray.tfar = r.tmax, ray.mask = ~0u;
    rtcOccluded1(s.root(), &context, &ray);
    if (ray.tfar != -std::numeric_limits<float>::infinity()) return {};
    return {0.0f, canopy::occluded_unreported, canopy::invalid_id, 0.0f, 0.0f};
}

// ---- rays ---------------------------------------------------------------------------------

struct ray_set {
    std::string name;
    std::vector<canopy::ray> rays;
    bool shadow = false; // traced with any-hit only
};

std::vector<ray_set> make_rays(canopy_scene const& s, canopy::aabb const& box) {
    std::vector<ray_set> sets;
    auto const c = canopy::center(box);
    auto const d = canopy::diagonal(box);
    float const extent = canopy::length(d);
    int const w = 512, h = 512;
    canopy::vec3<float> const eye = c + canopy::vec3<float>(0.3f, 0.4f, 1.0f) * extent;
    canopy::vec3<float> const forward = canopy::normalize(c - eye);
    canopy::vec3<float> const right = canopy::normalize(canopy::cross(forward, canopy::vec3<float>(0, 1, 0)));
    canopy::vec3<float> const up = canopy::cross(right, forward);
    ray_set primary{"primary", {}, false};
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            float const x = (float(i) + 0.5f) / float(w) - 0.5f, y = (float(j) + 0.5f) / float(h) - 0.5f;
            primary.rays.push_back({eye, 0.0f, forward + right * (0.8f * x) + up * (0.8f * y),
                                    std::numeric_limits<float>::infinity()});
        }
    ray_set random{"random", {}, false};
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u01(0.0f, 1.0f);
    std::normal_distribution<float> n01(0.0f, 1.0f);
    for (int k = 0; k < w * h; ++k) {
        canopy::vec3<float> const o(box.min.x + d.x * u01(rng), box.min.y + d.y * u01(rng), box.min.z + d.z * u01(rng));
        random.rays.push_back({o, 0.0f, {n01(rng), n01(rng), n01(rng)}, std::numeric_limits<float>::infinity()});
    }
    ray_set shadow{"shadow", {}, true};
    canopy::vec3<float> const light = c + canopy::vec3<float>(-0.5f, 1.0f, 0.5f) * extent;
    canopy::default_intersector none;
    for (auto const& r : primary.rays) {
        auto const hit = canopy_trace(s, r, true, none);
        if (hit.prim == canopy::invalid_id) continue;
        canopy::vec3<float> const p = r.origin + r.direction * hit.t;
        shadow.rays.push_back({p, 1e-4f, light - p, 1.0f});
    }
    sets.push_back(std::move(primary));
    sets.push_back(std::move(random));
    sets.push_back(std::move(shadow));
    return sets;
}

// Runs f(i) for every ray, repeat times; returns the best Mrays/s.
double measure(std::size_t n, int repeat, std::function<void(std::size_t, std::size_t)> const& f) {
    double best = 0.0;
    for (int k = 0; k < repeat; ++k) {
        auto const start = clock_type::now();
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024),
                          [&](auto const& r) { f(r.begin(), r.end()); });
        best = std::max(best, double(n) / seconds_since(start) * 1e-6);
    }
    return best;
}

// Comma-separated list → items.
std::vector<std::string> split_list(char const* text) {
    std::vector<std::string> items;
    std::string item;
    for (char const* p = text;; ++p) {
        if (*p == ',' || *p == '\0') {
            if (!item.empty()) items.push_back(item);
            item.clear();
            if (*p == '\0') break;
        } else {
            item += *p;
        }
    }
    return items;
}

void run_scene(scene_input const& in, std::vector<int> const& thread_counts, int repeat,
               std::vector<std::string> const& ray_sets) {
    fmt::print("\n## {} ({} triangles{})\n\n", in.name, in.mesh.size(),
               in.instances.empty() ? "" : fmt::format(", {} instances", in.instances.size()));
    fmt::print("| threads | figure | Canopy | Embree | Canopy/Embree |\n|---|---|---|---|---|\n");
    for (int threads : thread_counts) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
        RTCDevice device = rtcNewDevice(fmt::format("threads={}", threads).c_str());
        rtcSetDeviceMemoryMonitorFunction(device, memory_monitor, nullptr);

        double canopy_build = 1e30, embree_build = 1e30;
        std::unique_ptr<canopy_scene> cs;
        std::unique_ptr<embree_scene> es, es_alpha;
        for (int k = 0; k < repeat; ++k) {
            auto t = clock_type::now();
            cs = build_canopy(in);
            canopy_build = std::min(canopy_build, seconds_since(t));
            es.reset();
            embree_bytes = 0;
            t = clock_type::now();
            es = build_embree(device, in, false);
            embree_build = std::min(embree_build, seconds_since(t));
        }
        long long const embree_memory = embree_bytes.load();
        es_alpha = build_embree(device, in, true);
        fmt::print("| {} | build (ms) | {:.1f} | {:.1f} | {:.2f} (time) |\n", threads, canopy_build * 1e3,
                   embree_build * 1e3, canopy_build / embree_build);
        fmt::print("| {} | memory (bytes/triangle) | {:.1f} | {:.1f} | {:.2f} |\n", threads,
                   double(cs->bytes) / double(in.mesh.size()), double(embree_memory) / double(in.mesh.size()),
                   double(cs->bytes) / double(embree_memory));

        canopy::aabb const box = cs->instanced ? cs->top.bounds() : cs->mesh.bounds();
        auto const sets = make_rays(*cs, box);
        for (auto const& set : sets) {
            if (std::find(ray_sets.begin(), ray_sets.end(), set.name) == ray_sets.end()) continue;
            for (bool closest : {true, false}) {
                if (set.shadow && closest) continue;
                for (bool alpha : {false, true}) {
                    std::vector<canopy::bench_hit> a(set.rays.size()), b(set.rays.size());
                    double const mc = measure(set.rays.size(), repeat, [&](std::size_t lo, std::size_t hi) {
                        canopy::default_intersector none;
                        canopy::bench_alpha_intersector mask;
                        for (std::size_t i = lo; i < hi; ++i)
                            a[i] = alpha ? canopy_trace(*cs, set.rays[i], closest, mask)
                                         : canopy_trace(*cs, set.rays[i], closest, none);
                    });
                    embree_scene const& e = alpha ? *es_alpha : *es;
                    double const me = measure(set.rays.size(), repeat, [&](std::size_t lo, std::size_t hi) {
                        for (std::size_t i = lo; i < hi; ++i) b[i] = embree_trace(e, set.rays[i], closest);
                    });
                    std::size_t disagree = 0;
                    for (std::size_t i = 0; i < a.size(); ++i)
                        disagree += (a[i].prim == canopy::invalid_id) != (b[i].prim == canopy::invalid_id);
                    fmt::print("| {} | {} {}{} (Mrays/s; {} of {} rays differ in hit/miss) | {:.2f} | {:.2f} | {:.2f} |\n",
                               threads, set.name, closest ? "closest" : "any", alpha ? " + alpha" : "", disagree,
                               set.rays.size(), mc, me, mc / me);
                }
            }
        }
        es.reset();
        es_alpha.reset();
        rtcReleaseDevice(device);
    }
}

} // namespace

int main(int argc, char** argv) {
    std::vector<int> threads{1, 2};
    int repeat = 3;
    std::string scene_path;
    std::vector<std::string> ray_sets{"primary", "random", "shadow"};
    bool usage = false;
    for (int i = 1; i < argc; i += 2) {
        if (i + 1 == argc) {
            usage = true;
            break;
        }
        std::string const name = argv[i];
        if (name == "--scene") scene_path = argv[i + 1];
        else if (name == "--repeat") repeat = std::max(1, std::atoi(argv[i + 1]));
        else if (name == "--rays") ray_sets = split_list(argv[i + 1]);
        else if (name == "--threads-list") {
            threads.clear();
            for (char const* p = argv[i + 1]; *p;) {
                threads.push_back(std::max(1, std::atoi(p)));
                while (*p && *p != ',') ++p;
                if (*p) ++p;
            }
        } else {
            usage = true;
        }
    }
    for (auto const& r : ray_sets)
        if (r != "primary" && r != "random" && r != "shadow") usage = true;
    if (usage) {
        std::fprintf(stderr,
                     "usage: %s [--scene FILE.obj|FILE.inst] [--threads-list 1,2] [--repeat N] "
                     "[--rays primary,random,shadow]\n",
                     argv[0]);
        return 2;
    }
    std::vector<scene_input> scenes;
    if (!scene_path.empty()) {
        std::filesystem::path const p(scene_path);
        if (p.extension() == ".inst") {
            auto inst = canopy::read_bench_inst(p);
            scenes.push_back({p.filename().string(), std::move(inst.mesh.triangles), std::move(inst.instances)});
        } else {
            scenes.push_back({p.filename().string(), canopy::read_bench_obj(p).triangles, {}});
        }
    } else {
        scenes.push_back({"icosphere, 7 subdivisions", canopy::make_icosphere(7), {}});
        scene_input forest{"64 instances of an icosphere (5 subdivisions)", canopy::make_icosphere(5), {}};
        for (int k = 0; k < 64; ++k) {
            float const s = 0.5f + 0.1f * float(k % 5);
            std::array<float, 12> rows{s, 0, 0, float(k % 8) * 3.0f, 0, s * 1.5f, 0, 0, 0, 0, s, float(k / 8) * 3.0f};
            forest.instances.push_back(canopy::affine_transform<float>::from_rows(rows));
        }
        scenes.push_back(std::move(forest));
    }
    fmt::print("# Canopy vs Embree {}.{}.{} (same scenes, same rays; best of {})\n", RTC_VERSION_MAJOR,
               RTC_VERSION_MINOR, RTC_VERSION_PATCH, repeat);
    for (auto const& s : scenes) run_scene(s, threads, repeat, ray_sets);
}
