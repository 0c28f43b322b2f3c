// canopy.testing.scene — what the scene and plugin tests share: catching the scene_error that bad
// input must give, setting resource limits for one test, and a reference ray–triangle test.
module;
#include <catch2/catch.hpp>

#include <array>
#include <cmath>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
export module canopy.testing.scene;
import canopy.scene;

export namespace test_support {

// The distance t at which ray r hits the triangle v, in [tmin, tmax], or nullopt: Möller–Trumbore
// in double, a reference for the library's float test (use rays aimed at triangle interiors, far
// from edges, where both agree on whether there is a hit).
inline std::optional<double> hit_double(canopy::ray const& r, std::array<canopy::vec3<double>, 3> const& v) {
    using vec = canopy::vec3<double>;
    vec const o(r.origin), d(r.direction);
    vec const e1 = v[1] - v[0], e2 = v[2] - v[0];
    vec const p = cross(d, e2);
    double const det = dot(e1, p);
    if (std::abs(det) < 1e-300) return std::nullopt;
    vec const s = o - v[0];
    double const u = dot(s, p) / det;
    vec const q = cross(s, e1);
    double const w = dot(d, q) / det;
    double const t = dot(e2, q) / det;
    if (u < 0 || w < 0 || u + w > 1 || t < double(r.tmin) || t > double(r.tmax)) return std::nullopt;
    return t;
}

// Sets canopy::default_limits() back to what it was when the guard was made, when it goes: a
// test that lowers a limit cannot leave it lowered for the next, whatever it throws.
struct limits_guard {
    canopy::resource_limits saved = canopy::default_limits();
    ~limits_guard() { canopy::default_limits() = saved; }
};

// The scene_error that f throws. A failed check if it throws none (the error returned then says
// "(no scene_error)"); any other exception propagates.
inline canopy::scene_error error_of(auto&& f) {
    try {
        f();
    } catch (canopy::scene_error const& e) {
        return e;
    }
    FAIL_CHECK("no scene_error");
    return canopy::scene_error("", "", "(no scene_error)");
}

// The message (what()) of the scene_error that f throws, as error_of.
inline std::string message_of(auto&& f) { return error_of(f).what(); }

struct load_failure_report {
    std::string file, where, problem, message;
};

// Loads `file` through `r` (with `plugin`, if named) into a scene that holds one group, expecting
// a scene_error: the scene must be left as it was (no node, mesh, material or image added). A
// failed check, and an empty report, if the load succeeds.
inline load_failure_report load_failure(canopy::registry const& r, std::filesystem::path const& file,
                                        std::string_view plugin = {}) {
    canopy::scene s;
    s.add_group(s.root(), "before");
    auto const nodes = s.nodes().size();
    try {
        r.load(s, file, s.root(), plugin);
    } catch (canopy::scene_error const& e) {
        CHECK(s.nodes().size() == nodes);
        CHECK(s.meshes().empty());
        CHECK(s.materials().empty());
        CHECK(s.images().empty());
        return {e.file(), e.where(), e.problem(), e.what()};
    }
    FAIL_CHECK("no scene_error for " << file);
    return {};
}

} // namespace test_support
