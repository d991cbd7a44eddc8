"""Ctrl+C while ``lfm-studio`` is still loading (torch and the engine take seconds to import):
one line and exit 130, not a traceback. The interrupt is raised by an import hook at the moment
the command line's main module loads, in a fresh interpreter (no timing involved)."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import sys

class InterruptTheLoad:
    def find_spec(self, name, path=None, target=None):
        if name == "lfm_studio.cli.commands":
            raise KeyboardInterrupt
        return None

sys.meta_path.insert(0, InterruptTheLoad())
import lfm_studio.cli
sys.exit(lfm_studio.cli.main(["info", "flfm_guo2019"]))
"""


def test_ctrl_c_while_starting_says_so_in_one_line_and_exits_130():
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120)
    assert done.returncode == 130
    assert done.stderr.strip() == "lfm-studio: interrupted while starting; nothing was done."
    assert "Traceback" not in done.stderr and done.stdout == ""
