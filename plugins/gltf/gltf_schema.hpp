// The glTF 2.0 schema check of canopy.plugins.gltf (internal to the plugin): the JSON document is
// checked, every property of the core specification with its JSON type, range, and references
// between elements, before tinygltf reads it (tinygltf drops a property of the wrong type, or an
// index of -1, without a word).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace canopy::gltf_schema {

// Where the document's buffers and images are: the uris it gives them ("" where it gives none),
// as written, the buffers' declared lengths and the images' buffer bytes.
struct document_uris {
    std::vector<std::string> buffers, images;
    std::vector<std::uint64_t> buffer_lengths; // each buffer's byteLength
    // For each image in a buffer view, the bytes it is read from: buffer, byteOffset, byteLength
    // (all -1 for an image given by uri).
    std::vector<std::array<std::int64_t, 3>> image_bytes;
};

// Throws canopy::scene_error(file, JSON path, problem), as
//   "model.gltf: materials[0].pbrMetallicRoughness: expected an object, got an array"
// for malformed JSON, JSON nested deeper than max_depth (or the loader's own ceiling), and any
// property of the wrong type, out of its range, or referring to an element that does not exist;
// accessors, sparse accessors and buffer views must lie inside their buffer views and buffers
// (by their declared byteLength); the nodes must form disjoint trees (one parent each, no
// cycle, each scene's nodes roots) no deeper than max_depth.
document_uris check_document(std::string_view json, std::string const& file, std::uint64_t max_depth);

// The deepest nesting of JSON arrays and objects allowed in a glTF file, whatever max_depth says:
// tinygltf copies extras and extensions recursively.
inline constexpr std::uint64_t nesting_ceiling = 512;

} // namespace canopy::gltf_schema
