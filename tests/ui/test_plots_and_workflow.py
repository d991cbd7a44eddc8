"""Plots (state -> view) and the workflow panel (both ways)."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pyqtgraph as pg
import pytest

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.performance import compute_design_metrics
from lfm_studio.ui import pipeline
from lfm_studio.ui.plots import ConvergencePlot, ProfilePlots, RequirementsView
from lfm_studio.ui.results import ReconstructionResult, WorkflowSettings
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.workflow_panel import WorkflowPanel
from tests.ui.standins import small_fourier_design


def _ctx():
    return SimpleNamespace(
        cancel=threading.Event(), progress=lambda *a: None, partial=lambda v: None, check=lambda *a: None
    )


@pytest.fixture(scope="module")
def computed():
    design = small_fourier_design()
    psf = pipeline.compute_psf(_ctx(), pipeline.PSFRequest.for_design(design), None)
    return design, psf, pipeline.measure_design(_ctx(), design, psf.stack)


def test_plots_show_profiles_requirements_and_convergence(qtbot, computed):
    design, psf, metrics = computed
    state = StudioState(design)
    profiles, requirements, convergence = ProfilePlots(state), RequirementsView(state), ConvergencePlot(state)
    for view in (profiles, requirements, convergence):
        qtbot.addWidget(view)
    assert requirements.rows() == []  # the controller computes metrics; none yet
    state.set_psf(psf)
    state.set_metrics(metrics)
    x, y = profiles.lateral_curve.getData()
    assert len(x) > 10 and y.max() == pytest.approx(1.0) and abs(x[y.argmax()]) < 1e-9
    for plot in (profiles.lateral_plot, profiles.axial_plot):  # the key names the curve shown
        assert _key_names(plot) == ["full PSF"]
    z, peak = profiles.axial_curve.getData()
    assert list(z) == pytest.approx([-10.0, 0.0, 10.0]) and peak.max() == pytest.approx(1.0)
    rows = requirements.rows()
    assert len(rows) == len(metrics.requirements)
    results = {(r[0].split(" ")[0], r[1]): r[3] for r in rows}
    assert results[("FoV", "formula")] == "FAIL"  # 50 um field stop vs 800 um required
    assert rows[0][0] == "FoV ≥ 800 µm" and rows[0][2] == "50 µm"
    # the lateral criterion is named (issue 22), on a line of its own (the long line pushed Value out of view)
    lateral = {r[1]: r[0] for r in rows if r[0].startswith("Lateral res.")}
    assert lateral["formula"] == "Lateral res. ≤ 3 µm\nRayleigh 0.61 lambda/NA"
    assert lateral["measured"] == "Lateral res. ≤ 3 µm\ntwo-point dip < 0.735"
    assert {r[1] for r in rows} == {"formula", "measured"}
    assert "Does not meet" in requirements.summary.text()
    state.set_convergence((10.0, 12.0, 13.0), (0.5, 0.2, 0.1))
    assert list(convergence.curve.getData()[1]) == [10.0, 12.0, 13.0]
    state.set_psf(None)
    assert len(profiles.lateral_curve.getData()[0] or []) == 0
    for view in (profiles, requirements, convergence):
        view.disconnect_state()
    state.set_metrics(None)  # disconnected: the table keeps its rows
    assert len(requirements.rows()) == len(metrics.requirements)


def test_a_conventional_lateral_row_names_the_lenslet_sampling(qtbot):
    # Prevedel: 7.5 µm = 150 µm pitch / 20x, not Rayleigh 0.61 x 0.525 µm / 0.5 = 0.64 µm (walk-through 6).
    design = load_preset("lfm_prevedel2014")
    state = StudioState(design)
    view = RequirementsView(state)
    qtbot.addWidget(view)
    state.set_metrics(compute_design_metrics(design))
    row = next(r for r in view.rows() if r[0].startswith("Lateral res."))
    assert row[0] == "Lateral res. ≤ 3 µm\nlenslet sampling pitch/M, same for every criterion"
    assert row[2] == f"{150 / 20:g} µm"
    view.disconnect_state()


def _key_names(plot) -> list[str]:
    """The curve names the plot's key shows, in order (the key is the title's second line)."""
    title = plot.getPlotItem().titleLabel.text
    return [name for name in ("full PSF", "quick preview") if name in title.partition("<br>")[2]]


def _boxes_over_the_axes(plot) -> list:
    """Items drawn over the data area that are not data (a legend box hid part of a curve, walk 4)."""
    item = plot.getPlotItem()
    area = item.getViewBox().sceneBoundingRect()
    return [
        child
        for child in item.scene().items()
        if isinstance(child, pg.LegendItem)
        and child.isVisible()
        and child.sceneBoundingRect().intersects(area)
    ]


def test_the_profile_keys_sit_above_the_axes_and_name_the_curves_shown(qtbot, computed):
    """No key box over the curves: the key is in the title, full PSF and the dashed preview."""
    _, psf, _ = computed
    profiles = ProfilePlots()
    qtbot.addWidget(profiles)
    profiles.resize(380, 360)
    profiles.show()
    qtbot.waitExposed(profiles)
    for plot in (profiles.lateral_plot, profiles.axial_plot):
        assert _key_names(plot) == []  # nothing shown: no key
    profiles.show_preview(psf)
    profiles.show_result(psf)
    for plot in (profiles.lateral_plot, profiles.axial_plot):
        assert _boxes_over_the_axes(plot) == []
        assert _key_names(plot) == ["full PSF", "quick preview"]
    profiles.show_preview(None)  # the preview gone: its key entry too
    assert _key_names(profiles.lateral_plot) == ["full PSF"]


def test_workflow_panel_both_ways(qtbot, computed):
    design = computed[0]
    state = StudioState(design)
    panel = WorkflowPanel(state, reconstruction_available=True)
    qtbot.addWidget(panel)
    # view -> state
    for field, text in ((panel.seed, "7"), (panel.bead_count, "4")):  # typed and committed
        field.setText(text)
        field.commit()
    panel.noise_free.setChecked(True)
    assert state.workflow.seed == 7 and state.workflow.bead_count == 4 and state.workflow.photons is None
    panel.phantom.setCurrentIndex(panel.phantom.findData("cells"))
    assert state.workflow.phantom == "cells" and not panel.bead_count.isEnabled()
    # state -> view
    state.set_workflow(
        WorkflowSettings(phantom="tiff", tiff_path="/data/brain.tif", photons=2e5, iterations=12)
    )
    assert panel.phantom.currentData() == "tiff" and panel.tiff_path.text() == "/data/brain.tif"
    assert panel.photons.value() == pytest.approx(2e5) and panel.photons.text() == "200000 photons"
    assert panel.iterations.value() == 12 and panel.tiff_path.isEnabled()
    # the photon box steps by decades
    panel.photons.stepBy(1)
    assert state.workflow.photons == pytest.approx(1e6)
    # buttons
    with qtbot.waitSignal(panel.simulate_requested):
        panel.simulate_button.click()
    with qtbot.waitSignal(panel.reconstruct_requested):
        panel.reconstruct_button.click()
    state.set_reconstruction(
        ReconstructionResult(computed[1].stack.data, (1, 1, 1), 5, psnr=31.25, ssim=0.875)
    )
    assert "PSNR 31.25 dB" in panel.quality.text() and "SSIM 0.875" in panel.quality.text()
    panel.disconnect_state()


def test_the_workflow_panel_offers_a_conventional_design_only_the_methods_that_take_it(qtbot):
    """Wiener needs a shift-invariant (Fourier LFM) projector: on a conventional design it is disabled,
    and a Wiener chosen on a Fourier design is replaced in the settings when the design changes."""
    state = StudioState(small_fourier_design())
    panel = WorkflowPanel(state, reconstruction_available=True)
    qtbot.addWidget(panel)
    box = panel.method_options.method
    panel.method_options.set_method("wiener")
    assert state.workflow.method == "wiener"
    state.set_design(load_preset("lfm_10x_na03"))
    assert not box.model().item(box.findData("wiener")).isEnabled()
    assert state.workflow.method != "wiener" and box.currentData() == state.workflow.method
    panel.disconnect_state()


def test_reconstruct_is_disabled_without_the_engine_module(qtbot, computed):
    panel = WorkflowPanel(StudioState(computed[0]), reconstruction_available=False)
    qtbot.addWidget(panel)
    assert not panel.reconstruct_button.isEnabled()
    assert "lfm_studio.engine.reconstruct" in panel.reconstruct_button.toolTip()
    panel.disconnect_state()
