#!/usr/bin/env bash
# Runs the main job from nothing: setup, configure and build the release preset, run the demo.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
"$here/setup.sh"
source "$here/env.sh"
cd "$canopy_root"
cmake --preset release >/dev/null
cmake --build --preset release --target canopy_hello_simd
./build/release/examples/canopy_hello_simd "$@"
