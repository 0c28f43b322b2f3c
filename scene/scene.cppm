// canopy.scene — the scene graph, the plugin registry, and scenes compiled into BVHs.
//
//   canopy::scene s;                                  // :graph    nodes, meshes, materials, images
//   registry.load(s, "forest.json");                  // :registry loaders, generators, node types, plugins
//   canopy::compiled_scene c = canopy::compile(s);    // :compile  BVHs and instances, skip rules
//   c.closest_hit(ray, isect);                        // :compiled what queries and kernels trace
//   triangulate_polygon(corners);                     // :polygon  loaders' faces of n > 3 corners
//   default_limits().max_texels = 1 << 28;            // :limits   resource limits, checked file opening
//   line_reader lines(text); parse_float(token, ...); // :text     loaders' lines, tokens, numbers, OBJ indices
//
// Built-in loaders and generators live in plugins/ (module canopy.plugins).
export module canopy.scene;
export import :error;
export import :limits;
export import :graph;
export import :registry;
export import :compiled;
export import :compile;
export import :polygon;
export import :text;
