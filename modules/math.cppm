export module canopy.math;
export import canopy.simd;
export namespace canopy {
template <typename T> struct vec3 { T x, y, z; };
}
