// The scenes of `canopy render` and `canopy info` (scenes.hpp).
#include "scenes.hpp"
#include <algorithm>
#include <string_view>
#include "options.hpp"
#include "processes.hpp"
import canopy.plugins;

namespace cli {

canopy::registry& plugin_registry(std::vector<std::string> const& plugin_files) {
    step("loading the plugins of CANOPY_PLUGIN_PATH");
    canopy::registry& r = canopy::builtin_registry();
    for (auto const& f : plugin_files) {
        step("loading plugin " + f);
        r.load_plugin(f);
    }
    return r;
}

std::optional<generator_call> parse_generator(std::string const& spec) {
    if (!spec.starts_with("gen:")) return std::nullopt;
    std::string_view rest = std::string_view(spec).substr(4);
    auto const colon = rest.find(':');
    generator_call call{std::string(rest.substr(0, colon)), {}};
    if (call.name.empty()) throw usage_error("gen: needs a generator name (gen:NAME[:KEY=VALUE,...])");
    if (colon == std::string_view::npos) return call;
    rest.remove_prefix(colon + 1);
    while (!rest.empty()) {
        auto const comma = std::min(rest.find(','), rest.size());
        std::string_view const item = rest.substr(0, comma);
        auto const eq = item.find('=');
        if (eq == std::string_view::npos || eq == 0)
            throw usage_error("generator parameter " + quote(item) + " is not KEY=VALUE");
        std::string key(item.substr(0, eq));
        if (call.params.has(key)) throw usage_error("generator parameter " + quote(key) + " given more than once");
        call.params.set(std::move(key), std::string(item.substr(eq + 1)));
        rest.remove_prefix(std::min(comma + 1, rest.size()));
    }
    return call;
}

loaded_graph load_and_compile(std::string const& spec, canopy::registry const& r, canopy::build_quality quality) {
    loaded_graph out;
    step("loading " + spec);
    auto const start = clock_type::now();
    if (auto const call = parse_generator(spec)) {
        r.generate(out.graph, call->name, call->params, out.graph.root());
    } else {
        r.load(out.graph, spec, out.graph.root());
    }
    out.load_seconds = seconds_since(start);
    step("compiling " + spec);
    out.compiled = canopy::compile(out.graph, {.plugins = &r, .bvh = {.quality = quality}, .name = spec});
    return out;
}

} // namespace cli
