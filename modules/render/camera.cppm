// canopy.render:camera — the pinhole camera (refusing degenerate ones, saying why) and its
// primary rays.
module;
// No FMA contraction here, whatever -ffp-contract says (why: README.md, "Accuracy").
#pragma STDC FP_CONTRACT OFF
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
export module canopy.render:camera;
import canopy.query;

export namespace canopy {

struct pinhole_camera {
    vec3<float> eye;
    vec3<float> forward; // unit, towards the image centre
    vec3<float> right;   // scaled: half the image width at distance 1
    vec3<float> up;      // scaled: half the image height at distance 1

    // fovy in degrees; aspect = width / height. Throws std::invalid_argument with look_at_problem's
    // text when the values give no camera. An up hint parallel to the view direction (within
    // 0.06°) is no error: the fallback up is then +y, or -z when the view is along ±y (looking
    // straight down, the top of the image is towards -z).
    static pinhole_camera look_at(vec3<float> eye, vec3<float> target, vec3<float> up_hint, float fovy, float aspect) {
        pinhole_camera c;
        std::string const problem = build(c, eye, target, up_hint, fovy, aspect);
        if (!problem.empty()) throw std::invalid_argument("camera: " + problem);
        return c;
    }

    // Why look_at cannot make a camera of these values, in plain words; empty when it can. The
    // basis is computed in float as the renderer uses it, and refused unless it is finite and
    // orthonormal: a value that is not finite, a field of view outside (0°, 180°), a bad aspect,
    // eye and target that coincide or are too close (or too far apart) for a float direction (a
    // camera under a scale of 1e-30), an up hint of zero or underflowing length.
    static std::string look_at_problem(vec3<float> eye, vec3<float> target, vec3<float> up_hint, float fovy,
                                       float aspect) {
        pinhole_camera c;
        return build(c, eye, target, up_hint, fovy, aspect);
    }

    // Ray through image position (px, py) in pixels, (0, 0) the top-left corner of the image.
    inline ray primary_ray(float px, float py, int width, int height) const {
        float const sx = 2.0f * px / float(width) - 1.0f;
        float const sy = 1.0f - 2.0f * py / float(height);
        return {eye, 0.0f, forward + right * sx + up * sy, std::numeric_limits<float>::infinity()};
    }

private:
    static std::string text(float f) {
        char buffer[32];
        std::snprintf(buffer, sizeof buffer, "%g", double(f));
        return buffer;
    }
    static std::string text(vec3<float> v) { return "(" + text(v.x) + ", " + text(v.y) + ", " + text(v.z) + ")"; }

    static bool unit(vec3<float> v) {
        double const l = std::sqrt(double(v.x) * double(v.x) + double(v.y) * double(v.y) + double(v.z) * double(v.z));
        return std::fabs(l - 1.0) <= 1e-5;
    }

    static std::string build(pinhole_camera& c, vec3<float> eye, vec3<float> target, vec3<float> up_hint, float fovy,
                             float aspect) {
        if (!all_finite(eye)) return "eye " + text(eye) + " is not finite";
        if (!all_finite(target)) return "target " + text(target) + " is not finite";
        if (!all_finite(up_hint)) return "up " + text(up_hint) + " is not finite";
        if (!(fovy > 0.0f && fovy < 180.0f)) return "field of view " + text(fovy) + " is not in (0, 180) degrees";
        if (!(aspect > 0.0f && aspect < std::numeric_limits<float>::infinity()))
            return "aspect ratio " + text(aspect) + " is not a positive number";
        vec3<float> const view = target - eye;
        if (eye.x == target.x && eye.y == target.y && eye.z == target.z)
            return "eye and target coincide at " + text(eye) + ": no view direction";
        if (!all_finite(view)) return "eye " + text(eye) + " and target " + text(target) + " are too far apart for float";
        c.eye = eye;
        c.forward = normalize(view);
        if (!all_finite(c.forward) || !unit(c.forward)) {
            // normalize squares the components in float: a distance over √FLT_MAX overflows there,
            // one so small that its square underflows leaves no direction.
            double const distance = std::sqrt(double(view.x) * double(view.x) + double(view.y) * double(view.y) +
                                              double(view.z) * double(view.z));
            if (distance > 1.0)
                return "eye " + text(eye) + " and target " + text(target) + " are " + text(float(distance)) +
                       " apart, too far for a float view direction (its squared length overflows)";
            return "eye " + text(eye) + " and target " + text(target) +
                   " are too close to give a view direction in float (a collapsed camera)";
        }
        if (up_hint.x == 0.0f && up_hint.y == 0.0f && up_hint.z == 0.0f) return "up is zero: no orientation";
        vec3<float> const up_direction = normalize(up_hint);
        if (!all_finite(up_direction) || !unit(up_direction))
            return "up " + text(up_hint) + " has no direction in float (its length under- or overflows)";
        vec3<float> up = up_hint;
        if (length(cross(c.forward, up_direction)) < 1e-3f)
            up = std::fabs(c.forward.y) < 0.9f ? vec3<float>(0.0f, 1.0f, 0.0f) : vec3<float>(0.0f, 0.0f, -1.0f);
        vec3<float> const r = normalize(cross(c.forward, up));
        vec3<float> const u = cross(r, c.forward);
        float const half_height = std::tan(fovy * std::numbers::pi_v<float> / 360.0f);
        c.up = u * half_height;
        c.right = r * (half_height * aspect);
        if (!all_finite(c.up) || !all_finite(c.right) || !unit(r) || !unit(u))
            return "the camera's basis is not finite (field of view " + text(fovy) + ", aspect " + text(aspect) + ")";
        return {};
    }
};

} // namespace canopy
