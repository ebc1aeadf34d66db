#!/usr/bin/env bash
# Installs the Debian packages meshdenoise needs, only when they are missing, so a second run is instant.
#   libusb-1.0-0 libegl1 libgl1       Open3D's library links libusb-1.0.so.0, libEGL.so.1 and libGL.so.1, pymeshlab's
#                                     libGL.so.1: neither imports without them (libegl1/libgl1 pull libegl-mesa0/libglx-mesa0)
#   libvulkan1 mesa-vulkan-drivers    headless rendering with Open3D's OffscreenRenderer (Filament on Mesa's
#                                     software Vulkan, lavapipe)
#   chromium                          the report test opens the HTML report in headless Chromium
#   python3-venv                      Debian's python3 cannot create a virtual environment without it
#   libsuitesparse-dev, gcc,
#   python3-dev                       to build scikit-sparse (CHOLMOD with reusable analysis, dev extras)
set -euo pipefail

PY=${PY:-python3}
wanted=(libusb-1.0-0 libegl1 libgl1 libvulkan1 mesa-vulkan-drivers chromium libsuitesparse-dev)
missing=()
for pkg in "${wanted[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ! "$PY" -c "import ensurepip, venv" >/dev/null 2>&1; then
    missing+=(python3-venv)
fi
command -v cc >/dev/null 2>&1 || missing+=(gcc)
if ! "$PY" -c "import os, sysconfig; exit(not os.path.exists(os.path.join(sysconfig.get_paths()['include'], 'Python.h')))" >/dev/null 2>&1; then
    missing+=(python3-dev)
fi
[ ${#missing[@]} -eq 0 ] && exit 0

if ! command -v apt-get >/dev/null 2>&1; then
    echo "meshdenoise: missing system packages (${missing[*]}) and no apt-get here: install them with your package manager." >&2
    exit 1
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
        echo "meshdenoise: need root to install ${missing[*]}: run 'sudo apt-get update && sudo apt-get install -y ${missing[*]}'." >&2
        exit 1
    fi
fi
echo "meshdenoise: installing system packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
