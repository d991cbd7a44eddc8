"""The design-change loop at a glance: which stage runs, how long each took, which failed.

``PSF preview 0.2 s → PSF full 24.1 s → image 0.3 s → reconstruction (running)``. A new PSF
job (a design change) starts a new trail; a new image job drops the image and reconstruction
entries. Times: the PSF entries use the seconds the PSF stage measured itself
(:attr:`~lfm_studio.ui.results.PSFResult.seconds`), the others the time from "running" to
"done" as the GUI saw it. Qt-free (observes the :class:`~lfm_studio.ui.state.StudioState`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from lfm_studio.ui.results import JobStatus, PSFResult
from lfm_studio.ui.state import StudioState

#: Entries of the trail in loop order: key -> label.
TRAIL_LABELS = {
    "preview": "PSF preview",
    "psf": "PSF full",
    "image": "image",
    "reconstruction": "reconstruction",
}
_JOBS = ("psf", "image", "reconstruction")


@dataclass(frozen=True)
class StageRecord:
    """One entry: ``state`` is "running", "done", "failed" or "cancelled"; seconds when done."""

    state: str
    seconds: float | None = None
    error: str = ""

    def describe(self, label: str) -> str:
        if self.state == "done":
            return f"{label} {_seconds(self.seconds)}"
        if self.state == "failed":
            return f"{label} FAILED: {self.error}"
        return f"{label} ({self.state})"


class StageTrail:
    """Records the stages of the current design-change loop from the state's signals.

    ``changed`` (a plain list of callables) is called after every change, for the widget.
    """

    def __init__(self, state: StudioState) -> None:
        self.state = state
        self.records: dict[str, StageRecord] = {}
        self._started: dict[str, tuple[int, float]] = {}  # job -> (generation, monotonic start)
        self.listeners: list = []
        state.job_changed.connect(self._on_job)
        state.preview_changed.connect(self._on_preview)
        state.psf_changed.connect(self._on_psf)

    def disconnect_state(self) -> None:
        self.state.job_changed.disconnect(self._on_job)
        self.state.preview_changed.disconnect(self._on_preview)
        self.state.psf_changed.disconnect(self._on_psf)

    def text(self) -> str:
        """The trail as one line (empty before the first job)."""
        ordered = [key for key in TRAIL_LABELS if key in self.records]
        return " → ".join(self.records[key].describe(self._label(key)) for key in ordered)

    def _label(self, key: str) -> str:
        return "PSF" if key == "psf" and "preview" not in self.records else TRAIL_LABELS[key]

    # ----- observers -----

    def _on_job(self, status: JobStatus) -> None:
        name = status.name
        if name not in _JOBS:
            return
        if status.state == "running" and self._started.get(name, (None,))[0] != status.generation:
            self._started[name] = (status.generation, time.monotonic())
            later = {"psf": TRAIL_LABELS, "image": ("image", "reconstruction")}.get(name, (name,))
            for key in later:
                self.records.pop(key, None)
            self.records[name] = StageRecord("running")
        elif status.state in ("done", "failed", "cancelled"):
            started = self._started.get(name)
            if started is None or started[0] != status.generation:
                return
            if status.state == "done":
                measured = self.records.get(name)
                seconds = measured.seconds if measured and measured.seconds is not None else None
                seconds = time.monotonic() - started[1] if seconds is None else seconds
                self.records[name] = StageRecord("done", seconds)
            elif status.state == "failed":
                self.records[name] = StageRecord("failed", error=status.message.removeprefix("failed: "))
            else:
                self.records[name] = StageRecord("cancelled")
                if self.records.get("preview", StageRecord("done")).state == "running":
                    self.records["preview"] = StageRecord("cancelled")
        else:
            return
        self._notify()

    def _on_preview(self, result: PSFResult | None) -> None:
        if result is not None and "psf" in self.records:
            self.records["preview"] = StageRecord("done", result.seconds)
            self._notify()

    def _on_psf(self, result: PSFResult | None) -> None:
        record = self.records.get("psf")
        if result is not None and record is not None and record.state == "running":
            # the full stack's own time; the job's "done" (which follows) keeps it
            self.records["psf"] = StageRecord("running", result.seconds)

    def _notify(self) -> None:
        for listener in self.listeners:
            listener()


def _seconds(value: float | None) -> str:
    if value is None:
        return ""
    return f"{value:.1f} s" if value < 100 else f"{value:.0f} s"
