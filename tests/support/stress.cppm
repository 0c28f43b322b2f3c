// canopy.testing:stress — what the stress battery's test files (stress_test.cpp,
// stress_instancing_test.cpp) share: the battery's sizes and build quality, transforms made from
// rotations and scales, hit records compared bit for bit and described in hexadecimal, and a log of
// failed checks.
module;
#include <catch2/catch.hpp>

#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>
export module canopy.testing:stress;
import canopy.query;
import :random;

export namespace stress_support {

using test_support::pack;
using test_support::random_rays;
using test_support::random_source;
using test_support::triangle_soup;

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

// The build quality of the battery's BVHs: build_quality::high under CANOPY_STRESS_QUALITY=high
// (ctest runs the battery at both qualities; see tests/CMakeLists.txt), else the default.
inline canopy::build_quality stress_quality() {
    char const* value = std::getenv("CANOPY_STRESS_QUALITY");
    return value != nullptr && std::string_view(value) == "high" ? canopy::build_quality::high
                                                                 : canopy::build_quality::fast;
}

// build_binned_sah at the battery's quality (spatial splits apply to triangle BVHs only).
template <typename Prim>
canopy::bvh<Prim> build_bvh(std::vector<Prim> const& prims, canopy::bvh_build_options options = {}) {
    options.quality = stress_quality();
    return canopy::build_binned_sah(prims, options);
}

// The default size, or the full one under CANOPY_STRESS_FULL=1.
inline int sized(int small, int full) { return full_battery() ? full : small; }

// The same for the ray counts of the battery's longest cases, whose default is a tenth under ASan +
// UBSan (CANOPY_TESTING_SANITIZED, tests/CMakeLists.txt): there each ray costs about ten times as
// much, and what those builds check is memory and undefined behaviour. The other builds (release,
// isa-v3 and contract-fast in CI) run the default, which gives the battery its power to find rare
// misses.
inline int sized_rays(int small, int full) {
#if CANOPY_TESTING_SANITIZED
    if (!full_battery()) return small / 10;
#endif
    return sized(small, full);
}

inline std::uint32_t bits(float x) { return std::bit_cast<std::uint32_t>(x); }

// Rotation by a random unit quaternion, in double.
inline std::array<dvec3, 3> random_rotation_rows(random_source& rng) {
    double w = 0, x = 0, y = 0, z = 0, n = 0;
    do {
        w = rng.uniform_double(-1, 1), x = rng.uniform_double(-1, 1), y = rng.uniform_double(-1, 1),
        z = rng.uniform_double(-1, 1);
        n = std::sqrt(w * w + x * x + y * y + z * z);
    } while (n < 0.1 || n > 1.0);
    w /= n, x /= n, y /= n, z /= n;
    return {dvec3{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
            dvec3{2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
            dvec3{2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
}

inline std::array<dvec3, 3> const no_rotation{dvec3{1, 0, 0}, dvec3{0, 1, 0}, dvec3{0, 0, 1}};

// rotation · diag(scale), then translation, rounded to float.
inline transform make_transform(std::array<dvec3, 3> const& rows, dvec3 const& scale, vec3<float> const& translation) {
    auto const f = [](double v) { return static_cast<float>(v); };
    return transform::from_rows({f(rows[0].x * scale.x), f(rows[0].y * scale.y), f(rows[0].z * scale.z), translation.x,
                                 f(rows[1].x * scale.x), f(rows[1].y * scale.y), f(rows[1].z * scale.z), translation.y,
                                 f(rows[2].x * scale.x), f(rows[2].y * scale.y), f(rows[2].z * scale.z), translation.z});
}

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
