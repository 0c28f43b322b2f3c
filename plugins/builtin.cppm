// canopy.plugins — every built-in plugin, registered in one registry.
//
//   canopy::registry& r = canopy::builtin_registry();   // built-ins + CANOPY_PLUGIN_PATH
//   canopy::scene s = canopy::load_scene("forest.json", r);
//
// builtin_registry() is made on first use: it registers each built-in plugin (the folders of
// plugins/), then loads the shared-library plugins listed in the CANOPY_PLUGIN_PATH environment
// variable (files or folders separated by ':'; see canopy.scene:registry for the entry point).
// A plugin in that list that fails to load is an error (scene_error), thrown by the first call
// and again by every later one; register_builtin_plugins(r) fills a registry of one's own.
export module canopy.plugins;
export import canopy.scene;

export namespace canopy {

void register_builtin_plugins(registry& r);
registry& builtin_registry();

} // namespace canopy
