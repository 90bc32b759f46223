#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# Installs the Debian 12 packages iwlomap needs to build, test and run (as root, or with sudo).
# Does nothing when they are all present already.
set -euo pipefail

PACKAGES=(build-essential cmake git pkg-config
  libeigen3-dev libpcl-dev liboctomap-dev libvtk9-dev libflann-dev libopenmpi-dev openmpi-bin
  libgtest-dev libgmock-dev libbenchmark-dev
  octomap-tools pcl-tools xvfb xauth doxygen
  clang libclang-rt-14-dev ccache
  libceres-dev libyaml-cpp-dev
  python3-dev python3-pybind11 python3-numpy python3-pytest python3-pip python3-setuptools python3-wheel)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#PACKAGES[@]} packages present"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "setup: need root (or sudo) to install: ${missing[*]}" >&2; exit 1; }
  SUDO="sudo"
fi
echo "setup: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
