// canopy.plugins — implementation: the list of built-in plugins.
module;
#include <cstdlib>
#include <exception>
#include <string>
module canopy.plugins;
import canopy.plugins.oiio;
import canopy.plugins.openmesh;
import canopy.plugins.bench;
import canopy.plugins.procedural;
import canopy.plugins.obj;
import canopy.plugins.json;
import canopy.plugins.gltf;

namespace canopy {

void register_builtin_plugins(registry& r) {
    // In any order: an extension's default loader is chosen by the rank each loader registers with
    // (canopy.scene:registry's loader_rank), e.g. obj for .obj, with bench and openmesh as alternatives.
    register_bench_plugin(r);
    register_openmesh_plugin(r);
    register_procedural_plugin(r);
    register_oiio_plugin(r);
    register_obj_plugin(r);
    register_json_plugin(r);
    register_gltf_plugin(r);
}

registry& builtin_registry() {
    struct holder {
        registry r;
        std::exception_ptr failure;
        holder() {
            register_builtin_plugins(r);
            if (char const* path = std::getenv("CANOPY_PLUGIN_PATH")) {
                try {
                    r.load_plugin_path(path);
                } catch (...) {
                    failure = std::current_exception();
                }
            }
        }
    };
    static holder h;
    if (h.failure) std::rethrow_exception(h.failure);
    return h.r;
}

} // namespace canopy
