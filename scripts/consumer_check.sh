#!/usr/bin/env bash
# Installs the release build into build/install and builds examples/consumer — a project outside
# the tree that does find_package(canopy) and `import canopy;` — against it, then runs it. Checks
# that the installed package records a concrete ISA (never 'native'), that the consumer's
# configure states it, that the consumer was compiled with exactly the recorded flags, and that
# the consumer's compile-time features match the package's (the program checks that itself).
# The README's C++ blocks are built in the same project (scripts/readme_code.py: programs are
# compiled, linked and run; translation units compiled; the others are lines of compiled sources).
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
"$here/setup.sh"
source "$here/env.sh"
cd "$canopy_root"
cmake --preset release >/dev/null
cmake --build --preset release
rm -rf build/install build/consumer build/readme_blocks
cmake --install build/release --prefix build/install >/dev/null
python3 scripts/readme_code.py write build/readme_blocks

config=build/install/lib/cmake/canopy/canopyConfig.cmake
isa=$(sed -n 's/^set(canopy_ISA "\(.*\)")$/\1/p' "$config")
flags=$(sed -n 's/^set(canopy_ISA_FLAGS "\(.*\)")$/\1/p' "$config" | tr ';' ' ')
if [ -z "$isa" ] || [ -z "$flags" ] || grep -q 'native' <<<"$isa $flags"; then
  echo "consumer: the installed package records no concrete ISA (canopy_ISA='$isa', flags '$flags')" >&2
  exit 1
fi

configure_log=$(cmake -S examples/consumer -B build/consumer -G Ninja -DCMAKE_CXX_COMPILER="${CXX:-clang++-19}" \
      -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_EXPORT_COMPILE_COMMANDS=ON -DCMAKE_PREFIX_PATH="$canopy_root/build/install" \
      -DCANOPY_README_BLOCKS="$canopy_root/build/readme_blocks")
grep -F "canopy 0.1.0: built for the x86-64 ISA $isa ($flags)" <<<"$configure_log" >&2 || {
  echo "consumer: configure did not state the package's ISA $isa:" >&2; echo "$configure_log" >&2; exit 1; }
cmake --build build/consumer
# The consumer's own source is compiled with the recorded flags, in order.
grep -F "main.cpp" build/consumer/compile_commands.json | grep -qF -- "$flags" || {
  echo "consumer: main.cpp was not compiled with the recorded ISA flags '$flags'" >&2; exit 1; }
./build/consumer/consumer
while read -r program; do
  ./build/consumer/"$program" || { echo "consumer: the README's $program failed (status $?)" >&2; exit 1; }
done <build/readme_blocks/programs.txt
echo "consumer: built against the installed package (ISA $isa) and ran, with the README's C++ blocks"
