// Helpers shared by the stress battery's test files (stress_test.cpp, stress_instancing_test.cpp).
//
// Include it after the standard headers and the `import canopy.query;` of the test file: it uses
// <bit>, <cmath>, <cstdlib>, <limits>, <random>, <sstream>, <string>, <string_view> and Catch2,
// which the test file includes before its imports (standard headers may not follow an import).
#pragma once

namespace stress_support {

using canopy::ray;
using canopy::triangle;
using canopy::vec3;
using dvec3 = vec3<double>;
using float8 = canopy::simd::float8;
using packet_ray = canopy::basic_ray<float8>;
using mesh_bvh = canopy::bvh<triangle>;
using mesh_instance = canopy::instance<mesh_bvh>;
using instance_bvh = canopy::bvh<mesh_instance>;
using record = canopy::hit_record<ray, triangle>;
using packet_record = canopy::basic_hit_record<float8>;
using transform = canopy::affine_transform<float>;

inline constexpr float inf = std::numeric_limits<float>::infinity();
inline constexpr float quiet_nan = std::numeric_limits<float>::quiet_NaN();

inline bool full_battery() {
    char const* value = std::getenv("CANOPY_STRESS_FULL");
    return value != nullptr && std::string_view(value) == "1";
}

// The default size, or the full one under CANOPY_STRESS_FULL=1.
inline int sized(int small, int full) { return full_battery() ? full : small; }

inline std::uint32_t bits(float x) { return std::bit_cast<std::uint32_t>(x); }

struct random_source {
    std::mt19937 engine;
    explicit random_source(std::uint32_t seed) : engine(seed) {}
    float uniform(float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(engine); }
    double uniform_double(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(engine); }
    int integer(int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(engine); }
    vec3<float> point(float lo, float hi) { return {uniform(lo, hi), uniform(lo, hi), uniform(lo, hi)}; }
    // A multiple of 2^-k in [-extent, extent].
    float dyadic(float extent, int k) {
        int const n = static_cast<int>(std::ldexp(extent, k));
        return std::ldexp(static_cast<float>(integer(-n, n)), -k);
    }
    vec3<float> dyadic_point(float extent, int k) { return {dyadic(extent, k), dyadic(extent, k), dyadic(extent, k)}; }
    // A point of the unit ball.
    vec3<float> in_ball() {
        for (;;) {
            vec3<float> const p = point(-1.0f, 1.0f);
            if (canopy::dot(p, p) <= 1.0f) return p;
        }
    }
    // A direction, uniform over the sphere, of length in [0.1, 1] (not normalised).
    vec3<float> direction() {
        for (;;) {
            vec3<float> const p = point(-1.0f, 1.0f);
            float const l2 = canopy::dot(p, p);
            if (l2 >= 0.01f && l2 <= 1.0f) return p;
        }
    }
};

inline std::string describe(vec3<float> const& v) {
    std::ostringstream s;
    s << std::hexfloat << '(' << v.x << ", " << v.y << ", " << v.z << ')';
    return s.str();
}

inline std::string describe(ray const& r) {
    std::ostringstream s;
    s << "ray origin " << describe(r.origin) << " direction " << describe(r.direction) << std::hexfloat << " tmin "
      << r.tmin << " tmax " << r.tmax;
    return s.str();
}

inline std::string describe(record const& h) {
    if (!h.hit) return "miss";
    std::ostringstream s;
    s << "hit prim " << h.prim_id << " inst " << h.inst_id << " inner " << h.inner_inst_id[0] << std::hexfloat
      << " t " << h.t << " u " << h.u << " v " << h.v;
    return s.str();
}

// Counts failed checks and keeps the first, for the message of the final REQUIRE.
struct failure_log {
    std::size_t count = 0;
    std::string first;
    void add(std::string const& what) {
        if (count++ == 0) first = what;
    }
};

inline void require_no_failures(failure_log const& log, std::string_view what) {
    INFO(what << ": " << log.count << " failure(s); first: " << log.first);
    REQUIRE(log.count == 0);
}

inline bool identical(record const& a, record const& b) {
    if (a.hit != b.hit) return false;
    if (!a.hit) return true;
    return bits(a.t) == bits(b.t) && bits(a.u) == bits(b.u) && bits(a.v) == bits(b.v) && a.prim_id == b.prim_id &&
           a.geom_id == b.geom_id && a.inst_id == b.inst_id && a.inner_inst_id == b.inner_inst_id;
}

} // namespace stress_support
