#!/usr/bin/env bash
# Installs every Debian 12 package that flyover's build, tests, benchmarks and demo need.
# Idempotent: when everything is already installed it prints nothing and exits 0.
set -euo pipefail

PACKAGES=(
  build-essential cmake ninja-build ccache pkg-config
  libopenvdb-dev libopenvdb-tools libboost-iostreams-dev zlib1g-dev
  libisal-dev                            # ISA-L: .nii.gz inflation (volume/io/gzip_stream.h)
  libopenmesh-dev libembree-dev libtbb-dev
  libinsighttoolkit5-dev libgdcm-tools   # gdcm-tools: GDCM's CMake config names its binaries
  libnifti2-dev                          # nifti2.h: the NIfTI-2 header struct (volume/image_io.cpp)
  libgtest-dev libgmock-dev libbenchmark-dev
  libcli11-dev libspdlog-dev nlohmann-json3-dev libxxhash-dev libpng-dev libtoml11-dev
  ffmpeg time
  libcpp-httplib-dev libturbojpeg0-dev   # flyover view: HTTP server (cpp-httplib), JPEG frames
  snakemake bc                           # workflows/cohort/Snakefile and its test; bench/cohort_bench.sh
)

# flyover view's browser test (tests/view/browser): Debian's chromium, driven from node by
# playwright-core. node and npm come from Debian (Node 18, npm 9) only when missing: a machine
# with Node from another source keeps it (Debian's npm conflicts with such a nodejs).
PACKAGES+=(chromium)
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
  PACKAGES+=(nodejs npm)
fi

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    SUDO="sudo -n"
  else
    echo "setup.sh: missing Debian packages: ${missing[*]}" >&2
    echo "setup.sh: run this script as root (or with password-less sudo) to install them" >&2
    exit 1
  fi
fi

echo "setup.sh: installing ${#missing[@]} Debian package(s): ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "setup.sh: done"
