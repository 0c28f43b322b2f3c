// The command line of `canopy`: options and their values (options.hpp).
#include "options.hpp"
#include <algorithm>
#include <charconv>
#include <cmath>
#include <limits>
#include <system_error>

namespace cli {

// The resource-limit options of every command; defaults from canopy::resource_limits.
char const* const limits_usage =
    "limits (checked before anything is allocated; a file over a limit is refused, naming it):\n"
    "  --max-file-bytes N  bytes of one input file (default 4294967296 = 4 GiB)\n"
    "  --max-texels N      texels of one image, and pixels of a rendered image (default 67108864\n"
    "                      = 2^26, 1 GiB as float RGBA)\n"
    "  --max-total-texels N\n"
    "                      texels of all the scene's images together (default 268435456 = 2^28,\n"
    "                      4 GiB as float RGBA)\n"
    "  --max-triangles N   triangles (and vertices) of the scene's meshes together, each mesh\n"
    "                      counted once (default 268435456 = 2^28)\n"
    "  --max-placements N  mesh placements after instances are flattened (default 4194304 = 2^22)\n"
    "  --max-depth N       nesting depth of the scene graph and of a file's structures (default 4096)\n";

// --quality, for the commands that build BVHs of a scene's meshes.
char const* const quality_usage =
    "  --quality Q         build quality of the mesh BVHs: automatic (default: high for meshes of\n"
    "                      long thin triangles, else fast), fast (object splits) or high (spatial\n"
    "                      splits too: faster tracing of long thin triangles, slower builds, more\n"
    "                      memory)\n";

std::string quote(std::string_view text) {
    std::string out = "'";
    for (char c : text.substr(0, 40)) out += c >= 0x20 && c < 0x7f ? c : '?';
    return out + (text.size() > 40 ? "...'" : "'");
}

namespace {

// Every command's limit options.
constexpr option_spec limit_options[] = {
    {"--max-file-bytes"}, {"--max-texels"},     {"--max-total-texels"},
    {"--max-triangles"},  {"--max-placements"}, {"--max-depth"}};

} // namespace

// Options (given once, unless repeatable; a value is the next argument, non-empty, not an option)
// and positional arguments ("--" ends the options). "--help" or "-h" anywhere stops parsing.
arguments parse_arguments(std::span<char*> args, std::vector<option_spec> specs) {
    specs.insert(specs.end(), std::begin(limit_options), std::end(limit_options));
    arguments out;
    bool options_ended = false;
    for (std::size_t i = 0; i < args.size(); ++i) {
        std::string const a = args[i];
        if (options_ended || a.size() < 2 || a[0] != '-') {
            if (a.empty()) throw usage_error("an empty argument (a file name was expected)");
            out.positional.push_back(a);
            continue;
        }
        if (a == "--") {
            options_ended = true;
            continue;
        }
        if (a == "--help" || a == "-h") {
            out.help = true;
            return out;
        }
        auto const spec = std::find_if(specs.begin(), specs.end(), [&](option_spec const& o) { return o.name == a; });
        if (spec == specs.end()) throw usage_error("unknown option " + quote(a));
        if (!spec->repeatable && out.has(a)) throw usage_error("option " + a + " given more than once");
        if (!spec->takes_value) {
            out.options[a].emplace_back();
            continue;
        }
        if (i + 1 >= args.size()) throw usage_error("option " + a + " needs a value");
        std::string const value = args[++i];
        if (value.empty()) throw usage_error("option " + a + " has an empty value");
        if (value.starts_with("--")) throw usage_error("option " + a + " needs a value, not the option " + quote(value));
        out.options[a].push_back(value);
    }
    return out;
}

std::string required(arguments const& args, std::string_view name) {
    if (!args.has(name)) throw usage_error("missing " + std::string(name));
    return args.value(name);
}

// The whole text as a number in [lo, hi], or nothing.
std::optional<std::uint64_t> whole_number(std::string_view text, std::uint64_t lo, std::uint64_t hi) {
    std::uint64_t v = 0;
    auto const [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size() || v < lo || v > hi) return std::nullopt;
    return v;
}

std::uint64_t whole_option(arguments const& args, std::string_view name, std::uint64_t lo, std::uint64_t hi) {
    std::string const& text = args.value(name);
    auto const v = whole_number(text, lo, hi);
    if (!v)
        throw usage_error(std::string(name) + " must be a whole number from " + std::to_string(lo) + " to " +
                          std::to_string(hi) + ", not " + quote(text));
    return *v;
}

// A finite decimal number in [lo, hi], the whole text.
double real_option(std::string_view name, std::string_view text, double lo, double hi, std::string const& range) {
    double v = 0.0;
    auto const [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(v) || v < lo || v > hi)
        throw usage_error(std::string(name) + " must be a number " + range + ", not " + quote(text));
    return v;
}

void apply_limits(arguments const& args) {
    canopy::resource_limits& limits = canopy::default_limits();
    std::uint64_t const most = std::numeric_limits<std::uint64_t>::max();
    if (args.has("--max-file-bytes")) limits.max_file_bytes = whole_option(args, "--max-file-bytes", 1, most);
    if (args.has("--max-texels")) limits.max_texels = whole_option(args, "--max-texels", 1, most);
    if (args.has("--max-total-texels")) limits.max_total_texels = whole_option(args, "--max-total-texels", 1, most);
    if (args.has("--max-triangles")) limits.max_triangles = whole_option(args, "--max-triangles", 1, most);
    if (args.has("--max-placements")) limits.max_placements = whole_option(args, "--max-placements", 1, most);
    if (args.has("--max-depth")) limits.max_depth = whole_option(args, "--max-depth", 1, most);
}

canopy::build_quality quality_option(arguments const& args) {
    std::string const q = args.value_or("--quality", "automatic");
    if (q == "high") return canopy::build_quality::high;
    if (q == "fast") return canopy::build_quality::fast;
    if (q != "automatic") throw usage_error("--quality must be automatic, fast or high, not " + quote(q));
    return canopy::build_quality::automatic;
}

char const* quality_name(canopy::build_quality q) {
    return q == canopy::build_quality::high ? "high" : q == canopy::build_quality::fast ? "fast" : "automatic";
}

std::string quality_used(canopy::build_quality asked, canopy::build_quality used) {
    if (asked != canopy::build_quality::automatic) return quality_name(asked);
    return std::string("automatic (") + quality_name(used) + ")";
}

void limit_threads(arguments const& args, std::optional<tbb::global_control>& control) {
    if (args.has("--threads"))
        control.emplace(tbb::global_control::max_allowed_parallelism, std::size_t(whole_option(args, "--threads", 1, 1024)));
}

std::string choice_list(std::vector<choice> const& rows, bool with_text, std::string_view first) {
    std::vector<std::string> items;
    if (!first.empty()) items.emplace_back(first);
    for (choice const& c : rows) items.push_back(std::string(c.name) + (with_text ? std::string(c.text) : std::string()));
    std::string out;
    for (std::size_t i = 0; i < items.size(); ++i)
        out += (i == 0 ? "" : i + 1 == items.size() ? " or " : ", ") + items[i];
    return out;
}

std::string choice_bar(std::vector<choice> const& rows) {
    std::string out;
    for (choice const& c : rows) out += (out.empty() ? "" : "|") + std::string(c.name);
    return out;
}

void check_choice(std::vector<choice> const& rows, std::string_view option, std::string const& value,
                  std::string_view first) {
    bool const known = value == first || std::any_of(rows.begin(), rows.end(), [&](choice const& c) { return c.name == value; });
    if (!known) throw usage_error(std::string(option) + " must be " + choice_list(rows, false, first) + ", not " + quote(value));
}

std::string option_usage(std::string_view option, std::string_view text) {
    constexpr std::size_t column = 22, width = 93;
    std::string out = "  " + std::string(option);
    out.resize(column, ' ');
    std::size_t line_start = 0;
    bool first_word = true;
    while (!text.empty()) {
        std::size_t const space = std::min(text.find(' '), text.size());
        std::string_view const word = text.substr(0, space);
        if (!first_word && out.size() - line_start + 1 + word.size() > width) {
            out += "\n";
            line_start = out.size();
            out.append(column, ' ');
        } else if (!first_word) {
            out += ' ';
        }
        out += word;
        first_word = false;
        text.remove_prefix(std::min(space + 1, text.size()));
    }
    return out + "\n";
}

} // namespace cli
