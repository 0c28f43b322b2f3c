// accuracy — run time against error: Mrays/s and exact-reference error rates of five ray/triangle
// configurations, on the same closed meshes and the same rays.
//
//   canopy_bench_accuracy [--out DIR] [--subdivisions N] [--rays N] [--repeat N]
//
//   --out DIR           where accuracy.csv and accuracy_pareto.png go (default out/bench/)
//   --subdivisions N    icosphere subdivisions: 20·4^N triangles (default 5: 20,480)
//   --rays N            rays per ray set (default 100,000)
//   --repeat N          timed runs per configuration and ray set; the best counts (default 3)
//
// Configurations: Canopy watertight float (the default test), Canopy Möller–Trumbore float
// (moller_trumbore_intersector), Canopy watertight double (vertices and rays converted to double,
// exactly), Embree 3 default, Embree 3 with RTC_SCENE_FLAG_ROBUST. Closest hit, one thread.
//
// Scenes: a closed icosphere of radius 1 at the origin, and the same icosphere translated by
// 1e5·(1, -0.75, 0.5) and by 1e6·(1, -0.75, 0.5) (vertices rounded to float once, so neighbours
// keep bit-identical shared vertices and the mesh stays closed however much rounding distorts it).
// Ray sets (tmin = 0, tmax = +inf, directions not normalised):
//   primary    camera rays from outside the sphere (a √N × √N image)
//   random     origins uniform in the sphere's box scaled by 1.5, normal-distributed directions
//   vertices   rays from inside through a mesh vertex: origin o = c + s ⊙ (v − c) (c the centre,
//              s = 0 first, then s uniform in [0.5, 0.9] per axis), direction v − o, kept only
//              when that direction is exact (checked in rational arithmetic), so the ray passes
//              exactly through the vertex
//   edges      the same through the exact midpoint of a mesh edge (a, b): direction
//              (a − o) + (b − o), kept only when exact; the ray meets the midpoint at t = 1/2
//   far 1e5, far 1e6   rays from inside the translated spheres: half from random points within
//              0.9 radius of the centre in random directions, a quarter through vertices, a
//              quarter through edge midpoints, as above
//
// Measures, for each configuration and ray set: Mrays/s (best of --repeat single-threaded runs,
// also as a ratio to Canopy watertight float), and against the exact reference, per million rays:
//   false misses      the reference hits, the configuration misses
//   false hits        the configuration hits, the reference misses
//   wrong primitive   both hit, but the reported triangle is not one the exact test hits at the
//                     exact minimal t (at a tie on a shared edge or vertex, every tied triangle
//                     is right)
// and the t error of right hits: the distance in float ULPs between the reported t (double t
// rounded to float) and the exact t rounded to the nearest float (median / p99 / max).
//
// The exact reference: rational arithmetic (GMP mpq_class) on the float inputs. With
// a_i = v_i − o, the ray's line meets the closed triangle iff the three signed volumes
// s_i = det(d, a_i, a_{i+1}) (Plücker side tests of the line against the edges) are all ≥ 0 or
// all ≤ 0 and not all zero; edges and vertices are inside. Since s_0 + s_1 + s_2 = n·d with
// n = (v1 − v0) × (v2 − v0), this also excludes degenerate (zero-area) triangles and rays in the
// triangle's plane. Then t = det(a_0, a_1, a_2) / (s_0 + s_1 + s_2) = n·(v0 − o) / n·d exactly,
// and the triangle is hit iff tmin ≤ t ≤ tmax. The closest exact t wins; every triangle hit at
// that t is a right answer. A floating-point filter only ever rejects: each s_i (and the sign of
// t when tmin = 0) is evaluated in double from exact double differences with a forward error bound
// (5 roundings: γ5 times the permanent, taken as 1e-15 times it); a candidate is dropped when two
// of the s_i are certainly of opposite signs or t is certainly negative, and every other
// candidate is decided in mpq_class.
// Candidates: every triangle in a leaf reached by Canopy's BVH traversal of the float ray, through
// a hook that records each triangle and reports a miss (so tmax never shrinks and no subtree is
// culled). The box test is conservative (Ize 2013, "Robust BVH Ray Traversal", JCGT 2(2): the far
// distance is scaled by 1 + 2γ3), so a box the exact ray touches is never reported missed, and a
// triangle lies inside the box of each node above it: every triangle the exact ray hits is
// reached. This is checked: the first 1000 rays of each set are also decided by a brute-force
// loop over all triangles, and any difference stops the program.
//
// Output: DIR/accuracy.csv (config, ray set, rays, Mrays/s, false misses / hits / wrong primitive
// per million, t error median / p99 / max in ULPs), a Markdown table on stdout, and
// DIR/accuracy_pareto.png drawn by bench/accuracy_plot.py from the CSV (x: false misses per
// million rays, log scale; y: Mrays/s; configurations without false misses are drawn hollow at
// the 95 % upper bound 3/N of the rule of three).
#include <algorithm>
#include <atomic>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <tuple>
#include <vector>
#include <embree3/rtcore.h>
#include "embree_support.hpp"
#include <fmt/core.h>
#include <gmpxx.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
import canopy;
import canopy.procedural;

namespace {

using canopy::triangle;
using canopy::vec3;
using clock_type = std::chrono::steady_clock;
constexpr float inf = std::numeric_limits<float>::infinity();

// ---- exact reference ----------------------------------------------------------------------

using qvec = std::array<mpq_class, 3>;
using dvec = std::array<double, 3>;

qvec exact(vec3<float> const& v) { return {mpq_class(double(v.x)), mpq_class(double(v.y)), mpq_class(double(v.z))}; }
qvec exact(dvec const& v) { return {mpq_class(v[0]), mpq_class(v[1]), mpq_class(v[2])}; }
qvec operator-(qvec const& a, qvec const& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }

mpq_class det(qvec const& a, qvec const& b, qvec const& c) {
    return a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2]) + a[2] * (b[0] * c[1] - b[1] * c[0]);
}

// det(a, b, c) in double with a bound on its error (inputs exact doubles, no underflow).
struct filtered {
    double value;
    double bound;
    // -1, 0, 1 when the sign is certain, 2 when it is not.
    int sign() const {
        if (std::abs(value) > bound || bound == 0.0) return (value > 0.0) - (value < 0.0);
        return 2;
    }
};

filtered det(dvec const& a, dvec const& b, dvec const& c) {
    double const p0 = b[1] * c[2], p1 = b[2] * c[1];
    double const p2 = b[2] * c[0], p3 = b[0] * c[2];
    double const p4 = b[0] * c[1], p5 = b[1] * c[0];
    double const value = a[0] * (p0 - p1) + a[1] * (p2 - p3) + a[2] * (p4 - p5);
    double const permanent = std::abs(a[0]) * (std::abs(p0) + std::abs(p1)) +
                             std::abs(a[1]) * (std::abs(p2) + std::abs(p3)) +
                             std::abs(a[2]) * (std::abs(p4) + std::abs(p5));
    return {value, 1e-15 * permanent};
}

// x − y in double, or nothing when it is not exact (Knuth's TwoSum error term is not zero).
std::optional<double> exact_difference(float x, float y) {
    double const a = x, b = -double(y);
    double const s = a + b;
    double const bb = s - a;
    double const error = (a - (s - bb)) + (b - bb);
    if (error != 0.0) return std::nullopt;
    return s;
}

struct exact_ray {
    vec3<float> origin, direction;
    float tmin = 0.0f, tmax = inf;
};

// The exact test of one triangle: the exact t when the ray hits it (see the file's header).
std::optional<mpq_class> exact_hit(exact_ray const& r, triangle const& tri) {
    vec3<float> const v[3] = {tri.v0, tri.v1, tri.v2};
    std::array<dvec, 3> a{};
    bool differences_exact = true;
    for (int i = 0; i < 3 && differences_exact; ++i)
        for (int k = 0; k < 3 && differences_exact; ++k) {
            auto const d = exact_difference(v[i][k], r.origin[k]);
            if (d) a[std::size_t(i)][std::size_t(k)] = *d;
            else differences_exact = false;
        }
    dvec const d{r.direction.x, r.direction.y, r.direction.z};

    // Filter: drop candidates that certainly miss.
    if (differences_exact) {
        int positive = 0, negative = 0, zero = 0;
        for (int i = 0; i < 3; ++i) {
            int const s = det(d, a[std::size_t(i)], a[std::size_t((i + 1) % 3)]).sign();
            positive += s == 1, negative += s == -1, zero += s == 0;
        }
        if ((positive > 0 && negative > 0) || zero == 3) return std::nullopt;
        if (r.tmin == 0.0f && positive + negative + zero == 3) {
            // All signs certain: n·d has the sign of the nonzero s_i, t the sign of det(a0, a1, a2)·(n·d).
            int const s = det(a[0], a[1], a[2]).sign();
            if (s != 2 && s != 0 && s != (positive > 0 ? 1 : -1)) return std::nullopt;
        }
    }

    qvec const dq = exact(d);
    std::array<qvec, 3> aq;
    for (int i = 0; i < 3; ++i)
        aq[std::size_t(i)] = differences_exact ? exact(a[std::size_t(i)]) : exact(v[i]) - exact(r.origin);
    std::array<mpq_class, 3> s;
    int positive = 0, negative = 0;
    for (int i = 0; i < 3; ++i) {
        s[std::size_t(i)] = det(dq, aq[std::size_t(i)], aq[std::size_t((i + 1) % 3)]);
        int const sg = sgn(s[std::size_t(i)]);
        positive += sg > 0, negative += sg < 0;
    }
    if ((positive > 0 && negative > 0) || positive + negative == 0) return std::nullopt;
    mpq_class t = det(aq[0], aq[1], aq[2]) / mpq_class(s[0] + s[1] + s[2]);
    if (t < mpq_class(double(r.tmin))) return std::nullopt;
    if (std::isfinite(r.tmax) && t > mpq_class(double(r.tmax))) return std::nullopt;
    return t;
}

// q rounded to the nearest float, ties to even.
float round_to_float(mpq_class const& q) {
    float const guess = static_cast<float>(q.get_d()); // get_d truncates: within one float of the answer
    if (!std::isfinite(guess)) return guess;
    float best = guess;
    mpq_class best_error = abs(q - mpq_class(double(guess)));
    for (float const c : {std::nextafter(guess, -inf), std::nextafter(guess, inf)}) {
        if (!std::isfinite(c)) continue;
        mpq_class const error = abs(q - mpq_class(double(c)));
        int const order = cmp(error, best_error);
        if (order < 0 || (order == 0 && (std::bit_cast<std::uint32_t>(c) & 1u) == 0)) {
            best = c;
            best_error = error;
        }
    }
    return best;
}

struct reference_hit {
    bool hit = false;
    float t = inf;                   // exact t rounded to float
    std::vector<std::uint32_t> tied; // every triangle hit at the exact minimal t
};

reference_hit closest_exact(exact_ray const& r, std::vector<triangle> const& mesh,
                            std::vector<std::uint32_t> const& candidates) {
    reference_hit out;
    std::optional<mpq_class> best;
    for (std::uint32_t const prim : candidates) {
        auto const t = exact_hit(r, mesh[prim]);
        if (!t) continue;
        if (!best || *t < *best) {
            best = *t;
            out.tied.assign(1, prim);
        } else if (*t == *best && std::find(out.tied.begin(), out.tied.end(), prim) == out.tied.end()) {
            out.tied.push_back(prim);
        }
    }
    if (best) {
        out.hit = true;
        out.t = round_to_float(*best);
        std::sort(out.tied.begin(), out.tied.end());
    }
    return out;
}

// Records every triangle that traversal reaches and reports a miss.
struct candidate_collector : canopy::basic_intersector<candidate_collector> {
    using canopy::basic_intersector<candidate_collector>::operator();
    std::vector<std::uint32_t>* candidates = nullptr;

    template <typename Ray>
    canopy::basic_hit_record<float> operator()(Ray const&, triangle const& tri) {
        candidates->push_back(tri.prim_id);
        return {};
    }
};

// ---- scenes and rays ----------------------------------------------------------------------

struct scene {
    std::string name;
    vec3<float> center;
    std::vector<triangle> mesh;
    std::vector<vec3<float>> vertices;                    // distinct
    std::vector<std::array<vec3<float>, 2>> edges;         // distinct
    canopy::bvh<triangle> bvh;
    canopy::bvh<canopy::basic_triangle<double>> bvh_double;
    std::size_t degenerate = 0;
};

auto key(vec3<float> const& v) { return std::tuple(v.x, v.y, v.z); }

std::unique_ptr<scene> make_scene(std::string name, int subdivisions, vec3<float> center) {
    auto s = std::make_unique<scene>();
    s->name = std::move(name);
    s->center = center;
    s->mesh = canopy::make_icosphere(subdivisions, center, 1.0f);
    std::map<std::tuple<float, float, float>, vec3<float>> vertices;
    std::map<std::tuple<float, float, float, float, float, float>, std::array<vec3<float>, 2>> edges;
    std::vector<canopy::basic_triangle<double>> mesh_double;
    for (auto const& t : s->mesh) {
        vec3<float> const v[3] = {t.v0, t.v1, t.v2};
        for (int i = 0; i < 3; ++i) {
            vertices.emplace(key(v[i]), v[i]);
            auto a = v[i], b = v[(i + 1) % 3];
            if (key(b) < key(a)) std::swap(a, b);
            if (key(a) != key(b)) edges.emplace(std::tuple_cat(key(a), key(b)), std::array{a, b});
        }
        s->degenerate += canopy::is_degenerate(t);
        mesh_double.push_back({vec3<double>(t.v0), vec3<double>(t.v1), vec3<double>(t.v2), t.prim_id, t.geom_id});
    }
    for (auto const& [k, v] : vertices) s->vertices.push_back(v);
    for (auto const& [k, e] : edges) s->edges.push_back(e);
    s->bvh = canopy::build_binned_sah(s->mesh);
    s->bvh_double = canopy::build_binned_sah(mesh_double);
    return s;
}

struct ray_set {
    std::string name;
    scene const* where = nullptr;
    std::vector<canopy::ray> rays;
};

bool equals_exactly(vec3<float> const& d, qvec const& expected) {
    qvec const got = exact(d);
    return got[0] == expected[0] && got[1] == expected[1] && got[2] == expected[2];
}

// A ray from inside through `target` (one point: a vertex; two points: the midpoint of an edge),
// with an exact direction, or nothing after a few tries.
std::optional<canopy::ray> aim(scene const& s, std::vector<vec3<float>> const& target, bool from_center,
                               std::mt19937& rng) {
    std::uniform_real_distribution<double> scale(0.5, 0.9);
    vec3<float> point = target[0];
    if (target.size() == 2) point = (target[0] + target[1]) * 0.5f;
    for (int attempt = 0; attempt < 8; ++attempt) {
        vec3<float> origin = s.center;
        if (!from_center || attempt > 0) {
            vec3<double> const c(s.center), p(point);
            origin = vec3<float>(vec3<double>(c.x + scale(rng) * (p.x - c.x), c.y + scale(rng) * (p.y - c.y),
                                              c.z + scale(rng) * (p.z - c.z)));
        }
        vec3<float> direction = target[0] - origin;
        qvec expected = exact(target[0]) - exact(origin);
        if (target.size() == 2) {
            direction = direction + (target[1] - origin);
            qvec const second = exact(target[1]) - exact(origin);
            for (int k = 0; k < 3; ++k) expected[std::size_t(k)] += second[std::size_t(k)];
        }
        if (equals_exactly(direction, expected)) return canopy::ray{origin, 0.0f, direction, inf};
    }
    return std::nullopt;
}

// Rays through vertices (edges == false) or edge midpoints, cycling over them until count rays.
void add_aimed(std::vector<canopy::ray>& out, scene const& s, bool edges, std::size_t count, std::mt19937& rng) {
    std::size_t const targets = edges ? s.edges.size() : s.vertices.size();
    std::size_t const goal = out.size() + count;
    for (std::size_t i = 0, failures = 0; out.size() < goal && failures < count; ++i) {
        std::size_t const k = i % targets;
        std::vector<vec3<float>> target{edges ? s.edges[k][0] : s.vertices[k]};
        if (edges) target.push_back(s.edges[k][1]);
        auto const r = aim(s, target, i < targets, rng);
        if (r) out.push_back(*r);
        else ++failures;
    }
}

vec3<float> random_direction(std::mt19937& rng) {
    std::normal_distribution<float> n01(0.0f, 1.0f);
    float const x = n01(rng), y = n01(rng), z = n01(rng);
    return {x, y, z};
}

std::vector<ray_set> make_ray_sets(scene const& sphere, scene const& far5, scene const& far6, std::size_t n) {
    std::vector<ray_set> sets;
    std::mt19937 rng(2024);
    std::uniform_real_distribution<float> u01(0.0f, 1.0f);

    ray_set primary{"primary", &sphere, {}};
    auto const side = std::size_t(std::sqrt(double(n)));
    vec3<float> const eye(1.2f, 1.6f, 4.0f);
    vec3<float> const forward = canopy::normalize(sphere.center - eye);
    vec3<float> const right = canopy::normalize(canopy::cross(forward, vec3<float>(0, 1, 0)));
    vec3<float> const up = canopy::cross(right, forward);
    for (std::size_t j = 0; j < side; ++j)
        for (std::size_t i = 0; i < side; ++i) {
            float const x = (float(i) + 0.5f) / float(side) - 0.5f, y = (float(j) + 0.5f) / float(side) - 0.5f;
            primary.rays.push_back({eye, 0.0f, forward + right * (0.6f * x) + up * (0.6f * y), inf});
        }
    sets.push_back(std::move(primary));

    ray_set random{"random", &sphere, {}};
    for (std::size_t k = 0; k < n; ++k) {
        vec3<float> const o(3.0f * u01(rng) - 1.5f, 3.0f * u01(rng) - 1.5f, 3.0f * u01(rng) - 1.5f);
        random.rays.push_back({o, 0.0f, random_direction(rng), inf});
    }
    sets.push_back(std::move(random));

    ray_set vertices{"vertices", &sphere, {}};
    add_aimed(vertices.rays, sphere, false, n, rng);
    sets.push_back(std::move(vertices));
    ray_set edges{"edges", &sphere, {}};
    add_aimed(edges.rays, sphere, true, n, rng);
    sets.push_back(std::move(edges));

    for (auto const* s : {&far5, &far6}) {
        ray_set far{s == &far5 ? "far 1e5" : "far 1e6", s, {}};
        vec3<double> const c(s->center);
        while (far.rays.size() < n / 2) {
            vec3<double> const p(2.0 * u01(rng) - 1.0, 2.0 * u01(rng) - 1.0, 2.0 * u01(rng) - 1.0);
            if (canopy::length_squared(p) > 1.0) continue;
            far.rays.push_back({vec3<float>(c + p * 0.9), 0.0f, random_direction(rng), inf});
        }
        add_aimed(far.rays, *s, false, n / 4, rng);
        add_aimed(far.rays, *s, true, n - far.rays.size(), rng);
        sets.push_back(std::move(far));
    }
    return sets;
}

struct reference_set {
    std::vector<reference_hit> hits;
    double candidates_per_ray = 0.0;
};

reference_set make_reference(ray_set const& set) {
    auto const& s = *set.where;
    reference_set ref;
    ref.hits.resize(set.rays.size());
    std::vector<std::size_t> candidate_counts(set.rays.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, set.rays.size(), 256), [&](auto const& range) {
        std::vector<std::uint32_t> candidates;
        candidate_collector collect;
        collect.candidates = &candidates;
        for (std::size_t i = range.begin(); i < range.end(); ++i) {
            auto const& r = set.rays[i];
            candidates.clear();
            canopy::closest_hit(r, &s.bvh, &s.bvh + 1, collect);
            candidate_counts[i] = candidates.size();
            ref.hits[i] = closest_exact({r.origin, r.direction, r.tmin, r.tmax}, s.mesh, candidates);
        }
    });
    std::size_t total = 0;
    for (auto c : candidate_counts) total += c;
    ref.candidates_per_ray = set.rays.empty() ? 0.0 : double(total) / double(set.rays.size());

    // The candidates are complete: the first rays against every triangle.
    std::size_t const checked = std::min<std::size_t>(1000, set.rays.size());
    std::vector<std::uint32_t> all(s.mesh.size());
    for (std::size_t k = 0; k < all.size(); ++k) all[k] = std::uint32_t(k);
    // The first ray (lowest index) where they disagree is reported from this thread once the
    // loop is done: exiting from a worker thread would tear the thread pool down under itself.
    std::atomic<std::size_t> first_bad{checked};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, checked, 16), [&](auto const& range) {
        for (std::size_t i = range.begin(); i < range.end(); ++i) {
            auto const& r = set.rays[i];
            auto const brute = closest_exact({r.origin, r.direction, r.tmin, r.tmax}, s.mesh, all);
            auto const& fast = ref.hits[i];
            if (brute.hit != fast.hit || brute.t != fast.t || brute.tied != fast.tied) {
                std::size_t seen = first_bad.load();
                while (i < seen && !first_bad.compare_exchange_weak(seen, i)) {}
            }
        }
    });
    if (std::size_t const i = first_bad.load(); i < checked) {
        auto const& r = set.rays[i];
        auto const brute = closest_exact({r.origin, r.direction, r.tmin, r.tmax}, s.mesh, all);
        auto const& fast = ref.hits[i];
        std::fprintf(stderr,
                     "accuracy: %s ray %zu: the BVH candidates and a brute-force loop disagree "
                     "(hit %d/%d, t %.9g/%.9g)\n",
                     set.name.c_str(), i, int(fast.hit), int(brute.hit), double(fast.t), double(brute.t));
        std::exit(1);
    }
    return ref;
}

// ---- configurations -----------------------------------------------------------------------

struct trace_result {
    bool hit = false;
    double t = 0.0;
    std::uint32_t prim = canopy::invalid_id;
};

template <typename T>
trace_result from_record(canopy::basic_hit_record<T> const& hr) {
    if (!hr.hit) return {};
    return {true, double(hr.t), hr.prim_id};
}

struct embree_scene {
    RTCScene handle = nullptr;
    embree_scene(RTCDevice device, std::vector<triangle> const& mesh, bool robust) {
        handle = rtcNewScene(device);
        if (robust) rtcSetSceneFlags(handle, RTC_SCENE_FLAG_ROBUST);
        RTCGeometry geom = canopy_bench::embree_triangles(device, mesh);
        rtcCommitGeometry(geom);
        rtcAttachGeometry(handle, geom);
        rtcReleaseGeometry(geom);
        rtcCommitScene(handle);
    }
    embree_scene(embree_scene const&) = delete;
    embree_scene& operator=(embree_scene const&) = delete;
    ~embree_scene() { rtcReleaseScene(handle); }
};

trace_result embree_trace(RTCScene scene, canopy::ray const& r) {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRayHit rh = canopy_bench::embree_ray_hit(r);
    rtcIntersect1(scene, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return {};
    return {true, double(rh.ray.tfar), rh.hit.primID};
}

// trace(i) for every ray, repeat times on this thread; returns the best Mrays/s and the results.
template <typename Trace>
double time_rays(std::size_t n, int repeat, std::vector<trace_result>& results, Trace&& trace) {
    results.assign(n, {});
    double best = 0.0;
    for (int k = 0; k < repeat; ++k) {
        auto const start = clock_type::now();
        for (std::size_t i = 0; i < n; ++i) results[i] = trace(i);
        double const seconds = std::chrono::duration<double>(clock_type::now() - start).count();
        best = std::max(best, double(n) / seconds * 1e-6);
    }
    return best;
}

struct row {
    std::string config, set;
    std::size_t rays = 0;
    double mrays = 0.0, speed_ratio = 0.0;
    double false_miss = 0.0, false_hit = 0.0, wrong_primitive = 0.0; // per million rays
    std::uint32_t ulp_median = 0, ulp_p99 = 0, ulp_max = 0;
};

row evaluate(std::string config, ray_set const& set, reference_set const& ref, std::vector<trace_result> const& got,
             double mrays) {
    row out{std::move(config), set.name, set.rays.size(), mrays};
    std::size_t false_miss = 0, false_hit = 0, wrong = 0;
    std::vector<std::uint32_t> ulps;
    for (std::size_t i = 0; i < got.size(); ++i) {
        auto const& e = ref.hits[i];
        auto const& g = got[i];
        if (e.hit && !g.hit) ++false_miss;
        else if (!e.hit && g.hit) ++false_hit;
        else if (e.hit && g.hit) {
            if (!std::binary_search(e.tied.begin(), e.tied.end(), g.prim)) ++wrong;
            else ulps.push_back(canopy::ulp_distance(float(g.t), e.t));
        }
    }
    double const per_million = got.empty() ? 0.0 : 1e6 / double(got.size());
    out.false_miss = double(false_miss) * per_million;
    out.false_hit = double(false_hit) * per_million;
    out.wrong_primitive = double(wrong) * per_million;
    if (!ulps.empty()) {
        std::sort(ulps.begin(), ulps.end());
        out.ulp_median = ulps[ulps.size() / 2];
        out.ulp_p99 = ulps[std::min(ulps.size() - 1, std::size_t(std::ceil(0.99 * double(ulps.size()))) - 1)];
        out.ulp_max = ulps.back();
    }
    return out;
}

} // namespace

int main(int argc, char** argv) {
    std::filesystem::path out_dir = "out/bench";
    int subdivisions = 5;
    std::size_t ray_count = 100'000;
    int repeat = 3;
    for (int i = 1; i < argc; i += 2) {
        std::string const name = argv[i];
        char const* value = i + 1 < argc ? argv[i + 1] : nullptr;
        if (value && name == "--out") out_dir = value;
        else if (value && name == "--subdivisions") subdivisions = std::clamp(std::atoi(value), 0, 9);
        else if (value && name == "--rays") ray_count = std::size_t(std::max(16L, std::atol(value)));
        else if (value && name == "--repeat") repeat = std::max(1, std::atoi(value));
        else {
            std::fprintf(stderr, "usage: %s [--out DIR] [--subdivisions N] [--rays N] [--repeat N]\n", argv[0]);
            return 2;
        }
    }

    auto const sphere = make_scene("icosphere", subdivisions, {0.0f, 0.0f, 0.0f});
    auto const far5 = make_scene("icosphere at 1e5", subdivisions, {1e5f, -0.75e5f, 0.5e5f});
    auto const far6 = make_scene("icosphere at 1e6", subdivisions, {1e6f, -0.75e6f, 0.5e6f});
    auto const sets = make_ray_sets(*sphere, *far5, *far6, ray_count);

    fmt::print("# Run time against error (Embree {}.{}.{}; closest hit, 1 thread, best of {})\n\n", RTC_VERSION_MAJOR,
               RTC_VERSION_MINOR, RTC_VERSION_PATCH, repeat);
    fmt::print("Scenes: closed icospheres of radius 1 with {} triangles ({} / {} / {} degenerate at the origin / "
               "1e5 / 1e6).\n\n",
               sphere->mesh.size(), sphere->degenerate, far5->degenerate, far6->degenerate);
    fmt::print("| ray set | scene | rays | exact hits | hits at a tie | candidates per ray |\n|---|---|---|---|---|---|\n");
    std::vector<reference_set> references;
    for (auto const& set : sets) {
        references.push_back(make_reference(set));
        std::size_t hits = 0, ties = 0;
        for (auto const& h : references.back().hits) hits += h.hit, ties += h.tied.size() > 1;
        fmt::print("| {} | {} | {} | {} | {} | {:.1f} |\n", set.name, set.where->name, set.rays.size(), hits, ties,
                   references.back().candidates_per_ray);
    }

    RTCDevice device = rtcNewDevice("threads=1");
    std::vector<row> rows;
    {
        std::map<scene const*, std::pair<std::unique_ptr<embree_scene>, std::unique_ptr<embree_scene>>> embree;
        for (auto const* s : {sphere.get(), far5.get(), far6.get()})
            embree[s] = {std::make_unique<embree_scene>(device, s->mesh, false),
                         std::make_unique<embree_scene>(device, s->mesh, true)};
        std::vector<trace_result> got;
        for (std::size_t k = 0; k < sets.size(); ++k) {
            auto const& set = sets[k];
            auto const& s = *set.where;
            auto const& rays = set.rays;
            std::vector<canopy::basic_ray<double>> rays_double;
            for (auto const& r : rays)
                rays_double.push_back({vec3<double>(r.origin), double(r.tmin), vec3<double>(r.direction), double(r.tmax)});

            double const base = time_rays(rays.size(), repeat, got, [&](std::size_t i) {
                return from_record(canopy::closest_hit(rays[i], &s.bvh, &s.bvh + 1));
            });
            rows.push_back(evaluate("Canopy watertight float", set, references[k], got, base));
            double m = time_rays(rays.size(), repeat, got, [&](std::size_t i) {
                return from_record(canopy::closest_hit(rays[i], &s.bvh, &s.bvh + 1, canopy::moller_trumbore_intersector{}));
            });
            rows.push_back(evaluate("Canopy Möller–Trumbore float", set, references[k], got, m));
            m = time_rays(rays.size(), repeat, got, [&](std::size_t i) {
                return from_record(canopy::closest_hit(rays_double[i], &s.bvh_double, &s.bvh_double + 1));
            });
            rows.push_back(evaluate("Canopy watertight double", set, references[k], got, m));
            RTCScene const plain = embree[&s].first->handle, robust = embree[&s].second->handle;
            m = time_rays(rays.size(), repeat, got, [&](std::size_t i) { return embree_trace(plain, rays[i]); });
            rows.push_back(evaluate("Embree 3", set, references[k], got, m));
            m = time_rays(rays.size(), repeat, got, [&](std::size_t i) { return embree_trace(robust, rays[i]); });
            rows.push_back(evaluate("Embree 3 robust", set, references[k], got, m));
            for (std::size_t r = rows.size() - 5; r < rows.size(); ++r) rows[r].speed_ratio = rows[r].mrays / base;
        }
    }
    rtcReleaseDevice(device);

    fmt::print("\n| configuration | ray set | rays | Mrays/s | × watertight float | false misses /M | false hits /M | "
               "wrong primitive /M | t error ULPs median / p99 / max |\n|---|---|---|---|---|---|---|---|---|\n");
    for (auto const& r : rows)
        fmt::print("| {} | {} | {} | {:.2f} | {:.2f} | {:.1f} | {:.1f} | {:.1f} | {} / {} / {} |\n", r.config, r.set,
                   r.rays, r.mrays, r.speed_ratio, r.false_miss, r.false_hit, r.wrong_primitive, r.ulp_median,
                   r.ulp_p99, r.ulp_max);

    std::filesystem::create_directories(out_dir);
    auto const csv_path = out_dir / "accuracy.csv";
    {
        std::ofstream csv(csv_path);
        csv << "config,ray_set,rays,mrays_per_s,false_miss_per_million,false_hit_per_million,"
               "wrong_primitive_per_million,t_error_ulps_median,t_error_ulps_p99,t_error_ulps_max\n";
        for (auto const& r : rows)
            csv << fmt::format("{},{},{},{:.4f},{:.3f},{:.3f},{:.3f},{},{},{}\n", r.config, r.set, r.rays, r.mrays,
                               r.false_miss, r.false_hit, r.wrong_primitive, r.ulp_median, r.ulp_p99, r.ulp_max);
        if (!csv) {
            std::fprintf(stderr, "accuracy: cannot write %s\n", csv_path.c_str());
            return 1;
        }
    }
    auto const png_path = out_dir / "accuracy_pareto.png";
    std::string const plot = fmt::format("'{}' '{}' '{}' '{}'", CANOPY_BENCH_PYTHON, CANOPY_ACCURACY_PLOT_SCRIPT,
                                         csv_path.string(), png_path.string());
    fmt::print("\nWrote {}\n", csv_path.string());
    if (std::system(plot.c_str()) != 0) {
        std::fprintf(stderr, "accuracy: the plot failed; run it by hand: %s\n", plot.c_str());
        return 1;
    }
    fmt::print("Wrote {}\n", png_path.string());
}
