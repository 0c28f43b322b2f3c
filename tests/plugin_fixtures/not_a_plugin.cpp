// A shared library that is not a Canopy plugin: it has a symbol, but not canopy_plugin_register.
// scene_plugin_test loads it to check the loader's "no entry point" error.
extern "C" [[gnu::visibility("default")]] int canopy_plugin_registers(unsigned abi_version) {
    return abi_version == 0 ? 1 : 0;
}
