#!/usr/bin/env bash
# Idempotent set-up for a fresh Debian machine (run as root, or as a user with the
# packages already installed). Installs the Debian packages the project needs when
# they are missing, then a virtual environment in .venv with ctr-bench in it.
# Usage: source-free; call it, then use .venv/bin/ctr-bench.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"

# Debian packages: Python, OSMesa/EGL for offscreen rendering, the AVR toolchain and
# simavr for the firmware-in-the-loop tests.
debs=(python3 python3-venv python3-pip python3-dev gcc make pkg-config
      libosmesa6 libegl1 libegl-mesa0 libgl1 libglx-mesa0 libgles2
      gcc-avr avr-libc binutils-avr simavr libsimavr-dev libelf-dev)
missing=()
if command -v dpkg-query >/dev/null 2>&1; then
  for p in "${debs[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
fi
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "setup: missing Debian packages: ${missing[*]} (run as root, or install them)" >&2
    exit 1
  fi
  echo "setup: installing Debian packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

py=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  "$py" -m venv .venv
fi
stamp=.venv/.ctr-bench-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing ctr-bench and its dependencies into .venv"
  .venv/bin/python -m pip install -q --upgrade pip "setuptools>=77"
  .venv/bin/python -m pip install -q -e ".[test]"
  touch "$stamp"
fi
