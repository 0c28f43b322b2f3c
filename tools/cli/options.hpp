// The command line of `canopy`: options and their values, shared by every command.
//
// parse_arguments reads options (given once, unless repeatable; a value is the next argument,
// non-empty, not an option) and positional arguments; every command also takes the limit options
// (canopy::resource_limits). Numbers are read whole and range-checked. A choice option (--kernel,
// --intersector, ...) is a table of rows {name, text}: its validation message and its usage text
// come from the table (choice_names, choice_usage).
#pragma once
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>
#include <tbb/global_control.h>
import canopy;
import canopy.scene;

namespace cli {

// A usage error: printed with the command's usage, exit status 2.
struct usage_error : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// At most 40 characters of an argument in quotes, bytes that are not printable as '?'.
std::string quote(std::string_view text);

struct option_spec {
    std::string_view name;
    bool takes_value = true;
    bool repeatable = false;
};

struct arguments {
    std::map<std::string, std::vector<std::string>, std::less<>> options;
    std::vector<std::string> positional;
    bool help = false;

    bool has(std::string_view name) const { return options.find(name) != options.end(); }
    std::string const& value(std::string_view name) const { return options.find(name)->second.front(); }
    std::string value_or(std::string_view name, std::string fallback) const {
        return has(name) ? value(name) : std::move(fallback);
    }
    std::vector<std::string> values(std::string_view name) const {
        return has(name) ? options.find(name)->second : std::vector<std::string>{};
    }
};

// The options of `specs` and the limit options, and positional arguments ("--" ends the
// options). "--help" or "-h" anywhere stops parsing.
arguments parse_arguments(std::span<char*> args, std::vector<option_spec> specs);

// The value of an option that must be given ("missing --scene").
std::string required(arguments const& args, std::string_view name);

// The whole text as a number in [lo, hi], or nothing.
std::optional<std::uint64_t> whole_number(std::string_view text, std::uint64_t lo, std::uint64_t hi);
std::uint64_t whole_option(arguments const& args, std::string_view name, std::uint64_t lo, std::uint64_t hi);
// A finite decimal number in [lo, hi], the whole text; `range` words the range in the message.
double real_option(std::string_view name, std::string_view text, double lo, double hi, std::string const& range);

// Sets canopy::default_limits() from the limit options, before anything is loaded.
void apply_limits(arguments const& args);

// --quality automatic|fast|high: the build quality of the mesh BVHs (default automatic, the
// library's: spatial splits only for meshes of long thin triangles).
canopy::build_quality quality_option(arguments const& args);
char const* quality_name(canopy::build_quality q);
// The quality asked for and, when automatic, the one a build used: "automatic (high)".
std::string quality_used(canopy::build_quality asked, canopy::build_quality used);

// --threads N: the worker limit, kept in `control` (constructed in place: a global_control must
// not be copied) for as long as the caller keeps it.
void limit_threads(arguments const& args, std::optional<tbb::global_control>& control);

// ---- choice tables ------------------------------------------------------------------------
// A choice option (--kernel, --intersector) is one table: a std::tuple of rows, each with the
// name given on the command line, what the usage says after it (" (texture alpha mask)",
// ": reject hits where ...", or nothing) and what the command does with it. The validation
// message, the usage text and the dispatch all come from the table: a new choice is a new row.

struct choice {
    std::string_view name;
    std::string_view text;
};

template <typename Table>
std::vector<choice> choices(Table const& table) {
    return std::apply([](auto const&... row) { return std::vector<choice>{choice{row.name, row.text}...}; }, table);
}

// Calls f(row) with the row named `name`; false when no row has that name.
template <typename Table, typename F>
bool with_choice(Table const& table, std::string_view name, F&& f) {
    return std::apply([&](auto const&... row) { return ((row.name == name ? (f(row), true) : false) || ...); }, table);
}

// "a, b or c" (with each row's text when `with_text`), after `first` when given ("auto, a, b or c").
std::string choice_list(std::vector<choice> const& rows, bool with_text, std::string_view first = {});
// "a|b|c"
std::string choice_bar(std::vector<choice> const& rows);
// Refuses a name that is no row's: "--kernel must be primary, ao, path or heatmap, not 'x'".
void check_choice(std::vector<choice> const& rows, std::string_view option, std::string const& value,
                  std::string_view first = {});
// An option's line(s) in a usage: "  --kernel KIND       " then `text`, wrapped at 93 columns
// under its own column.
std::string option_usage(std::string_view option, std::string_view text);

// The usage texts every command shares.
extern char const* const limits_usage;
extern char const* const quality_usage;

} // namespace cli
