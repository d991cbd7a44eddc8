#!/usr/bin/env bash
# Launch the lfm_studio desktop app on the bundled default design (sets itself up first).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=scripts/setup_env.sh
source "$here/setup_env.sh"
exec lfm-studio gui "$@"
