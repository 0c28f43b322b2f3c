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

# Zero cost of unused intersectors, by instruction counts (callgrind cannot run AVX-512 code,
# hence the x86-64-v3 build of the one workload binary).
if [ "$preset" = release ]; then
  cmake --preset isa-v3 >/dev/null
  cmake --build --preset isa-v3 --target canopy_bench_zero_cost
  bench/zero_cost.sh --check 2000 build/isa-v3/bench/canopy_bench_zero_cost
fi
