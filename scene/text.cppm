// canopy.scene:text — the toolkit of the text loaders: lines, tokens, numbers and OBJ indices,
// read by one set of rules and refused with scene_error(file, line, problem).
//
//   line_reader lines(text);                  // lines from 1, '#' comments cut, blank lines skipped
//   while (lines.next(tokens)) ...            //   tokens: views into the text
//   parse_float(token, file, line)            // "bad number 'x'", "value 1e300 overflows a float"
//   resolve_obj_index(part, corner, n, ...)   // 1-based or negative (relative) OBJ index → 0-based
//   read_obj_corner(token, counts, ...)       // v, v/vt, v//vn, v/vt/vn, each index resolved
//
// Used by the benchmark formats (canopy.plugins.bench:formats: the OBJ subset, .inst), the OBJ and
// MTL reader (canopy.plugins.obj) and the checks of OpenMesh's text formats (canopy.plugins.openmesh).
//
// The rules (where the readers once differed, the strict one was kept):
//   blanks       space, tab, CR, VT and FF separate tokens; a line ends at LF. Text is checked to be
//                text first (require_text, canopy.scene:limits); a UTF-8 byte-order mark is
//                skipped where a format allows one (skip_utf8_bom).
//   float        [+|-] digits [. digits] [(e|E) [+|-] digits] (a digit before or after the point),
//                read straight to the nearest float (not through double, which can round twice),
//                as std::from_chars does. Not numbers: hexadecimal ("0x10"), a second sign ("+-1"),
//                trailing characters ("1.5f"). "inf", "infinity" and "nan" are numbers that are not
//                finite, and refused. A value beyond the float range (3.4e38, e.g. 1e300 or 1e999)
//                overflows a float, and is refused: finiteness is judged in float, not in double.
//                A value too small for a float becomes a denormal or a zero of its sign.
//   integer      [+|-] digits, within 64 bits (a value beyond is refused, not clamped).
//   OBJ index    an integer; 1 is the first element, -1 the last defined so far; 0 and indices
//                beyond the elements defined so far are refused.
//   OBJ corner   v, v/vt, v//vn or v/vt/vn: at most three parts, "v/" (an empty texture index
//                without a normal) refused.
// A token quoted in a message is cut to 40 bytes (excerpt, canopy.scene:error).
module;
#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>
export module canopy.scene:text;
import :error;

export namespace canopy {

// The characters that separate tokens on a line.
constexpr bool is_blank(char c) noexcept { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

// `s` without the blanks at either end.
constexpr std::string_view trim_blanks(std::string_view s) noexcept {
    while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
    while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
    return s;
}

// Splits `line` into its blank-separated tokens (views into `line`); `tokens` is cleared first.
inline void split_tokens(std::string_view line, std::vector<std::string_view>& tokens) {
    tokens.clear();
    std::size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && is_blank(line[i])) ++i;
        std::size_t const start = i;
        while (i < line.size() && !is_blank(line[i])) ++i;
        if (i > start) tokens.push_back(line.substr(start, i - start));
    }
}

// `text` without a leading UTF-8 byte-order mark.
constexpr std::string_view skip_utf8_bom(std::string_view text) noexcept {
    return text.starts_with("\xEF\xBB\xBF") ? text.substr(3) : text;
}

// The lines of a text, numbered from 1; `comment` (none when '\0') starts a comment that runs to
// the end of its line.
class line_reader {
public:
    explicit line_reader(std::string_view text, char comment = '#') noexcept : text_(text), comment_(comment) {}

    // The next line, its comment cut (blank lines too); false after the last.
    bool next_line(std::string_view& line) noexcept {
        if (position_ >= text_.size()) return false;
        std::size_t const end = std::min(text_.find('\n', position_), text_.size());
        line = text_.substr(position_, end - position_);
        position_ = std::min(end + 1, text_.size());
        ++number_;
        if (comment_ != '\0') line = line.substr(0, line.find(comment_));
        line_ = line;
        return true;
    }

    // The next line that holds tokens (comments and blank lines skipped), split into `tokens`.
    bool next(std::vector<std::string_view>& tokens) {
        std::string_view line;
        while (next_line(line)) {
            split_tokens(line, tokens);
            if (!tokens.empty()) return true;
        }
        tokens.clear();
        return false;
    }

    // The line last read (comment cut), its number (from 1; 0 before the first), and that number
    // as a scene_error's `where`.
    std::string_view line() const noexcept { return line_; }
    std::size_t number() const noexcept { return number_; }
    std::string where() const { return std::to_string(number_); }
    // Where the line after the one last read begins.
    std::size_t position() const noexcept { return position_; }

private:
    std::string_view text_, line_;
    char comment_;
    std::size_t position_ = 0, number_ = 0;
};

// The text after `token` on `line` (a view into it), blanks trimmed: names and paths may hold
// spaces. `token` must be a view into `line`.
inline std::string_view rest_after(std::string_view line, std::string_view token) noexcept {
    return trim_blanks(line.substr(std::size_t(token.data() + token.size() - line.data())));
}

// The text from `token` on (a view into `line`), blanks trimmed.
inline std::string_view rest_from(std::string_view line, std::string_view token) noexcept {
    return trim_blanks(line.substr(std::size_t(token.data() - line.data())));
}

// A token quoted in a message: 'token', cut to 40 bytes.
inline std::string quoted(std::string_view token) { return "'" + excerpt(token) + "'"; }

// What is wrong with a number token.
enum class number_problem : std::uint8_t { none, not_a_number, not_finite, overflows_float, not_an_integer, overflows_integer };

// "is not a number", "overflows a float", ... (empty for none).
constexpr char const* describe(number_problem p) noexcept {
    switch (p) {
    case number_problem::none: return "";
    case number_problem::not_a_number: return "is not a number";
    case number_problem::not_finite: return "is not a finite number";
    case number_problem::overflows_float: return "overflows a float";
    case number_problem::not_an_integer: return "is not an integer";
    case number_problem::overflows_integer: return "is beyond the 64-bit integer range";
    }
    return "";
}

template <typename T> struct number_token {
    T value{};
    number_problem problem = number_problem::none;
    explicit operator bool() const noexcept { return problem == number_problem::none; }
};

} // namespace canopy

namespace canopy::detail {

// A leading '+' dropped (std::from_chars reads none); "++1" and "+-1" keep theirs, and fail.
constexpr std::string_view without_plus(std::string_view t) noexcept {
    if (t.size() > 1 && t[0] == '+' && t[1] != '+' && t[1] != '-') t.remove_prefix(1);
    return t;
}

// Whether a decimal number (syntax already checked, from_chars' out of range) is large rather than
// tiny: the decimal exponent of its first non-zero digit is not negative.
constexpr bool large_magnitude(std::string_view t) noexcept {
    std::size_t i = t.empty() || (t[0] != '-' && t[0] != '+') ? 0 : 1;
    auto const digit = [&](std::size_t k) { return k < t.size() && t[k] >= '0' && t[k] <= '9'; };
    std::int64_t lead = 0; // decimal exponent of the first non-zero digit, before the explicit exponent
    bool nonzero = false;
    for (; digit(i); ++i)
        if (nonzero || t[i] != '0') nonzero = true, ++lead;
    if (nonzero) --lead;
    if (i < t.size() && t[i] == '.')
        for (++i; digit(i); ++i) {
            if (nonzero) continue;
            --lead;
            nonzero = t[i] != '0';
        }
    std::int64_t exponent = 0;
    if (i < t.size() && (t[i] == 'e' || t[i] == 'E')) {
        ++i;
        bool const negative = i < t.size() && t[i] == '-';
        if (i < t.size() && (t[i] == '-' || t[i] == '+')) ++i;
        for (; digit(i); ++i) exponent = std::min<std::int64_t>(exponent * 10 + (t[i] - '0'), std::int64_t(1) << 40);
        if (negative) exponent = -exponent;
    }
    return lead + exponent >= 0;
}

} // namespace canopy::detail

export namespace canopy {

// A token as a float, by the rules above; value is 0 when there is a problem.
inline number_token<float> read_float(std::string_view token) noexcept {
    std::string_view const t = detail::without_plus(token);
    float value = 0.0f;
    auto const [end, ec] = std::from_chars(t.data(), t.data() + t.size(), value);
    if (t.empty() || end != t.data() + t.size() || (ec != std::errc{} && ec != std::errc::result_out_of_range))
        return {0.0f, number_problem::not_a_number};
    if (ec == std::errc::result_out_of_range) {
        if (detail::large_magnitude(t)) return {0.0f, number_problem::overflows_float};
        return {t[0] == '-' ? -0.0f : 0.0f, number_problem::none};
    }
    if (!std::isfinite(value)) return {0.0f, number_problem::not_finite};
    return {value, number_problem::none};
}

// A token as a 64-bit integer, by the rules above; value is 0 when there is a problem.
inline number_token<std::int64_t> read_integer(std::string_view token) noexcept {
    std::string_view const t = detail::without_plus(token);
    std::int64_t value = 0;
    auto const [end, ec] = std::from_chars(t.data(), t.data() + t.size(), value);
    if (t.empty() || end != t.data() + t.size() || (ec != std::errc{} && ec != std::errc::result_out_of_range))
        return {0, number_problem::not_an_integer};
    if (ec == std::errc::result_out_of_range) return {0, number_problem::overflows_integer};
    return {value, number_problem::none};
}

// Whether a token is a decimal number by the float syntax above, whatever its value (values a
// reader reads and drops).
inline bool is_decimal_number(std::string_view token) noexcept {
    number_problem const p = read_float(token).problem;
    return p == number_problem::none || p == number_problem::overflows_float;
}

// The message for a number token with a problem: labelled "<what> 'token' <describe(p)>", or,
// with no label, "bad number 'token'", "number 'token' is not finite", "value token overflows a
// float", "bad integer 'token'", "integer 'token' is beyond the 64-bit integer range".
inline std::string number_message(std::string_view token, number_problem p, std::string_view what = {}) {
    if (!what.empty()) return std::string(what) + " " + quoted(token) + " " + describe(p);
    switch (p) {
    case number_problem::not_a_number: return "bad number " + quoted(token);
    case number_problem::not_finite: return "number " + quoted(token) + " is not finite";
    case number_problem::overflows_float: return "value " + excerpt(token) + " overflows a float";
    case number_problem::not_an_integer: return "bad integer " + quoted(token);
    default: return "integer " + quoted(token) + " " + describe(p);
    }
}

// `where` of a line number: "" for none (0).
inline std::string line_where(std::size_t line) { return line ? std::to_string(line) : std::string(); }

// A float token, or scene_error(file, where, number_message(token, problem, what)).
inline float parse_float(std::string_view token, std::string const& file, std::string const& where, std::string_view what) {
    number_token<float> const n = read_float(token);
    if (!n) throw scene_error(file, where, number_message(token, n.problem, what));
    return n.value;
}
inline float parse_float(std::string_view token, std::string const& file, std::size_t line) {
    number_token<float> const n = read_float(token);
    if (!n) throw scene_error(file, line_where(line), number_message(token, n.problem));
    return n.value;
}

// An integer token, or scene_error(file, where, number_message(token, problem, what)).
inline std::int64_t parse_integer(std::string_view token, std::string const& file, std::string const& where,
                                  std::string_view what) {
    number_token<std::int64_t> const n = read_integer(token);
    if (!n) throw scene_error(file, where, number_message(token, n.problem, what));
    return n.value;
}

// An OBJ index `part` (of `corner`, for messages) resolved against the `count` elements defined
// so far: 1-based, or negative (-1: the last); returns it 0-based. `what` and `plural` name the
// elements ("vertex", "vertices"). Errors: "bad vertex index 'x' in corner 'x/1'", "vertex index 0
// is not valid (OBJ indices start at 1)", "vertex index 9 is out of range (3 vertices so far)".
inline std::size_t resolve_obj_index(std::string_view part, std::string_view corner, std::size_t count, char const* what,
                                     char const* plural, std::string const& file, std::size_t line) {
    number_token<std::int64_t> const n = read_integer(part);
    if (!n)
        throw scene_error(file, line_where(line),
                          std::string("bad ") + what + " index " + quoted(part) + " in corner " + quoted(corner));
    if (n.value == 0)
        throw scene_error(file, line_where(line), std::string(what) + " index 0 is not valid (OBJ indices start at 1)");
    auto const defined = std::int64_t(count);
    std::int64_t const resolved = n.value > 0 ? n.value - 1 : defined + n.value;
    if (resolved < 0 || resolved >= defined)
        throw scene_error(file, line_where(line), std::string(what) + " index " + std::to_string(n.value) +
                                                      " is out of range (" + std::to_string(count) + " " + plural +
                                                      " so far)");
    return std::size_t(resolved);
}

// The elements an OBJ corner may refer to: those defined so far.
struct obj_counts {
    std::size_t vertices = 0, texcoords = 0, normals = 0;
};

// An OBJ face corner, its indices 0-based.
struct obj_corner {
    std::size_t v = 0;
    std::optional<std::size_t> vt, vn;
};

// A face corner (v, v/vt, v//vn or v/vt/vn), each index resolved against `counts`.
inline obj_corner read_obj_corner(std::string_view token, obj_counts const& counts, std::string const& file,
                                  std::size_t line) {
    std::size_t const slash1 = token.find('/');
    std::size_t const slash2 = slash1 == std::string_view::npos ? slash1 : token.find('/', slash1 + 1);
    if (slash2 != std::string_view::npos && token.find('/', slash2 + 1) != std::string_view::npos)
        throw scene_error(file, line_where(line), "corner " + quoted(token) + " has more than three parts");
    obj_corner c;
    c.v = resolve_obj_index(token.substr(0, slash1), token, counts.vertices, "vertex", "vertices", file, line);
    if (slash1 == std::string_view::npos) return c;
    std::string_view const vt =
        token.substr(slash1 + 1, slash2 == std::string_view::npos ? std::string_view::npos : slash2 - slash1 - 1);
    if (!vt.empty())
        c.vt = resolve_obj_index(vt, token, counts.texcoords, "texture coordinate", "texture coordinates", file, line);
    else if (slash2 == std::string_view::npos)
        throw scene_error(file, line_where(line), "corner " + quoted(token) + " has an empty texture coordinate index");
    if (slash2 != std::string_view::npos)
        c.vn = resolve_obj_index(token.substr(slash2 + 1), token, counts.normals, "normal", "normals", file, line);
    return c;
}

// Paths longer than this cannot name a file (Linux's PATH_MAX); longer ones are refused by length
// rather than quoted whole in a "not found".
inline constexpr std::size_t max_path_bytes = 4096;

// Throws scene_error(file, where, "<what> of N bytes is too long ('…')") for a path over
// max_path_bytes (`where`: a line number, or an element such as a JSON path).
inline void check_path_length(std::string_view path, std::string const& file, std::string const& where, std::string_view what) {
    if (path.size() > max_path_bytes)
        throw scene_error(file, where, std::string(what) + " of " + std::to_string(path.size()) + " bytes is too long (" +
                                           quoted(path) + ")");
}
inline void check_path_length(std::string_view path, std::string const& file, std::size_t line, std::string_view what) {
    check_path_length(path, file, line_where(line), what);
}

} // namespace canopy
