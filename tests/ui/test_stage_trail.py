"""The stage trail: which stage of PSF -> image -> reconstruction runs, how long each took, failures."""

from __future__ import annotations

import torch

from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.ui.results import JobStatus, PSFResult
from lfm_studio.ui.stage_trail import StageTrail
from lfm_studio.ui.state import StudioState
from tests.ui.standins import small_fourier_design


def _psf(design, seconds: float, preview: bool) -> PSFResult:
    stack = PSFStack(torch.ones(2, 4, 4), (0.0, 1e-6), 6.5e-6, 10.0, 500e-9)
    return PSFResult(design, stack, preview, "per_lenslet", seconds=seconds)


def test_the_trail_lists_each_stage_with_its_time_and_marks_a_failure():
    design = small_fourier_design()
    state = StudioState(design)
    trail = StageTrail(state)
    changes = []
    trail.listeners.append(lambda: changes.append(trail.text()))
    assert trail.text() == ""
    state.set_job(JobStatus("psf", "running", 0, 0, "starting", 1))
    assert trail.text() == "PSF (running)"
    state.set_job(JobStatus("psf", "running", 1, 5, "lenslet 1/5", 1))  # progress: same entry
    state.set_preview(_psf(design, 0.25, True))
    assert trail.text() == "PSF preview 0.2 s → PSF full (running)"
    state.set_psf(_psf(design, 24.04, False))
    state.set_job(JobStatus("psf", "done", 1, 1, "done in 24.3 s", 1))
    assert trail.text() == "PSF preview 0.2 s → PSF full 24.0 s"  # the stack's own time
    state.set_job(JobStatus("metrics", "running", 0, 0, "", 1))  # not a stage of the trail
    state.set_job(JobStatus("image", "running", 0, 3, "image: projector", 1))
    assert trail.text().endswith("→ image (running)")
    state.set_job(JobStatus("image", "failed", 0, 0, "failed: phantom 'TIFF volume' needs a file", 1))
    assert trail.text() == (
        "PSF preview 0.2 s → PSF full 24.0 s → image FAILED: phantom 'TIFF volume' needs a file"
    )
    assert trail.records["image"].state == "failed" and changes[-1] == trail.text()

    state.set_job(JobStatus("image", "running", 0, 3, "", 2))  # a new image drops the failure
    state.set_job(JobStatus("image", "done", 1, 1, "done in 0.3 s", 2))
    image = trail.records["image"]
    assert image.state == "done" and image.seconds is not None and image.seconds >= 0
    state.set_job(JobStatus("reconstruction", "running", 0, 10, "", 1))
    assert trail.text().endswith("→ reconstruction (running)")

    state.set_job(JobStatus("psf", "running", 0, 0, "starting", 2))  # a design change: a new loop
    assert trail.text() == "PSF (running)" and list(trail.records) == ["psf"]
    state.set_job(JobStatus("psf", "cancelled", 0, 0, "cancelled", 2))
    assert trail.text() == "PSF (cancelled)"
    trail.disconnect_state()
    state.set_job(JobStatus("psf", "running", 0, 0, "starting", 3))
    assert trail.text() == "PSF (cancelled)"  # no longer observing


def test_a_small_design_without_preview_shows_one_psf_entry():
    design = small_fourier_design()
    state = StudioState(design)
    trail = StageTrail(state)
    state.set_job(JobStatus("psf", "running", 0, 0, "", 1))
    state.set_psf(_psf(design, 1.5, False))
    state.set_job(JobStatus("psf", "done", 1, 1, "done in 1.6 s", 1))
    assert trail.text() == "PSF 1.5 s"
    state.set_job(JobStatus("psf", "failed", 0, 0, "failed: x", 0))  # an old generation: ignored
    assert trail.text() == "PSF 1.5 s"
