"""Controllers: connect the application state, the background jobs and the views.

:class:`StudioController` owns the recompute chain design -> PSF -> image ->
reconstruction. Changes mark stages stale (see :class:`~lfm_studio.ui.state.StudioState`);
after a debounce only the stale stages run, in order, on worker threads. The PSF stage
keeps a per-lenslet cache across edits, so editing one lenslet of a Fourier design
recomputes that lenslet only. Results are written to the state on the GUI thread when
a job succeeded and is still current (:mod:`lfm_studio.widgets.jobs`).

:class:`MLAEditorBinding` and :class:`ViewerBinding` tie the two reusable widgets
(:mod:`lfm_studio.widgets`) to the state; both only need the widgets' public contracts.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Any

from qtpy.QtCore import QObject, QTimer

from lfm_studio.engine.design import MLASpec
from lfm_studio.engine.performance import compute_design_metrics
from lfm_studio.engine.systems.lenslet_cache import LensletCache
from lfm_studio.ui import pipeline
from lfm_studio.ui.edits import try_changes
from lfm_studio.ui.results import ImageResult, PSFResult, ReconstructionResult
from lfm_studio.ui.state import StudioState, psf_key
from lfm_studio.widgets.jobs import JobOutcome, JobRunner

DEBOUNCE_MS = 300  # quiet time after the last edit before recomputing
CACHE_BYTES = 2 * 2**30  # per-lenslet PSF patches kept across edits


class StudioController(QObject):
    """Runs the stale stages of the state in the background.

    Parameters
    ----------
    state : the application state.
    runner : the job runner (default: a new one).
    cache : per-lenslet PSF cache (default: 2 GiB).
    debounce_ms : quiet time after the last change before a stage starts.
    preview : compute a quick preview before the full PSF stack of big designs.
    """

    def __init__(
        self,
        state: StudioState,
        runner: JobRunner | None = None,
        *,
        cache: LensletCache | None = None,
        debounce_ms: int = DEBOUNCE_MS,
        preview: bool = True,
        parent: QObject | None = None,
    ) -> None:
        super().__init__(parent)
        self.state = state
        self.runner = runner if runner is not None else JobRunner(self)
        self.cache = cache if cache is not None else LensletCache(CACHE_BYTES)
        self.preview = preview
        self.image_requested = False  # the user asked for an image once: keep it up to date
        self.reconstruction_requested = False
        self.last_error: JobOutcome | None = None
        self._asked: set[str] = set()  # stages asked for by a button: run once even without auto-update
        self._inputs: dict[str, Any] = {}  # what the latest job of each stage was started with
        self._refusals = 0  # reconstructions refused before their job started
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(debounce_ms)
        self._timer.timeout.connect(self.run_stale)
        self.runner.status_changed.connect(self._on_status)
        self.runner.ended.connect(self._on_ended)
        state.design_changed.connect(self._on_design_changed)
        state.device_changed.connect(self._on_changed)
        state.workflow_changed.connect(self._on_changed)
        self._update_closed_form_metrics()

    # ----- public actions -----

    def start(self) -> None:
        """Compute what is stale now (used at launch), without waiting for the debounce."""
        self._timer.stop()
        self.run_stale()

    def schedule(self) -> None:
        """Run the stale stages after the debounce interval (restarted by every call)."""
        self._timer.start()

    def flush(self) -> None:
        """Run a pending debounced recompute now."""
        if self._timer.isActive():
            self._timer.stop()
            self.run_stale()

    def request_image(self) -> None:
        """Simulate the light-field image now (and keep it up to date while auto-update is on)."""
        self.image_requested = True
        self._asked.add("image")
        self.state.mark_stale("image", "reconstruction", changed=False)  # asked for: nothing changed
        self.run_stale()

    def request_reconstruction(self) -> None:
        """Reconstruct the current image now (simulating it first when needed)."""
        if not pipeline.reconstruction_available():
            return
        self.reconstruction_requested = True
        self._asked.add("reconstruction")
        if self.state.image is None:
            self.image_requested = True
            self._asked.add("image")
            self.state.mark_stale("image", changed=False)
        self.state.mark_stale("reconstruction", changed=False)  # asked for: nothing changed
        self.run_stale()

    def cancel(self, name: str | None = None) -> None:
        """Stop the running job ``name`` (default: all); previous results stay."""
        self._timer.stop()
        self.runner.cancel(name)

    def shutdown(self) -> None:
        """Stop observing the state, stop every job and wait for the worker threads (on close)."""
        self._timer.stop()
        state = self.state
        for signal, slot in (
            (state.design_changed, self._on_design_changed),
            (state.device_changed, self._on_changed),
            (state.workflow_changed, self._on_changed),
        ):
            signal.disconnect(slot)  # psygnal: missing_ok, so a second shutdown is harmless
        self.runner.shutdown()

    # ----- the recompute chain -----

    def run_stale(self) -> None:
        """Start the first stale stage whose inputs are fresh; later stages follow its result."""
        state = self.state
        stale = state.stale
        if "psf" in stale:
            self._start_psf()
        elif "image" in stale and self._wants_image():
            self._start_image()
        elif "reconstruction" in stale and self._wants_reconstruction():
            self._start_reconstruction()

    def _wants_image(self) -> bool:
        return "image" in self._asked or (self.image_requested and self.state.workflow.auto_update)

    def _wants_reconstruction(self) -> bool:
        state = self.state
        wanted = "reconstruction" in self._asked or (
            self.reconstruction_requested and state.workflow.auto_update
        )
        return wanted and state.image is not None and "image" not in state.stale

    def _submit_once(self, stage: str, inputs: Any) -> bool:
        """False when the running job of ``stage`` already works on ``inputs`` (no restart)."""
        if self.runner.is_running(stage) and self._inputs.get(stage) == inputs:
            return False
        self._inputs[stage] = inputs
        return True

    def _start_psf(self) -> None:
        design, device = self.state.design, self.state.device
        if not self._submit_once("psf", (psf_key(design), device)):
            return
        request = pipeline.PSFRequest.for_design(design, device=device, preview=self.preview)
        self.runner.submit(
            "psf", pipeline.compute_psf, request, self.cache,
            on_result=self._on_psf, on_partial=self._on_preview, on_error=self._on_error,
        )  # fmt: skip

    def _start_image(self) -> None:
        state = self.state
        psf = state.psf
        settings = tuple(getattr(state.workflow, f) for f in state.workflow.IMAGE_FIELDS)
        if psf is None or not self._submit_once("image", (id(psf), state.design.camera, settings)):
            return
        self._asked.discard("image")
        self.runner.submit(
            "image", pipeline.simulate_image, state.design, psf.stack, state.workflow, state.device,
            on_result=self._on_image, on_error=self._on_error,
        )  # fmt: skip

    def _start_reconstruction(self) -> None:
        image, workflow = self.state.image, self.state.workflow
        settings = tuple(getattr(workflow, f) for f in workflow.RECONSTRUCTION_FIELDS)
        if image is None or not self._submit_once("reconstruction", (id(image), settings)):
            return
        self._asked.discard("reconstruction")
        refusal = pipeline.reconstruction_refusal(workflow)
        if (
            refusal is not None
        ):  # not started: failed at once, in the studio's words (the result on screen goes stale)
            self.runner.cancel("reconstruction")
            self._inputs.pop("reconstruction", None)
            self._refusals += (
                1  # a generation of its own (negative: never a runner job's), one failure notice each
            )
            job = replace(self.state.job("reconstruction"), state="failed", done=0, total=0,
                          message=f"failed: {refusal}", generation=-self._refusals)  # fmt: skip
            self.state.set_job(job)
            return
        self.state.set_convergence((), ())
        self.runner.submit(
            "reconstruction", pipeline.reconstruct, self.state.design, image, self.state.workflow,
            on_result=self._on_reconstruction, on_partial=self._on_rl_progress, on_error=self._on_error,
        )  # fmt: skip

    # ----- results (GUI thread, current jobs only) -----

    def _on_preview(self, result: PSFResult) -> None:
        self.state.set_preview(result)

    def _on_psf(self, result: PSFResult) -> None:
        state = self.state
        state.set_psf(result)
        if result.design == state.design:
            state.mark_fresh("psf")
        self.runner.submit(
            "metrics", pipeline.measure_design, result.design, result.stack,
            on_result=self._on_metrics, on_error=self._on_error,
        )  # fmt: skip
        self.run_stale()

    def _on_metrics(self, metrics: Any) -> None:
        self.state.set_metrics(metrics)  # a design change since then cancelled this job

    def _on_image(self, result: ImageResult) -> None:
        self.state.set_image(result)
        self.state.mark_fresh("image")
        self.run_stale()

    def _on_rl_progress(self, curves: tuple[tuple[float, ...], tuple[float, ...]]) -> None:
        self.state.set_convergence(*curves)

    def _on_reconstruction(self, result: ReconstructionResult) -> None:
        self.state.set_reconstruction(result)
        self.state.mark_fresh("reconstruction")

    def _on_error(self, outcome: JobOutcome) -> None:
        self.last_error = outcome

    def _on_ended(self, outcome: JobOutcome) -> None:
        if outcome.name == "reconstruction" and outcome.state != "done":  # its partial curves were shown
            self.state.restore_convergence()

    # ----- changes -----

    def _on_design_changed(self, design: Any) -> None:
        self.runner.cancel("metrics")  # measured on the previous design's PSF
        self._update_closed_form_metrics()
        self.schedule()

    def _on_changed(self, *_: Any) -> None:
        self.schedule()

    def _update_closed_form_metrics(self) -> None:
        self.state.set_metrics(compute_design_metrics(self.state.design))

    def _on_status(self, status: Any) -> None:
        self.state.set_job(status)


REGULAR_PATCH_PITCHES = 5  # a regular array is shown (read-only) within this many pitches of its centre


def editor_pupil_radius_um(design: Any) -> float | None:
    """The pupil footprint's radius at the MLA in micrometres (the editor's unit); None when the
    design has no pupil image at the MLA (conventional LFM): the editor then draws no circle."""
    pupil = design.pupil_diameter_at_mla
    return None if pupil is None else pupil / 2.0 * 1e6


def editor_lenslets(design: Any) -> tuple:
    """The lenslets the MLA editor shows: all of an explicit array; a regular array's central patch
    (its thousands of lenslets are edited by pitch, not one by one)."""
    mla = design.mla
    if isinstance(mla, MLASpec):
        return tuple(mla.lenslets)
    reach = REGULAR_PATCH_PITCHES * mla.pitch_um
    x0, y0 = mla.offset_um
    return tuple(
        lens
        for lens in mla.lenslets
        if abs(lens.center_um[0] - x0) <= reach and abs(lens.center_um[1] - y0) <= reach
    )


def regular_grid_summary(design: Any, shown: int) -> str | None:
    """What the MLA editor says of a regular lenslet grid it shows ``shown`` lenslets of (its size,
    pitch and lenslet focal length, and where to change them); None for an explicit lenslet list."""
    mla = design.mla
    if isinstance(mla, MLASpec):
        return None
    rows, per_row = mla.shape
    return (
        f"Regular {mla.lattice} lenslet grid: {rows} rows x {per_row} lenslets ({len(mla.lenslets)} in all), "
        f"pitch {mla.pitch_um:g} µm, lenslet focal length {mla.focal_length_mm:g} mm; the central {shown} are "
        "drawn. Change the grid in the design file, or free the MLA pitch and lenslet focal length in the "
        "Optimise dock."
    )


class MLAEditorBinding(QObject):
    """Keeps an MLA editor (the :class:`~lfm_studio.widgets.mla_editor.MLAEditor` contract) and the state in step.

    state -> editor: lenslets, pupil footprint and sensor of the design in force.
    editor -> state: a committed lenslet list becomes a new design, or an error under ``"mla"``.
    """

    ERROR_KEY = "mla"

    def __init__(self, state: StudioState, editor: Any, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.state = state
        self.editor = editor
        editor.lensletsCommitted.connect(self._on_committed)
        state.design_changed.connect(self._on_design)
        self._on_design(state.design)

    def disconnect_state(self) -> None:
        self.state.design_changed.disconnect(self._on_design)

    def _on_design(self, design: Any) -> None:
        editor = self.editor
        editable = isinstance(design.mla, MLASpec)
        editor.setEnabled(editable)
        editor.set_pupil_radius(editor_pupil_radius_um(design))  # None also clears the previous circle
        width, height = design.camera.sensor_size
        radius = design.sub_image_radius
        editor.set_sensor((width * 1e6, height * 1e6), 0.0 if radius is None else radius * 1e6)
        lenslets = editor_lenslets(design)
        if tuple(editor.lenslets()) != lenslets:
            editor.set_lenslets(lenslets)
        summary = regular_grid_summary(design, len(lenslets))
        editor.setToolTip(summary or "")
        editor.set_summary(summary)

    def _on_committed(self, lenslets: Any) -> None:
        outcome = try_changes(self.state.design, {"mla.lenslets": tuple(lenslets)})
        if outcome.ok:
            self.state.set_field_error(self.ERROR_KEY, None)
            self.state.set_design(outcome.design, warnings=outcome.warnings)
        else:
            self.state.set_field_error(self.ERROR_KEY, outcome.error)


class ViewerBinding(QObject):
    """Shows the state's PSF stack, camera image and reconstruction in a viewer (the PSFViewer contract)."""

    def __init__(self, state: StudioState, viewer: Any, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.state = state
        self.viewer = viewer
        state.psf_changed.connect(self._on_psf)
        state.preview_changed.connect(self._on_preview)
        state.image_changed.connect(self._on_image)
        state.reconstruction_changed.connect(self._on_reconstruction)
        if state.psf is not None:
            self._on_psf(state.psf)
        elif state.preview is not None:
            self._on_preview(state.preview)

    def disconnect_state(self) -> None:
        state = self.state
        state.psf_changed.disconnect(self._on_psf)
        state.preview_changed.disconnect(self._on_preview)
        state.image_changed.disconnect(self._on_image)
        state.reconstruction_changed.disconnect(self._on_reconstruction)

    # Results carry display data prepared on the worker thread (range, max-pooled pyramid: about
    # a second for a 64 x 2048 x 2048 stack); a viewer without show_display gets the raw data.
    def _show(self, display: Any, fallback: Any) -> None:
        if display is not None and hasattr(self.viewer, "show_display"):
            self.viewer.show_display(display)
        else:
            fallback()

    def _on_psf(self, result: PSFResult | None) -> None:
        if result is None:
            self.viewer.clear()
        else:
            self._show(result.display, partial(self.viewer.show_psf, result.stack))

    def _on_preview(self, result: PSFResult | None) -> None:
        psf = self.state.psf
        if result is not None and (psf is None or psf.design != result.design):
            self._show(result.display, partial(self.viewer.show_psf, result.stack))

    def _on_image(self, result: ImageResult | None) -> None:
        if result is not None:
            if hasattr(self.viewer, "show_volume") and result.ground_truth is not None:  # the phantom
                self._show(
                    result.truth_display,
                    partial(self.viewer.show_volume, result.ground_truth, result.voxel_size, name="phantom"),
                )
            show = partial(self.viewer.show_image, result.counts, result.pixel_size, name="light field")
            self._show(result.display, show)

    def _on_reconstruction(self, result: ReconstructionResult | None) -> None:
        if result is not None:
            show = partial(self.viewer.show_volume, result.volume, result.voxel_size, name="reconstruction")
            self._show(result.display, show)
