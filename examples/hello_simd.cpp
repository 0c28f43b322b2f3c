#include <cstdio>
import canopy.simd;
import canopy.math;
int main() { std::printf("%s\n", canopy::simd::isa_name().data()); }
