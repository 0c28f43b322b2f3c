#!/usr/bin/env bash
# Instructions per ray of one canopy_bench_profile workload, counted by callgrind inside trace_rays
# (or trace_batch with --batch) only; the per-function breakdown is in the callgrind output OUT
# (callgrind_annotate OUT).
#   bench/callgrind_rays.sh BINARY OUT SCENE RAYS QUERY [canopy_bench_profile options...]
# e.g. bench/callgrind_rays.sh build/isa-v3/bench/canopy_bench_profile /tmp/cg.out sphere primary closest --quick
# valgrind does not decode AVX-512: BINARY must be built for x86-64-v3 or lower (the isa-v3 preset).
# The benchmark scenes have no textures, so OpenImageIO (canopy.image's backend, loaded only for
# images) stays out of the process: its libhwy reads the time-stamp counter with RDTSCP when it is
# loaded, which valgrind 3.19 cannot run.
set -euo pipefail
[ $# -ge 5 ] || { sed -n 2,7p "$0" >&2; exit 2; }
bin=$1 out=$2; shift 2
command -v valgrind >/dev/null || { echo "callgrind_rays: valgrind is needed (apt-get install valgrind)" >&2; exit 1; }
toggle='*trace_rays*'
passes=1 prev=
for a in "$@"; do
  [ "$a" = "--batch" ] && toggle='*trace_batch*'
  [ "$prev" = "--passes" ] && passes=$a
  prev=$a
done
# valgrind's own messages go to $out.valgrind; the program's errors (an ISA valgrind's CPU lacks,
# for one: BINARY built with -march=native) stay on stderr, and a failed run stops here.
if ! valgrind --tool=callgrind --log-file="$out.valgrind" --callgrind-out-file="$out" --collect-atstart=no \
  --toggle-collect="$toggle" "$bin" "$@" > "$out.log"; then
  echo "callgrind_rays: $bin failed under valgrind (see above and $out.valgrind)" >&2
  exit 1
fi
cat "$out.log"
rays=$(awk '/^rays / {gsub(",", "", $2); print $2}' "$out.log")
total=$(awk '/^summary:/ {print $2}' "$out")
awk -v t="$total" -v r="$rays" -v p="$passes" \
  'BEGIN { printf "instructions in the traced function: %d, %.1f per ray (%d rays, %d passes)\n", t, t / (r * p), r, p }'
