#!/usr/bin/env bash
# Builds the fuzz preset and runs every scene-parser fuzzer (fuzz/: the list is the one
# fuzz/CMakeLists.txt writes to <build>/fuzz/fuzzers.txt) for a bounded time under ASan + UBSan;
# fails on any crash, sanitizer report, leak, out-of-memory or slow input (libFuzzer exits
# non-zero and leaves the input in the work folder's artifacts/).
#   scripts/fuzz.sh [SECONDS]    total seconds for all fuzzers together, split evenly (default 120;
#                                at least 10 s each)
# CANOPY_FUZZ_BUILD names another build folder, already configured with CANOPY_BUILD_FUZZERS=ON and
# sanitizers (e.g. build/asan, which CI uses); by default build/fuzz, configured with the preset
# fuzz. Inputs found interesting are kept
# in <build>/fuzz-work/<fuzzer>/corpus between runs; the committed seeds are fuzz/corpus/<fuzzer>,
# the dictionaries fuzz/<fuzzer>.dict.
set -euo pipefail
total=${1:-120}
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
source "$here/env.sh"
cd "$canopy_root"
build=${CANOPY_FUZZ_BUILD:-build/fuzz}
if [[ -z ${CANOPY_FUZZ_BUILD:-} ]]; then
  cmake --preset fuzz -B "$build" >/dev/null
elif ! grep -q '^CANOPY_BUILD_FUZZERS:BOOL=ON' "$build/CMakeCache.txt" 2>/dev/null; then
  echo "fuzz: $build is not a build folder configured with CANOPY_BUILD_FUZZERS=ON" >&2
  exit 2
fi
cmake --build "$build" -j2 --target fuzzers
mapfile -t fuzzers < <(grep -v '^$' "$build/fuzz/fuzzers.txt")
seconds=$(( total / ${#fuzzers[@]} ))
(( seconds >= 10 )) || seconds=10
for name in "${fuzzers[@]}"; do
  work="$build/fuzz-work/$name"
  mkdir -p "$work/corpus" "$work/artifacts"
  options=(-max_total_time="$seconds" -rss_limit_mb=2048 -max_len=16384 -timeout=10
           -artifact_prefix="$work/artifacts/" -print_final_stats=1)
  [[ -f "fuzz/$name.dict" ]] && options+=(-dict="fuzz/$name.dict")
  seeds=()
  [[ -d "fuzz/corpus/$name" ]] && seeds=("fuzz/corpus/$name")
  echo "fuzz: $name for $seconds s"
  status=0
  "$build/fuzz/${name}_fuzzer" "${options[@]}" "$work/corpus" "${seeds[@]}" >"$work/log" 2>&1 || status=$?
  grep -v -e '^#[0-9]' -e '^"' "$work/log" || true
  if (( status != 0 )); then echo "fuzz: $name failed (see $work/artifacts and $work/log)"; exit 1; fi
done
echo "fuzz: no findings"
