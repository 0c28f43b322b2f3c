#!/usr/bin/env bash
# Builds the fuzz preset and runs each scene-parser fuzzer (fuzz/) for a bounded time; fails on
# any crash, sanitizer report, leak, out-of-memory or slow input (libFuzzer exits non-zero and
# leaves the input in the work folder's artifacts/).
#   scripts/fuzz.sh [SECONDS]    seconds per fuzzer, default 60
# CANOPY_FUZZ_BUILD sets the build folder (default build/fuzz). Inputs found interesting are kept
# in <build>/fuzz-work/<parser>/corpus between runs; the committed seeds are fuzz/corpus/<parser>.
set -euo pipefail
seconds=${1:-60}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
source "$here/env.sh"
cd "$canopy_root"
build=${CANOPY_FUZZ_BUILD:-build/fuzz}
cmake --preset fuzz -B "$build" >/dev/null
cmake --build "$build" -j2 --target obj_fuzzer json_fuzzer
for parser in obj json; do
  work="$build/fuzz-work/$parser"
  mkdir -p "$work/corpus" "$work/artifacts"
  echo "fuzz: $parser for $seconds s"
  "$build/fuzz/${parser}_fuzzer" -max_total_time="$seconds" -rss_limit_mb=2048 -max_len=16384 -timeout=10 \
    -dict="fuzz/$parser.dict" -artifact_prefix="$work/artifacts/" -print_final_stats=1 \
    "$work/corpus" "fuzz/corpus/$parser" 2>&1 | grep -v -e '^#[0-9]' -e '^"' || { echo "fuzz: $parser failed (see $work/artifacts)"; exit 1; }
done
echo "fuzz: no findings"
