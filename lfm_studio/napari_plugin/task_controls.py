"""Run / Cancel buttons, a progress bar and a status line for one :class:`BackgroundTask` at a time."""

from __future__ import annotations

from qtpy.QtCore import Signal
from qtpy.QtWidgets import QHBoxLayout, QLabel, QProgressBar, QPushButton, QVBoxLayout, QWidget

from lfm_studio.napari_plugin.background import BackgroundTask, Outcome


class TaskControls(QWidget):
    """The bottom of a dock widget: ``Run`` starts (the owner connects ``runClicked``), ``Cancel`` stops.

    While a task runs, Run is disabled, Cancel enabled and the bar follows the task's
    progress; when it ends the status line says how (done in N s, cancelled, failed).
    """

    runClicked = Signal()  # noqa: N815 - Qt signal names are camelCase

    def __init__(self, run_text: str, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.run_button = QPushButton(run_text)
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setEnabled(False)
        self.bar = QProgressBar()
        self.bar.setRange(0, 1)
        self.bar.setValue(0)
        self.status = QLabel("")
        self.status.setWordWrap(True)
        buttons = QHBoxLayout()
        buttons.addWidget(self.run_button)
        buttons.addWidget(self.cancel_button)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(buttons)
        layout.addWidget(self.bar)
        layout.addWidget(self.status)
        self.run_button.clicked.connect(self._on_run)
        self.cancel_button.clicked.connect(self.cancel)
        self._task: BackgroundTask | None = None

    @property
    def busy(self) -> bool:
        """Whether a task is running."""
        return self._task is not None

    def attach(self, task: BackgroundTask, message: str = "starting") -> None:
        """Follow ``task`` (not yet started) until it ends."""
        self._task = task
        task.progressed.connect(self._on_progress)
        task.ended.connect(self._on_ended)
        self.run_button.setEnabled(False)
        self.cancel_button.setEnabled(True)
        self.bar.setRange(0, 0)  # busy until the first progress report
        self.status.setText(message)

    def set_status(self, text: str) -> None:
        """Replace the status line, e.g. with the owner's verdict after its task ended."""
        self.status.setText(text)

    def _on_run(self) -> None:
        if self._task is None:
            self.runClicked.emit()

    def cancel(self) -> None:
        """Ask the running task to stop (no-op when idle)."""
        if self._task is not None:
            self._task.cancel()
            self.cancel_button.setEnabled(False)
            self.status.setText("cancelling...")

    def _on_progress(self, done: int, total: int, message: str) -> None:
        if self._task is None or self._task.cancel_requested:
            return
        self.bar.setRange(0, max(total, 1))
        self.bar.setValue(min(done, max(total, 1)))
        self.status.setText(message)

    def _on_ended(self, outcome: Outcome) -> None:
        self._task = None
        self.run_button.setEnabled(True)
        self.cancel_button.setEnabled(False)
        self.bar.setRange(0, 1)
        self.bar.setValue(1 if outcome.state == "done" else 0)
        texts = {
            "done": f"done in {outcome.seconds:.1f} s",
            "cancelled": "cancelled: nothing was added",
            "failed": f"failed: {outcome.message}",
        }
        self.status.setText(texts.get(outcome.state, outcome.state))
