"""The design-metrics panel says why a conventional design gets no measured (*) values, instead of
promising them "once the full stack is in" (the metrics job skips its lenslet-pattern stack)."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest

from lfm_studio.ui import pipeline
from lfm_studio.ui.measured_note import MEASURED_LATER
from lfm_studio.ui.plots import RequirementsView
from lfm_studio.ui.stale_marks import metrics_mark
from lfm_studio.ui.state import StudioState
from tests.ui.standins import small_conventional_design, small_fourier_design


def _ctx():
    return SimpleNamespace(
        cancel=threading.Event(), progress=lambda *a: None, partial=lambda v: None, check=lambda *a: None
    )


@pytest.fixture(scope="module")
def conventional():
    """The small conventional design with the metrics the studio computes once its full stack is in."""
    design = small_conventional_design()
    psf = pipeline.compute_psf(_ctx(), pipeline.PSFRequest.for_design(design, preview=False), None)
    assert not psf.stack.shift_invariant  # lenslet patterns (S, S, Z, H, H)
    return design, psf, pipeline.measure_design(_ctx(), design, psf.stack)


def test_a_conventional_design_is_told_why_it_has_no_measured_values(qtbot, conventional):
    design, psf, metrics = conventional
    assert metrics.measured is None and {c.basis for c in metrics.requirements} == {"closed_form"}
    state = StudioState(design)
    view = RequirementsView(state)
    qtbot.addWidget(view)
    state.set_psf(psf)
    state.set_metrics(metrics)
    note, why = view.note.text(), view.note.toolTip()
    assert note.startswith("Bars: formula estimates only. A Conventional LFM gets no measured values (*)")
    assert "shift-invariant PSF per depth" in note and "once the full stack is in" not in note
    assert "source position behind each lenslet" in why and "lfm-studio resolution" in why
    assert {row[1] for row in view.rows()} == {"formula"}
    # A Fourier design's metrics: measured values do come with its full stack.
    state.set_metrics(pipeline.measure_design(_ctx(), small_fourier_design(), None))
    assert view.note.text() == MEASURED_LATER
    view.disconnect_state()


def test_nothing_waits_for_the_psf_in_a_conventional_designs_requirements():
    conventional, fourier = StudioState(small_conventional_design()), StudioState(small_fourier_design())
    assert "psf" in conventional.stale and "psf" in fourier.stale  # no PSF yet
    assert metrics_mark(conventional) is None  # it said "measured values wait for the PSF"
    assert "measured values wait for the PSF" in metrics_mark(fourier).text
