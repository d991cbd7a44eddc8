"""The status bar's job line: the job's title once, then what the job says."""

from __future__ import annotations

import pytest

from lfm_studio.ui.status_bar import headline


@pytest.mark.parametrize(
    ("name", "message", "line"),
    [
        ("image", "image: building the projector", "Light-field image: building the projector"),
        ("reconstruction", "reconstruction: accelerated Richardson-Lucy: iteration 3 of 10",
         "Reconstruction: accelerated Richardson-Lucy: iteration 3 of 10"),
        ("reconstruction", "Reconstruction: done", "Reconstruction: done"),
        ("psf", "PSF stack (81 depths): depth 18/81 (full field)", "PSF stack (81 depths): depth 18/81 (full field)"),
        ("metrics", "done in 0.0 s", "Design metrics: done in 0.0 s"),
        ("custom job", "custom job: half way", "custom job: half way"),
    ],
)  # fmt: skip
def test_the_job_title_appears_once_with_a_capital(name, message, line):
    assert headline(name, message) == line
