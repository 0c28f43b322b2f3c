#!/usr/bin/env bash
# Two builds of canopy_bench_profile against each other over 17 workloads (seven scenes; primary,
# shadow and random rays), the binaries alternating run by run: per workload the fastest ns per
# ray of each over the rounds, the ratio B / A, and the geometric mean of the ratios.
#   bench/compare_profiles.sh BINARY_A BINARY_B [ROUNDS (default 3)] [RAW_OUTPUT]
# A change to the traversal loop moves single workloads by ±3 % through code layout alone (a build
# with -falign-loops=64 next to one without, the same source: docs/performance.md, Run 18); the
# mean over many workloads is what tells a change from its layout. Build both binaries with the
# same flags, and keep the machine otherwise idle. COMPARE_SET=batch compares the batch queries.
set -euo pipefail
[ $# -ge 2 ] || { sed -n 2,8p "$0" >&2; exit 2; }
a=$1 b=$2 rounds=${3:-3} raw=${4:-$(mktemp)}
: > "$raw"
workloads=("sphere primary closest" "sphere shadow any" "sphere random closest" "terrain primary closest"
  "terrain shadow any" "soup primary closest" "soup shadow any" "engine primary closest" "engine shadow any"
  "engine random closest" "bunny primary closest" "bunny shadow any" "bunny primary any"
  "forest primary closest" "forest shadow any" "slivers primary closest" "slivers shadow any")
# COMPARE_SET=batch: the batch queries instead (coherent primary and shadow rays in packets).
if [ "${COMPARE_SET:-single}" = batch ]; then
  workloads=("engine primary closest --batch" "engine primary any --batch" "engine shadow any --batch"
    "bunny primary closest --batch" "bunny primary any --batch" "bunny shadow any --batch"
    "sphere primary closest --batch" "sphere primary any --batch" "soup primary closest --batch"
    "slivers primary closest --batch" "slivers primary any --batch" "forest primary closest --batch")
fi
for r in $(seq "$rounds"); do
  for w in "${workloads[@]}"; do
    for bin in "$a" "$b"; do
      # shellcheck disable=SC2086 # the workload is three words
      ns=$("$bin" $w --passes 2 2>/dev/null | grep -o "[0-9.]* ns/ray" | awk '{print $1}')
      echo "$r|$w|$bin|$ns" >> "$raw"
    done
  done
done
python3 - "$raw" "$a" "$b" <<'PY'
import collections, math, sys
raw, a, b = sys.argv[1:4]
runs = collections.defaultdict(lambda: collections.defaultdict(list))
order = []
for line in open(raw):
    _, w, binary, ns = line.rstrip("\n").split("|")
    if w not in order:
        order.append(w)
    if ns:
        runs[w][binary].append(float(ns))
logs = []
print(f"{'workload':28s} {'A ns/ray':>9s} {'B ns/ray':>9s} {'B/A':>6s}")
for w in order:
    if not runs[w][a] or not runs[w][b]:
        print(f"{w:28s} (no result)")
        continue
    x, y = min(runs[w][a]), min(runs[w][b])
    logs.append(math.log(y / x))
    print(f"{w:28s} {x:9.1f} {y:9.1f} {y / x:6.3f}")
if logs:
    print(f"geometric mean of B/A over {len(logs)} workloads: {math.exp(sum(logs) / len(logs)):.4f}")
PY
