#!/usr/bin/env bash
# Set up bimscan from nothing on a Debian-like machine: the system library Open3D needs,
# a virtual environment in .venv, and the package with every optional part.
#   scripts/install.sh          install bimscan (all extras)
#   scripts/install.sh --test   also install the test dependencies
set -euo pipefail
cd "$(dirname "$0")/.."

extras="all"
[ "${1:-}" = "--test" ] && extras="all,test"

# Open3D's wheel imports only with libusb-1.0 present.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = 0 ]; then sudo_cmd=""; else sudo_cmd="sudo"; fi
  $sudo_cmd apt-get update -qq
  $sudo_cmd apt-get install -y -qq libusb-1.0-0
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# torch is pinned in the extras (2.13.0, CPU wheel on this kind of machine).
.venv/bin/python -m pip install -q -e ".[${extras}]"
