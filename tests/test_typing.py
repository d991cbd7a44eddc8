"""mypy guards the engine's seams: the projectors satisfy the protocols, wrong types are reported.

Runs mypy (skipped when it is not installed) on a small snippet with the project's
configuration: assigning each engine projector to a protocol-typed name must type-check,
and each line marked ``# wrong`` (a string or a shift-variant projector where a protocol is
expected, a misspelled option) must be reported as an error; no other line may be.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SNIPPET = """\
import torch

from lfm_studio.engine.operators import FourierProjector, Projector, ShiftInvariantProjector
from lfm_studio.engine.operators.binned import BinnedProjector
from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.reconstruct import reconstruct_frame, richardson_lucy, tikhonov, wiener

fourier = ShiftInvariantProjector(torch.ones(2, 8, 8), (4, 4))
lattice = LensletLatticeProjector([([0, 1], torch.ones(2, 3, 3, 9, 9))], 2, (4, 4), 3)
image = torch.ones(8, 8)
a: Projector = fourier
b: Projector = lattice
c: Projector = BinnedProjector(fourier, 2)
d: FourierProjector = fourier
volume = richardson_lucy(a, image, iterations=3, acceleration="geometric")
stack = wiener(d, image, snr=10.0)
frame = reconstruct_frame(b, image, method="rl")
richardson_lucy("not a projector", image)  # wrong
wiener(lattice, image)  # wrong
e: FourierProjector = c  # wrong
richardson_lucy(a, image, iteration=3)  # wrong
richardson_lucy(a, image, acceleration="fastest")  # wrong
tikhonov(fourier, image, mu="small")  # wrong
"""


@pytest.mark.skipif(importlib.util.find_spec("mypy") is None, reason="mypy is not installed")
def test_mypy_accepts_the_projectors_and_reports_wrong_types_at_the_seams(tmp_path):
    snippet = tmp_path / "seams.py"
    snippet.write_text(SNIPPET)
    wrong = {i for i, line in enumerate(SNIPPET.splitlines(), start=1) if line.endswith("# wrong")}
    result = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"), str(snippet)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "MYPYPATH": str(ROOT)},
        check=False,
    )
    reported = {int(n) for n in re.findall(r"seams\.py:(\d+): error", result.stdout)}
    assert reported == wrong, result.stdout + result.stderr
    assert result.returncode == 1


def test_the_seam_modules_are_checked_strictly():
    """No explicit ``Any`` and every def annotated where modules meet (pyproject's [tool.mypy])."""
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["mypy"]
    assert config["check_untyped_defs"] and config["warn_unused_ignores"]
    strict = [
        o for o in config["overrides"] if o.get("disallow_any_explicit") and o.get("disallow_untyped_defs")
    ]
    modules = {m for o in strict for m in o["module"]}
    assert {
        "lfm_studio.engine.types",
        "lfm_studio.engine.operators.*",
        "lfm_studio.engine.reconstruct.*",
        "lfm_studio.engine.simulation",
        "lfm_studio.engine.psf_stack",
        "lfm_studio.engine.learned.*",
        "lfm_studio.engine.batch.*",
    } <= modules
