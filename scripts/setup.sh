#!/usr/bin/env bash
# Set up pointtraj on a fresh Debian/Ubuntu machine: the system libraries Open3D needs, then a
# local virtual environment (.venv) with the project installed in editable mode.
# Idempotent: a second run only checks. Usage: bash scripts/setup.sh [EXTRAS], e.g. "test".
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-}"

# Open3D needs libEGL/libGL/libusb to import, and Vulkan (Mesa's llvmpipe) to render off-screen.
sys_pkgs=(libegl1 libgl1 libusb-1.0-0 libvulkan1 mesa-vulkan-drivers libgomp1)
missing=()
if command -v dpkg >/dev/null 2>&1; then
  for p in "${sys_pkgs[@]}"; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
  done
fi
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing system packages: ${missing[*]}" >&2
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($PY --version)" >&2
  "$PY" -m venv .venv
fi
# The numerical libraries at the versions the documented figures were measured with
# (scripts/constraints.txt); POINTTRAJ_UNPINNED=1 takes the newest instead.
constraints=scripts/constraints.txt
pins=(-c "$constraints")
[ "${POINTTRAJ_UNPINNED:-}" = "1" ] && pins=()
stamp=".venv/.pointtraj-installed${extras:+-$extras}${pins[*]:+-pinned}"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ "$constraints" -nt "$stamp" ]; then
  echo "setup: installing pointtraj${extras:+[$extras]} into .venv${pins[*]:+ (versions of $constraints)}" >&2
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".${extras:+[$extras]}" "${pins[@]}"
  touch "$stamp"
fi
