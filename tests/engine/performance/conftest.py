"""One real PSF simulation shared by the tests that need it (the Guo 2019 FLFM preset, a few seconds)."""

from __future__ import annotations

import pytest

from lfm_studio.engine.design import Design, load_preset
from lfm_studio.engine.performance import DesignMetrics, compute_design_metrics, measurement_psf
from lfm_studio.engine.psf_stack import PSFStack


@pytest.fixture(scope="session")
def guo_design() -> Design:
    return load_preset("flfm_guo2019")


@pytest.fixture(scope="session")
def guo_psf(guo_design: Design) -> PSFStack:
    """The ``info --measure`` stack of the Guo preset: 15 depths on a 296 x 296 pixel crop."""
    return measurement_psf(guo_design)


@pytest.fixture(scope="session")
def guo_metrics(guo_design: Design, guo_psf: PSFStack) -> DesignMetrics:
    """Closed-form and measured metrics of the Guo preset, measured at the native focal plane."""
    return compute_design_metrics(guo_design, psf=guo_psf, focus_depth=0.0)
