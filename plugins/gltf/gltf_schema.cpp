// canopy.plugins.gltf — the glTF 2.0 schema check (see gltf_schema.hpp). Every property of the
// core specification (glTF 2.0, §5, "Properties Reference") is checked where it appears: its JSON
// type, its range or allowed values, and, for an index, that the element exists. Extensions'
// contents are not checked beyond being objects; extras may hold anything.
#include "gltf_schema.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

import canopy.scene;

namespace canopy::gltf_schema {

namespace {

using json = nlohmann::json;

constexpr std::int64_t int_max = 2147483647;           // tinygltf keeps most integers in an int
constexpr std::int64_t exact_max = 9007199254740992;   // 2^53, JSON's exact integers

// A string from the file, quoted and cut to a short prefix.
std::string shown(std::string_view s) {
    constexpr std::size_t longest = 40;
    return "'" + std::string(s.substr(0, longest)) + (s.size() > longest ? "…'" : "'");
}

std::string number_text(double d) {
    std::ostringstream s;
    s.precision(10);
    s << d;
    return s.str();
}

// An integer value's digits.
std::string integer_text(json const& v) {
    return v.is_number_unsigned() ? std::to_string(v.get<std::uint64_t>()) : std::to_string(v.get<std::int64_t>());
}

std::string described(json const& v) {
    switch (v.type()) {
    case json::value_t::null: return "null";
    case json::value_t::boolean: return v.get<bool>() ? "true" : "false";
    case json::value_t::string: return "a string (" + shown(v.get_ref<std::string const&>()) + ")";
    case json::value_t::number_integer: return "the number " + std::to_string(v.get<std::int64_t>());
    case json::value_t::number_unsigned: return "the number " + std::to_string(v.get<std::uint64_t>());
    case json::value_t::number_float: return "the number " + number_text(v.get<double>());
    case json::value_t::array: return "an array";
    case json::value_t::object: return "an object";
    default: return "a value of no JSON type";
    }
}

std::string join(std::string const& path, std::string_view key) {
    return path.empty() ? std::string(key) : path + "." + std::string(key);
}
std::string item(std::string const& path, std::size_t i) { return path + "[" + std::to_string(i) + "]"; }

struct range {
    double low, high;
    bool low_open = false; // low itself excluded
};
constexpr range unit{0.0, 1.0};
constexpr range non_negative{0.0, 1e308};
constexpr range positive{0.0, 1e308, true};
constexpr range any_number{-1e308, 1e308};

std::string range_text(range r) {
    return (r.low_open ? "(" : "[") + number_text(r.low) + ", " + (r.high >= 1e308 ? "∞)" : number_text(r.high) + "]");
}

// Bytes of one component of an accessor's componentType.
std::uint64_t component_bytes(std::int64_t type) {
    switch (type) {
    case 5120:
    case 5121: return 1;
    case 5122:
    case 5123: return 2;
    default: return 4;
    }
}

// Bytes of one element: components × component bytes, matrix columns padded to 4 bytes (§3.6.2.4).
std::uint64_t element_bytes(std::string const& type, std::uint64_t component) {
    if (type == "MAT2") return component == 4 ? 16 : 8;
    if (type == "MAT3") return component == 1 ? 12 : component == 2 ? 24 : 36;
    std::uint64_t const n = type == "SCALAR" ? 1 : type == "VEC2" ? 2 : type == "VEC3" ? 3 : type == "VEC4" ? 4 : 16;
    return n * component;
}

// `count` elements of `element` bytes, `stride` apart, from byte `offset` of `length` bytes, without
// overflow.
bool fits(std::uint64_t offset, std::uint64_t count, std::uint64_t element, std::uint64_t stride, std::uint64_t length) {
    if (count == 0) return offset <= length;
    if (offset > length || element > length - offset) return false;
    return count - 1 <= (length - offset - element) / stride;
}

class checker {
public:
    checker(json const& root, std::string const& file, std::uint64_t max_depth)
        : root_(root), file_(file), max_depth_(max_depth) {}

    document_uris uris;

    void run() {
        if (!root_.is_object()) fail("", "the document is " + described(root_) + ", not a JSON object");
        // The version first: a glTF 1.0 file is refused as such, not for its 1.0 layout.
        json const& asset = *object(root_, "", "asset", true);
        std::string const version = *string(asset, "asset", "version", true);
        if (!version.starts_with("2."))
            fail("asset.version", "glTF " + shown(version) + " is not supported (this loader reads glTF 2.0)");
        for (char const* key : {"accessors", "animations", "buffers", "bufferViews", "cameras", "images", "materials",
                                "meshes", "nodes", "samplers", "scenes", "skins", "textures"}) {
            if (json const* v = member(root_, "", key, false)) {
                if (!v->is_array()) wrong_type(key, "an array", *v);
                sizes_[key] = v->size();
            }
        }
        string(asset, "asset", "minVersion");
        string(asset, "asset", "generator");
        string(asset, "asset", "copyright");
        common(asset, "asset");
        strings(root_, "", "extensionsUsed");
        strings(root_, "", "extensionsRequired");
        index(root_, "", "scene", "scenes");
        extensions(root_, "");

        each("buffers", [&](json const& o, std::string const& path) {
            uris.buffers.push_back(string(o, path, "uri").value_or(""));
            buffer_lengths_.push_back(std::uint64_t(*integer(o, path, "byteLength", 1, exact_max, true)));
            uris.buffer_lengths.push_back(buffer_lengths_.back());
            common(o, path);
        });
        each("bufferViews", [&](json const& o, std::string const& path) {
            std::size_t const buffer = *index(o, path, "buffer", "buffers", true);
            std::uint64_t const offset = std::uint64_t(integer(o, path, "byteOffset", 0, exact_max).value_or(0));
            std::uint64_t const length = std::uint64_t(*integer(o, path, "byteLength", 1, exact_max, true));
            auto const stride = integer(o, path, "byteStride", 4, 252);
            if (stride && *stride % 4 != 0) fail(join(path, "byteStride"), std::to_string(*stride) + " is not a multiple of 4");
            integer_enum(o, path, "target", {34962, 34963});
            if (!fits(offset, 1, length, length, buffer_lengths_[buffer]))
                fail(path, "bytes " + std::to_string(offset) + " + " + std::to_string(length) + " lie outside " +
                               item("buffers", buffer) + " (" + std::to_string(buffer_lengths_[buffer]) + " bytes)");
            views_.push_back({buffer, offset, length, std::uint64_t(stride.value_or(0))});
            common(o, path);
        });
        each("accessors", [&](json const& o, std::string const& path) { accessor(o, path); });
        each("images", [&](json const& o, std::string const& path) {
            auto const uri_value = string(o, path, "uri");
            uris.images.push_back(uri_value.value_or(""));
            bool const uri = uri_value.has_value();
            string(o, path, "mimeType");
            auto const view_index = index(o, path, "bufferView", "bufferViews");
            bool const view = view_index.has_value();
            if (view) {
                auto const& v = views_[*view_index];
                uris.image_bytes.push_back({std::int64_t(v.buffer), std::int64_t(v.offset), std::int64_t(v.length)});
            } else {
                uris.image_bytes.push_back({-1, -1, -1});
            }
            if (uri == view) fail(path, uri ? "has both a uri and a bufferView" : "has neither a uri nor a bufferView");
            if (view && !o.contains("mimeType")) fail(join(path, "mimeType"), "is missing (required with a bufferView)");
            common(o, path);
        });
        each("samplers", [&](json const& o, std::string const& path) {
            integer_enum(o, path, "magFilter", {9728, 9729});
            integer_enum(o, path, "minFilter", {9728, 9729, 9984, 9985, 9986, 9987});
            integer_enum(o, path, "wrapS", {33071, 33648, 10497});
            integer_enum(o, path, "wrapT", {33071, 33648, 10497});
            common(o, path);
        });
        each("textures", [&](json const& o, std::string const& path) {
            index(o, path, "sampler", "samplers");
            index(o, path, "source", "images");
            common(o, path);
        });
        each("materials", [&](json const& o, std::string const& path) { material(o, path); });
        each("meshes", [&](json const& o, std::string const& path) { mesh(o, path); });
        each("cameras", [&](json const& o, std::string const& path) { camera(o, path); });
        each("nodes", [&](json const& o, std::string const& path) {
            index(o, path, "camera", "cameras");
            indices(o, path, "children", "nodes", 0);
            index(o, path, "skin", "skins");
            if (o.contains("skin") && !o.contains("mesh")) fail(join(path, "skin"), "is given without a mesh");
            numbers(o, path, "matrix", 16, any_number);
            index(o, path, "mesh", "meshes");
            numbers(o, path, "rotation", 4, {-1.0, 1.0});
            numbers(o, path, "scale", 3, any_number);
            numbers(o, path, "translation", 3, any_number);
            numbers(o, path, "weights", 0, any_number);
            common(o, path);
        });
        each("skins", [&](json const& o, std::string const& path) {
            index(o, path, "inverseBindMatrices", "accessors");
            index(o, path, "skeleton", "nodes");
            indices(o, path, "joints", "nodes", 1, true);
            common(o, path);
        });
        each("scenes", [&](json const& o, std::string const& path) {
            indices(o, path, "nodes", "nodes", 0);
            common(o, path);
        });
        each("animations", [&](json const& o, std::string const& path) { animation(o, path); });
        hierarchy();
    }

private:
    json const& root_;
    std::string const& file_;
    std::uint64_t max_depth_;
    std::map<std::string, std::size_t, std::less<>> sizes_;
    std::vector<std::uint64_t> buffer_lengths_;
    struct view {
        std::uint64_t buffer, offset, length, stride; // stride 0: none given
    };
    std::vector<view> views_;

    [[noreturn]] void fail(std::string const& path, std::string const& problem) const {
        throw scene_error(file_, path, problem);
    }
    [[noreturn]] void wrong_type(std::string const& path, char const* expected, json const& v) const {
        fail(path, std::string("expected ") + expected + ", got " + described(v));
    }
    std::size_t size_of(std::string_view array) const {
        auto it = sizes_.find(array);
        return it == sizes_.end() ? 0 : it->second;
    }

    // Member `key` of object o at `path`; nullptr when absent (an error when required).
    json const* member(json const& o, std::string const& path, std::string_view key, bool required) const {
        auto const it = o.find(std::string(key));
        if (it == o.end()) {
            if (required) fail(join(path, key), "is missing (required)");
            return nullptr;
        }
        return &*it;
    }

    json const* object(json const& o, std::string const& path, std::string_view key, bool required = false) const {
        json const* v = member(o, path, key, required);
        if (v && !v->is_object()) wrong_type(join(path, key), "an object", *v);
        return v;
    }

    json const* array(json const& o, std::string const& path, std::string_view key, std::size_t min_items,
                      bool required = false) const {
        json const* v = member(o, path, key, required);
        if (!v) return v;
        if (!v->is_array()) wrong_type(join(path, key), "an array", *v);
        if (v->size() < min_items)
            fail(join(path, key), "has " + std::to_string(v->size()) + " items (at least " + std::to_string(min_items) +
                                      " needed)");
        return v;
    }

    std::int64_t integer_at(json const& v, std::string const& path, std::int64_t low, std::int64_t high) const {
        if (!v.is_number_integer()) wrong_type(path, "an integer", v);
        bool const above = v.is_number_unsigned() ? v.get<std::uint64_t>() > std::uint64_t(high) : v.get<std::int64_t>() > high;
        bool const below = v.is_number_unsigned() ? low > 0 && v.get<std::uint64_t>() < std::uint64_t(low)
                                                  : v.get<std::int64_t>() < low;
        if (above || below)
            fail(path, integer_text(v) + " is out of range [" + std::to_string(low) + ", " + std::to_string(high) + "]");
        return v.get<std::int64_t>();
    }

    std::optional<std::int64_t> integer(json const& o, std::string const& path, std::string_view key, std::int64_t low,
                                        std::int64_t high, bool required = false) const {
        json const* v = member(o, path, key, required);
        if (!v) return std::nullopt;
        return integer_at(*v, join(path, key), low, high);
    }

    void integer_enum(json const& o, std::string const& path, std::string_view key, std::initializer_list<std::int64_t> values,
                      bool required = false) const {
        auto const v = integer(o, path, key, -exact_max, exact_max, required);
        if (v && std::find(values.begin(), values.end(), *v) == values.end()) {
            std::string allowed;
            for (auto a : values) allowed += (allowed.empty() ? "" : ", ") + std::to_string(a);
            fail(join(path, key), std::to_string(*v) + " is not one of " + allowed);
        }
    }

    std::size_t index_at(json const& v, std::string const& path, std::string_view array, std::size_t size) const {
        if (!v.is_number_integer()) wrong_type(path, "an integer index", v);
        bool const inside = v.is_number_unsigned() ? v.get<std::uint64_t>() < size
                                                   : v.get<std::int64_t>() >= 0 && std::uint64_t(v.get<std::int64_t>()) < size;
        if (!inside)
            fail(path, "index " + integer_text(v) + " is out of range (" + std::to_string(size) + " " +
                           std::string(array) + ")");
        return std::size_t(v.get<std::uint64_t>());
    }

    std::optional<std::size_t> index(json const& o, std::string const& path, std::string_view key, std::string_view array,
                                     bool required = false) const {
        json const* v = member(o, path, key, required);
        if (!v) return std::nullopt;
        return index_at(*v, join(path, key), array, size_of(array));
    }

    // An array of distinct indices into `array`.
    void indices(json const& o, std::string const& path, std::string_view key, std::string_view array, std::size_t min_items,
                 bool required = false) const {
        json const* v = this->array(o, path, key, min_items, required);
        if (!v) return;
        std::string const p = join(path, key);
        std::set<std::size_t> seen;
        for (std::size_t i = 0; i < v->size(); ++i) {
            std::size_t const n = index_at((*v)[i], item(p, i), array, size_of(array));
            if (!seen.insert(n).second) fail(item(p, i), "index " + std::to_string(n) + " is listed twice");
        }
    }

    double number_at(json const& v, std::string const& path, range r) const {
        if (!v.is_number()) wrong_type(path, "a number", v);
        double const d = v.get<double>();
        if (!(d >= r.low && d <= r.high) || (r.low_open && d == r.low))
            fail(path, number_text(d) + " is out of range " + range_text(r));
        return d;
    }

    std::optional<double> number(json const& o, std::string const& path, std::string_view key, range r,
                                 bool required = false) const {
        json const* v = member(o, path, key, required);
        if (!v) return std::nullopt;
        return number_at(*v, join(path, key), r);
    }

    // An array of `count` numbers (any count of at least one when count is 0).
    void numbers(json const& o, std::string const& path, std::string_view key, std::size_t count, range r) const {
        json const* v = array(o, path, key, 1);
        if (!v) return;
        std::string const p = join(path, key);
        if (count != 0 && v->size() != count)
            fail(p, "has " + std::to_string(v->size()) + " values (" + std::to_string(count) + " needed)");
        for (std::size_t i = 0; i < v->size(); ++i) number_at((*v)[i], item(p, i), r);
    }

    std::optional<std::string> string(json const& o, std::string const& path, std::string_view key,
                                      bool required = false) const {
        json const* v = member(o, path, key, required);
        if (!v) return std::nullopt;
        if (!v->is_string()) wrong_type(join(path, key), "a string", *v);
        return v->get<std::string>();
    }

    void string_enum(json const& o, std::string const& path, std::string_view key,
                     std::initializer_list<std::string_view> values, bool required = false) const {
        auto const v = string(o, path, key, required);
        if (v && std::find(values.begin(), values.end(), *v) == values.end()) {
            std::string allowed;
            for (auto a : values) allowed += (allowed.empty() ? "" : ", ") + std::string(a);
            fail(join(path, key), shown(*v) + " is not one of " + allowed);
        }
    }

    void strings(json const& o, std::string const& path, std::string_view key) const {
        json const* v = array(o, path, key, 1);
        if (!v) return;
        std::string const p = join(path, key);
        std::set<std::string> seen;
        for (std::size_t i = 0; i < v->size(); ++i) {
            if (!(*v)[i].is_string()) wrong_type(item(p, i), "a string", (*v)[i]);
            if (!seen.insert((*v)[i].get<std::string>()).second)
                fail(item(p, i), shown((*v)[i].get<std::string>()) + " is listed twice");
        }
    }

    void boolean(json const& o, std::string const& path, std::string_view key) const {
        json const* v = member(o, path, key, false);
        if (v && !v->is_boolean()) wrong_type(join(path, key), "true or false", *v);
    }

    // extensions: an object whose members are objects.
    void extensions(json const& o, std::string const& path) const {
        json const* v = object(o, path, "extensions");
        if (!v) return;
        std::string const p = join(path, "extensions");
        for (auto const& [name, value] : v->items())
            if (!value.is_object()) wrong_type(join(p, name), "an object", value);
    }

    // The properties every glTF object may have (extras may hold anything).
    void common(json const& o, std::string const& path) const {
        string(o, path, "name");
        extensions(o, path);
    }

    // Each element of top-level array `key`, which must be an object.
    template <typename F>
    void each(std::string_view key, F&& f) const {
        json const* v = member(root_, "", key, false);
        if (!v) return;
        for (std::size_t i = 0; i < v->size(); ++i) {
            std::string const path = item(std::string(key), i);
            if (!(*v)[i].is_object()) wrong_type(path, "an object", (*v)[i]);
            f((*v)[i], path);
        }
    }

    void accessor(json const& o, std::string const& path) const {
        auto const view = index(o, path, "bufferView", "bufferViews");
        std::uint64_t const offset = std::uint64_t(integer(o, path, "byteOffset", 0, exact_max).value_or(0));
        integer_enum(o, path, "componentType", {5120, 5121, 5122, 5123, 5125, 5126}, true);
        boolean(o, path, "normalized");
        std::uint64_t const count = std::uint64_t(*integer(o, path, "count", 1, exact_max, true));
        string_enum(o, path, "type", {"SCALAR", "VEC2", "VEC3", "VEC4", "MAT2", "MAT3", "MAT4"}, true);
        numbers(o, path, "max", 0, any_number);
        numbers(o, path, "min", 0, any_number);
        std::uint64_t const component = component_bytes(o.at("componentType").get<std::int64_t>());
        std::uint64_t const element = element_bytes(o.at("type").get<std::string>(), component);
        if (view) {
            auto const& v = views_[*view];
            std::uint64_t const stride = v.stride == 0 ? element : v.stride;
            if (stride < element)
                fail(path, "byteStride " + std::to_string(stride) + " of " + item("bufferViews", *view) +
                               " is smaller than an element (" + std::to_string(element) + " bytes)");
            if (!fits(offset, count, element, stride, v.length))
                fail(path, std::to_string(count) + " elements of " + std::to_string(element) + " bytes, " +
                               std::to_string(stride) + " apart from byte " + std::to_string(offset) + ", do not fit in " +
                               item("bufferViews", *view) + " (" + std::to_string(v.length) + " bytes)");
        } else if (o.contains("byteOffset")) {
            fail(join(path, "byteOffset"), "is given without a bufferView");
        }
        json const* sparse = object(o, path, "sparse");
        if (!sparse) {
            common(o, path);
            return;
        }
        std::string const sp = join(path, "sparse");
        std::uint64_t const n = std::uint64_t(*integer(*sparse, sp, "count", 1, std::min<std::int64_t>(int_max, std::int64_t(count)), true));
        json const& idx = *object(*sparse, sp, "indices", true);
        std::string const ip = join(sp, "indices");
        std::size_t const iview = *index(idx, ip, "bufferView", "bufferViews", true);
        std::uint64_t const ioffset = std::uint64_t(integer(idx, ip, "byteOffset", 0, int_max).value_or(0));
        integer_enum(idx, ip, "componentType", {5121, 5123, 5125}, true);
        std::uint64_t const isize = component_bytes(idx.at("componentType").get<std::int64_t>());
        if (!fits(ioffset, n, isize, isize, views_[iview].length))
            fail(ip, std::to_string(n) + " indices of " + std::to_string(isize) + " bytes from byte " +
                         std::to_string(ioffset) + " do not fit in " + item("bufferViews", iview) + " (" +
                         std::to_string(views_[iview].length) + " bytes)");
        common(idx, ip);
        json const& values = *object(*sparse, sp, "values", true);
        std::string const vp = join(sp, "values");
        std::size_t const vview = *index(values, vp, "bufferView", "bufferViews", true);
        std::uint64_t const voffset = std::uint64_t(integer(values, vp, "byteOffset", 0, int_max).value_or(0));
        if (!fits(voffset, n, element, element, views_[vview].length))
            fail(vp, std::to_string(n) + " elements of " + std::to_string(element) + " bytes from byte " +
                         std::to_string(voffset) + " do not fit in " + item("bufferViews", vview) + " (" +
                         std::to_string(views_[vview].length) + " bytes)");
        common(values, vp);
        common(*sparse, sp);
        common(o, path);
    }

    void texture_info(json const& o, std::string const& path, std::string_view key, char const* extra = nullptr,
                      range extra_range = unit) const {
        json const* t = object(o, path, key);
        if (!t) return;
        std::string const p = join(path, key);
        index(*t, p, "index", "textures", true);
        integer(*t, p, "texCoord", 0, int_max);
        if (extra) number(*t, p, extra, extra_range);
        common(*t, p);
    }

    void material(json const& o, std::string const& path) const {
        if (json const* pbr = object(o, path, "pbrMetallicRoughness")) {
            std::string const p = join(path, "pbrMetallicRoughness");
            numbers(*pbr, p, "baseColorFactor", 4, unit);
            texture_info(*pbr, p, "baseColorTexture");
            number(*pbr, p, "metallicFactor", unit);
            number(*pbr, p, "roughnessFactor", unit);
            texture_info(*pbr, p, "metallicRoughnessTexture");
            common(*pbr, p);
        }
        texture_info(o, path, "normalTexture", "scale", any_number);
        texture_info(o, path, "occlusionTexture", "strength", unit);
        texture_info(o, path, "emissiveTexture");
        numbers(o, path, "emissiveFactor", 3, unit);
        string_enum(o, path, "alphaMode", {"OPAQUE", "MASK", "BLEND"});
        number(o, path, "alphaCutoff", non_negative);
        boolean(o, path, "doubleSided");
        common(o, path);
    }

    void mesh(json const& o, std::string const& path) const {
        json const& primitives = *array(o, path, "primitives", 1, true);
        std::string const pp = join(path, "primitives");
        for (std::size_t i = 0; i < primitives.size(); ++i) {
            std::string const p = item(pp, i);
            json const& prim = primitives[i];
            if (!prim.is_object()) wrong_type(p, "an object", prim);
            json const& attributes = *object(prim, p, "attributes", true);
            for (auto const& [name, value] : attributes.items())
                index_at(value, join(join(p, "attributes"), name), "accessors", size_of("accessors"));
            index(prim, p, "indices", "accessors");
            index(prim, p, "material", "materials");
            integer(prim, p, "mode", 0, 6);
            if (json const* targets = array(prim, p, "targets", 1)) {
                for (std::size_t t = 0; t < targets->size(); ++t) {
                    std::string const tp = item(join(p, "targets"), t);
                    if (!(*targets)[t].is_object()) wrong_type(tp, "an object", (*targets)[t]);
                    for (auto const& [name, value] : (*targets)[t].items())
                        index_at(value, join(tp, name), "accessors", size_of("accessors"));
                }
            }
            common(prim, p);
        }
        numbers(o, path, "weights", 0, any_number);
        common(o, path);
    }

    void camera(json const& o, std::string const& path) const {
        string_enum(o, path, "type", {"perspective", "orthographic"}, true);
        bool const perspective = o.at("type").get<std::string>() == "perspective";
        if (json const* p = object(o, path, "perspective", perspective)) {
            std::string const pp = join(path, "perspective");
            number(*p, pp, "aspectRatio", positive);
            number(*p, pp, "yfov", positive, true);
            number(*p, pp, "zfar", positive);
            number(*p, pp, "znear", positive, true);
            common(*p, pp);
        }
        if (json const* p = object(o, path, "orthographic", !perspective)) {
            std::string const op = join(path, "orthographic");
            number(*p, op, "xmag", any_number, true);
            number(*p, op, "ymag", any_number, true);
            number(*p, op, "zfar", positive, true);
            number(*p, op, "znear", non_negative, true);
            common(*p, op);
        }
        common(o, path);
    }

    // The node hierarchy: the nodes must form disjoint trees (glTF 2.0, §3.5.3: at most one
    // parent each, no node its own descendant), each scene's nodes must be roots, and no node may
    // lie deeper than max_depth. Parents are walked with explicit lists, without recursion.
    void hierarchy() const {
        json const* nodes = member(root_, "", "nodes", false);
        std::size_t const count = nodes ? nodes->size() : 0;
        std::vector<std::int64_t> parent(count, -1);
        for (std::size_t p = 0; p < count; ++p) {
            json const* children = member((*nodes)[p], "", "children", false);
            if (!children) continue;
            for (auto const& child : *children) {
                std::size_t const c = child.get<std::size_t>();
                if (parent[c] >= 0)
                    fail(item("nodes", c), "is a child of both " + item("nodes", std::size_t(parent[c])) + " and " +
                                               item("nodes", p) + " (a glTF node has at most one parent)");
                parent[c] = std::int64_t(p);
            }
        }
        std::vector<std::uint64_t> depth(count, 0); // 0: not known yet
        std::vector<char> on_path(count, 0);
        std::vector<std::size_t> path;              // from a node up towards its root
        for (std::size_t start = 0; start < count; ++start) {
            path.clear();
            std::size_t k = start;
            while (depth[k] == 0 && !on_path[k] && parent[k] >= 0) {
                on_path[k] = 1;
                path.push_back(k);
                k = std::size_t(parent[k]);
            }
            if (on_path[k]) {
                // k is its own ancestor: the cycle is path's part from k on, read downwards.
                auto const from = std::find(path.begin(), path.end(), k);
                std::string cycle = item("nodes", k);
                std::size_t listed = 0;
                for (auto it = path.end(); it != from && listed < 8; ++listed) cycle += " → " + item("nodes", *--it);
                if (std::size_t(path.end() - from) > 8) cycle += " → …";
                fail(item("nodes", k), "is its own descendant (" + cycle + ")");
            }
            if (depth[k] == 0) depth[k] = 1; // a root
            for (auto it = path.rbegin(); it != path.rend(); ++it) {
                depth[*it] = depth[std::size_t(parent[*it])] + 1;
                on_path[*it] = 0;
                if (depth[*it] > max_depth_)
                    fail(item("nodes", *it), "is " + std::to_string(depth[*it]) +
                                                 " levels deep in the node hierarchy, over the limit of " +
                                                 std::to_string(max_depth_) + " (--max-depth)");
            }
        }
        each("scenes", [&](json const& o, std::string const& path) {
            if (json const* roots = member(o, path, "nodes", false))
                for (auto const& r : *roots)
                    if (std::size_t const n = r.get<std::size_t>(); parent[n] >= 0)
                        fail(join(path, "nodes"), item("nodes", n) + " is a child of " +
                                                      item("nodes", std::size_t(parent[n])) + ", not a root node");
        });
    }

    void animation(json const& o, std::string const& path) const {
        json const& samplers = *array(o, path, "samplers", 1, true);
        std::string const sp = join(path, "samplers");
        for (std::size_t i = 0; i < samplers.size(); ++i) {
            std::string const p = item(sp, i);
            if (!samplers[i].is_object()) wrong_type(p, "an object", samplers[i]);
            index(samplers[i], p, "input", "accessors", true);
            string_enum(samplers[i], p, "interpolation", {"LINEAR", "STEP", "CUBICSPLINE"});
            index(samplers[i], p, "output", "accessors", true);
            common(samplers[i], p);
        }
        json const& channels = *array(o, path, "channels", 1, true);
        std::string const cp = join(path, "channels");
        for (std::size_t i = 0; i < channels.size(); ++i) {
            std::string const p = item(cp, i);
            if (!channels[i].is_object()) wrong_type(p, "an object", channels[i]);
            index_at(*member(channels[i], p, "sampler", true), join(p, "sampler"), "samplers of the animation", samplers.size());
            json const& target = *object(channels[i], p, "target", true);
            std::string const tp = join(p, "target");
            index(target, tp, "node", "nodes");
            string_enum(target, tp, "path", {"translation", "rotation", "scale", "weights"}, true);
            common(target, tp);
            common(channels[i], p);
        }
        common(o, path);
    }
};

} // namespace

document_uris check_document(std::string_view text, std::string const& file, std::uint64_t max_depth) {
    // Nesting first, on the text: no parser or copy below recurses deeper than this.
    std::uint64_t const limit = std::min(max_depth, nesting_ceiling);
    if (std::size_t const at = json_nesting_over(text, limit); at != std::string_view::npos)
        throw scene_error(file, "", "JSON arrays and objects nest deeper than " + std::to_string(limit) +
                                        " levels (at byte " + std::to_string(at) + "), over the limit of " +
                                        (limit == max_depth ? std::string("--max-depth") : std::string("the glTF loader")));

    json root;
    try {
        root = json::parse(text.begin(), text.end());
    } catch (json::exception const& e) {
        std::string message = e.what();
        if (message.starts_with("[json.exception.")) message.erase(0, message.find(']') + 2);
        constexpr std::size_t longest = 200;
        if (message.size() > longest) message = message.substr(0, longest) + "…";
        throw scene_error(file, "", "malformed JSON: " + message);
    }
    checker c(root, file, max_depth);
    c.run();
    return std::move(c.uris);
}

} // namespace canopy::gltf_schema
