#!/usr/bin/env bash
# Installs the Debian 12 packages sope builds and tests with. Skips apt when they are all
# present already; uses sudo when not run as root.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config ccache
  libopencv-dev libopencv-contrib-dev libpcl-dev libceres-dev libeigen3-dev
  libglfw3-dev libx11-dev libosmesa6-dev libv4l-dev
  libcli11-dev nlohmann-json3-dev libfmt-dev libspdlog-dev
  libfaiss-dev libtbb-dev libblas-dev liblapack-dev liblz4-dev
  libgtest-dev libbenchmark-dev lld
  pybind11-dev python3-dev python3-numpy python3-pytest python3-open3d python3-faiss
  xvfb xauth
)

missing=()
for package in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$package")
  fi
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
echo "install-deps: installing ${missing[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y --no-install-recommends "${missing[@]}"
