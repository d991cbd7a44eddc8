"""The studio's "Train" dock: train a learned reconstructor from the current design, watch it, compare.

Top: model, time budget (minutes), max steps, photon budgets, phantoms, seed, optics jitter
(optics-mismatch augmentation, %; off by default); "Train" runs
:func:`lfm_studio.ui.training.train_model` as job "train" on the studio's job runner on the
current full PSF stack (the status bar shows its progress and a Cancel button; the dock has its
own Cancel). A live pyqtgraph curve shows the training loss per step (thin line), its running mean
(thick line) and the validation loss (points), log scale. A cancelled or failed run leaves the previous model and its curve,
and its own steps as a dashed grey line ("stopped run, not kept": how far it got) until the next run.

A finished model lives only in memory until "Save checkpoint…" (the done message says so); while
it is unsaved it is the studio's unsaved input (:attr:`~lfm_studio.ui.state.StudioState.unsaved_model`):
closing the studio or opening another design asks first, and so does training again here.
Opening another design drops the model (it was trained for the previous design).

After a run: "Save checkpoint…" writes the model (safetensors, atomic; an existing file only
after a yes to the overwrite question) and "Compare with RL" reconstructs the studio's current
simulated image with the registry's default method and with the model (job "compare"); the
table shows both score sets beside the all-zero volume's, and both volumes go to the viewer
("RL" and "learned"). Those layers are marked stale (:meth:`TrainDock.layer_marks`, shown by
:class:`~lfm_studio.ui.stale_marks.StaleMarks`) once the design or settings they were made with
change (the state's inputs version of the reconstruction), and "learned" also once another model
is trained; pressing Compare again with nothing changed marks nothing.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyqtgraph as pg
from qtpy.QtCore import Qt, Signal
from qtpy.QtWidgets import (
    QComboBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QMessageBox,
    QPushButton,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.learned.data import TrainingDataSpec
from lfm_studio.engine.learned.mismatch import JITTER_LIMIT
from lfm_studio.engine.learned.models import DEFAULT_MODEL, MODELS
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.training import (
    PHANTOM_KINDS,
    Comparison,
    TrainedModel,
    TrainSettings,
    compare_with_rl,
    comparison_rows,
    jitter_refusal,
    parse_photons,
    running_mean,
    save_trained,
    train_model,
)
from lfm_studio.widgets.jobs import JobOutcome, JobRunner
from lfm_studio.widgets.numeric_field import NumericField, commit_all
from lfm_studio.widgets.numeric_text import NumberRule, shown_units_in
from lfm_studio.widgets.stale_mark import StaleMark

TRAIN_JOB, COMPARE_JOB = "train", "compare"
COMPARE_LAYERS = ("RL", "learned")  # the viewer layers of a comparison
MEAN_STEPS = 10  # steps in the running mean of the training loss (one random sample per step: noisy)
STOPPED_COLOR = "#8c8c8c"  # the stopped run's dashed line
KEY_GAP = "&nbsp;&nbsp;&nbsp;"
PLOT_KEY = (
    f'<span style="color:#9ecae1;">━</span> training (per step){KEY_GAP}'
    f'<span style="color:#1f77b4;">━━</span> training (mean of {MEAN_STEPS} steps){KEY_GAP}'
    '<span style="color:#d62728;">●</span> validation'
)
STOPPED_KEY = f'{KEY_GAP}<span style="color:{STOPPED_COLOR};">╌╌</span> stopped run (not kept)'
UNSAVED_NOTE = (
    "Not saved yet: the model is only in memory. Save checkpoint… keeps it "
    "(the Learned model method reads it from that file)."
)
TABLE_HEADER = ("score", "RL", "learned", "all-zero")
JITTER_TIP = (
    "Optics-mismatch augmentation: train on images of slightly wrong instruments. The MLA and "
    "Fourier-lens focal lengths, the NA and the wavelength of a pool of designs are each jittered "
    "by up to ± this percentage; the model keeps the nominal design. Costs one PSF simulation per "
    f"jittered design ({TrainingDataSpec().jitter_designs}) before training starts. Off (0) by default."
)


def _loss_points(history: list[tuple[int, float, float]]) -> tuple[list[int], list[float]]:
    """Steps and training losses of ``(step, loss, validation)`` points a log axis can show (loss > 0)."""
    kept = [(step, loss) for step, loss, _ in history if loss > 0]
    return [step for step, _ in kept], [loss for _, loss in kept]


@dataclass(frozen=True)
class ComparedWith:
    """What a comparison on screen was made with.

    Attributes
    ----------
    version : the state's inputs version of the reconstruction when the comparison started.
    image_outdated : the image compared already missed a change of the design or settings.
    model : the trained model compared.
    """

    version: int
    image_outdated: bool
    model: TrainedModel


class TrainDock(QWidget):
    """Training controls, the live loss curve and the RL comparison for ``state``.

    Parameters
    ----------
    state : the studio state (its full PSF stack, current image, workflow settings).
    runner : the studio's job runner (jobs "train" and "compare").
    viewer : the studio viewer (``show_volume``) or None.
    """

    layer_marks_changed = Signal()  # a comparison arrived or a model was trained: see layer_marks()

    def __init__(
        self, state: StudioState, runner: JobRunner, viewer: Any = None, parent: QWidget | None = None
    ):
        super().__init__(parent)
        self.state, self.runner, self.viewer = state, runner, viewer
        self.trained: TrainedModel | None = None
        self.comparison: Comparison | None = None
        self.live: list[tuple[int, float, float]] = []
        self._scratch = tempfile.TemporaryDirectory(prefix="lfm_train_")
        self._compared_path: Path | None = None
        self._comparing: ComparedWith | None = None  # the running comparison's inputs
        self.compared_with: ComparedWith | None = None  # the inputs of the comparison in the viewer
        self._replaced = state.design_replaced  # kept: disconnected on closing
        self._replaced.connect(self._on_design_replaced)

        self.model = QComboBox()
        self.model.addItems(sorted(MODELS))
        self.model.setCurrentText(DEFAULT_MODEL)
        self.minutes = NumericField(NumberRule("Time budget", 0.1, 600.0, unit="min"), 10.0, step=1.0)
        self.max_steps = NumericField(
            NumberRule("Max steps", 0, 1_000_000, integer=True, special_text="no limit"), 0, step=1
        )
        self.photons = QLineEdit("1e4, 1e5, 1e6")
        self.photons.setToolTip("expected photons per training image, one drawn per sample")
        self.phantoms = QComboBox()
        self.phantoms.addItems(PHANTOM_KINDS)
        self.seed = NumericField(NumberRule("Seed", 0, 2**31 - 1, integer=True), 0, step=1)
        self.jitter = NumericField(
            NumberRule("Optics jitter", 0.0, 100.0 * JITTER_LIMIT, unit="%", special_text="off", example=3.0),
            0.0, step=0.5, tip=JITTER_TIP,
        )  # fmt: skip
        self._refusal: str | None = None  # a number field's refusal on show (cleared by its next commit)
        form = QFormLayout()
        for label, field in (("Model", self.model), ("Time budget", self.minutes), ("Max steps", self.max_steps),
                             ("Photon budgets", self.photons), ("Phantoms", self.phantoms), ("Seed", self.seed),
                             ("Optics jitter", self.jitter)):  # fmt: skip
            form.addRow(label, field)

        self.train_button, self.cancel_button = QPushButton("Train"), QPushButton("Cancel")
        self.save_button, self.compare_button = (
            QPushButton("Save checkpoint…"),
            QPushButton("Compare with RL"),
        )
        buttons = QHBoxLayout()
        for button in (self.train_button, self.cancel_button, self.save_button, self.compare_button):
            buttons.addWidget(button)
        self.train_button.clicked.connect(self.start_training)
        self.cancel_button.clicked.connect(self.cancel)
        self.save_button.clicked.connect(self.save)
        self.compare_button.clicked.connect(self.compare)

        self.message = QLabel("Train a model on the current design's PSF stack.")
        self.message.setWordWrap(True)

        self.plot = pg.PlotWidget()
        self.plot.setBackground("w")
        self.plot.setLabel("bottom", "step")
        self.plot.setLabel("left", "loss (energy-normalised MSE + high-pass)")
        self.plot.setLogMode(y=True)
        # The key is the plot's title, above the data: a legend inside covered the curves, and its red
        # validation marker read as one more validation point.
        self.plot.setTitle(PLOT_KEY, size="9pt")
        self.loss_curve = self.plot.plot([], [], pen=pg.mkPen("#9ecae1", width=1), name="training (per step)")
        self.mean_curve = self.plot.plot(
            [], [], pen=pg.mkPen("#1f77b4", width=2.5), name=f"training (mean of {MEAN_STEPS} steps)"
        )
        self.validation_points = self.plot.plot(
            [], [], pen=None, symbol="o", symbolSize=7, symbolBrush="#d62728", name="validation"
        )
        self.stopped_curve = self.plot.plot(
            [],
            [],
            pen=pg.mkPen(STOPPED_COLOR, width=1.5, style=Qt.PenStyle.DashLine),
            name="stopped run (not kept)",
        )
        self.plot.setMinimumHeight(160)

        self.table = QTableWidget(0, len(TABLE_HEADER))
        self.table.setHorizontalHeaderLabels(TABLE_HEADER)
        self.table.verticalHeader().setVisible(False)
        self.table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
        self.table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)

        left = QVBoxLayout()
        left.addLayout(form)
        left.addLayout(buttons)
        left.addWidget(self.message)
        for field in self._numbers():
            field.refused.connect(self._on_refused)
            field.committed.connect(self._on_committed)
        left.addWidget(self.table, 1)
        row = QHBoxLayout(self)
        row.addLayout(left, 2)
        row.addWidget(self.plot, 3)
        self.runner.status_changed.connect(self._update_buttons)
        self.runner.ended.connect(self._on_ended)
        self._update_buttons()

    # ----- actions -----

    def settings(self) -> TrainSettings:
        """The settings the fields show (a ValueError naming the bad field)."""
        steps = self.max_steps.value()
        return TrainSettings(
            model=self.model.currentText(), minutes=float(self.minutes.value()), max_steps=steps or None,
            photons=parse_photons(self.photons.text()), phantoms=self.phantoms.currentText(),
            seed=int(self.seed.value()), optics_jitter=float(self.jitter.value()) / 100.0,
        )  # fmt: skip

    def _numbers(self) -> tuple[NumericField, ...]:
        return (self.minutes, self.max_steps, self.seed, self.jitter)

    def start_training(self) -> bool:
        """Start job "train" on the current full PSF stack; False (with a message) when it cannot start."""
        psf = self.state.psf
        if psf is None or psf.preview:
            self._say("No full PSF stack yet: wait for it (status bar) before training.", error=True)
            return False
        if not commit_all(self._numbers()):  # a refused text stops the run instead of the value before
            self._say(next(str(f.reason()) for f in self._numbers() if f.reason()), error=True)
            return False
        try:
            settings = self.settings()
        except ValueError as error:
            self._say(str(error), error=True)
            return False
        refusal = jitter_refusal(settings, psf.design)
        if refusal is not None:
            self._say(refusal, error=True)
            return False
        if self.state.unsaved_model is not None and not self._confirm_replace_unsaved(
            self.state.unsaved_model
        ):
            self._say("not started: the unsaved model is kept. Save checkpoint… keeps it in a file.")
            return False
        self.live = []
        self._draw(self.live)
        self._draw_stopped([])
        jitter = (
            f", optics jitter ±{100 * settings.optics_jitter:g} %: simulating the jittered designs first"
            if settings.optics_jitter > 0
            else ""
        )
        self._say(
            f"training {settings.model} on '{psf.design.name}' ({len(psf.stack.depths)} depths{jitter})…"
        )
        self.runner.submit(TRAIN_JOB, train_model, psf.design, psf.stack, settings, on_partial=self._on_step,
                           on_result=self._on_trained)  # fmt: skip
        self._update_buttons()
        return True

    def cancel(self) -> None:
        """Stop the running training or comparison (the previous model and curve stay)."""
        self.runner.cancel(TRAIN_JOB)
        self.runner.cancel(COMPARE_JOB)

    def save(self) -> Path | None:
        """Ask for a file and write the trained model there; None when nothing was written."""
        if self.trained is None:
            return None
        path = self._ask_path()
        if not path:
            return None
        target = Path(path)
        if target.suffix != ".safetensors":
            target = target.with_name(target.name + ".safetensors")
        overwrite = target.exists()
        if overwrite and not self._confirm_overwrite(target):
            self._say(f"not saved: {target} exists and was kept.")
            return None
        try:
            written = save_trained(self.trained, target, overwrite=overwrite)
        except OSError as error:
            self._say(f"could not save {target}: {error}. Fix: choose a folder you can write to.", error=True)
            return None
        self.state.set_unsaved_model(None)
        self._say(f"saved {written}")
        return written

    def compare(self) -> bool:
        """Start job "compare" (RL and the model on the current image); False (with a message) when it cannot."""
        image = self.state.image
        if self.trained is None:
            return False
        if image is None or image.ground_truth is None:
            self._say(
                "No simulated image: press 'Simulate image' in 'Simulate and reconstruct' first.", error=True
            )
            return False
        path = save_trained(self.trained, Path(self._scratch.name) / "compare.safetensors", overwrite=True)
        self._compared_path = path
        state = self.state
        self._comparing = ComparedWith(
            state.inputs_version("reconstruction"), "image" in state.outdated, self.trained
        )
        self._say("reconstructing the current image with RL and the learned model…")
        self.runner.submit(COMPARE_JOB, compare_with_rl, self.state.design, image, self.state.workflow, str(path),
                           on_result=self._on_compared)  # fmt: skip
        self._update_buttons()
        return True

    # ----- dialogs (tests replace these) -----

    def _ask_path(self) -> str:
        name = (
            f"{self.trained.settings.model}.safetensors" if self.trained is not None else "model.safetensors"
        )
        path, _ = QFileDialog.getSaveFileName(
            self, "Save checkpoint", name, "Checkpoints (*.safetensors)",
            options=QFileDialog.Option.DontConfirmOverwrite,
        )  # fmt: skip
        return path

    def _confirm_replace_unsaved(self, what: str) -> bool:
        answer = QMessageBox.question(
            self, "Unsaved trained model",
            f"{what[:1].upper()}{what[1:]} is not saved; training again replaces it. Train anyway?",
            QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.Cancel, QMessageBox.StandardButton.Cancel,
        )  # fmt: skip
        return answer == QMessageBox.StandardButton.Yes

    def _confirm_overwrite(self, target: Path) -> bool:
        answer = QMessageBox.question(self, "Overwrite checkpoint?", f"{target} exists. Replace it?")
        return answer == QMessageBox.StandardButton.Yes

    # ----- job deliveries (GUI thread) -----

    def _on_step(self, point: tuple[int, float, float]) -> None:
        self.live.append(point)
        self._draw(self.live)

    def _on_trained(self, trained: TrainedModel) -> None:
        self.trained = trained
        self.live = list(trained.result.history)
        self._draw(self.live)
        self._say(f"{trained.summary}. {UNSAVED_NOTE}")
        self.table.setRowCount(0)
        self.comparison = None
        steps = trained.result.header.training["steps"]
        self.state.set_unsaved_model(f"the trained {trained.settings.model} model ({steps} steps)")
        self.layer_marks_changed.emit()  # the "learned" layer shows the previous model

    def _on_design_replaced(self, *_: Any) -> None:
        """Another document: the model (trained for the previous design) and its comparison go (layers
        in the viewer stay, marked stale)."""
        self.trained, self.comparison, self.live = None, None, []
        self._draw(self.live)
        self._draw_stopped([])
        self.table.setRowCount(0)
        self._say("Train a model on the current design's PSF stack.")
        self._update_buttons()

    def _on_ended(self, outcome: JobOutcome) -> None:
        """A failed or cancelled job of this dock (a superseded one never gets here)."""
        if outcome.state == "done" or outcome.name not in (TRAIN_JOB, COMPARE_JOB):
            return
        if outcome.name == COMPARE_JOB:
            what = "failed: " + str(outcome.error) if outcome.state == "failed" else "cancelled"
            self._say(f"comparison {what}", error=outcome.state == "failed")
            return
        stopped = self.live
        self.live = list(self.trained.result.history) if self.trained is not None else []
        self._draw(self.live)
        self._draw_stopped(stopped)
        reached = f" after {len(stopped)} step(s) (dashed grey line)" if stopped else ""
        if outcome.state == "failed":
            self._say(f"training failed{reached}: {outcome.error}", error=True)
        else:
            self._say(f"training cancelled{reached}; the previous model (if any) is kept.")

    def _on_compared(self, comparison: Comparison) -> None:
        self.comparison, self.compared_with = comparison, self._comparing
        rows = comparison_rows(comparison)
        self.table.setRowCount(len(rows))
        for r, row in enumerate(rows):
            for c, text in enumerate(row):
                self.table.setItem(r, c, QTableWidgetItem(text))
        if self.viewer is not None and hasattr(self.viewer, "show_volume"):
            for name, result in zip(COMPARE_LAYERS, (comparison.rl, comparison.learned), strict=True):
                self.viewer.show_volume(result.volume, result.voxel_size, name=name)
        self._say(f"RL ({comparison.rl.method}, {comparison.rl.iterations} iterations) and the learned model "
                  "on the current image; higher is better, the all-zero column is the trivial floor.")  # fmt: skip
        self.layer_marks_changed.emit()

    def layer_marks(self) -> dict[str, StaleMark]:
        """Stale marks of the comparison's viewer layers ("RL", "learned"): out of date once the design
        or settings changed since it was made (or the image it used already was), and "learned" also
        once another model was trained; none while they match (e.g. Compare pressed again)."""
        made = self.compared_with
        if made is None:
            return {}
        changed = made.image_outdated or self.state.inputs_version("reconstruction") != made.version
        inputs = ["design or settings"] if changed else []
        rl, learned = COMPARE_LAYERS
        reasons = {
            rl: inputs,
            learned: inputs + (["trained model"] if self.trained is not made.model else []),
        }
        return {
            layer: StaleMark(f"stale: made with the previous {' and '.join(why)}")
            for layer, why in reasons.items()
            if why
        }

    # ----- display -----

    def _draw(self, history: list[tuple[int, float, float]]) -> None:
        steps, losses = _loss_points(history)
        checked = [(s, v) for s, _, v in history if not math.isnan(v) and v > 0]
        self.loss_curve.setData(steps, losses)
        self.mean_curve.setData(steps, running_mean(losses, MEAN_STEPS))
        self.validation_points.setData([s for s, _ in checked], [v for _, v in checked])

    def _draw_stopped(self, history: list[tuple[int, float, float]]) -> None:
        """Show a stopped run's loss (its running mean) dashed, and its key entry; [] hides both."""
        steps, losses = _loss_points(history)
        self.stopped_curve.setData(steps, running_mean(losses, MEAN_STEPS))
        self.plot.setTitle(PLOT_KEY + (STOPPED_KEY if steps else ""), size="9pt")

    def _on_refused(self, reason: str) -> None:
        self._refusal = reason
        self._say(reason, error=True)

    def _on_committed(self, *_: Any) -> None:
        if self._refusal is not None and self.message.text() == self._refusal:
            self._say("")
        self._refusal = None

    def _say(self, text: str, *, error: bool = False) -> None:
        self.message.setText(shown_units_in(text))  # the engine writes "um"; the studio shows "µm"
        self.message.setStyleSheet("color: #b00020;" if error else "")

    def _update_buttons(self, *_: Any) -> None:
        training = self.runner.is_running(TRAIN_JOB)
        busy = training or self.runner.is_running(COMPARE_JOB)
        self.train_button.setEnabled(not training)
        self.cancel_button.setEnabled(busy)
        self.save_button.setEnabled(self.trained is not None and not training)
        self.compare_button.setEnabled(self.trained is not None and not busy)

    def disconnect_state(self) -> None:
        """Stop listening to the runner and drop the scratch checkpoint (window closing)."""
        self.runner.status_changed.disconnect(self._update_buttons)
        self.runner.ended.disconnect(self._on_ended)
        self._replaced.disconnect(self._on_design_replaced)
        self._scratch.cleanup()
