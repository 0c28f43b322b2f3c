// canopy.plugins.openmesh — implementation: checks of each format, then OpenMesh's readers
// through an importer that records every face as the reader hands it over.
module;
#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cfloat>
#include <climits>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <mutex>
#include <new>
#include <optional>
#include <span>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include <OpenMesh/Core/IO/IOManager.hh>
#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>
module canopy.plugins.openmesh;

namespace canopy {

namespace {

using om_mesh = OpenMesh::PolyMesh_ArrayKernelT<>;

// ---------------------------------------------------------------------------------------------
// Text helpers

std::string shown(std::string_view token) {
    constexpr std::size_t longest = 24;
    return "'" + std::string(token.substr(0, longest)) + (token.size() > longest ? "…'" : "'");
}

bool is_digit(char c) { return c >= '0' && c <= '9'; }

// A decimal number as C++ streams read one (std::num_get, which OpenMesh's text readers use):
// [+-] digits [. digits] [(e|E) [+-] digits], with a digit before the exponent. No "inf", "nan"
// or hexadecimal: a stream stops at those, and every read after it fails.
bool decimal_syntax(std::string_view t) {
    std::size_t i = 0, digits = 0;
    if (i < t.size() && (t[i] == '+' || t[i] == '-')) ++i;
    while (i < t.size() && is_digit(t[i])) ++i, ++digits;
    if (i < t.size() && t[i] == '.')
        for (++i; i < t.size() && is_digit(t[i]); ++i) ++digits;
    if (digits == 0) return false;
    if (i < t.size() && (t[i] == 'e' || t[i] == 'E')) {
        ++i;
        if (i < t.size() && (t[i] == '+' || t[i] == '-')) ++i;
        std::size_t const start = i;
        while (i < t.size() && is_digit(t[i])) ++i;
        if (i == start) return false;
    }
    return i == t.size();
}

bool names_infinity_or_nan(std::string_view t) {
    if (!t.empty() && (t.front() == '+' || t.front() == '-')) t.remove_prefix(1);
    std::string lower(t.substr(0, 8));
    for (char& c : lower) c = char(std::tolower(static_cast<unsigned char>(c)));
    return lower.starts_with("inf") || lower.starts_with("nan");
}

// A token read as a float by a stream: the value, or why the read fails. A value beyond the
// float range fails (the stream sets failbit, and OpenMesh's readers then read nothing more);
// one too small for a float becomes 0 or a denormal, as in the stream.
struct float_token {
    std::optional<float> value;
    std::string problem; // when !value: "is not a number", "is not a finite number", "overflows a float"
};

float_token read_float(std::string_view t) {
    if (!decimal_syntax(t))
        return {std::nullopt, names_infinity_or_nan(t) ? "is not a finite number" : "is not a number"};
    float v = 0.0f;
    if (t.size() < 64) {
        char buffer[64];
        std::memcpy(buffer, t.data(), t.size());
        buffer[t.size()] = '\0';
        v = std::strtof(buffer, nullptr);
    } else {
        v = std::strtof(std::string(t).c_str(), nullptr);
    }
    if (std::isinf(v)) return {std::nullopt, "overflows a float"};
    return {v, {}};
}

// An integer token ([+-] digits), as a stream reads one; a value beyond long long is clamped to
// its range (and then fails any range check).
std::optional<long long> read_integer(std::string_view t) {
    bool const negative = !t.empty() && t.front() == '-';
    if (!t.empty() && (t.front() == '+' || t.front() == '-')) t.remove_prefix(1);
    if (t.empty() || !std::all_of(t.begin(), t.end(), is_digit)) return std::nullopt;
    unsigned long long v = 0;
    auto const [end, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
    if (ec == std::errc::result_out_of_range || v > static_cast<unsigned long long>(LLONG_MAX))
        return negative ? LLONG_MIN : LLONG_MAX;
    if (ec != std::errc() || end != t.data() + t.size()) return std::nullopt;
    return negative ? -static_cast<long long>(v) : static_cast<long long>(v);
}

// Any number strtod reads (values of PLY properties OpenMesh skips).
bool any_number(std::string_view t) {
    if (!t.empty() && t.front() == '+') t.remove_prefix(1);
    double v = 0.0;
    auto const [end, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
    return !t.empty() && (ec == std::errc() || ec == std::errc::result_out_of_range) && end == t.data() + t.size();
}

std::uint32_t little_endian_u32(char const* p) {
    auto const b = [&](int i) { return std::uint32_t(static_cast<unsigned char>(p[i])); };
    return b(0) | b(1) << 8 | b(2) << 16 | b(3) << 24;
}

float little_endian_float(char const* p) { return std::bit_cast<float>(little_endian_u32(p)); }

// Lines of a text with their numbers (from 1); `comment` starts a comment to the end of a line.
class line_reader {
public:
    line_reader(std::string_view text, char comment) : text_(text), comment_(comment) {}

    // The next line that holds tokens (comments and blank lines skipped), split into tokens.
    bool next(std::vector<std::string_view>& tokens) {
        while (position_ < text_.size()) {
            std::size_t const end = std::min(text_.find('\n', position_), text_.size());
            std::string_view line = text_.substr(position_, end - position_);
            position_ = std::min(end + 1, text_.size());
            ++number_;
            if (comment_ != '\0') line = line.substr(0, line.find(comment_));
            split(line, tokens);
            if (!tokens.empty()) return true;
        }
        return false;
    }
    std::size_t number() const { return number_; }
    std::string where() const { return std::to_string(number_); }
    // Where the line after the one last read begins.
    std::size_t position() const { return position_; }

    static void split(std::string_view line, std::vector<std::string_view>& tokens) {
        tokens.clear();
        std::size_t i = 0;
        auto const space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; };
        while (i < line.size()) {
            while (i < line.size() && space(line[i])) ++i;
            std::size_t const start = i;
            while (i < line.size() && !space(line[i])) ++i;
            if (i > start) tokens.push_back(line.substr(start, i - start));
        }
    }

private:
    std::string_view text_;
    char comment_;
    std::size_t position_ = 0, number_ = 0;
};

// ---------------------------------------------------------------------------------------------
// Checks before OpenMesh. OpenMesh's readers trust the file: a count they reserve or loop over, a
// value their stream cannot read (after which every read fails while the loops go on), a layout
// they misread. Each check below walks the whole file as the OpenMesh reader of its format will
// read it, and returns the number of faces the file declares.

// OpenMesh's OFF header: [ST][C][N][4][n]OFF, "BINARY" after one more character for binary files.
struct off_header {
    bool texcoords = false, colours = false, normals = false, higher_dimension = false, binary = false;
};

std::optional<off_header> parse_off_header(std::string_view line) {
    off_header h;
    std::size_t p = 0;
    if (line.substr(p, 2) == "ST") h.texcoords = true, p += 2;
    if (p < line.size() && line[p] == 'C') h.colours = true, ++p;
    if (p < line.size() && line[p] == 'N') h.normals = true, ++p;
    if (p < line.size() && line[p] == '4') h.higher_dimension = true, ++p;
    if (p < line.size() && line[p] == 'n') h.higher_dimension = true, ++p;
    if (line.substr(p, 3) != "OFF") return std::nullopt;
    h.binary = line.size() >= p + 10 && line.substr(p + 4, 6) == "BINARY";
    return h;
}

struct file_checker {
    std::string file; // for messages
    std::string_view data;
    resource_limits limits = default_limits();

    [[noreturn]] void fail(std::string const& where, std::string const& problem) const {
        throw scene_error(file, where, problem);
    }

    void check_counts(std::string const& where, std::uint64_t vertices, std::uint64_t faces) const {
        check_limit(file, where, vertices, limits.max_triangles, "vertices", "--max-triangles");
        check_limit(file, where, faces, limits.max_triangles, "faces", "--max-triangles");
    }

    // A value OpenMesh reads as a float from text.
    float text_float(std::string_view token, std::string const& where, std::string const& what) const {
        float_token const f = read_float(token);
        if (!f.value) fail(where, what + " " + shown(token) + " " + f.problem);
        return *f.value;
    }

    // An integer OpenMesh reads from text, in [low, high].
    long long text_integer(std::string_view token, std::string const& where, std::string const& what, long long low,
                           long long high) const {
        auto const v = read_integer(token);
        if (!v) fail(where, what + " " + shown(token) + " is not an integer");
        if (*v < low || *v > high)
            fail(where, what + " " + std::to_string(*v) + " is out of range [" + std::to_string(low) + ", " +
                            std::to_string(high) + "]");
        return *v;
    }

    // --- OFF. ASCII: header, counts, every vertex and face line; `clean` receives the checked
    // text for import_off_text (comments and blank lines removed, one record per line, a face line
    // without colours cut after its last index). Binary: see check_off_binary.
    std::optional<std::size_t> check_off(std::string& clean) const {
        // OpenMesh decides between text and binary from the file's first line alone.
        std::string_view const first = data.substr(0, data.find('\n'));
        if (auto const h = parse_off_header(first); h && h->binary && !h->higher_dimension)
            return check_off_binary(*h, first.size());

        line_reader lines(data, '#');
        std::vector<std::string_view> t;
        if (!lines.next(t)) fail("", "file holds no OFF header");
        std::string_view const keyword = t[0];
        auto const header = parse_off_header(keyword);
        if (keyword.size() < 3 || keyword.substr(keyword.size() - 3) != "OFF")
            fail(lines.where(), "expected an OFF header, found " + shown(keyword));
        if (header && header->higher_dimension)
            fail(lines.where(), "OFF files of other than three dimensions (" + shown(keyword) + ") are not supported");
        if (!header || keyword.size() != keyword.find("OFF") + 3)
            fail(lines.where(), "unknown OFF header " + shown(keyword) + " (OpenMesh reads [ST][C][N]OFF)");
        if (t.size() > 1 && t[1] == "BINARY")
            fail(lines.where(), "'" + std::string(keyword) + " BINARY' must be the file's first line, one space apart");
        if (t.size() > 1)
            fail(lines.where(), "the OFF header line holds more than its keyword (OpenMesh reads the counts from the next line)");
        clean.append(keyword).push_back('\n');

        std::vector<std::string_view> counts;
        if (!lines.next(counts)) fail(lines.where(), "file ends before the OFF counts");
        if (counts.size() != 3)
            fail(lines.where(), "the OFF counts line must hold three numbers (vertices faces edges), it holds " +
                                    std::to_string(counts.size()));
        std::array<long long, 3> n{};
        for (std::size_t i = 0; i < 3; ++i) {
            auto const v = read_integer(counts[i]);
            if (!v || *v < 0) fail(lines.where(), "OFF count " + shown(counts[i]) + " is not a count");
            if (*v > static_cast<long long>(UINT32_MAX))
                fail(lines.where(), "OFF count " + std::to_string(*v) + " is more than OpenMesh reads (2^32 - 1)");
            n[i] = *v;
        }
        long long const vertices = n[0], faces = n[1];
        check_counts(lines.where(), std::uint64_t(vertices), std::uint64_t(faces));
        for (std::size_t i = 0; i < 3; ++i) clean.append(counts[i]).push_back(i < 2 ? ' ' : '\n');

        auto const append = [&](std::span<std::string_view const> tokens) {
            for (std::size_t i = 0; i < tokens.size(); ++i) clean.append(tokens[i]).push_back(i + 1 < tokens.size() ? ' ' : '\n');
        };
        std::size_t const needed = header->normals ? 6 : 3;
        for (long long v = 0; v < vertices; ++v) {
            if (!lines.next(t))
                fail(lines.where(), "file ends after " + std::to_string(v) + " of " + std::to_string(vertices) + " vertices");
            std::string const vertex = "vertex " + std::to_string(v);
            if (t.size() < needed)
                fail(lines.where(), vertex + " has " + std::to_string(t.size()) + " values, needs " + std::to_string(needed));
            for (std::size_t i = 0; i < needed; ++i) text_float(t[i], lines.where(), vertex + (i < 3 ? ": coordinate" : ": normal"));
            if (header->texcoords) check_off_texcoords(std::span(t).subspan(needed), header->colours, lines.where(), vertex);
            append(t);
        }
        for (long long f = 0; f < faces; ++f) {
            if (!lines.next(t))
                fail(lines.where(), "file ends after " + std::to_string(f) + " of " + std::to_string(faces) + " faces");
            std::string const face = "face " + std::to_string(f);
            auto const corners = read_integer(t[0]);
            if (!corners) fail(lines.where(), face + ": corner count " + shown(t[0]) + " is not an integer");
            if (*corners < 3) fail(lines.where(), face + " has " + std::to_string(*corners) + " corners (at least 3 needed)");
            if (std::uint64_t(*corners) + 1 > t.size())
                fail(lines.where(), face + " announces " + std::to_string(*corners) + " corners but lists " +
                                        std::to_string(t.size() - 1));
            for (std::size_t k = 1; k <= std::size_t(*corners); ++k) {
                auto const index = read_integer(t[k]);
                if (!index) fail(lines.where(), face + ": vertex index " + shown(t[k]) + " is not an integer");
                if (*index < 0 || *index >= vertices)
                    fail(lines.where(), face + ": vertex index " + std::to_string(*index) + " is out of range (" +
                                            std::to_string(vertices) + " vertices)");
            }
            append(std::span(t).first(header->colours ? t.size() : std::size_t(*corners) + 1));
        }
        return std::size_t(faces);
    }

    // The texture coordinates of an STOFF vertex line: OpenMesh reads them after the colour
    // (COFF), whose kind it guesses from the number of values left and a '.' in the first.
    void check_off_texcoords(std::span<std::string_view const> rest, bool colours, std::string const& where,
                             std::string const& vertex) const {
        if (rest.size() < 2) fail(where, vertex + ": texture coordinates missing (STOFF needs two after the position)");
        std::size_t first = 0;
        if (colours) {
            std::size_t const colour = rest.size() - 2;
            if (colour > 4) fail(where, vertex + ": " + std::to_string(colour) + " colour values (at most 4)");
            bool const decimals = colour >= 3 && rest[0].find('.') != std::string_view::npos;
            for (std::size_t i = 0; colour >= 3 && i < colour; ++i) {
                if (decimals) text_float(rest[i], where, vertex + ": colour");
                else text_integer(rest[i], where, vertex + ": colour", INT_MIN, INT_MAX);
            }
            first = colour;
        }
        for (std::size_t i = first; i < first + 2; ++i) text_float(rest[i], where, vertex + ": texture coordinate");
    }

    // Binary OFF (OpenMesh's layout, little-endian): the header line, u32 vertex, face and edge
    // counts; per vertex 3 float coordinates, [3 float normal (N)], [3 u32 colour (C)], [2 float
    // texture coordinates (ST)]; per face a u32 corner count and the u32 indices.
    std::size_t check_off_binary(off_header const& h, std::size_t header_end) const {
        if (header_end >= data.size()) fail("", "file ends after the OFF BINARY header line");
        std::size_t pos = header_end + 1;
        auto const left = [&] { return data.size() - pos; };
        if (left() < 12) fail("", "file ends before the OFF BINARY counts (12 bytes)");
        std::uint32_t const vertices = little_endian_u32(data.data() + pos);
        std::uint32_t const faces = little_endian_u32(data.data() + pos + 4);
        pos += 12;
        check_counts("", vertices, faces);
        std::size_t const record = 12 + (h.normals ? 12 : 0) + (h.colours ? 12 : 0) + (h.texcoords ? 8 : 0);
        if (vertices > left() / record)
            fail("", "the header declares " + std::to_string(vertices) + " vertices of " + std::to_string(record) +
                         " bytes, more than the " + std::to_string(left()) + " bytes after it hold");
        if (faces > (left() - std::size_t(vertices) * record) / 16)
            fail("", "the header declares " + std::to_string(faces) + " faces of at least 16 bytes, more than the " +
                         std::to_string(left() - std::size_t(vertices) * record) + " bytes after the vertices hold");
        for (std::uint32_t v = 0; v < vertices; ++v, pos += record) {
            auto const finite = [&](std::size_t offset, std::size_t count, char const* what) {
                for (std::size_t k = 0; k < count; ++k)
                    if (!std::isfinite(little_endian_float(data.data() + pos + offset + 4 * k)))
                        fail("vertex " + std::to_string(v), std::string(what) + " has a value that is not finite");
            };
            finite(0, 3, "position");
            if (h.normals) finite(12, 3, "normal");
            if (h.texcoords) finite(record - 8, 2, "texture coordinate");
        }
        for (std::uint32_t f = 0; f < faces; ++f) {
            std::string const where = "face " + std::to_string(f);
            if (left() < 4) fail(where, "file ends after " + std::to_string(f) + " of " + std::to_string(faces) + " faces");
            std::uint32_t const corners = little_endian_u32(data.data() + pos);
            pos += 4;
            if (corners < 3) fail(where, "has " + std::to_string(corners) + " corners (at least 3 needed)");
            if (corners > left() / 4)
                fail(where, "announces " + std::to_string(corners) + " corners, more than the file's remaining " +
                                std::to_string(left()) + " bytes hold");
            for (std::uint32_t k = 0; k < corners; ++k, pos += 4) {
                std::uint32_t const index = little_endian_u32(data.data() + pos);
                if (index >= vertices)
                    fail(where, "vertex index " + std::to_string(index) + " is out of range (" + std::to_string(vertices) +
                                    " vertices)");
            }
        }
        return faces;
    }

    // --- PLY: the header as OpenMesh's reader parses it (a stream of words), then every element
    // OpenMesh reads walked value by value (ASCII words or binary values).
    enum class ply_use {
        skip,       // read and dropped (other properties)
        coordinate, // vertex x, y, z: read as a float
        number,     // vertex normal and texture coordinate, float colours: read as a float
        integer,    // colours of integer types: read as an int
        corners,    // the face's vertex_indices list
    };
    struct ply_property {
        std::string name;
        std::string type;       // value type
        std::string count_type; // list count type; empty for a scalar
        ply_use use = ply_use::skip;
    };
    struct ply_element {
        std::string name;
        std::uint64_t count = 0;
        std::vector<ply_property> properties;
        bool read = false; // read by OpenMesh (the elements up to the face element)
    };

    static int ply_size(std::string_view type) {
        if (type == "char" || type == "uchar" || type == "int8" || type == "uint8") return 1;
        if (type == "short" || type == "ushort" || type == "int16" || type == "uint16") return 2;
        if (type == "int" || type == "uint" || type == "int32" || type == "uint32" || type == "float" || type == "float32")
            return 4;
        if (type == "double" || type == "float64") return 8;
        return 0;
    }
    static bool ply_float_type(std::string_view type) {
        return type == "float" || type == "float32" || type == "double" || type == "float64";
    }

    // Binary values of a PLY body, in the file's byte order.
    struct ply_binary_source {
        std::string_view body;
        bool big_endian;
        std::size_t offset = 0;

        void end_entry(std::string const&) {}

        std::optional<double> value(std::string_view type) {
            int const size = ply_size(type);
            if (std::size_t(size) > body.size() - offset) return std::nullopt;
            std::array<unsigned char, 8> b{};
            std::memcpy(b.data(), body.data() + offset, std::size_t(size));
            offset += std::size_t(size);
            if (big_endian != (std::endian::native == std::endian::big)) std::reverse(b.begin(), b.begin() + size);
            auto const as = [&]<typename T>(T) {
                T v;
                std::memcpy(&v, b.data(), sizeof v);
                return double(v);
            };
            if (type == "char" || type == "int8") return as(std::int8_t{});
            if (type == "uchar" || type == "uint8") return as(std::uint8_t{});
            if (type == "short" || type == "int16") return as(std::int16_t{});
            if (type == "ushort" || type == "uint16") return as(std::uint16_t{});
            if (type == "int" || type == "int32") return as(std::int32_t{});
            if (type == "uint" || type == "uint32") return as(std::uint32_t{});
            if (type == "float" || type == "float32") return as(float{});
            return as(double{});
        }
        // How a value is read; nullopt when it cannot be (a message then, else empty).
        std::optional<double> read(std::string_view type, ply_use use, std::string& problem) {
            auto const v = value(type);
            if (v && (use == ply_use::coordinate || use == ply_use::number) && !std::isfinite(float(*v)))
                problem = std::isfinite(*v) ? "overflows a float" : "is not finite";
            return v;
        }
        // Binary data has no lines: the messages name the element and its index themselves.
        std::string where() const { return {}; }
        std::string describe(double v) const {
            std::ostringstream s;
            s.precision(9);
            s << v;
            return s.str();
        }
    };

    // ASCII values of a PLY body: whitespace-separated words, with line numbers.
    struct ply_ascii_source {
        file_checker const& checker;
        std::string_view body;
        std::size_t first_line;
        std::size_t offset = 0, line = 0;
        std::string_view last;

        std::optional<double> read(std::string_view, ply_use use, std::string& problem) {
            auto const space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v'; };
            while (offset < body.size() && space(body[offset])) line += body[offset++] == '\n';
            if (offset == body.size()) return std::nullopt;
            std::size_t const start = offset;
            while (offset < body.size() && !space(body[offset])) ++offset;
            last = body.substr(start, offset - start);
            if (use == ply_use::coordinate || use == ply_use::number) {
                float_token const f = read_float(last);
                if (!f.value) problem = f.problem == "is not a finite number" ? "is not finite" : f.problem;
                return f.value ? double(*f.value) : 0.0;
            }
            if (use == ply_use::integer || use == ply_use::corners) {
                auto const v = read_integer(last);
                if (!v) problem = "is not an integer";
                else if (use == ply_use::integer && (*v < INT_MIN || *v > INT_MAX)) problem = "overflows an int";
                return v ? double(*v) : 0.0;
            }
            if (!any_number(last)) checker.fail(where(), "value " + shown(last) + " is not a number");
            double v = 0.0;
            std::from_chars(last.data() + (last.front() == '+'), last.data() + last.size(), v);
            return v;
        }
        std::string where() const { return std::to_string(first_line + line); }
        std::string describe(double) const { return shown(last); }
        // One entry a line (the PLY format): a value left on an entry's line is an error, not the
        // next entry's first value (which would shift every value after it).
        void end_entry(std::string const& entry) {
            std::size_t k = offset;
            while (k < body.size() && (body[k] == ' ' || body[k] == '\t' || body[k] == '\r')) ++k;
            if (k < body.size() && body[k] != '\n') {
                std::size_t end = k;
                while (end < body.size() && body[end] != '\n' && body[end] != ' ' && body[end] != '\t' && body[end] != '\r') ++end;
                checker.fail(where(), entry + ": more values on its line than its properties take (next: " +
                                          shown(body.substr(k, end - k)) + ")");
            }
        }
    };

    template <typename Source>
    void walk_ply(std::vector<ply_element> const& elements, Source& source) const {
        std::uint64_t vertices = 0;
        for (auto const& e : elements)
            if (e.name == "vertex") vertices = e.count;
        for (auto const& e : elements) {
            for (std::uint64_t i = 0; i < e.count; ++i) {
                std::string const entry = e.name + " " + std::to_string(i);
                auto const read = [&](std::string_view type, ply_use use, std::string const& what) {
                    std::string problem;
                    auto const v = source.read(type, use, problem);
                    if (!v)
                        fail(source.where(), "file ends in " + e.name + " " + std::to_string(i) + " of " +
                                                 std::to_string(e.count));
                    if (!problem.empty()) fail(source.where(), entry + ": " + what + " = " + source.describe(*v) + " " + problem);
                    return *v;
                };
                for (auto const& p : e.properties) {
                    if (p.count_type.empty()) {
                        read(p.type, p.use, p.use == ply_use::coordinate ? "coordinate " + p.name : p.name);
                        continue;
                    }
                    ply_use const count_use = p.use == ply_use::corners ? ply_use::corners : ply_use::skip;
                    double const n = read(p.count_type, count_use, p.name + " list length");
                    if (!(n >= 0.0) || n != std::floor(n))
                        fail(source.where(), entry + ": list length " + source.describe(n) + " is not a count");
                    bool const corners = p.use == ply_use::corners;
                    if (corners && n < 3.0)
                        fail(source.where(), "face " + std::to_string(i) + " has " + std::to_string(long(n)) +
                                                 " corners (at least 3 needed)");
                    for (std::uint64_t k = 0; k < static_cast<std::uint64_t>(n); ++k) {
                        double const v = read(p.type, count_use, p.name);
                        if (corners && (v < 0.0 || v >= double(vertices) || v != std::floor(v)))
                            fail(source.where(), "face " + std::to_string(i) + ": vertex index " + source.describe(v) +
                                                     " is out of range (" + std::to_string(vertices) + " vertices)");
                    }
                }
                source.end_entry(entry);
            }
        }
    }

    // How OpenMesh reads property p of element e (and whether it can).
    void classify_ply_property(ply_element const& e, ply_property& p, bool binary, std::string const& where) const {
        static constexpr std::array<std::string_view, 3> coordinates{"x", "y", "z"};
        static constexpr std::array<std::string_view, 7> numbers{"nx", "ny", "nz", "u", "v", "s", "t"};
        static constexpr std::array<std::string_view, 7> vertex_colours{"red",           "green",          "blue", "alpha",
                                                                        "diffuse_red",   "diffuse_green",  "diffuse_blue"};
        auto const in = [&](auto const& names) { return std::find(names.begin(), names.end(), p.name) != names.end(); };
        std::string const what = e.name + " property " + shown(p.name);
        bool const colour = (e.name == "vertex" && in(vertex_colours)) ||
                            (e.name == "face" && (p.name == "red" || p.name == "green" || p.name == "blue" || p.name == "alpha"));
        if (!p.count_type.empty()) {
            if (e.name == "face" && (p.name == "vertex_indices" || p.name == "vertex_index")) {
                p.use = ply_use::corners;
                if (binary && ply_float_type(p.type))
                    fail(where, what + ": binary vertex indices of type " + shown(p.type) + " are not read by OpenMesh");
            } else if (e.read) {
                fail(where, what + ": OpenMesh reads no list property other than the face's vertex_indices");
            }
            return;
        }
        if (e.name == "vertex" && in(coordinates)) p.use = ply_use::coordinate;
        else if (e.name == "vertex" && in(numbers)) p.use = ply_use::number;
        else if (colour) p.use = (p.type == "float" || p.type == "float32") ? ply_use::number : ply_use::integer;
        if (!binary) return;
        if ((p.use == ply_use::coordinate || p.use == ply_use::number) && !ply_float_type(p.type))
            fail(where, what + " of type " + shown(p.type) + " is not read by OpenMesh from binary files (float or double needed)");
        if (p.use == ply_use::integer && ply_float_type(p.type))
            fail(where, what + " of type " + shown(p.type) + " is not read by OpenMesh from binary files (an integer type or float needed)");
    }

    std::optional<std::size_t> check_ply() const {
        // Line 1, as OpenMesh reads it (one line, trimmed).
        std::string_view const first = data.substr(0, data.find('\n'));
        std::vector<std::string_view> t;
        line_reader::split(first, t);
        if (t.size() != 1 || (t[0] != "ply" && t[0] != "PLY")) fail("1", "not a PLY file (its first line is not 'ply')");
        line_reader lines(data, '\0');
        lines.next(t);

        // The format line: OpenMesh reads the three words after line 1 as it.
        if (!lines.next(t)) fail("", "PLY header has no format line");
        std::string const format_line = lines.where();
        if (t.size() != 3 || t[0] != "format") fail(format_line, "the line after 'ply' must be 'format <type> <version>'");
        std::string const format(t[1]);
        if (format != "ascii" && format != "binary_little_endian" && format != "binary_big_endian")
            fail(format_line, "unknown PLY format " + shown(t[1]));
        text_float(t[2], format_line, "PLY version");
        bool const binary = format != "ascii";
        // Where OpenMesh's stream stands before it reads end_header (for the binary seek below).
        std::size_t stream_position = std::size_t(t.back().data() + t.back().size() - data.data());

        std::vector<ply_element> elements;
        std::size_t body_start = std::string_view::npos;
        while (lines.next(t)) {
            std::string const where = lines.where();
            if (t[0] == "comment") {
                stream_position = lines.position();
                continue;
            }
            if (t[0] == "end_header") {
                if (t.size() > 1) fail(where, "end_header must be alone on its line");
                body_start = lines.position();
                break;
            }
            stream_position = std::size_t(t.back().data() + t.back().size() - data.data());
            if (t[0] == "obj_info") {
                // OpenMesh reads each word of the line as a keyword of its own.
                for (std::size_t i = 1; i < t.size(); ++i)
                    if (t[i] == "element" || t[i] == "property" || t[i] == "end_header" || t[i] == "comment")
                        fail(where, "obj_info line holds the keyword " + shown(t[i]) + ", which OpenMesh would act on");
            } else if (t[0] == "element") {
                if (t.size() != 3) fail(where, "element line needs a name and a count");
                auto const count = read_integer(t[2]);
                if (!count || *count < 0) fail(where, "element line needs a name and a count");
                if (*count > static_cast<long long>(UINT32_MAX))
                    fail(where, "element " + shown(t[1]) + ": count " + std::to_string(*count) +
                                    " is more than OpenMesh reads (2^32 - 1)");
                for (auto const& e : elements)
                    if (e.name == t[1] && (e.name == "vertex" || e.name == "face")) fail(where, "a second " + e.name + " element");
                elements.push_back({std::string(t[1]), std::uint64_t(*count), {}, false});
            } else if (t[0] == "property") {
                if (elements.empty()) fail(where, "property before any element");
                bool const list = t.size() == 5 && t[1] == "list";
                if (!(list || t.size() == 3)) fail(where, "malformed property line");
                ply_property p{std::string(t.back()), std::string(list ? t[3] : t[1]), list ? std::string(t[2]) : "", ply_use::skip};
                if (ply_size(p.type) == 0 || (list && ply_size(p.count_type) == 0))
                    fail(where, "unknown PLY type in property " + shown(p.name));
                if (list && p.count_type != "uchar" && p.count_type != "uint8" && p.count_type != "uint16" && p.count_type != "int")
                    fail(where, "list " + shown(p.name) + ": count type " + shown(p.count_type) +
                                    " is not one OpenMesh reads (uchar, uint8, uint16 or int)");
                for (auto const& q : elements.back().properties)
                    if (q.name == p.name) fail(where, elements.back().name + " property " + shown(p.name) + " appears twice");
                elements.back().properties.push_back(std::move(p));
            } else {
                fail(where, "unknown PLY header line " + shown(t[0]));
            }
        }
        if (body_start == std::string_view::npos) fail("", "PLY header has no end_header line");

        // Which elements OpenMesh reads (those up to the face element), and how.
        auto const vertex = std::find_if(elements.begin(), elements.end(), [](auto const& e) { return e.name == "vertex"; });
        auto const face = std::find_if(elements.begin(), elements.end(), [](auto const& e) { return e.name == "face"; });
        if (vertex == elements.end()) fail("", "PLY header has no vertex element");
        if (face != elements.end() && face < vertex) fail("", "the face element comes before the vertex element");
        for (auto e = elements.begin(); e != elements.end(); ++e) {
            e->read = face == elements.end() || e <= face;
            if (e->read && e->count > 0 && e->properties.empty())
                fail("", "element " + shown(e->name) + " has " + std::to_string(e->count) + " entries but no properties");
            for (auto& p : e->properties) classify_ply_property(*e, p, binary, "");
        }
        for (char const* c : {"x", "y", "z"})
            if (std::none_of(vertex->properties.begin(), vertex->properties.end(), [&](auto const& p) { return p.name == c; }))
                fail("", std::string("the vertex element has no property ") + c);
        if (face != elements.end() && face->count > 0 &&
            std::none_of(face->properties.begin(), face->properties.end(), [](auto const& p) { return p.use == ply_use::corners; }))
            fail("", "the face element has no vertex_indices list");
        std::uint64_t const faces = face == elements.end() ? 0 : face->count;
        check_counts("", vertex->count, faces);

        // The counts against the data: at least one byte per value (binary: its size; lists:
        // their count, and three indices per face), and one separator between words.
        std::string_view const body = data.substr(body_start);
        std::uint64_t available = binary ? body.size() : (body.size() + 1) / 2;
        for (auto const& e : elements) {
            std::uint64_t least = 0;
            for (auto const& p : e.properties) {
                std::uint64_t const value = binary ? std::uint64_t(ply_size(p.type)) : 1;
                least += p.count_type.empty() ? value
                                               : (binary ? std::uint64_t(ply_size(p.count_type)) : 1) +
                                                     (p.use == ply_use::corners ? 3 * value : 0);
            }
            if (least > 0 && e.count > available / least)
                fail("", "element " + shown(e.name) + " declares " + std::to_string(e.count) + " entries of at least " +
                             std::to_string(least) + (binary ? " bytes" : " values") + ", more than the " +
                             std::to_string(body.size()) + " bytes after the header hold (truncated?)");
            available -= least * e.count;
        }

        if (binary) {
            // OpenMesh seeks to the binary data 12 bytes after where its stream stood before it
            // read end_header (14 after "\r\n"): right only for "<last word>\nend_header\n".
            bool const crlf = data.substr(stream_position, 2) == "\r\n";
            std::size_t const openmesh_start = stream_position + (crlf ? 14 : 12);
            if (openmesh_start != body_start)
                fail("", "OpenMesh would read the binary data from byte " + std::to_string(openmesh_start) +
                             ", not from byte " + std::to_string(body_start) +
                             " where it begins (it needs the header to end in '<last word>\\nend_header\\n': "
                             "no comment, blank line or trailing space before end_header)");
            ply_binary_source source{body, format == "binary_big_endian"};
            walk_ply(elements, source);
        } else {
            ply_ascii_source source{*this, body, lines.number() + 1, 0, 0, {}};
            walk_ply(elements, source);
        }
        return std::size_t(faces);
    }

    // OpenMesh's STL reader merges corners closer than FLT_MIN in every coordinate into one
    // vertex and skips a facet two of whose corners are merged, before its importer sees it.
    static bool stl_facet_is_degenerate(std::array<float, 9> const& c) {
        auto const same = [&](std::size_t a, std::size_t b) {
            for (std::size_t k = 0; k < 3; ++k)
                if (!(std::fabs(c[3 * a + k] - c[3 * b + k]) <= FLT_MIN)) return false;
            return true;
        };
        return same(0, 1) || same(0, 2) || same(1, 2);
    }
    mutable std::size_t stl_degenerate = 0;

    // --- STL: binary when the size matches its triangle count (OpenMesh's test), else ASCII
    // beginning with "solid".
    std::optional<std::size_t> check_stl() const {
        constexpr std::size_t header = 84, record = 50;
        std::optional<std::size_t> announced;
        if (data.size() >= header) {
            std::uint32_t const n = little_endian_u32(data.data() + 80);
            announced = n;
            if (header + record * std::size_t(n) == data.size()) {
                check_counts("", 3 * std::uint64_t(n), n);
                for (std::size_t i = 0; i < n; ++i) {
                    std::array<float, 9> corners{};
                    for (std::size_t c = 0; c < 9; ++c) {
                        corners[c] = little_endian_float(data.data() + header + record * i + 12 + 4 * c);
                        if (!std::isfinite(corners[c]))
                            fail("triangle " + std::to_string(i),
                                 "corner " + std::to_string(c / 3) + " has a coordinate that is not finite");
                    }
                    stl_degenerate += stl_facet_is_degenerate(corners);
                }
                return std::size_t(n);
            }
        }
        std::size_t const first = data.find_first_not_of(" \t\r\n");
        if (first == std::string_view::npos || data.substr(first, 5) != "solid") {
            if (announced)
                fail("", "not an STL file: as binary STL its header announces " + std::to_string(*announced) +
                             " triangles (" + std::to_string(header + record * *announced) + " bytes), the file has " +
                             std::to_string(data.size()) + " bytes (truncated?); as ASCII STL it does not begin with 'solid'");
            fail("", "not an STL file: too short for binary STL (" + std::to_string(data.size()) +
                         " bytes, the header alone has 84) and not ASCII STL (it does not begin with 'solid')");
        }
        // OpenMesh reads the three lines after each line that holds "outer" (or "OUTER") as the
        // facet's corners: "<word> x y z".
        std::vector<std::string_view> t;
        std::size_t facets = 0, position = 0, line = 0;
        auto const next_line = [&] {
            std::size_t const end = std::min(data.find('\n', position), data.size());
            std::string_view const text = data.substr(position, end - position);
            position = end + 1;
            ++line;
            return text;
        };
        while (position < data.size()) {
            std::string_view const text = next_line();
            if (text.find("outer") == std::string_view::npos && text.find("OUTER") == std::string_view::npos) continue;
            std::string const facet = "facet " + std::to_string(facets);
            std::array<float, 9> corners{};
            for (std::size_t c = 0; c < 3; ++c) {
                if (position >= data.size())
                    fail(std::to_string(line), "file ends in " + facet + " (3 vertex lines follow 'outer loop')");
                line_reader::split(next_line(), t);
                std::string const where = std::to_string(line);
                if (t.size() != 4 || t[0] != "vertex")
                    fail(where, facet + ": expected 'vertex x y z' (OpenMesh reads the 3 lines after 'outer loop' as corners)");
                for (std::size_t i = 0; i < 3; ++i) corners[3 * c + i] = text_float(t[i + 1], where, "coordinate");
            }
            stl_degenerate += stl_facet_is_degenerate(corners);
            ++facets;
            check_counts("", 3 * std::uint64_t(facets), facets);
        }
        // The last line that is not blank opens with "endsolid": an ASCII STL cut after its last
        // complete facet is truncated, not a smaller mesh.
        std::size_t const last = data.find_last_not_of(" \t\r\n");
        std::size_t const start = data.find_last_of('\n', last) == std::string_view::npos ? 0 : data.find_last_of('\n', last) + 1;
        std::string_view const tail = data.substr(start, last + 1 - start);
        if (tail.substr(tail.find_first_not_of(" \t"), 8) != "endsolid")
            fail(std::to_string(line), "ASCII STL ends before its 'endsolid' line (truncated?)");
        return facets;
    }

    // --- OBJ: v, vt and vn values read as floats, face corners in range; returns the number of f lines.
    std::optional<std::size_t> check_obj() const {
        line_reader lines(data, '#');
        std::vector<std::string_view> t;
        std::size_t positions = 0, texcoords = 0, normals = 0, faces = 0;
        auto const check_index = [&](std::string_view token, std::size_t defined, char const* what) {
            auto const i = read_integer(token);
            if (!i) fail(lines.where(), std::string(what) + " index " + shown(token) + " is not an integer");
            long long const n = static_cast<long long>(defined);
            if (*i == 0 || *i > n || *i < -n)
                fail(lines.where(), std::string(what) + " index " + std::to_string(*i) + " is out of range (" +
                                        std::to_string(defined) + " defined before this line)");
        };
        auto const values = [&](std::size_t needed, char const* what) {
            if (t.size() < needed + 1)
                fail(lines.where(), std::string(what) + " needs " + std::to_string(needed) + " values");
            for (std::size_t i = 1; i <= needed; ++i) text_float(t[i], lines.where(), std::string(what) + " value");
        };
        while (lines.next(t)) {
            if (t[0] == "v") {
                if (t.size() < 4) fail(lines.where(), "vertex needs three coordinates");
                for (std::size_t i = 1; i < 4; ++i) text_float(t[i], lines.where(), "vertex coordinate");
                ++positions;
            } else if (t[0] == "vt") {
                values(2, "texture coordinate");
                ++texcoords;
            } else if (t[0] == "vn") {
                values(3, "normal");
                ++normals;
            } else if (t[0] == "f") {
                if (t.size() < 4)
                    fail(lines.where(), "face has " + std::to_string(t.size() - 1) + " corners (at least 3 needed)");
                for (std::size_t k = 1; k < t.size(); ++k) {
                    std::string_view c = t[k];
                    std::array<std::string_view, 3> parts{};
                    for (int part = 0; part < 3; ++part) {
                        std::size_t const slash = c.find('/');
                        parts[std::size_t(part)] = c.substr(0, slash);
                        if (slash == std::string_view::npos) break;
                        c.remove_prefix(slash + 1);
                    }
                    check_index(parts[0], positions, "vertex");
                    if (!parts[1].empty()) check_index(parts[1], texcoords, "texture coordinate");
                    if (!parts[2].empty()) check_index(parts[2], normals, "normal");
                }
                ++faces;
            }
        }
        check_counts("", positions, faces);
        return faces;
    }

    // --- OM: the header (magic, counts); OpenMesh reserves for its counts before reading, so they
    // are checked against the file's size (a vertex's position alone takes 12 bytes).
    std::optional<std::size_t> check_om() const {
        if (data.size() < 16 || data.substr(0, 2) != "OM")
            fail("", "not an OpenMesh .om file (no 16-byte header beginning with 'OM')");
        std::uint32_t const vertices = little_endian_u32(data.data() + 4), faces = little_endian_u32(data.data() + 8),
                            edges = little_endian_u32(data.data() + 12);
        check_counts("", vertices, faces);
        std::uint64_t const least = 16 + 12 * std::uint64_t(vertices) + std::uint64_t(faces) + std::uint64_t(edges);
        if (least > data.size())
            fail("", "the header declares " + std::to_string(vertices) + " vertices, " + std::to_string(faces) +
                         " faces and " + std::to_string(edges) + " edges, more than the file's " +
                         std::to_string(data.size()) + " bytes hold");
        return faces;
    }
};

// ---------------------------------------------------------------------------------------------
// The importer: OpenMesh's own, plus a record of every face and per-corner attribute as the
// reader hands them over.

struct face_record {
    std::vector<int> corners; // vertex indices as the file gives them
    std::vector<std::optional<OpenMesh::Vec2f>> uvs;
    std::vector<std::optional<OpenMesh::Vec3f>> normals;
    bool nonmanifold = false;
};

class recording_importer : public OpenMesh::IO::ImporterT<om_mesh> {
    using base = OpenMesh::IO::ImporterT<om_mesh>;

public:
    explicit recording_importer(om_mesh& m) : base(m), mesh_(m) {}

    std::vector<face_record> faces;
    std::size_t halfedge_faces = 0; // faces the reader built from halfedges (OM files)
    bool vertex_normals = false, vertex_texcoords = false;

    OpenMesh::FaceHandle add_face(VHandles const& indices) override {
        face_record r;
        r.corners.reserve(indices.size());
        for (auto v : indices) r.corners.push_back(v.idx());
        // Normals set since the previous face belong to this face's corners (OBJ's f v//n).
        r.normals.resize(indices.size());
        for (std::size_t k = 0; k < indices.size(); ++k) {
            auto it = pending_normals_.find(indices[k].idx());
            if (it != pending_normals_.end()) r.normals[k] = it->second;
        }
        pending_normals_.clear();
        r.uvs.resize(indices.size());
        std::size_t const vertices_before = mesh_.n_vertices();
        OpenMesh::FaceHandle const fh = base::add_face(indices);
        r.nonmanifold = fh.is_valid() && mesh_.n_vertices() != vertices_before;
        if (fh.is_valid()) face_of_handle_[fh.idx()] = faces.size();
        faces.push_back(std::move(r));
        return fh;
    }

    OpenMesh::FaceHandle add_face(OpenMesh::HalfedgeHandle heh) override {
        ++halfedge_faces;
        return base::add_face(heh);
    }

    void add_face_texcoords(OpenMesh::FaceHandle fh, OpenMesh::VertexHandle first,
                            std::vector<OpenMesh::Vec2f> const& uvs) override {
        auto it = face_of_handle_.find(fh.idx());
        if (it == face_of_handle_.end() || uvs.empty()) return;
        face_record& r = faces[it->second];
        // uvs[i] belongs to the corner i places after `first` (ImporterT's convention).
        auto const start = std::find(r.corners.begin(), r.corners.end(), first.idx());
        std::size_t const s = start == r.corners.end() ? 0 : std::size_t(start - r.corners.begin());
        for (std::size_t i = 0; i < uvs.size() && i < r.corners.size(); ++i) r.uvs[(s + i) % r.corners.size()] = uvs[i];
    }

    void set_normal(OpenMesh::VertexHandle vh, OpenMesh::Vec3f const& n) override {
        vertex_normals = true;
        pending_normals_[vh.idx()] = n;
        base::set_normal(vh, n);
    }
    void set_normal(OpenMesh::VertexHandle vh, OpenMesh::Vec3d const& n) override {
        set_normal(vh, OpenMesh::Vec3f(n));
    }
    void set_texcoord(OpenMesh::VertexHandle vh, OpenMesh::Vec2f const& uv) override {
        vertex_texcoords = true;
        base::set_texcoord(vh, uv);
    }

private:
    om_mesh& mesh_;
    std::map<int, OpenMesh::Vec3f> pending_normals_;
    std::map<int, std::size_t> face_of_handle_;
};

// OpenMesh's message streams (omerr, omlog) captured for the lifetime of this object: their
// stream buffers are swapped for a string buffer. (Connecting and disconnecting targets of
// OpenMesh's multiplexing buffer would leak one object per call in OpenMesh 9.)
class captured_omerr {
public:
    captured_omerr() : old_err_(::omerr().rdbuf(&text_)), old_log_(::omlog().rdbuf(&text_)) {}
    ~captured_omerr() {
        ::omerr().rdbuf(old_err_);
        ::omlog().rdbuf(old_log_);
    }
    captured_omerr(captured_omerr const&) = delete;
    captured_omerr& operator=(captured_omerr const&) = delete;

    // The distinct messages, in order, on one line.
    std::string messages() const {
        std::string out, line;
        std::istringstream in(text_.str());
        std::vector<std::string> seen;
        while (std::getline(in, line)) {
            if (line.empty() || std::find(seen.begin(), seen.end(), line) != seen.end()) continue;
            seen.push_back(line);
            out += (out.empty() ? "" : "; ") + line;
        }
        return out;
    }

private:
    std::stringbuf text_;
    std::streambuf* old_err_;
    std::streambuf* old_log_;
};

std::mutex& openmesh_mutex() {
    static std::mutex m;
    return m;
}

vec3<float> to_vec3(OpenMesh::Vec3f const& v) { return {v[0], v[1], v[2]}; }
vec2<float> to_vec2(OpenMesh::Vec2f const& v) { return {v[0], v[1]}; }

} // namespace

namespace {

// What the checks found: the faces the file declares (none for a format that declares none) and
// the text OpenMesh is given for an ASCII OFF file.
struct checked_input {
    std::optional<std::size_t> faces;
    std::string clean_off;
    std::size_t stl_degenerate = 0;
};

checked_input check_input(std::string_view data, std::string const& file, std::string const& ext) {
    if (data.find_first_not_of(" \t\r\n") == std::string_view::npos) throw scene_error(file, "", "file is empty");
    file_checker const checker{file, data};
    checked_input out;
    if (ext == ".off") out.faces = checker.check_off(out.clean_off);
    else if (ext == ".ply") out.faces = checker.check_ply();
    else if (ext == ".stl") out.faces = checker.check_stl();
    else if (ext == ".obj") out.faces = checker.check_obj();
    else if (ext == ".om") out.faces = checker.check_om();
    else throw scene_error(file, "", "extension '" + ext + "' is not one OpenMesh reads here (.ply .off .stl .om .obj)");
    out.stl_degenerate = checker.stl_degenerate;
    return out;
}

// ASCII OFF, checked and cleaned by check_off, into OpenMesh's importer as OpenMesh's OFF reader
// would put it: the reader itself cannot be given it, since it takes the header's [ST][C][N]
// flags from the last file it was asked about by name (a stream read keeps another file's).
bool import_off_text(std::string_view clean, recording_importer& importer) {
    line_reader lines(clean, '\0');
    std::vector<std::string_view> t;
    lines.next(t);
    off_header const h = *parse_off_header(t[0]);
    lines.next(t);
    std::size_t const vertices = std::size_t(*read_integer(t[0])), faces = std::size_t(*read_integer(t[1]));
    auto const number = [](std::string_view token) { return *read_float(token).value; };
    std::size_t const values = h.normals ? 6 : 3;
    std::vector<OpenMesh::VertexHandle> corners;
    for (std::size_t v = 0; v < vertices; ++v) {
        lines.next(t);
        OpenMesh::VertexHandle const vh = importer.add_vertex(OpenMesh::Vec3f(number(t[0]), number(t[1]), number(t[2])));
        if (h.normals) importer.set_normal(vh, OpenMesh::Vec3f(number(t[3]), number(t[4]), number(t[5])));
        if (h.texcoords) {
            // After the colour (COFF: the last two values), else right after the position.
            std::size_t const at = h.colours ? t.size() - 2 : values;
            importer.set_texcoord(vh, OpenMesh::Vec2f(number(t[at]), number(t[at + 1])));
        }
    }
    for (std::size_t f = 0; f < faces; ++f) {
        lines.next(t);
        std::size_t const n = std::size_t(*read_integer(t[0]));
        corners.clear();
        for (std::size_t k = 1; k <= n; ++k) corners.push_back(OpenMesh::VertexHandle(int(*read_integer(t[k]))));
        importer.add_face(corners);
    }
    return true;
}

openmesh_read_result read_checked(std::filesystem::path const& path) {
    std::string const file = path.string();
    std::string const ext = extension_of(path);

    checked_input checked;
    {
        std::uint64_t const size = require_regular_file(path);
        std::string data(std::size_t(size), '\0');
        std::ifstream in(path, std::ios::binary);
        if (!in) throw scene_error(file, "", "cannot be opened");
        in.read(data.data(), std::streamsize(size));
        if (std::uint64_t(in.gcount()) != size) throw scene_error(file, "", "cannot be read (it changed while being read?)");
        checked = check_input(data, file, ext);
    } // checked: OpenMesh reads the file itself (ASCII OFF: clean_off, through import_off_text)
    std::optional<std::size_t> declared = checked.faces;
    std::string const& clean_off = checked.clean_off;

    om_mesh mesh;
    mesh.request_vertex_normals();
    mesh.request_vertex_texcoords2D();
    mesh.request_halfedge_texcoords2D();
    recording_importer importer(mesh);
    OpenMesh::IO::Options options = OpenMesh::IO::Options::VertexNormal | OpenMesh::IO::Options::VertexTexCoord |
                                    OpenMesh::IO::Options::FaceTexCoord;
    std::string messages;
    {
        std::lock_guard const lock(openmesh_mutex());
        captured_omerr capture;
        bool ok = false;
        if (clean_off.empty()) ok = OpenMesh::IO::IOManager().read(file, importer, options);
        else ok = import_off_text(clean_off, importer);
        messages = capture.messages();
        if (!ok)
            throw scene_error(file, "", "OpenMesh cannot read it" + (messages.empty() ? std::string() : ": " + messages));
    }

    openmesh_read_result result;
    mesh_data& out = result.mesh;
    out.name = path.stem().string();
    out.source = file;

    // Faces as recorded, or (OM files, built from halfedges) as the mesh holds them.
    std::vector<face_record>& faces = importer.faces;
    bool const from_halfedges = faces.empty() && importer.halfedge_faces > 0;
    bool normals = importer.vertex_normals, vertex_uvs = importer.vertex_texcoords;
    bool corner_uvs = std::any_of(faces.begin(), faces.end(), [](face_record const& r) {
        return std::any_of(r.uvs.begin(), r.uvs.end(), [](auto const& uv) { return uv.has_value(); });
    });
    if (from_halfedges) {
        normals = options.vertex_has_normal();
        vertex_uvs = options.vertex_has_texcoord();
        corner_uvs = options.face_has_texcoord();
        for (auto fh : mesh.faces()) {
            face_record r;
            for (auto heh : mesh.fh_range(fh)) {
                r.corners.push_back(mesh.to_vertex_handle(heh).idx());
                r.uvs.emplace_back(corner_uvs ? std::optional(mesh.texcoord2D(heh)) : std::nullopt);
                r.normals.emplace_back(std::nullopt);
            }
            faces.push_back(std::move(r));
        }
    }

    std::size_t dropped = 0;
    std::string reason;
    for (std::size_t f = 0; f < faces.size(); ++f) {
        auto const& c = faces[f].corners;
        bool const in_range = std::all_of(c.begin(), c.end(), [&](int v) { return v >= 0 && std::size_t(v) < mesh.n_vertices(); });
        if (c.size() < 3 || !in_range) {
            if (dropped++ == 0)
                reason = "face " + std::to_string(f) + (c.size() < 3 ? " has fewer than 3 corners" : " has a vertex index out of range");
        }
    }
    if (declared && ext == ".stl") *declared -= std::min(*declared, checked.stl_degenerate);
    if (dropped > 0 || (declared && *declared != faces.size())) {
        std::size_t const expected = declared ? *declared : faces.size();
        std::size_t const lost = expected >= faces.size() ? expected - faces.size() + dropped : dropped;
        throw scene_error(file, "", std::to_string(lost) + " of " + std::to_string(expected) +
                                        " faces were dropped while reading" + (reason.empty() ? "" : " (" + reason + ")") +
                                        (messages.empty() ? "" : "; OpenMesh says: " + messages));
    }

    // Positions: the file's vertices (copies OpenMesh made for non-manifold faces come after
    // them and are not referenced by the recorded faces).
    std::size_t vertex_count = 0;
    for (auto const& r : faces)
        for (int v : r.corners) vertex_count = std::max(vertex_count, std::size_t(v) + 1);
    if (from_halfedges || faces.empty()) vertex_count = mesh.n_vertices();
    else {
        // Vertices read before the first copy: everything up to the largest index a face uses,
        // and any unreferenced vertices the file declares after it.
        std::size_t copies = 0;
        for (auto const& r : faces)
            if (r.nonmanifold) copies += r.corners.size();
        vertex_count = std::max(vertex_count, mesh.n_vertices() - copies);
    }
    out.positions.reserve(vertex_count);
    for (std::size_t v = 0; v < vertex_count; ++v)
        out.positions.push_back(to_vec3(mesh.point(OpenMesh::VertexHandle(int(v)))));

    bool const has_uvs = corner_uvs || vertex_uvs;
    result.vertex_normals = normals;
    result.texcoords = has_uvs;
    result.faces = faces.size();
    result.degenerate_faces = checked.stl_degenerate;
    std::vector<vec3<float>> points; // the corners of the face being triangulated
    for (auto const& r : faces) {
        std::size_t const n = r.corners.size();
        result.polygons += n > 3;
        result.nonmanifold_faces += r.nonmanifold;
        std::vector<int> sorted = r.corners;
        std::sort(sorted.begin(), sorted.end());
        result.degenerate_faces += std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end();

        auto const uv_at = [&](std::size_t k) {
            if (r.uvs[k]) return to_vec2(*r.uvs[k]);
            if (vertex_uvs) return to_vec2(mesh.texcoord2D(OpenMesh::VertexHandle(r.corners[k])));
            return vec2<float>{0.0f, 0.0f};
        };
        auto const normal_at = [&](std::size_t k) {
            if (r.normals[k]) return to_vec3(*r.normals[k]);
            return to_vec3(mesh.normal(OpenMesh::VertexHandle(r.corners[k])));
        };
        // Triangle t of the face, given by its corners' positions in the face.
        auto const emit = [&](std::array<std::uint32_t, 3> const& t) {
            out.triangles.push_back({std::uint32_t(r.corners[t[0]]), std::uint32_t(r.corners[t[1]]), std::uint32_t(r.corners[t[2]])});
            if (has_uvs) out.uvs.push_back({uv_at(t[0]), uv_at(t[1]), uv_at(t[2])});
            if (normals) out.normals.push_back({normal_at(t[0]), normal_at(t[1]), normal_at(t[2])});
        };
        if (n == 3) {
            emit({0, 1, 2});
            continue;
        }
        points.clear();
        for (int v : r.corners) points.push_back(out.positions[std::size_t(v)]);
        polygon_triangles const cut = triangulate_polygon(points);
        result.concave_polygons += cut.ear_clipped;
        if (cut.fanned_fallback && out.fanned_faces++ == 0)
            out.first_fanned = "face " + std::to_string(std::size_t(&r - faces.data()));
        for (auto const& t : cut.triangles) emit(t);
    }
    return result;
}

} // namespace

std::optional<std::size_t> check_openmesh_input(std::string_view data, std::string const& file, std::string const& ext) {
    return check_input(data, file, ext).faces;
}

openmesh_read_result read_openmesh(std::filesystem::path const& path) {
    try {
        return read_checked(path);
    } catch (std::bad_alloc const&) {
        throw scene_error(path.string(), "", "out of memory while reading");
    }
}

node_id load_openmesh(scene& s, std::filesystem::path const& file, node_id parent) {
    openmesh_read_result r = read_openmesh(file);
    node_id const group = s.add_group(parent, file.filename().string());
    std::string const name = r.mesh.name;
    std::uint32_t const mesh = s.add_mesh(std::move(r.mesh));
    s.add_mesh_node(group, mesh, name);
    s.at(group).source = file.string();
    return group;
}

void register_openmesh_plugin(registry& r) {
    for (char const* ext : {".ply", ".off", ".stl", ".om", ".obj"})
        r.add_loader(ext, "openmesh", "triangle mesh through OpenMesh (polygons triangulated)",
                     [](scene& s, std::filesystem::path const& file, node_id parent, registry const&) {
                         return load_openmesh(s, file, parent);
                     });
}

} // namespace canopy
