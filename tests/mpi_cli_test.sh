#!/usr/bin/env bash
# canopy under mpirun against canopy in one process (ctest label `mpi`, tests/CMakeLists.txt):
#   mpi_cli_test.sh CASE NP CANOPY WORKDIR MPIRUN [MPIRUN-OPTIONS...]
# CASE: render-demo   the demo's four images (every intersector of the figures, the heat map)
#       render-path   a generated terrain, path kernel (4 spp) and AO kernel with the bench alpha rule
#       trace         a generated mesh and ray file: closest/any, single/batch, none/alpha (two
#                     combinations for NP 2, the other two otherwise)
#       fail-all      a scene missing on every rank: one message, non-zero exit
#       fail-one      a scene missing on rank 1 only (each rank's own file name): rank 1's message,
#                     non-zero exit, and no hit file left (neither OUT nor OUT.partial)
# Outputs are compared byte for byte (cmp).
set -euo pipefail
case=$1 np=$2 canopy=$3 work=$4
shift 4
mpirun=("$@" -np "$np")
rm -rf "$work" && mkdir -p "$work" && cd "$work"

fail() { echo "FAIL: $*" >&2; exit 1; }
same() { cmp "$1" "$2" || fail "$2 differs from the one-process $1"; }

# A bumpy 24x24 grid (1152 triangles) and 3001 rays at it (not a multiple of the 256-ray chunks).
make_trace_inputs() {
  python3 - <<'PY'
import math, random, struct
random.seed(7)
n = 24
with open("grid.obj", "w") as f:
    for j in range(n + 1):
        for i in range(n + 1):
            f.write(f"v {i/n:.6f} {0.1*math.sin(7*i/n)*math.cos(5*j/n):.6f} {j/n:.6f}\n")
    for j in range(n):
        for i in range(n):
            a = j*(n + 1) + i + 1
            f.write(f"f {a} {a+1} {a+n+2}\nf {a} {a+n+2} {a+n+1}\n")
with open("grid.rays", "wb") as f:
    for k in range(3001):
        o = (random.uniform(-0.2, 1.2), 1.0, random.uniform(-0.2, 1.2))
        d = (random.uniform(-0.3, 0.3), -1.0, random.uniform(-0.3, 0.3))
        f.write(struct.pack("<8f", *o, 0.0, *d, float("inf")))
PY
}

case $case in
render-demo)
  "$canopy" render -o one --size 160x120 >/dev/null 2>&1
  "${mpirun[@]}" "$canopy" render -o many --size 160x120 >many.txt 2>&1 || { cat many.txt; fail "mpirun render"; }
  for f in one/*.png; do same "$f" "many/${f#one/}"; done
  [ "$(ls one | wc -l)" = 4 ] || fail "the demo wrote $(ls one | wc -l) images, not 4"
  [ "$(grep -c '^rendered 4 images' many.txt)" = 1 ] || { cat many.txt; fail "rank 0 alone prints the summary"; }
  ;;
render-path)
  scene=gen:terrain:resolution=24
  for run in one many; do
    launch=(); [ $run = many ] && launch=("${mpirun[@]}")
    "${launch[@]}" "$canopy" render "$scene" -o $run/path --size 64x48 --kernel path --spp 4 >$run.txt 2>&1 ||
      { cat $run.txt; fail "$run: path"; }
    "${launch[@]}" "$canopy" render "$scene" -o $run/ao --size 64x48 --kernel ao --spp 2 --intersector bench >>$run.txt 2>&1 ||
      { cat $run.txt; fail "$run: ao"; }
  done
  same one/path/terrain.png many/path/terrain.png
  same one/ao/terrain.png many/ao/terrain.png
  ;;
trace)
  make_trace_inputs
  # Two of the four query/mode/intersector combinations with 2 processes, the other two with 3.
  combos=("closest single none" "any batch alpha")
  [ "$np" = 2 ] || combos=("closest batch alpha" "any single none")
  for combo in "${combos[@]}"; do
    read -r query mode isect <<<"$combo"
    args=(trace --scene grid.obj --rays grid.rays --query "$query" --mode "$mode" --intersector "$isect")
    "$canopy" "${args[@]}" --out one.hits >/dev/null
    "${mpirun[@]}" "$canopy" "${args[@]}" --out many.hits >many.txt 2>&1 || { cat many.txt; fail "mpirun $combo"; }
    same one.hits many.hits
    [ ! -e many.hits.partial ] || fail "many.hits.partial left after a trace that succeeded"
    rm one.hits many.hits
  done
  ;;
fail-all)
  status=0
  "${mpirun[@]}" "$canopy" render missing.obj -o out --size 32x32 >out.txt 2>err.txt || status=$?
  [ "$status" != 0 ] || fail "a scene missing everywhere ended with status 0"
  [ "$(grep -c '^canopy' err.txt)" = 1 ] || { cat err.txt; fail "not exactly one message"; }
  grep -qx 'canopy: missing.obj: file not found' err.txt || { cat err.txt; fail "not the loader's message"; }
  ;;
fail-one)
  make_trace_inputs
  cp grid.obj scene_0.obj # rank 0 finds its scene, rank 1 does not
  status=0
  # shellcheck disable=SC2016
  "${mpirun[@]}" sh -c 'exec "$0" render "scene_$OMPI_COMM_WORLD_RANK.obj" -o out --size 32x32' "$canopy" \
    >out.txt 2>err.txt || status=$?
  [ "$status" != 0 ] || fail "a scene missing on rank 1 ended with status 0"
  [ "$(grep -c '^canopy' err.txt)" = 1 ] || { cat err.txt; fail "not exactly one message"; }
  grep -qx 'canopy: rank 1: scene_1.obj: file not found' err.txt || { cat err.txt; fail "not rank 1's message"; }
  status=0
  # shellcheck disable=SC2016
  "${mpirun[@]}" sh -c 'exec "$0" trace --scene "scene_$OMPI_COMM_WORLD_RANK.obj" --rays grid.rays --query any --out hits' \
    "$canopy" >out.txt 2>err.txt || status=$?
  [ "$status" != 0 ] || fail "a trace whose scene is missing on rank 1 ended with status 0"
  grep -qx 'canopy: rank 1: scene_1.obj: file not found' err.txt || { cat err.txt; fail "not rank 1's message"; }
  [ ! -e hits ] && [ ! -e hits.partial ] || fail "a failed trace left a hit file"
  ;;
*) fail "unknown case $case" ;;
esac
echo "ok: $case with $np processes"
