#!/usr/bin/env bash
# Runs the main job from nothing: setup, configure and build the release preset, then render the
# demo scene into the four images of the paper's Figure 1 (out/*.png). Arguments go to
# `canopy render` (e.g. -o DIR, --size WxH).
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
"$here/setup.sh"
source "$here/env.sh"
cd "$canopy_root"
cmake --preset release >/dev/null
cmake --build --preset release --target canopy_cli
./build/release/tools/canopy render "$@"
