#!/usr/bin/env bash
# Instructions per ray of both libraries, figure by figure, in one run of canopy_bench_embree under
# callgrind. Each library's loop over a figure's rays is counted whole (the bench's call, the
# ray's conversion and the hit written back included: the tbb task that runs the loop, one per
# library), and Embree's also inside rtcIntersect1 / rtcOccluded1 alone (its filter function
# included). A dump is written before each figure is measured, so each figure's counts sit in a
# file of their own; the work counts and builds are not collected.
#   bench/callgrind_embree.sh BINARY OUTDIR SCENE [RAYS]
# e.g. bench/callgrind_embree.sh build/isa-v3/bench/canopy_bench_embree /tmp/cg sphere primary,shadow
# valgrind does not decode AVX-512: BINARY must be built for x86-64-v3 or lower (the isa-v3 preset),
# and Embree then runs its AVX2 kernels. One thread, one round (the figures' speeds mean nothing).
set -euo pipefail
[ $# -ge 3 ] || { sed -n 2,10p "$0" >&2; exit 2; }
bin=$1 out=$2 scene=$3 rays=${4:-primary,random,shadow}
command -v valgrind >/dev/null || { echo "callgrind_embree: valgrind is needed (apt-get install valgrind)" >&2; exit 1; }
command -v callgrind_annotate >/dev/null || { echo "callgrind_embree: callgrind_annotate is needed" >&2; exit 1; }
mkdir -p "$out"
rm -f "$out"/cg.out*
valgrind --tool=callgrind --callgrind-out-file="$out/cg.out" --collect-atstart=no \
  --toggle-collect='_ZN3tbb6detail2d19start_for*measure_figure*7execute*' \
  --dump-before='_ZN12_GLOBAL__N_114measure_figure*' \
  "$bin" --scenes "$scene" --rays "$rays" --rounds 1 --threads-list 1 >"$out/bench.log" 2>"$out/valgrind.log"
# Figures in the order measured, with their ray counts (the bench prints them below the table).
mapfile -t figures < <(awk -F'|' '/\(Mrays\/s\)/ {gsub(/^ +| +$/, "", $3); sub(/ \(Mrays\/s\)/, "", $3); print $3}' "$out/bench.log")
declare -A count
for entry in $(awk '/^Rays:/ {sub(/^Rays: /, ""); gsub(/[,.]/, ""); print}' "$out/bench.log" | tr ' ' '\n' | paste -d= - -); do
  count[${entry%%=*}]=${entry##*=}
done
# Dump 1 holds what ran before the first figure (nothing collected); dump k + 1 holds figure k, the
# last figure's counts are in the final dump (the file without a number).
mapfile -t dumps < <(ls "$out"/cg.out.* 2>/dev/null | sort -t. -k3 -n)
dumps+=("$out/cg.out")
printf '| figure | rays | Canopy loop | Embree loop | Embree in rtc*1 | Canopy / Embree (loops) |\n|---|---|---|---|---|---|\n'
for k in "${!figures[@]}"; do
  file=${dumps[$((k + 1))]:-}
  [ -n "$file" ] && [ -f "$file" ] || { echo "callgrind_embree: no dump for ${figures[$k]}" >&2; exit 1; }
  set_name=${figures[$k]%% *}
  n=${count[$set_name]:-0}
  [ "$n" -gt 0 ] || { echo "callgrind_embree: no ray count for set '$set_name'" >&2; exit 1; }
  ann=$(callgrind_annotate --inclusive=yes --threshold=100 "$file" 2>/dev/null)
  # The loops' tasks, by their mangled names (module-attached names do not demangle here): the
  # first lambda of measure_figure (UlvE_) traces Canopy, the second (UlvE0_) Embree.
  core=$(awk '/:rtcIntersect1( |$)|:rtcOccluded1( |$)/ {gsub(",", "", $1); s += $1} END {print s + 0}' <<<"$ann")
  canopy=$(awk '/start_for/ && /7execute/ && /UlvE_clEv/ {gsub(",", "", $1); s += $1} END {print s + 0}' <<<"$ann")
  embree=$(awk '/start_for/ && /7execute/ && /UlvE0_clEv/ {gsub(",", "", $1); s += $1} END {print s + 0}' <<<"$ann")
  # A loop that matched nothing means the names above no longer fit the bench's source.
  [ "$canopy" != 0 ] && [ "$embree" != 0 ] || {
    echo "callgrind_embree: no traced loop found for ${figures[$k]} (were measure_figure's lambdas reordered?)" >&2
    exit 1
  }
  awk -v f="${figures[$k]}" -v n="$n" -v c="$canopy" -v e="$embree" -v r="$core" \
    'BEGIN { printf "| %s | %d | %.0f | %.0f | %.0f | %.2f |\n", f, n, c / n, e / n, r / n, (e > 0 ? c / e : 0) }'
done
