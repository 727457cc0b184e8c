#!/usr/bin/env bash
# Install everything crowdrom needs and build it. Idempotent: fast when all is present.
#   scripts/setup.sh            Debian packages + Python venv + Release build (build/bin)
#   scripts/setup.sh --debug    the same, plus the Debug-checked build used by the tests (build-debug)
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

PKGS=(gfortran cmake ninja-build pkg-config libopenmpi-dev openmpi-bin libopenblas-dev liblapack-dev
      libscalapack-openmpi-dev libhdf5-openmpi-dev hdf5-tools libfftw3-dev libsuitesparse-dev
      valgrind)
missing=()
for p in "${PKGS[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# Python post-processing environment
if ! .venv/bin/python -c "import numpy, scipy, h5py, sklearn, matplotlib, pytest, joblib, pedpy" >/dev/null 2>&1; then
  echo "setup: creating Python venv in .venv"
  python3 -m venv .venv
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
  .venv/bin/python -m pip install -q -r scripts/requirements.txt
fi

build() {  # build <dir> <type>
  if [ ! -f "$1/build.ninja" ]; then
    cmake -S . -B "$1" -G Ninja -DCMAKE_BUILD_TYPE="$2" >/dev/null
  fi
  cmake --build "$1" -j "$(nproc)"
}
build build Release
if [ "${1:-}" = "--debug" ]; then
  build build-debug Debug
fi
