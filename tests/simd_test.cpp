#include <catch2/catch.hpp>
import canopy.simd;
TEST_CASE("isa") { CHECK(canopy::simd::isa_name() == "scalar"); }
