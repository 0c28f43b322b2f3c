#!/usr/bin/env bash
# Runs the whole test suite from nothing: setup, configure, build, ctest.
#   scripts/test.sh [PRESET]      PRESET: release (default), debug, asan
set -euo pipefail
preset=${1:-release}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
"$here/setup.sh"
source "$here/env.sh"
cd "$canopy_root"
cmake --preset "$preset" >/dev/null
cmake --build --preset "$preset"
ctest --preset "$preset"
