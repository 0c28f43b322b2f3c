// canopy.scene:registry — where plugins register what they add to the scene graph.
//
// A plugin adds any of:
//   file loaders     by extension (".ply"): load a file into a scene under a parent node; several
//                    plugins may load one extension: each says at registration how it ranks
//                    (loader_rank), the highest is the default, the others are chosen by plugin
//                    name (load(s, file, parent, "openmesh")); the order of registration does
//                    not matter
//   image loaders    by extension (".png"): read a texture into an image_data
//   generators       by name ("icosphere"): build geometry from parameters, deterministic in them
//   node types       by name: a custom node that compile() expands into standard nodes
// Built-in plugins are registered by canopy.plugins (builtin_registry()). Plugins compiled as
// shared libraries are loaded at run time by load_plugin(file) or load_plugin_path(list) (the
// list in CANOPY_PLUGIN_PATH is loaded by builtin_registry()): see the entry point below.
//
// The C entry point of a shared-library plugin (the only symbol the loader looks up):
//
//   extern "C" int canopy_plugin_register(unsigned abi_version, void* registry);
//
// abi_version is canopy::plugin_abi_version of the loading program; a plugin built against
// another version returns non-zero without touching the registry. registry points to the
// canopy::registry to register into. The function returns 0 on success; a non-zero result, or
// an exception it lets escape, is reported as a scene_error naming the file. A loaded library
// stays loaded for the life of the process (its functions are held by the registry).
//
// Loading is all-or-nothing: when a loader or generator throws, the scene is rolled back to what
// it was before the call.
module;
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>
export module canopy.scene:registry;
import :error;
import :graph;

export namespace canopy {

// Version of the plugin interface (registry and scene types); raised on every incompatible change.
inline constexpr unsigned plugin_abi_version = 3;

// How a file loader ranks among the loaders of its extension. The extension's default loader is
// the one of highest rank; among equal ranks, the plugin whose name sorts first. The others are
// chosen by plugin name. The order in which plugins register never decides.
enum class loader_rank : std::uint8_t {
    alternative, // a second reader, asked for by name (the bench plugin's strict .obj subset, openmesh's .obj)
    standard,    // the extension's own reader (every built-in loader but the alternatives)
    preferred,   // a reader meant to replace the standard one (e.g. from a plugin loaded at run time)
};

class registry;

// Loads `file` into `s` under `parent`; returns the node it made (usually a group named after the
// file). Throws scene_error on bad input. `r` is the registry the load goes through (for
// textures and files the file refers to).
using file_loader = std::function<node_id(scene& s, std::filesystem::path const& file, node_id parent, registry const& r)>;
// Reads an image file. texels_held: the texels of the images the scene being loaded holds
// already; a loader refuses, from the file's header and before decoding, an image of more than
// default_limits().max_texels texels or one that would bring the total over max_total_texels
// (canopy.scene:limits' texel_problem gives the message).
using image_loader = std::function<image_data(std::filesystem::path const& file, std::uint64_t texels_held)>;
// Builds geometry under `parent` from `params`; returns the node it made.
using generator = std::function<node_id(scene& s, node_id parent, parameters const& params)>;
// Expands a custom node: builds its content under the node `self` from the node's parameters,
// through the registry when it needs other plugins (generators, files).
using node_expander = std::function<node_id(scene& s, node_id self, parameters const& params, registry const& r)>;

struct registered {
    std::string name;        // extension (with dot, lower case) or generator / node type name
    std::string plugin;      // the plugin that registered it
    std::string description; // one line for `canopy info` and --help
};

class registry {
public:
    // A plugin that registers a loader for an extension again replaces its earlier one.
    void add_loader(std::string extension, std::string plugin, std::string description, file_loader f,
                    loader_rank rank = loader_rank::standard);
    void add_image_loader(std::string extension, std::string plugin, image_loader f);
    void add_generator(std::string name, std::string plugin, std::string description, generator f);
    // A custom node type: `expand` builds the node's content under the node itself (parent = the
    // custom node), from the node's parameters (a generator serves as an expander too).
    void add_node_type(std::string name, std::string plugin, std::string description, node_expander expand);
    void add_node_type(std::string name, std::string plugin, std::string description, generator expand);

    // Loads a file by its extension (case-insensitive) under parent (default: the root), with
    // the extension's default loader or the one `plugin` registered. Errors: a path that is not
    // a regular file (missing, a folder, a device, a FIFO; checked before the extension), one over
    // the limit of bytes per file, an unknown extension (the message lists the known ones), no
    // such plugin for the extension, and whatever the loader reports. On error the scene is unchanged; errors that do not name
    // a file are given this one's name.
    node_id load(scene& s, std::filesystem::path const& file, node_id parent = 0, std::string_view plugin = {}) const;
    // Reads an image with the loader of its extension. texels_held: the texels of the images the
    // scene it is loaded for holds already (scene::texels(), plus any a loader holds decoded);
    // the loader refuses before decoding an image over --max-texels or one that would bring the
    // total over --max-total-texels, and an image a loader returned over either is refused here.
    image_data load_image(std::filesystem::path const& file, std::uint64_t texels_held = 0) const;
    node_id generate(scene& s, std::string const& name, parameters const& params, node_id parent = 0) const;
    // Expands every custom node of the scene (also those made by expansions), in place.
    void expand_custom_nodes(scene& s) const;

    bool has_loader(std::string_view extension) const;
    bool has_generator(std::string_view name) const { return generators_.contains(std::string(name)); }
    bool has_node_type(std::string_view name) const { return node_types_.contains(std::string(name)); }
    std::vector<registered> loaders() const; // per extension, the default first, then by rank and name
    std::vector<registered> image_loaders() const;
    std::vector<registered> generators() const;
    std::vector<registered> node_types() const;
    std::vector<std::string> const& plugins() const { return plugins_; } // loaded shared libraries

    // Loads one shared-library plugin (see the entry point above). Loading the same file twice
    // is a no-op. Throws scene_error naming the file on failure.
    void load_plugin(std::filesystem::path const& file);
    // Loads plugins from a list of files and folders separated by ':' (a folder: every *.so in
    // it, in name order). Empty entries are skipped; a missing entry is an error.
    void load_plugin_path(std::string_view list);

private:
    template <typename F>
    struct entry {
        registered info;
        F function;
    };
    struct loader_entry {
        registered info;
        file_loader function;
        loader_rank rank;
    };
    std::map<std::string, std::vector<loader_entry>> loaders_; // by rank (highest first), then plugin name
    std::map<std::string, entry<image_loader>> image_loaders_;
    std::map<std::string, entry<generator>> generators_;
    std::map<std::string, entry<node_expander>> node_types_;
    std::vector<std::string> plugins_;
};

// Lower-case extension with its dot ("Model.PLY" → ".ply").
std::string extension_of(std::filesystem::path const& file);

// A new scene holding one file (under a group named after it).
scene load_scene(std::filesystem::path const& file, registry const& r);

} // namespace canopy
