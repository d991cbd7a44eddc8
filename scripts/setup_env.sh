#!/usr/bin/env bash
# Set up everything lfm_studio needs, from a bare clone: Debian system packages
# (Qt/OpenGL runtime + Xvfb), a virtual environment in .venv, torch, and the
# package itself (editable) with the studio, scale (Dask, Zarr, OME-Zarr) and dev extras.
# Idempotent: a stamp of pyproject.toml + this script skips the pip step when
# nothing changed. Sourced by scripts/studio.sh and scripts/test.sh.
set -euo pipefail

repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${LFM_VENV:-$repo_root/.venv}"
torch_version="${LFM_TORCH_VERSION:-2.13.0}"

# Runtime libraries for Qt (PySide6) and napari's OpenGL canvas, and Xvfb for
# headless tests (docs/platform.md, "Display").
apt_packages=(libgl1 libegl1 libglib2.0-0 libfontconfig1 libdbus-1-3 libxkbcommon0
  libxkbcommon-x11-0 libxcb-cursor0 libxcb-icccm4 libxcb-keysyms1 libxcb-image0
  libxcb-render-util0 libxcb-shape0 libxcb-randr0 libxcb-xfixes0 xvfb xauth)

install_system_packages() {
  command -v dpkg-query >/dev/null 2>&1 || return 0   # not Debian/Ubuntu: see README
  local missing=()
  for pkg in "${apt_packages[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
  done
  python3 -c "import ensurepip, venv" >/dev/null 2>&1 || missing+=(python3-venv python3-pip)
  [ ${#missing[@]} -eq 0 ] && return 0
  echo "lfm_studio: installing system packages: ${missing[*]}"
  local sudo=""
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
      echo "lfm_studio: please install as root: apt-get install -y ${missing[*]}" >&2; return 1
    fi
  fi
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

install_python_packages() {
  [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
  local stamp="$venv/.lfm-studio-stamp"
  local want
  want="$(cat "$repo_root/pyproject.toml" "$repo_root/scripts/setup_env.sh" | sha256sum | cut -d' ' -f1)"
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then return 0; fi
  echo "lfm_studio: installing Python packages into $venv (first run takes a few minutes)"
  "$venv/bin/python" -m pip install -q --upgrade pip
  # torch first: with it present, the open range in pyproject installs nothing
  # more (no multi-GB CUDA download on CPU machines; docs/platform.md).
  "$venv/bin/python" -c "import torch" >/dev/null 2>&1 || "$venv/bin/python" -m pip install -q "torch==$torch_version"
  "$venv/bin/python" -m pip install -q -e "$repo_root[studio,scale,dev]"
  echo "$want" > "$stamp"
}

install_system_packages
install_python_packages
export QT_API=pyside6 PYQTGRAPH_QT_LIB=PySide6
PATH="$venv/bin:$PATH"
export PATH
