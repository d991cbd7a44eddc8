"""The status bar's job display: the stage trail of the design-change loop, what runs, a progress
bar, and a Cancel button."""

from __future__ import annotations

from qtpy.QtCore import Signal
from qtpy.QtWidgets import QHBoxLayout, QLabel, QProgressBar, QPushButton, QWidget

from lfm_studio.ui.results import JobStatus
from lfm_studio.ui.stage_trail import StageTrail
from lfm_studio.ui.state import StudioState

FAILED_STYLE = "QLabel { color: #ff6b6b; font-weight: bold; }"

JOB_TITLES = {
    "psf": "PSF",
    "metrics": "Design metrics",
    "image": "Light-field image",
    "reconstruction": "Reconstruction",
    "export": "Export",
    "optimise": "Optimise",
    "raw frame": "Raw light field",
    "video": "Light-field video",
}


def headline(name: str, message: str) -> str:
    """The status bar's line for job ``name``: its title, then ``message`` without a prefix that repeats it.

    "image: building the projector" reads "Light-field image: building the projector" (not "Light-field
    image: image: ..."), and "reconstruction: iteration 3 of 10" starts with a capital as "Reconstruction:
    done" does.
    """
    title = JOB_TITLES.get(name, name)
    lowered = message.lower()
    if lowered.startswith(f"{name.lower()}: "):
        return f"{title}: {message[len(name) + 2 :]}"
    if lowered.startswith(title.lower()):
        return title + message[len(title) :]
    return f"{title}: {message}"


class JobStatusBar(QWidget):
    """Shows the most recent active job (else the last that ended); ``cancel_requested`` on Cancel."""

    cancel_requested = Signal()

    def __init__(self, state: StudioState, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.state = state
        layout = QHBoxLayout(self)
        layout.setContentsMargins(4, 0, 4, 0)
        self.trail = StageTrail(state)
        self.trail_label = QLabel("", self)
        self.trail_label.setToolTip("The design-change loop: PSF -> image -> reconstruction, with times")
        self.trail.listeners.append(self._render_trail)
        self.message = QLabel("Ready", self)
        self.progress = QProgressBar(self)
        self.progress.setFixedWidth(220)
        self.progress.setRange(0, 1000)
        self.progress.setTextVisible(True)
        self.cancel_button = QPushButton("Cancel", self)
        self.cancel_button.setToolTip("Stop the running computation; the previous result stays.")
        self.cancel_button.clicked.connect(self._on_cancel)
        layout.addWidget(self.trail_label)
        layout.addWidget(self.message, 1)
        layout.addWidget(self.progress)
        layout.addWidget(self.cancel_button)
        self._latest: list[str] = []  # job names, most recent change last
        state.job_changed.connect(self._on_job)
        self._render()

    def disconnect_state(self) -> None:
        self.state.job_changed.disconnect(self._on_job)
        self.trail.disconnect_state()

    def _render_trail(self) -> None:
        text = self.trail.text()
        failed = any(record.state == "failed" for record in self.trail.records.values())
        self.trail_label.setText(text + ("   |" if text else ""))
        self.trail_label.setStyleSheet(FAILED_STYLE if failed else "")
        self.trail_label.setToolTip(text)

    def _on_cancel(self) -> None:
        self.cancel_requested.emit()

    def _on_job(self, status: JobStatus) -> None:
        if status.name in self._latest:
            self._latest.remove(status.name)
        self._latest.append(status.name)
        self._render()

    def _render(self) -> None:
        jobs = self.state.jobs
        active = [jobs[n] for n in self._latest if n in jobs and jobs[n].active]
        shown = active[-1] if active else (jobs[self._latest[-1]] if self._latest else None)
        self.cancel_button.setEnabled(bool(active))
        if shown is None:
            self.message.setText("Ready")
            self.progress.setVisible(False)
            return
        text = headline(shown.name, shown.message)
        if len(active) > 1:
            text += f"  (+{len(active) - 1} more running)"
        self.message.setText(text)
        self.message.setToolTip(text)
        self.progress.setVisible(shown.active)
        fraction = shown.fraction
        if fraction is None:
            self.progress.setRange(0, 0)  # busy indicator
        else:
            self.progress.setRange(0, 1000)
            self.progress.setValue(round(1000 * fraction))
