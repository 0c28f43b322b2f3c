#include <catch2/catch.hpp>
import canopy.math;
TEST_CASE("placeholder") { CHECK(true); }
