#!/usr/bin/env bash
# Set up bimscan from nothing on a Debian-like machine: the system library Open3D needs,
# a virtual environment in .venv, and the package with every optional part.
#   scripts/install.sh                 install bimscan (all extras)
#   scripts/install.sh --test          also install the test dependencies
#   scripts/install.sh --docs          also install the documentation tools (MkDocs; see mkdocs.yml)
#   scripts/install.sh --test --docs   flags combine, in any order
set -euo pipefail

test="" docs=""
for flag in "$@"; do
  case "$flag" in
    --test) test=",test" ;;
    --docs) docs=",docs" ;;
    -h|--help)
      sed -n '2,7p' "$0" | sed 's/^# \{0,1\}//'
      exit 0 ;;
    *)
      echo "error: unknown option '$flag'; use --test and/or --docs (see 'scripts/install.sh --help')" >&2
      exit 2 ;;
  esac
done
extras="all${test}${docs}"
cd "$(dirname "$0")/.."

# System libraries two wheels load: Open3D's libusb-1.0, LightGBM's OpenMP runtime (libgomp).
missing=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || missing+=(libusb-1.0-0)
ldconfig -p 2>/dev/null | grep -q 'libgomp.so.1' || missing+=(libgomp1)
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then sudo_cmd=""; else sudo_cmd="sudo"; fi
  $sudo_cmd apt-get update -qq
  $sudo_cmd apt-get install -y -qq "${missing[@]}"
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# torch is pinned in the extras (2.13.0, CPU wheel on this kind of machine).
.venv/bin/python -m pip install -q -e ".[${extras}]"
