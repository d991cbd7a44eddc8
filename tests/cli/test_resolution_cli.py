"""``lfm-studio resolution`` text output: the "n/a" footnote only beside an n/a.

The command takes ~17 s on a CPU, so the table is tested on hand-made reports.
"""

from __future__ import annotations

import pytest

from lfm_studio.cli.resolution import format_resolution_table
from lfm_studio.engine.performance.reconstructed import DepthResolution, ResolutionReport

FOOTNOTE = "n/a: not resolved up to --max-lateral / --max-axial."


def _report(lateral: float | None, axial: float | None) -> ResolutionReport:
    depth = DepthResolution(depth=20e-6, lateral=lateral, axial=axial, lateral_dips=(), axial_dips=())
    return ResolutionReport(
        design_name="lfm_prevedel2014",
        kind="conventional",
        lateral_voxel=1e-6,
        axial_voxel=2e-6,
        photons=None,
        iterations=100,
        threshold=0.735,
        crop=256,
        depths=(depth,),
    )


def test_no_footnote_when_every_separation_was_resolved():
    table = format_resolution_table(_report(3e-6, 8e-6))
    assert "n/a" not in table and FOOTNOTE not in table
    assert table.splitlines()[-1].split() == ["20", "3", "8"]


@pytest.mark.parametrize(("lateral", "axial"), [(None, 8e-6), (3e-6, None)])
def test_the_footnote_explains_an_unresolved_separation(lateral, axial):
    table = format_resolution_table(_report(lateral, axial))
    assert "n/a" in table.splitlines()[-3] and table.splitlines()[-1] == f"  {FOOTNOTE}"
