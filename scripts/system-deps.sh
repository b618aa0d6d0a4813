#!/usr/bin/env bash
# Installs the system libraries stratamap's Python wheels need on Debian/Ubuntu:
#   libusb-1.0-0  (Open3D's wheel links against libusb-1.0.so.0)
#   libgl1, libgomp1 (Open3D's rendering module and OpenMP runtime; present on most images)
# With --browser, also Debian's chromium, which the test suite's browser tests drive (`make test` asks
# for it; `make demo` does not).
# Idempotent: does nothing when the packages are already there.
set -euo pipefail

need=()
if [ "${1:-}" = "--browser" ] && ! command -v chromium >/dev/null 2>&1; then
    need+=(chromium)
fi
have_lib() { ldconfig -p 2>/dev/null | grep -q "$1"; }
have_lib 'libusb-1.0.so.0' || need+=(libusb-1.0-0)
have_lib 'libgomp.so.1' || need+=(libgomp1)
have_lib 'libGL.so.1' || need+=(libgl1)

if [ ${#need[@]} -eq 0 ]; then
    exit 0
fi

echo "stratamap: installing system packages: ${need[*]}" >&2
if [ "$(id -u)" -eq 0 ]; then
    SUDO=""
elif command -v sudo >/dev/null 2>&1; then
    SUDO="sudo"
else
    echo "stratamap: missing system packages ${need[*]} and no root/sudo to install them." >&2
    echo "           Ask an administrator to run: apt-get install -y ${need[*]}" >&2
    exit 1
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "stratamap: missing ${need[*]}; install them with your system's package manager." >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
