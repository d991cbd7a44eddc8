"""Stale marks: what the views say when the result they show no longer matches the design.

A stage (:data:`~lfm_studio.ui.results.STAGES`) whose result is on screen but out of date (the
design or settings changed since: :attr:`~lfm_studio.ui.state.StudioState.outdated`; a run asked
for again with nothing changed does not count), or whose job failed with nothing shown, gets a
one-line :class:`~lfm_studio.widgets.stale_mark.StaleMark` such as ``"stale: shows the
previous design; PSF failed: out of memory"`` (with the job's activity: recomputing, failed or
cancelled, so views colour it without reading the text). :func:`stage_mark` computes it from the state alone;
:class:`StaleMarks` keeps the views' marks up to date: the viewer's banner per layer, the
PSF profile plots, the measured rows of the requirements table and the RL convergence plot.
A fresh result clears the mark.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from qtpy.QtCore import QObject

from lfm_studio.ui.measured_note import measured_unavailable
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.stale_mark import Activity, StaleMark

STAGE_LABELS = {"psf": "PSF", "image": "image", "reconstruction": "reconstruction"}
#: The viewer's layers (the names :mod:`lfm_studio.ui.pipeline` gives them) and their stage.
LAYER_STAGES = {
    "PSF": "psf",
    "light field": "image",
    "phantom": "image",
    "reconstruction": "reconstruction",
}


def _shown_result(state: StudioState, stage: str) -> Any:
    if stage == "psf":
        return state.psf if state.psf is not None else state.preview
    return state.image if stage == "image" else state.reconstruction


def _job_part(state: StudioState, stage: str) -> tuple[Activity, str]:
    """What the stage's job is doing about it (recomputing, failed with the error, cancelled or
    nothing) and how that reads."""
    job = state.job(stage)
    label = STAGE_LABELS[stage]
    if job.active:
        return "recomputing", "recomputing…"
    if job.state == "failed":
        error = job.message.removeprefix("failed: ") or "unknown error"
        return "failed", f"{label} failed: {error}"
    if job.state == "cancelled":
        return "cancelled", f"{label} cancelled"
    return "", ""


def _current_preview_only(state: StudioState) -> bool:
    """The viewer shows the current design's quick preview (the full stack is older or absent)."""
    preview, psf = state.preview, state.psf
    current = state.design
    return preview is not None and preview.design == current and (psf is None or psf.design != current)


def stage_mark(state: StudioState, stage: str) -> StaleMark | None:
    """The mark for ``stage``'s result on screen, or None when it is fresh (or nothing is shown and nothing failed).

    Examples of its text: ``"stale: shows the previous design; recomputing…"``, ``"stale: shows
    the previous design; PSF failed: <error>"``, ``"quick preview of this design; full PSF: recomputing…"``.
    """
    if stage not in STAGE_LABELS:
        raise ValueError(f"stage must be one of {tuple(STAGE_LABELS)}; got {stage!r}.")
    if stage not in state.stale:
        return None
    shown = _shown_result(state, stage)
    activity, part = _job_part(state, stage)
    if shown is None:
        return StaleMark(part, activity) if activity == "failed" else None
    if stage not in state.outdated:  # only run again (a button pressed twice): what is shown still matches
        return None
    if stage == "psf" and _current_preview_only(state):
        return StaleMark(
            f"quick preview of this design; full PSF: {part or 'not computed yet'}", activity, preview=True
        )
    head = (
        "stale: shows the previous design"
        if stage == "psf"
        else "stale: made with the previous design or settings"
    )
    return StaleMark(f"{head}; {part}" if part else head, activity)


def metrics_mark(state: StudioState) -> StaleMark | None:
    """The requirements table's mark: its measured rows wait for (or lost) the current design's PSF
    (none for a design kind without measured values: nothing waits)."""
    if "psf" not in state.stale or measured_unavailable(state.design) is not None:
        return None
    activity, part = _job_part(state, "psf")
    if activity in ("failed", "cancelled"):
        return StaleMark(f"formula estimates only: {part}", activity)
    text = "formula estimates only: measured values wait for the PSF" + (" (recomputing…)" if part else "")
    return StaleMark(text, activity)


class StaleMarks(QObject):
    """Keeps the stale marks of a viewer and plots in step with the state.

    Parameters
    ----------
    state : the application state.
    viewer : anything with ``set_stale_marks(dict[layer name, StaleMark])`` (the PSFViewer), or None.
    profiles, convergence, requirements : views with ``set_stale(StaleMark | None)``, or None.
    """

    def __init__(
        self,
        state: StudioState,
        *,
        viewer: Any = None,
        profiles: Any = None,
        convergence: Any = None,
        requirements: Any = None,
        parent: QObject | None = None,
    ) -> None:
        super().__init__(parent)
        self.state = state
        self.viewer = viewer if hasattr(viewer, "set_stale_marks") else None
        self.profiles, self.convergence, self.requirements = profiles, convergence, requirements
        self._layer_sources: list[tuple[Callable[[], dict[str, StaleMark]], Any]] = []
        self._signals = (
            state.stale_changed, state.psf_changed, state.preview_changed,
            state.image_changed, state.reconstruction_changed, state.metrics_changed,
        )  # fmt: skip
        for signal in self._signals:
            signal.connect(self.refresh)
        # job_changed fires on every progress tick: restyle the views only when a mark changed.
        state.job_changed.connect(self._on_job_changed)
        self._shown: tuple[dict[str, StaleMark], StaleMark | None] | None = None
        self.refresh()

    def marks(self) -> dict[str, StaleMark]:
        """Stage -> mark for every marked stage."""
        found = {stage: stage_mark(self.state, stage) for stage in STAGE_LABELS}
        return {stage: mark for stage, mark in found.items() if mark}

    def add_layer_marks(self, source: Callable[[], dict[str, StaleMark]], changed: Any) -> None:
        """Marks of more viewer layers than the stages' (e.g. the Train dock's "RL" and "learned"):
        ``source()`` gives them by layer name; they are asked for again at every change of the
        state's results or staleness and when the signal ``changed`` fires."""
        self._layer_sources.append((source, changed))
        changed.connect(self.refresh)
        self.refresh()

    def _on_job_changed(self, *_: Any) -> None:
        if (self.marks(), metrics_mark(self.state)) != self._shown:
            self.refresh()

    def refresh(self, *_: Any) -> None:
        """Recompute the marks and hand them to the views."""
        marks = self.marks()
        self._shown = (marks, metrics_mark(self.state))
        if self.viewer is not None:
            layers = {layer: marks[stage] for layer, stage in LAYER_STAGES.items() if stage in marks}
            for source, _ in self._layer_sources:
                layers.update(source())
            self.viewer.set_stale_marks(layers)
        if self.profiles is not None:
            self.profiles.set_stale(marks.get("psf"))
        if self.convergence is not None:
            self.convergence.set_stale(marks.get("reconstruction"))
        if self.requirements is not None:
            self.requirements.set_stale(metrics_mark(self.state))

    def disconnect_state(self) -> None:
        for signal in self._signals:
            signal.disconnect(self.refresh)
        self.state.job_changed.disconnect(self._on_job_changed)
        for _, changed in self._layer_sources:
            changed.disconnect(self.refresh)
