#!/usr/bin/env bash
# Run lfm_studio's whole test suite: lint, architecture contracts, pytest (engine,
# stress, UI under a virtual X server). Sets itself up first.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=scripts/setup_env.sh
source "$here/setup_env.sh"
cd "$here/.."

# Keep napari/Mesa caches and settings out of the home directory.
scratch="$(mktemp -d)"
trap 'rm -rf "$scratch"' EXIT
export XDG_CONFIG_HOME="$scratch/config" XDG_CACHE_HOME="$scratch/cache" MPLCONFIGDIR="$scratch/mpl"
unset QT_QPA_PLATFORM   # pytest-xvfb provides a real X server for napari's OpenGL canvas

echo "== ruff"
ruff check .
ruff format --check .
echo "== import contracts"
lint-imports
echo "== napari plugin manifest (discovered, every command imports)"
npe2 validate --imports lfm-studio
echo "== pytest"
python -m pytest "$@"
