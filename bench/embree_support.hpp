// What the programs that run Embree share (embree_compare.cpp, accuracy.cpp, zero_cost_embree.cpp):
// a triangle list as an Embree geometry and a ray as an Embree ray, written once so that every
// comparison gives Embree the same input. Templates over the mesh and ray types (anything with
// v0, v1, v2 and origin, direction, tmin, tmax), so the header needs no import.
#pragma once
#include <cstddef>
#include <embree3/rtcore.h>

namespace canopy_bench {

// The mesh as an unindexed triangle geometry, triangle i as primitive i (as in Canopy), not yet
// committed: the caller sets filters or build quality, then calls rtcCommitGeometry.
template <typename Mesh>
RTCGeometry embree_triangles(RTCDevice device, Mesh const& mesh) {
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                          3 * sizeof(float), 3 * mesh.size()));
    auto* idx = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                               3 * sizeof(unsigned), mesh.size()));
    for (std::size_t i = 0; i < mesh.size(); ++i) {
        auto const& t = mesh[i];
        decltype(t.v0) const p[3] = {t.v0, t.v1, t.v2};
        for (std::size_t k = 0; k < 3; ++k) {
            v[9 * i + 3 * k + 0] = p[k].x;
            v[9 * i + 3 * k + 1] = p[k].y;
            v[9 * i + 3 * k + 2] = p[k].z;
            idx[3 * i + k] = unsigned(3 * i + k);
        }
    }
    return geom;
}

// The ray for rtcOccluded1: the same origin, direction (not normalised) and [tmin, tmax].
template <typename Ray>
RTCRay embree_ray(Ray const& r) {
    RTCRay ray{};
    ray.org_x = r.origin.x, ray.org_y = r.origin.y, ray.org_z = r.origin.z;
    ray.dir_x = r.direction.x, ray.dir_y = r.direction.y, ray.dir_z = r.direction.z;
    ray.tnear = r.tmin, ray.tfar = r.tmax, ray.mask = ~0u;
    return ray;
}

// The ray and an empty hit for rtcIntersect1.
template <typename Ray>
RTCRayHit embree_ray_hit(Ray const& r) {
    RTCRayHit rh{};
    rh.ray = embree_ray(r);
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    return rh;
}

} // namespace canopy_bench
