#!/usr/bin/env bash
# Install the Debian system libraries VoxNeRO needs, only where missing (idempotent).
#   libusb-1.0-0                    : Open3D's shared library links against it
#   libvulkan1 mesa-vulkan-drivers  : Open3D's headless (offscreen) renderer on software Vulkan
#   libgl1 libegl1 libgomp1         : Open3D's GUI/rendering and OpenMP runtime
#   xvfb xauth                      : a virtual X server, so the test of `voxnero view`'s
#                                     interactive window runs on headless CI machines
# Extra package names given as arguments are installed too (`make corpus` passes libllvm19,
# which Mitsuba 3's fast JIT variants load).
set -euo pipefail
need=()
for p in libusb-1.0-0 libvulkan1 mesa-vulkan-drivers libgl1 libegl1 libgomp1 xvfb xauth "$@"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || need+=("$p")
done
if [ ${#need[@]} -eq 0 ]; then exit 0; fi
if [ "$(id -u)" != "0" ]; then
  echo "voxnero: missing system packages: ${need[*]}" >&2
  echo "  install them with: sudo apt-get install ${need[*]}" >&2
  exit 1
fi
echo "installing system packages: ${need[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
