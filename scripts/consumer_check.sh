#!/usr/bin/env bash
# Installs the release build into build/install and builds examples/consumer — a project outside
# the tree that does find_package(canopy) and `import canopy;` — against it, then runs it.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
"$here/setup.sh"
source "$here/env.sh"
cd "$canopy_root"
cmake --preset release >/dev/null
cmake --build --preset release
rm -rf build/install build/consumer
cmake --install build/release --prefix build/install >/dev/null
cmake -S examples/consumer -B build/consumer -G Ninja -DCMAKE_CXX_COMPILER=clang++-19 -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_PREFIX_PATH="$canopy_root/build/install" >/dev/null
cmake --build build/consumer
./build/consumer/consumer
echo "consumer: built against the installed package and ran"
