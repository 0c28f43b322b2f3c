// Tests of canopy.scene:text, the loaders' toolkit: every rule of its head comment on tokens
// whose values are known by hand (decimal → float rounding checked against the float next to the
// exact value), and the messages of its errors, word for word.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

import canopy.scene;

namespace {

using canopy::number_problem;

template <typename F> std::string message_of(F&& f) {
    try {
        f();
    } catch (canopy::scene_error const& e) {
        return e.what();
    }
    return "no error";
}

} // namespace

TEST_CASE("text: floats by one rule: signs, syntax, finiteness and overflow judged in float") {
    auto const value = [](std::string_view t) {
        auto const n = canopy::read_float(t);
        REQUIRE(n.problem == number_problem::none);
        return n.value;
    };
    auto const problem = [](std::string_view t) { return canopy::read_float(t).problem; };
    CHECK(value("1.5") == 1.5f);
    CHECK(value("+1.5") == 1.5f);
    CHECK(value("-.5") == -0.5f);
    CHECK(value("5.") == 5.0f);
    CHECK(value("2E3") == 2000.0f);
    CHECK(value("3.4028235e38") == std::numeric_limits<float>::max());
    // Below the float range: a denormal, or a zero of the number's sign.
    CHECK(value("1e-40") == 0x1.16c2p-133f);
    CHECK(value("1e-50") == 0.0f);
    CHECK(!std::signbit(value("1e-50")));
    CHECK(std::signbit(value("-1e-50")));
    CHECK(std::signbit(value("-0.000000000000000000000000000000000000000000000000000001e-9999")));
    // Straight to the nearest float: 1 + 2^-24 + 2.46e-17 lies just above the midpoint between 1
    // and 1 + 2^-23; through double it would round to the midpoint, then (ties to even) to 1.
    CHECK(value("1.0000000596046448") == 1.0f + 0x1p-23f);

    for (std::string_view bad : {"", "+", "-", "++1", "+-1", "1.5f", "0x10", "0x1p3", "1e", "1e+", ".", "e5", "1,5", " 1",
                                 "1..2", "3.1+e2", "infx"})
        CHECK(problem(bad) == number_problem::not_a_number);
    for (std::string_view inf : {"inf", "-inf", "+inf", "infinity", "INF", "nan", "-nan", "NaN"})
        CHECK(problem(inf) == number_problem::not_finite);
    // 1e300 is a finite double, but not a float.
    for (std::string_view huge : {"1e39", "3.5e38", "-3.5e38", "1e300", "1e999", "1000000000000000000000000000000000000000",
                                  "0.0000001e46", "1e99999999999999999999"})
        CHECK(problem(huge) == number_problem::overflows_float);
    CHECK(canopy::is_decimal_number("1e300"));
    CHECK(!canopy::is_decimal_number("nan"));
    CHECK(!canopy::is_decimal_number("0x10"));
}

TEST_CASE("text: integers by one rule: signs, syntax and 64-bit range") {
    CHECK(canopy::read_integer("+42").value == 42);
    CHECK(canopy::read_integer("-42").value == -42);
    CHECK(canopy::read_integer("9223372036854775807").value == std::numeric_limits<std::int64_t>::max());
    CHECK(canopy::read_integer("-9223372036854775808").value == std::numeric_limits<std::int64_t>::min());
    CHECK(canopy::read_integer("9223372036854775808").problem == number_problem::overflows_integer);
    CHECK(canopy::read_integer("-99999999999999999999").problem == number_problem::overflows_integer);
    for (std::string_view bad : {"", "+", "++1", "+-1", "1.0", "1e3", "0x10", "12a", " 1"})
        CHECK(canopy::read_integer(bad).problem == number_problem::not_an_integer);
}

TEST_CASE("text: number errors name the file, the line and the token") {
    CHECK(message_of([] { canopy::parse_float("x", "a.obj", 3); }) == "a.obj:3: bad number 'x'");
    CHECK(message_of([] { canopy::parse_float("nan", "a.obj", 3); }) == "a.obj:3: number 'nan' is not finite");
    CHECK(message_of([] { canopy::parse_float("1e300", "a.obj", 3); }) == "a.obj:3: value 1e300 overflows a float");
    CHECK(message_of([] { canopy::parse_float(std::string(50, '9'), "a.obj", 0); }) ==
          "a.obj: value " + std::string(40, '9') + "… overflows a float");
    CHECK(message_of([] { canopy::parse_float("inf", "m.off", "4", "vertex 1: coordinate"); }) ==
          "m.off:4: vertex 1: coordinate 'inf' is not a finite number");
    CHECK(message_of([] { canopy::parse_integer("1.0", "m.off", "7", "face 0: corner count"); }) ==
          "m.off:7: face 0: corner count '1.0' is not an integer");
    CHECK(message_of([] { canopy::parse_integer("99999999999999999999", "m.off", "7", "face 0: vertex index"); }) ==
          "m.off:7: face 0: vertex index '99999999999999999999' is beyond the 64-bit integer range");
}

TEST_CASE("text: OBJ indices and corners") {
    auto const resolve = [](std::string_view part, std::size_t count) {
        return canopy::resolve_obj_index(part, part, count, "vertex", "vertices", "f.obj", 9);
    };
    CHECK(resolve("1", 3) == 0);
    CHECK(resolve("+3", 3) == 2);
    CHECK(resolve("-1", 3) == 2);
    CHECK(resolve("-3", 3) == 0);
    CHECK(message_of([&] { resolve("0", 3); }) == "f.obj:9: vertex index 0 is not valid (OBJ indices start at 1)");
    CHECK(message_of([&] { resolve("4", 3); }) == "f.obj:9: vertex index 4 is out of range (3 vertices so far)");
    CHECK(message_of([&] { resolve("-4", 3); }) == "f.obj:9: vertex index -4 is out of range (3 vertices so far)");
    CHECK(message_of([&] { resolve("99999999999999999999", 3); }) ==
          "f.obj:9: bad vertex index '99999999999999999999' in corner '99999999999999999999'");

    canopy::obj_counts const counts{3, 2, 1};
    auto const corner = [&](std::string_view t) { return canopy::read_obj_corner(t, counts, "f.obj", 2); };
    auto const c = corner("3/-1/1");
    CHECK(c.v == 2);
    CHECK(c.vt == std::optional<std::size_t>(1));
    CHECK(c.vn == std::optional<std::size_t>(0));
    CHECK(!corner("2").vt);
    CHECK(!corner("2//1").vt);
    CHECK(corner("2//1").vn == std::optional<std::size_t>(0));
    CHECK(message_of([&] { corner("1/1/1/1"); }) == "f.obj:2: corner '1/1/1/1' has more than three parts");
    CHECK(message_of([&] { corner("1/"); }) == "f.obj:2: corner '1/' has an empty texture coordinate index");
    CHECK(message_of([&] { corner("1/1/"); }) == "f.obj:2: bad normal index '' in corner '1/1/'");
    CHECK(message_of([&] { corner("1/3"); }) == "f.obj:2: texture coordinate index 3 is out of range (2 texture coordinates so far)");
}

TEST_CASE("text: lines numbered from 1, comments cut, blank lines skipped, tokens split on blanks") {
    std::string_view const text = "v 1 2 3 # a comment\r\n\n  # only a comment\n\tf\v1\f2  3\r\nlast";
    canopy::line_reader lines(text);
    std::vector<std::string_view> t;
    REQUIRE(lines.next(t));
    CHECK(lines.number() == 1);
    CHECK(t == std::vector<std::string_view>{"v", "1", "2", "3"});
    REQUIRE(lines.next(t));
    CHECK(lines.where() == "4");
    CHECK(t == std::vector<std::string_view>{"f", "1", "2", "3"});
    CHECK(canopy::rest_after(lines.line(), t[0]) == "1\f2  3");
    REQUIRE(lines.next(t));
    CHECK(lines.number() == 5);
    CHECK(t == std::vector<std::string_view>{"last"});
    CHECK(!lines.next(t));
    CHECK(t.empty());

    // Without comments, every line (blank ones too) through next_line.
    canopy::line_reader raw("a#b\n\nc\n", '\0');
    std::string_view line;
    std::vector<std::string_view> seen;
    while (raw.next_line(line)) seen.push_back(line);
    CHECK(seen == std::vector<std::string_view>{"a#b", "", "c"});
    CHECK(canopy::skip_utf8_bom("\xEF\xBB\xBFv 1") == "v 1");
    CHECK(canopy::skip_utf8_bom("v 1") == "v 1");
    CHECK(message_of([] { canopy::check_path_length(std::string(5000, 'm'), "i.inst", 1, "mesh path"); }) ==
          "i.inst:1: mesh path of 5000 bytes is too long ('" + std::string(40, 'm') + "…')");
}
