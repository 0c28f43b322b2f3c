// canopy.plugins.openmesh:checks — the checks of each format before OpenMesh reads a file (see
// openmesh_plugin.cppm for what they refuse and why). No OpenMesh header is needed here: each
// check walks the file's bytes as OpenMesh's reader of its format will read them. Text is read by
// canopy.scene:text's rules (lines, tokens, numbers, OBJ corners); the one place a format needs
// more (PLY's ASCII body is one stream of words across lines) reads words itself and numbers by
// those rules.
module;
#include <algorithm>
#include <array>
#include <bit>
#include <cfloat>
#include <climits>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <optional>
#include <span>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>
module canopy.plugins.openmesh:checks;
import canopy.scene;

namespace canopy::openmesh_checks {

std::uint32_t little_endian_u32(char const* p) {
    auto const b = [&](int i) { return std::uint32_t(static_cast<unsigned char>(p[i])); };
    return b(0) | b(1) << 8 | b(2) << 16 | b(3) << 24;
}

float little_endian_float(char const* p) { return std::bit_cast<float>(little_endian_u32(p)); }

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
        return parse_float(token, file, where, what);
    }

    // An integer OpenMesh reads from text, in [low, high].
    long long text_integer(std::string_view token, std::string const& where, std::string const& what, long long low,
                           long long high) const {
        std::int64_t const v = parse_integer(token, file, where, what);
        if (v < low || v > high)
            fail(where, what + " " + std::to_string(v) + " is out of range [" + std::to_string(low) + ", " +
                            std::to_string(high) + "]");
        return v;
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
            fail(lines.where(), "expected an OFF header, found " + quoted(keyword));
        if (header && header->higher_dimension)
            fail(lines.where(), "OFF files of other than three dimensions (" + quoted(keyword) + ") are not supported");
        if (!header || keyword.size() != keyword.find("OFF") + 3)
            fail(lines.where(), "unknown OFF header " + quoted(keyword) + " (OpenMesh reads [ST][C][N]OFF)");
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
            if (!v || v.value < 0) fail(lines.where(), "OFF count " + quoted(counts[i]) + " is not a count");
            if (v.value > static_cast<long long>(UINT32_MAX))
                fail(lines.where(), "OFF count " + std::to_string(v.value) + " is more than OpenMesh reads (2^32 - 1)");
            n[i] = v.value;
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
            std::int64_t const corners = parse_integer(t[0], file, lines.where(), face + ": corner count");
            if (corners < 3) fail(lines.where(), face + " has " + std::to_string(corners) + " corners (at least 3 needed)");
            if (std::uint64_t(corners) + 1 > t.size())
                fail(lines.where(), face + " announces " + std::to_string(corners) + " corners but lists " +
                                        std::to_string(t.size() - 1));
            for (std::size_t k = 1; k <= std::size_t(corners); ++k) {
                std::int64_t const index = parse_integer(t[k], file, lines.where(), face + ": vertex index");
                if (index < 0 || index >= vertices)
                    fail(lines.where(), face + ": vertex index " + std::to_string(index) + " is out of range (" +
                                            std::to_string(vertices) + " vertices)");
            }
            append(std::span(t).first(header->colours ? t.size() : std::size_t(corners) + 1));
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

        std::optional<double> read(std::string_view type, ply_use use, std::string& problem) {
            auto const space = [](char c) { return is_blank(c) || c == '\n'; };
            while (offset < body.size() && space(body[offset])) line += body[offset++] == '\n';
            if (offset == body.size()) return std::nullopt;
            std::size_t const start = offset;
            while (offset < body.size() && !space(body[offset])) ++offset;
            last = body.substr(start, offset - start);
            if (use == ply_use::coordinate || use == ply_use::number) {
                number_token<float> const f = read_float(last);
                if (!f) problem = f.problem == number_problem::not_finite ? "is not finite" : canopy::describe(f.problem);
                return double(f.value);
            }
            // Integers: corners, integer colours, and the values (list lengths among them) of the
            // integer-typed properties OpenMesh reads and drops.
            if (use == ply_use::integer || use == ply_use::corners || !ply_float_type(type)) {
                number_token<std::int64_t> const v = read_integer(last);
                if (!v) problem = canopy::describe(v.problem);
                else if (use == ply_use::integer && (v.value < INT_MIN || v.value > INT_MAX)) problem = "overflows an int";
                return double(v.value);
            }
            // Dropped values of float types: any decimal number.
            if (!is_decimal_number(last)) checker.fail(where(), "value " + quoted(last) + " is not a number");
            return double(read_float(last).value);
        }
        std::string where() const { return std::to_string(first_line + line); }
        std::string describe(double) const { return quoted(last); }
        // One entry a line (the PLY format): a value left on an entry's line is an error, not the
        // next entry's first value (which would shift every value after it).
        void end_entry(std::string const& entry) {
            std::size_t k = offset;
            while (k < body.size() && (body[k] == ' ' || body[k] == '\t' || body[k] == '\r')) ++k;
            if (k < body.size() && body[k] != '\n') {
                std::size_t end = k;
                while (end < body.size() && body[end] != '\n' && body[end] != ' ' && body[end] != '\t' && body[end] != '\r') ++end;
                checker.fail(where(), entry + ": more values on its line than its properties take (next: " +
                                          quoted(body.substr(k, end - k)) + ")");
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
        std::string const what = e.name + " property " + quoted(p.name);
        bool const colour = (e.name == "vertex" && in(vertex_colours)) ||
                            (e.name == "face" && (p.name == "red" || p.name == "green" || p.name == "blue" || p.name == "alpha"));
        if (!p.count_type.empty()) {
            if (e.name == "face" && (p.name == "vertex_indices" || p.name == "vertex_index")) {
                p.use = ply_use::corners;
                if (binary && ply_float_type(p.type))
                    fail(where, what + ": binary vertex indices of type " + quoted(p.type) + " are not read by OpenMesh");
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
            fail(where, what + " of type " + quoted(p.type) + " is not read by OpenMesh from binary files (float or double needed)");
        if (p.use == ply_use::integer && ply_float_type(p.type))
            fail(where, what + " of type " + quoted(p.type) + " is not read by OpenMesh from binary files (an integer type or float needed)");
    }

    std::optional<std::size_t> check_ply() const {
        // Line 1, as OpenMesh reads it (one line, trimmed).
        std::string_view const first = data.substr(0, data.find('\n'));
        std::vector<std::string_view> t;
        split_tokens(first, t);
        if (t.size() != 1 || (t[0] != "ply" && t[0] != "PLY")) fail("1", "not a PLY file (its first line is not 'ply')");
        line_reader lines(data, '\0');
        lines.next(t);

        // The format line: OpenMesh reads the three words after line 1 as it.
        if (!lines.next(t)) fail("", "PLY header has no format line");
        std::string const format_line = lines.where();
        if (t.size() != 3 || t[0] != "format") fail(format_line, "the line after 'ply' must be 'format <type> <version>'");
        std::string const format(t[1]);
        if (format != "ascii" && format != "binary_little_endian" && format != "binary_big_endian")
            fail(format_line, "unknown PLY format " + quoted(t[1]));
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
                        fail(where, "obj_info line holds the keyword " + quoted(t[i]) + ", which OpenMesh would act on");
            } else if (t[0] == "element") {
                if (t.size() != 3) fail(where, "element line needs a name and a count");
                auto const count = read_integer(t[2]);
                if (!count || count.value < 0) fail(where, "element line needs a name and a count");
                if (count.value > static_cast<long long>(UINT32_MAX))
                    fail(where, "element " + quoted(t[1]) + ": count " + std::to_string(count.value) +
                                    " is more than OpenMesh reads (2^32 - 1)");
                for (auto const& e : elements)
                    if (e.name == t[1] && (e.name == "vertex" || e.name == "face")) fail(where, "a second " + e.name + " element");
                elements.push_back({std::string(t[1]), std::uint64_t(count.value), {}, false});
            } else if (t[0] == "property") {
                if (elements.empty()) fail(where, "property before any element");
                bool const list = t.size() == 5 && t[1] == "list";
                if (!(list || t.size() == 3)) fail(where, "malformed property line");
                ply_property p{std::string(t.back()), std::string(list ? t[3] : t[1]), list ? std::string(t[2]) : "", ply_use::skip};
                if (ply_size(p.type) == 0 || (list && ply_size(p.count_type) == 0))
                    fail(where, "unknown PLY type in property " + quoted(p.name));
                if (list && p.count_type != "uchar" && p.count_type != "uint8" && p.count_type != "uint16" && p.count_type != "int")
                    fail(where, "list " + quoted(p.name) + ": count type " + quoted(p.count_type) +
                                    " is not one OpenMesh reads (uchar, uint8, uint16 or int)");
                for (auto const& q : elements.back().properties)
                    if (q.name == p.name) fail(where, elements.back().name + " property " + quoted(p.name) + " appears twice");
                elements.back().properties.push_back(std::move(p));
            } else {
                fail(where, "unknown PLY header line " + quoted(t[0]));
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
                fail("", "element " + quoted(e->name) + " has " + std::to_string(e->count) + " entries but no properties");
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
                fail("", "element " + quoted(e.name) + " declares " + std::to_string(e.count) + " entries of at least " +
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
        std::size_t facets = 0;
        line_reader lines(data, '\0');
        std::string_view text;
        while (lines.next_line(text)) {
            if (text.find("outer") == std::string_view::npos && text.find("OUTER") == std::string_view::npos) continue;
            std::string const facet = "facet " + std::to_string(facets);
            std::array<float, 9> corners{};
            for (std::size_t c = 0; c < 3; ++c) {
                if (!lines.next_line(text))
                    fail(lines.where(), "file ends in " + facet + " (3 vertex lines follow 'outer loop')");
                split_tokens(text, t);
                std::string const where = lines.where();
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
            fail(lines.where(), "ASCII STL ends before its 'endsolid' line (truncated?)");
        return facets;
    }

    // --- OBJ: v, vt and vn values read as floats, face corners (canopy.scene:text's OBJ corners) in
    // range; returns the number of f lines. OpenMesh's OBJ reader does not skip a UTF-8 byte-order
    // mark: it would drop the first statement, so such a file is refused.
    std::optional<std::size_t> check_obj() const {
        if (data.starts_with("\xEF\xBB\xBF"))
            fail("1", "the file begins with a UTF-8 byte-order mark, which OpenMesh's OBJ reader does not skip "
                      "(load it with the \"obj\" plugin)");
        line_reader lines(data, '#');
        std::vector<std::string_view> t;
        obj_counts defined;
        std::size_t faces = 0;
        auto const values = [&](std::size_t needed, char const* what) {
            if (t.size() < needed + 1)
                fail(lines.where(), std::string(what) + " needs " + std::to_string(needed) + " values");
            for (std::size_t i = 1; i <= needed; ++i) text_float(t[i], lines.where(), std::string(what) + " value");
        };
        while (lines.next(t)) {
            if (t[0] == "v") {
                if (t.size() < 4) fail(lines.where(), "vertex needs three coordinates");
                for (std::size_t i = 1; i < 4; ++i) text_float(t[i], lines.where(), "vertex coordinate");
                ++defined.vertices;
            } else if (t[0] == "vt") {
                values(2, "texture coordinate");
                ++defined.texcoords;
            } else if (t[0] == "vn") {
                values(3, "normal");
                ++defined.normals;
            } else if (t[0] == "f") {
                if (t.size() < 4)
                    fail(lines.where(), "face has " + std::to_string(t.size() - 1) + " corners (at least 3 needed)");
                for (std::size_t k = 1; k < t.size(); ++k) read_obj_corner(t[k], defined, file, lines.number());
                ++faces;
            }
        }
        check_counts("", defined.vertices, faces);
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

// What the checks found: the faces the file declares (none for a format that declares none) and
// the text OpenMesh is given for an ASCII OFF file.
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

} // namespace canopy::openmesh_checks
