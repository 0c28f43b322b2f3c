// canopy.scene:registry — implementation (dlopen lives here, out of the interface).
module;
#include <dlfcn.h>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <exception>
#include <new>
#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>
module canopy.scene;

namespace canopy {

namespace {

template <typename Map>
std::vector<registered> list(Map const& m) {
    std::vector<registered> out;
    for (auto const& [key, e] : m) {
        if constexpr (requires { e.info; }) out.push_back(e.info);
        else
            for (auto const& x : e) out.push_back(x.info); // default first
    }
    return out;
}

std::string lower(std::string s) {
    for (char& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
    return s;
}

std::string normalise_extension(std::string ext) {
    ext = lower(std::move(ext));
    if (!ext.empty() && ext.front() != '.') ext.insert(ext.begin(), '.');
    return ext;
}

template <typename F>
auto with_rollback(scene& s, F&& f) {
    auto const m = s.make_mark();
    try {
        return f();
    } catch (...) {
        s.roll_back(m);
        throw;
    }
}

} // namespace

std::string extension_of(std::filesystem::path const& file) { return lower(file.extension().string()); }

void registry::add_loader(std::string extension, std::string plugin, std::string description, file_loader f,
                          loader_rank rank) {
    extension = normalise_extension(std::move(extension));
    auto& list = loaders_[extension];
    std::erase_if(list, [&](auto const& e) { return e.info.plugin == plugin; });
    // Kept in the order of choice: the default first.
    auto const before = [&](auto const& e) { return e.rank > rank || (e.rank == rank && e.info.plugin < plugin); };
    auto const at = std::find_if_not(list.begin(), list.end(), before);
    list.insert(at, {{extension, std::move(plugin), std::move(description)}, std::move(f), rank});
}

void registry::add_image_loader(std::string extension, std::string plugin, image_loader f) {
    extension = normalise_extension(std::move(extension));
    image_loaders_[extension] = {{extension, std::move(plugin), "image"}, std::move(f)};
}

void registry::add_generator(std::string name, std::string plugin, std::string description, generator f) {
    generators_[name] = {{name, std::move(plugin), std::move(description)}, std::move(f)};
}

void registry::add_node_type(std::string name, std::string plugin, std::string description, node_expander expand) {
    node_types_[name] = {{name, std::move(plugin), std::move(description)}, std::move(expand)};
}

void registry::add_node_type(std::string name, std::string plugin, std::string description, generator expand) {
    add_node_type(std::move(name), std::move(plugin), std::move(description),
                  node_expander([g = std::move(expand)](scene& s, node_id self, parameters const& p, registry const&) {
                      return g(s, self, p);
                  }));
}

bool registry::has_loader(std::string_view extension) const {
    return loaders_.contains(normalise_extension(std::string(extension)));
}

std::vector<registered> registry::loaders() const { return list(loaders_); }
std::vector<registered> registry::image_loaders() const { return list(image_loaders_); }
std::vector<registered> registry::generators() const { return list(generators_); }
std::vector<registered> registry::node_types() const { return list(node_types_); }

node_id registry::load(scene& s, std::filesystem::path const& file, node_id parent, std::string_view plugin) const {
    // The file first: a folder or a device is named as such, whatever its name ends with.
    require_regular_file(file);
    std::string const ext = extension_of(file);
    auto it = loaders_.find(ext);
    if (it == loaders_.end() || it->second.empty()) {
        std::string known;
        for (auto const& [k, e] : loaders_) known += (known.empty() ? "" : " ") + k;
        throw scene_error(file.string(), "",
                          (ext.empty() ? std::string("has no extension") : "unknown extension '" + excerpt(ext) + "'") +
                              " (known: " + (known.empty() ? "none" : known) + ")");
    }
    loader_entry const* chosen = &it->second.front();
    if (!plugin.empty()) {
        chosen = nullptr;
        std::string offered;
        for (auto const& e : it->second) {
            if (e.info.plugin == plugin) chosen = &e;
            offered += (offered.empty() ? "" : " ") + e.info.plugin;
        }
        if (chosen == nullptr)
            throw scene_error(file.string(), "", "plugin '" + excerpt(plugin) + "' does not load '" + excerpt(ext) +
                                                     "' files (" + offered + " do)");
    }
    return with_rollback(s, [&] {
        try {
            return chosen->function(s, file, parent, *this);
        } catch (scene_error const& e) {
            if (!e.file().empty()) throw;
            throw scene_error(file.string(), e.where(), e.problem());
        } catch (std::bad_alloc const&) {
            throw scene_error(file.string(), "", "out of memory while loading");
        } catch (std::exception const& e) {
            throw scene_error(file.string(), "", e.what());
        }
    });
}

image_data registry::load_image(std::filesystem::path const& file, std::uint64_t texels_held) const {
    require_regular_file(file, "texture");
    std::string const ext = extension_of(file);
    auto it = image_loaders_.find(ext);
    if (it == image_loaders_.end())
        throw scene_error(file.string(), "", "no image loader for extension '" + excerpt(ext) + "'");
    image_data img;
    try {
        img = it->second.function(file, texels_held);
    } catch (scene_error const&) {
        throw;
    } catch (std::bad_alloc const&) {
        throw scene_error(file.string(), "", "out of memory while reading the image");
    } catch (std::exception const& e) {
        throw scene_error(file.string(), "", e.what());
    }
    if (img.source.empty()) img.source = file.string();
    // A loader that let an image through its limits (after decoding it) is held to them all the same.
    if (img.width > 0 && img.height > 0) {
        std::string const problem = texel_problem(std::uint64_t(img.width), std::uint64_t(img.height), texels_held,
                                                  default_limits().max_texels, default_limits().max_total_texels);
        if (!problem.empty()) throw scene_error(file.string(), "", problem);
    }
    return img;
}

node_id registry::generate(scene& s, std::string const& name, parameters const& params, node_id parent) const {
    auto it = generators_.find(name);
    if (it == generators_.end()) {
        std::string known;
        for (auto const& [k, e] : generators_) known += (known.empty() ? "" : " ") + k;
        throw scene_error("", "generator '" + excerpt(name) + "'", "is not registered (known: " + (known.empty() ? "none" : known) + ")");
    }
    return with_rollback(s, [&] { return it->second.function(s, parent, params); });
}

void registry::expand_custom_nodes(scene& s) const {
    // Expansions may add custom nodes; they are appended, so one pass over a growing list does.
    for (node_id n = 0; n < s.nodes().size(); ++n) {
        if (s.at(n).kind != node_kind::custom || !s.at(n).children.empty()) continue;
        auto it = node_types_.find(s.at(n).custom_type);
        if (it == node_types_.end())
            throw scene_error(s.at(n).source, "node '" + excerpt(s.at(n).name) + "'",
                              "node type '" + excerpt(s.at(n).custom_type) + "' is not registered by any plugin");
        parameters const params = s.at(n).params;
        with_rollback(s, [&] { return it->second.function(s, n, params, *this); });
    }
}

void registry::load_plugin(std::filesystem::path const& file) {
    std::error_code ec;
    auto const canonical = std::filesystem::weakly_canonical(file, ec);
    std::string const key = (ec ? file : canonical).string();
    if (std::find(plugins_.begin(), plugins_.end(), key) != plugins_.end()) return;
    require_regular_file(file);
    void* handle = dlopen(key.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
        char const* why = dlerror();
        throw scene_error(file.string(), "", std::string("cannot load plugin: ") + (why ? why : "unknown reason"));
    }
    using entry_point = int (*)(unsigned, void*);
    auto entry = reinterpret_cast<entry_point>(dlsym(handle, "canopy_plugin_register"));
    if (entry == nullptr) {
        dlclose(handle);
        throw scene_error(file.string(), "", "not a canopy plugin: it has no canopy_plugin_register entry point");
    }
    // Register into a copy: a plugin that fails leaves this registry as it was.
    registry staged = *this;
    int result = 0;
    try {
        result = entry(plugin_abi_version, &staged);
    } catch (std::exception const& e) {
        throw scene_error(file.string(), "", std::string("plugin failed to register: ") + e.what());
    }
    if (result != 0)
        throw scene_error(file.string(), "",
                          "plugin refused to register (code " + std::to_string(result) +
                              "; built for another plugin_abi_version than " + std::to_string(plugin_abi_version) + "?)");
    *this = std::move(staged);
    plugins_.push_back(key);
    // The handle is never closed: the registry holds functions that live in the library.
}

void registry::load_plugin_path(std::string_view list) {
    std::size_t start = 0;
    while (start <= list.size()) {
        std::size_t const end = std::min(list.find(':', start), list.size());
        std::string const item(list.substr(start, end - start));
        start = end + 1;
        if (item.empty()) continue;
        std::filesystem::path const p(item);
        std::error_code ec;
        if (std::filesystem::is_directory(p, ec)) {
            std::vector<std::filesystem::path> libs;
            for (auto const& e : std::filesystem::directory_iterator(p, ec))
                if (e.path().extension() == ".so") libs.push_back(e.path());
            std::sort(libs.begin(), libs.end());
            for (auto const& lib : libs) load_plugin(lib);
        } else {
            load_plugin(p);
        }
    }
}

scene load_scene(std::filesystem::path const& file, registry const& r) {
    scene s;
    r.load(s, file, s.root());
    return s;
}

} // namespace canopy
