#!/usr/bin/env bash
# Instruction counts (callgrind, deterministic) of the same query with and without intersectors
# and instancing, counted inside trace_all only. Prints a Markdown table; with --check, fails
# when the explicit default_intersector, or a filter that accepts everything, costs more than 1 %
# over the default query. (A triangle hook of the user's own is called once per triangle by
# contract, so leaves are tested one triangle at a time instead of four at once; a box hook is
# called once per box instead of the 8-wide SIMD test: their costs are reported, not bounded.)
#   bench/zero_cost.sh [--check] [RAYS] [BINARY]
# When canopy_bench_zero_cost_embree sits beside BINARY (benchmarks built), Embree's cost of a
# no-op intersection filter is added for comparison.
set -euo pipefail
check=0
if [ "${1:-}" = "--check" ]; then check=1; shift; fi
rays=${1:-20000}
bin=${2:-build/release/bench/canopy_bench_zero_cost}
command -v valgrind >/dev/null || { echo "zero_cost: valgrind is needed (apt-get install valgrind)" >&2; exit 1; }
count() {
  local out
  out=$(mktemp)
  valgrind --tool=callgrind --callgrind-out-file="$out" --collect-atstart=no --toggle-collect='*trace_all*' \
    "$bin" "$1" "$rays" >/dev/null 2>&1
  awk '/^summary:/ {print $2}' "$out"
  rm -f "$out"
}
declare -A n
for mode in default explicit filter_all forwarding forwarding_tri single instanced instanced_rt; do n[$mode]=$(count "$mode"); done
ratio() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%+.3f %%", (a / b - 1) * 100 }'; }
echo "| workload ($rays rays, icosphere 5120 triangles) | instructions | vs. baseline |"
echo "|---|---|---|"
echo "| closest_hit(r, f, l) | ${n[default]} | baseline |"
echo "| closest_hit(r, f, l, default_intersector{}) | ${n[explicit]} | $(ratio "${n[explicit]}" "${n[default]}") |"
echo "| a filter that accepts every candidate | ${n[filter_all]} | $(ratio "${n[filter_all]}" "${n[default]}") |"
echo "| paper-style forwarding triangle hook (called per triangle: leaves tested one at a time) | ${n[forwarding_tri]} | $(ratio "${n[forwarding_tri]}" "${n[default]}") |"
echo "| paper-style forwarding triangle + box hooks (box hook called per box) | ${n[forwarding]} | $(ratio "${n[forwarding]}" "${n[default]}") |"
echo "| one level (mesh BVH) | ${n[single]} | baseline |"
echo "| identity instance in a top-level BVH | ${n[instanced]} | $(ratio "${n[instanced]}" "${n[single]}") |"
echo "| rotated instance in a top-level BVH | ${n[instanced_rt]} | $(ratio "${n[instanced_rt]}" "${n[single]}") |"
embree_bin="$(dirname "$bin")/canopy_bench_zero_cost_embree"
if [ -x "$embree_bin" ]; then
  bin=$embree_bin
  e_none=$(count none)
  e_noop=$(count noop_filter)
  echo "| Embree 3 rtcIntersect1, no filter | $e_none | baseline |"
  echo "| Embree 3 with a no-op intersection filter | $e_noop | $(ratio "$e_noop" "$e_none") |"
fi
if [ "$check" = 1 ]; then
  awk -v d="${n[default]}" -v e="${n[explicit]}" -v f="${n[filter_all]}" 'BEGIN {
    if (e > d * 1.01 || f > d * 1.01) { print "zero_cost: an intersector that adds nothing costs more than 1 %" > "/dev/stderr"; exit 1 }
  }'
  echo "zero_cost: default_intersector and an accept-all filter are within 1 % of the default query"
fi
