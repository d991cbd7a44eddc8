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
# Idle OpenMP threads sleep instead of spinning: with another job on one of the 2 cores,
# spinning 2-thread torch runs were up to 16x slower (docs/platform.md). Results do not depend on it.
export OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-PASSIVE}"
# The CLI's default thread count follows the machine's load (engine/threads.py); tests call it
# in-process, so fix it here: every test runs on the same number of threads, whatever the load.
export LFM_STUDIO_THREADS="${LFM_STUDIO_THREADS:-2}"

echo "== machine"
python - <<'PY'
import os, platform, torch
print(f"python {platform.python_version()}, torch {torch.__version__}, numpy {__import__('numpy').__version__}")
print(f"CPU capability {torch.backends.cpu.get_cpu_capability()}, {os.cpu_count()} cores, "
      f"torch intra-op threads {torch.get_num_threads()}, interop {torch.get_num_interop_threads()}")
print("LFM_STUDIO_THREADS=%s OMP_NUM_THREADS=%s MKL_NUM_THREADS=%s OMP_WAIT_POLICY=%s ATEN_CPU_CAPABILITY=%s" % tuple(
    os.environ.get(k, "(unset)") for k in ("LFM_STUDIO_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OMP_WAIT_POLICY", "ATEN_CPU_CAPABILITY")))
PY

echo "== ruff"
ruff check .
ruff format --check .
echo "== mypy (engine)"
mypy lfm_studio/engine
echo "== import contracts"
lint-imports
echo "== napari plugin manifest (discovered, every command imports)"
npe2 validate --imports lfm-studio
echo "== pytest"
python -m pytest "$@"
