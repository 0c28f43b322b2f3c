#include <catch2/catch.hpp>
import canopy.simd;
TEST_CASE("placeholder") { CHECK(!canopy::simd::isa_name().empty()); }
