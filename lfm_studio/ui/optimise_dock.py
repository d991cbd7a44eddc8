"""The studio's "Optimise" dock: pick a method, free parameters, set its options, run, plot, load, compare.

Top left: the **method** (:data:`~.optimise_model.METHODS`): grid search / design study (the
default, described below), the thesis' Algorithm 2 for the MLA layout, or gradient
optimisation (PSF engineering or end to end). Each method shows only its own options, with
the CLI's defaults (``lfm-studio optimize``; tooltips give units and meaning). Algorithm 2
fills the table with one row per layout considered (the best one green: load it like a
candidate); a gradient run with one row per step and the final design (green), and the plot
with the objective against the step (the loss curve).

Grid search. Left: the freeable design values (:func:`~.optimise_model.freeable_fields`; tick a row and
give low / high / points), the objectives (:func:`~lfm_studio.engine.optimize.objective_names`;
the first ticked one ranks the candidates), the sampler, the budget (number of candidates)
and an optional SQLite study file (store; tick "Resume" to continue it). Right, in tabs:
"Run" (a live plot of the first objective against the evaluation number, each candidate a
dot, the best-so-far line, the count of infeasible ones, which have no score, in the title, and
the table of candidates with parameters, scores and feasibility or reason) and "Compare"
(closed-form metrics and requirement checks of two candidates side by side).

The run is the job ``"optimise"`` of the studio's shared :class:`~lfm_studio.widgets.jobs.JobRunner`
(progress and Cancel in the status bar too); each stored candidate arrives as a partial
result, so the table and plot fill in while the GUI stays responsive. Cancel or a failure
keeps the candidates already shown (or, when the new run delivered nothing yet, the previous
results: a run's rows replace the old ones only when its first row arrives). Double-click a
candidate (or "Load into studio") to make its design the design in force (an edit: the
document becomes unsaved; the studio has no undo).
"""

from __future__ import annotations

from typing import Any

import pyqtgraph as pg
from qtpy.QtCore import Qt
from qtpy.QtGui import QBrush, QColor
from qtpy.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QComboBox,
    QFileDialog,
    QFormLayout,
    QFrame,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QScrollArea,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.optimize import objective_names
from lfm_studio.engine.optimize.crop import auto_crop
from lfm_studio.engine.optimize.end_to_end import RECONSTRUCTIONS
from lfm_studio.engine.optimize.gradient import OPTIMIZERS, PSF_OBJECTIVES, SCHEDULES
from lfm_studio.engine.optimize.mla_cells import SYMMETRIES
from lfm_studio.engine.optimize.objectives import CRB_BACKGROUND, CRB_PHOTONS
from lfm_studio.engine.optimize.task_score import TASK_PHOTONS
from lfm_studio.ui.edits import with_design_warnings
from lfm_studio.ui.optimise_model import (
    CLI_CROP,
    METHODS,
    NOT_EVALUATED,
    PHANTOMS,
    PREVIEW_CROP,
    SAMPLERS,
    Algorithm2Request,
    AnyRequest,
    CandidateRow,
    FreeParameter,
    GradientRequest,
    OptimiseRequest,
    RunResult,
    algorithm2_cells,
    best_row,
    best_so_far,
    cell_text,
    column_labels,
    comparison_rows,
    default_min_lenslet_um,
    freeable_fields,
    objective_info,
    parse_sizes,
    psf_preview,
    reason_tip,
    reasons_tip,
    resume_note,
    run_algorithm2_layout,
    run_gradient,
    run_optimisation,
)
from lfm_studio.ui.plots import keyed_title, show_title
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.table_fit import fit_columns, give_room
from lfm_studio.ui.unit_text import shown_unit
from lfm_studio.widgets.jobs import JobOutcome, JobRunner
from lfm_studio.widgets.numeric_field import NumericField, commit_all
from lfm_studio.widgets.numeric_text import NumberRule, shown_units_in

JOB_NAME = "optimise"
PREVIEW_JOB = "optimise_psf"  # the Compare tab's PSF previews of A and B
DEFAULT_OBJECTIVE = "lateral_resolution"
FEASIBLE, INFEASIBLE, BEST = QColor("#1565c0"), QColor("#c62828"), QColor("#2e7d32")
_FREE, _LABEL, _CURRENT, _LOW, _HIGH, _POINTS = range(6)


def _run_job(ctx: Any, base: Any, request: OptimiseRequest) -> list[CandidateRow]:
    """Worker-thread body of the ``"optimise"`` job (each stored candidate goes out as a partial)."""
    return run_optimisation(base, request, on_row=ctx.partial, progress=ctx.progress, cancel=ctx.cancel)


def _algorithm2_job(ctx: Any, base: Any, request: Algorithm2Request) -> RunResult:
    """Worker-thread body of an Algorithm 2 run (each layout goes out as a partial)."""
    return run_algorithm2_layout(base, request, on_row=ctx.partial, progress=ctx.progress, cancel=ctx.cancel)


def _gradient_job(ctx: Any, base: Any, request: GradientRequest) -> RunResult:
    """Worker-thread body of a gradient run (each step goes out as a partial; the final design with the result)."""
    return run_gradient(base, request, on_row=ctx.partial, progress=ctx.progress, cancel=ctx.cancel)


_JOBS = {
    "grid": _run_job,
    "algorithm2": _algorithm2_job,
    "gradient-psf": _gradient_job,
    "gradient-end-to-end": _gradient_job,
}
X_LABELS = {"grid": "evaluation", "algorithm2": "layout considered", "gradient": "step"}


def _preview_job(ctx: Any, design_a: Any, design_b: Any) -> tuple[Any, Any]:
    """Worker-thread body of the Compare tab's PSF previews."""
    ctx.progress(0, 2, "PSF preview of A")
    a = psf_preview(design_a, cancel=ctx.cancel)
    ctx.progress(1, 2, "PSF preview of B")
    return a, psf_preview(design_b, cancel=ctx.cancel)


def _item(text: str, *, editable: bool = False, tip: str = "") -> QTableWidgetItem:
    item = QTableWidgetItem(text)
    flags = Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable
    item.setFlags(flags | Qt.ItemFlag.ItemIsEditable if editable else flags)
    if tip:
        item.setToolTip(tip)
    return item


def _field(
    name: str,
    low: float,
    high: float,
    value: float,
    tip: str,
    *,
    unit: str = "",
    integer: bool = False,
    special: str = "",
    step: float = 0.0,
    log_step: bool = False,
) -> NumericField:
    """An option's number field (its refusals name ``name``)."""
    rule = NumberRule(name, low, high, unit=unit, integer=integer, special_text=special)
    field = NumericField(rule, value, step=step, log_step=log_step, tip=tip)
    field.setToolTip(tip)  # shown before the first commit too
    return field


def _crb_fields() -> tuple[NumericField, NumericField]:
    """axial_crb's photons (per emitter) and background (photons per pixel) fields, at the CLI's defaults."""
    photons = _field(
        "Photons", 1.0, 1e15, CRB_PHOTONS, log_step=True,
        tip=f"axial_crb: photons detected per emitter (Poisson noise). CLI --photons (default {CRB_PHOTONS:g}; "
        "the task scores' photons, per image, are not set here).",
    )  # fmt: skip
    background = _field(
        "Background", 0.0, 1e12, CRB_BACKGROUND, unit="ph/px", step=1.0,
        tip=f"Background of axial_crb, photons per pixel. CLI --background (default {CRB_BACKGROUND:g}).",
    )  # fmt: skip
    return photons, background


def _combo(items: tuple[str, ...] | list[str], current: str, tip: str) -> QComboBox:
    combo = QComboBox()
    combo.addItems(list(items))
    combo.setCurrentText(current)
    combo.setToolTip(tip)
    return combo


def _check(text: str, tip: str, checked: bool = False) -> QCheckBox:
    box = QCheckBox(text)
    box.setChecked(checked)
    box.setToolTip(tip)
    return box


def _form_line(form: QFormLayout, label: str, *items: QWidget | tuple[QWidget, int] | str | None) -> None:
    """Add a form row of ``items`` side by side: a widget, ``(widget, stretch)``, a text (a label) or
    ``None`` (a stretch)."""
    line = QHBoxLayout()
    for item in items:
        if item is None:
            line.addStretch(1)
        elif isinstance(item, str):
            line.addWidget(QLabel(item))
        elif isinstance(item, tuple):
            line.addWidget(*item)
        else:
            line.addWidget(item)
    form.addRow(label, line)


def _form_box() -> tuple[QWidget, QFormLayout]:
    box = QWidget()
    form = QFormLayout(box)
    form.setContentsMargins(0, 0, 0, 0)
    return box, form


def _number(text: str, what: str) -> float:
    try:
        return float(text.strip())
    except ValueError:
        raise ValueError(f"{what} must be a number; got {text.strip()!r}. Fix: type a number.") from None


def _holds(cells: list[str], value: float) -> bool:
    """Whether the kept ``(low, high, points)`` texts are a range that holds ``value``."""
    try:
        low, high = float(cells[0]), float(cells[1])
    except (ValueError, IndexError):
        return False
    return min(low, high) <= value <= max(low, high)


class OptimiseDock(QWidget):
    """The "Optimise" dock of ``state``, running on ``runner`` (the studio controller's).

    ``rows`` holds the candidates shown (in trial order); ``selected_rows()`` the selection.
    """

    def __init__(self, state: StudioState, runner: JobRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.state, self.runner = state, runner
        self.rows: list[CandidateRow] = []
        self.request: AnyRequest | None = None
        # the row the engine picked (Algorithm 2's best layout, a gradient run's final design)
        self.chosen: int | None = None
        self.summary = ""
        self._note = ""  # a note on the run's study (a resume whose options could not be checked)
        # a run started whose first row has not arrived: the rows shown stay until it does
        self._pending: tuple[AnyRequest, dict[str, tuple[str, str]], dict[str, str]] | None = None
        self._labels: dict[str, str] = {}  # the run table's column label of each freed path
        self._min_lenslet_edited = False
        self._directions: dict[str, str] = {}
        self._objective_order: list[str] = []
        self._units: dict[str, str] = {}

        splitter = QSplitter(Qt.Orientation.Horizontal, self)
        outer = QVBoxLayout(self)
        outer.setContentsMargins(2, 2, 2, 2)
        outer.addWidget(splitter)
        splitter.addWidget(self._build_setup())
        self.tabs = QTabWidget()
        self.tabs.addTab(self._build_run_view(), "Run")
        self.tabs.addTab(self._build_compare_view(), "Compare")
        splitter.addWidget(self.tabs)
        splitter.setStretchFactor(0, 2)
        splitter.setStretchFactor(1, 3)
        splitter.setSizes([520, 880])  # pixels; the setup column keeps its labels readable

        self.runner.ended.connect(self._on_ended)
        self.runner.progressed.connect(self._on_progress)
        state.design_changed.connect(self._on_design_changed)
        self._crop_edited: set[int] = set()  # ids of the crop fields the user committed a value in
        for crop_field in (self.a2_crop, self.g_crop):
            crop_field.committed.connect(lambda *_, f=crop_field: self._crop_edited.add(id(f)))
        self._follow_auto_crop()
        self._fill_parameters()
        self._on_method_changed()

    # ----- building -----

    def _build_setup(self) -> QWidget:
        box = QWidget()
        outer = QVBoxLayout(box)
        outer.setContentsMargins(0, 0, 0, 0)
        # The method, the free parameters and the options scroll in a short dock; Run, Cancel
        # and the message stay in view below them.
        settings = QWidget()
        column = QVBoxLayout(settings)
        column.setContentsMargins(0, 0, 4, 0)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setWidget(settings)
        outer.addWidget(scroll, 1)
        line = QHBoxLayout()
        line.addWidget(QLabel("<b>Method</b>"))
        self.method = QComboBox()
        for key, label in METHODS.items():
            self.method.addItem(label, key)
        self.method.setToolTip(
            "Grid search / design study: score the grid (or sampled) points of the freed values.\n"
            "Algorithm 2: the thesis' greedy search of the MLA layout (merged cells of the minimum lenslet size).\n"
            "Gradient: descend a differentiable PSF objective (PSF engineering), or train the optics and an "
            "unrolled Richardson-Lucy reconstruction on the task loss (end to end)."
        )
        self.method.currentIndexChanged.connect(self._on_method_changed)
        line.addWidget(self.method, 1)
        column.addLayout(line)
        self.parameters_title = QLabel("<b>Free parameters</b> (tick, then set low / high / points)")
        self.parameters_title.setWordWrap(True)
        column.addWidget(self.parameters_title)
        self.parameters = QTableWidget(0, 6)
        self.parameters.setHorizontalHeaderLabels(["Free", "Parameter", "Now", "Low", "High", "Points"])
        self.parameters.verticalHeader().setVisible(False)
        header = self.parameters.horizontalHeader()
        header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(_LABEL, QHeaderView.ResizeMode.Stretch)
        self.parameters.setMinimumHeight(140)  # pixels: a few rows stay visible whatever the options below
        column.addWidget(self.parameters, 3)

        self.grid_box, form = _form_box()
        self.objectives = QListWidget()
        self.objectives.setMaximumHeight(110)
        for name, text in objective_names().items():
            item = QListWidgetItem(name)
            item.setToolTip(text)
            item.setFlags(item.flags() | Qt.ItemFlag.ItemIsUserCheckable)
            item.setCheckState(
                Qt.CheckState.Checked if name == DEFAULT_OBJECTIVE else Qt.CheckState.Unchecked
            )
            self.objectives.addItem(item)
        form.addRow("Objectives", self.objectives)
        self.sampler = QComboBox()
        self.sampler.addItems(SAMPLERS)
        self.budget = NumericField(
            NumberRule("Budget", 1, 100_000, unit="candidates", integer=True), 9, step=1
        )
        _form_line(form, "Sampler, budget", self.sampler, (self.budget, 1))
        self.study_path = QLineEdit()
        self.study_path.setPlaceholderText("none: not stored")
        browse = QPushButton("…")
        browse.setMaximumWidth(32)
        browse.setToolTip("Choose a SQLite study file to store the candidates in (and resume later)")
        browse.clicked.connect(self._browse_study)
        self.resume = QCheckBox("Resume")
        _form_line(form, "Study file", (self.study_path, 1), browse, self.resume)
        column.addWidget(self.grid_box)
        column.addWidget(self._build_algorithm2_box())
        column.addWidget(self._build_crb_box())
        column.addWidget(self._build_gradient_box())
        column.addWidget(self._build_psf_box())
        column.addWidget(self._build_end_to_end_box())
        column.addStretch(0)

        column = outer  # Run, Cancel and the message: below the scroll area, always in view
        buttons = QHBoxLayout()
        self.run_button = QPushButton("Run")
        self.run_button.clicked.connect(self.start)
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setEnabled(False)
        self.cancel_button.clicked.connect(self.cancel)
        buttons.addWidget(self.run_button)
        buttons.addWidget(self.cancel_button)
        column.addLayout(buttons)
        self.message = QLabel("")
        self.message.setWordWrap(True)
        column.addWidget(self.message)
        self._refusal: str | None = None  # a number field's refusal on show (cleared by its next commit)
        for field in self.all_option_fields():
            field.refused.connect(self._on_field_refused)
            field.committed.connect(self._on_field_committed)
        return box

    def _build_algorithm2_box(self) -> QWidget:
        self.algorithm2_box, form = _form_box()
        self.a2_objective = QComboBox()
        for name, text in objective_names().items():
            self.a2_objective.addItem(name)
            self.a2_objective.setItemData(self.a2_objective.count() - 1, text, Qt.ItemDataRole.ToolTipRole)
        self.a2_objective.setCurrentText("axial_crb")
        self.a2_objective.setToolTip(
            "The one score Algorithm 2 optimises (greedy: a merge is kept when it strictly improves it). "
            "CLI --objective (one name)."
        )
        form.addRow("Objective", self.a2_objective)
        self.a2_min_lenslet = _field(
            "Minimum lenslet size", 1.0, 1e6, default_min_lenslet_um(self.state.design), unit="µm", step=100.0,
            tip="d_min, µm: the side of a cell of the MLA grid and the smallest lenslet. The pupil at the MLA "
            "holds M = floor(D / d_min) cells per side; the search tries about M⁴/4 layouts. "
            "CLI --min-lenslet-um (required there; the dock starts at 4 cells across the pupil).",
        )  # fmt: skip
        self.a2_min_lenslet.committed.connect(self._on_min_lenslet_committed)
        self.a2_cells = QLabel("")
        _form_line(form, "Min. lenslet", (self.a2_min_lenslet, 1), self.a2_cells)
        self.a2_symmetry = _combo(
            SYMMETRIES, "none",
            "Every merge is applied to the block's symmetric images: none; mirror (x → −x); mirror-xy "
            "(x → −x and y → −y); 4-fold (90° rotations); 8-fold (rotations and mirrors). CLI --symmetry (default none).",
        )  # fmt: skip
        form.addRow("Symmetry", self.a2_symmetry)
        self.a2_sizes = QLineEdit()
        self.a2_sizes.setPlaceholderText("all: 1 … M−1")
        self.a2_sizes.setToolTip(
            "Block sizes tried, in cells, comma-separated, in this order (e.g. 2,3). Blank: every size from 1 "
            "to M − 1. CLI --sizes."
        )
        form.addRow("Sizes (cells)", self.a2_sizes)
        self.a2_crop = _field(
            "PSF crop", 0, 100_000, CLI_CROP, unit="px", integer=True, special="whole sensor", step=64,
            tip="Camera pixels simulated about the axis for objectives that need a PSF (px; 0 = the whole "
            "sensor). Follows the design until edited: the smallest crop holding enough sub-images, as the "
            "CLI --crop default.",
        )  # fmt: skip
        form.addRow("PSF crop", self.a2_crop)
        return self.algorithm2_box

    def _build_crb_box(self) -> QWidget:
        """axial_crb's photons and background for grid search and Algorithm 2 (the PSF gradient has its own)."""
        self.crb_box, form = _form_box()
        self.c_photons, self.c_background = _crb_fields()
        _form_line(form, "axial_crb photons, background", (self.c_photons, 1), (self.c_background, 1))
        return self.crb_box

    def _build_gradient_box(self) -> QWidget:
        self.gradient_box, form = _form_box()
        self.g_steps = _field(
            "Steps", 1, 100_000, 20, integer=True, step=1,
            tip="Gradient steps: one loss and gradient evaluation and one update each. CLI --steps (default 20).",
        )  # fmt: skip
        self.g_optimizer = _combo(
            OPTIMIZERS, "adam",
            "adam: Adam; lbfgs: L-BFGS with one evaluation per step (curvature kept across steps). "
            "CLI --optimizer (default adam).",
        )  # fmt: skip
        _form_line(form, "Steps, optimiser", (self.g_steps, 1), self.g_optimizer)
        self.g_lr = _field(
            "Learning rate", 1e-9, 10.0, 0.05, step=0.01,
            tip="Optics step per update, as a fraction of each parameter's range (high − low); unitless. "
            "CLI --lr (default 0.05).",
        )  # fmt: skip
        self.g_schedule = _combo(
            SCHEDULES, "constant",
            "Factor on the learning rate per step: constant; cosine (to 5 %); exponential (to 10 %); step "
            "(halved every third of the run). CLI --schedule (default constant).",
        )  # fmt: skip
        _form_line(form, "Learning rate", (self.g_lr, 1), self.g_schedule)
        self.g_crop = _field(
            "PSF crop", 0, 100_000, CLI_CROP, unit="px", integer=True, special="whole sensor", step=64,
            tip="Camera pixels simulated about the axis (px; 0 = the whole sensor). Follows the design until edited: "
            "the smallest crop holding enough sub-images, as the CLI --crop default.",
        )  # fmt: skip
        self.g_check = _check(
            "float64 check",
            "Compare the start gradient in float32 with float64 (relative difference, tolerance 1e-3); costs "
            "one extra gradient in each precision. CLI: on unless --no-float64-check.",
            checked=True,
        )
        _form_line(form, "PSF crop", (self.g_crop, 1), self.g_check)
        return self.gradient_box

    def _build_psf_box(self) -> QWidget:
        self.psf_box, form = _form_box()
        self.g_objective = _combo(
            PSF_OBJECTIVES, "axial_crb",
            "The differentiable PSF objective: axial_crb (axial Cramér-Rao bound, µm, minimise); "
            "depth_dissimilarity (unitless, minimise); mtf_support (soft MTF support, maximise). "
            "CLI --objective (default axial_crb).",
        )  # fmt: skip
        self.g_keep_last = _check(
            "keep last point",
            "The final design is the point after the last update, not the best point evaluated. CLI --keep-last.",
        )
        _form_line(form, "Objective", (self.g_objective, 1), self.g_keep_last)
        self.g_photons, self.g_background = _crb_fields()
        _form_line(form, "Photons, background", (self.g_photons, 1), (self.g_background, 1))
        return self.psf_box

    def _build_end_to_end_box(self) -> QWidget:
        self.e2e_box, form = _form_box()
        self.e_reconstruction = _combo(
            RECONSTRUCTIONS, "unrolled-rl",
            "unrolled-rl: a learned unrolled Richardson-Lucy network trained with the optics; rl: plain "
            "unrolled Richardson-Lucy (nothing to train). CLI --reconstruction (default unrolled-rl).",
        )  # fmt: skip
        self.e_phantom = _combo(
            PHANTOMS,
            "beads",
            "Training and held-out phantoms (4-10 objects each). CLI --phantom (default beads).",
        )
        _form_line(form, "Reconstruction", (self.e_reconstruction, 1), self.e_phantom)
        self.e_freeze_optics = _check(
            "freeze optics", "Train the reconstruction only (the design stays). CLI --freeze-optics."
        )
        self.e_freeze_reconstruction = _check(
            "freeze reconstruction", "Train the optics only. CLI --freeze-reconstruction."
        )
        _form_line(form, "Freeze", self.e_freeze_optics, self.e_freeze_reconstruction, None)
        self.e_lr = _field(
            "Reconstruction learning rate", 1e-9, 10.0, 0.01, step=0.01,
            tip="Adam learning rate of the reconstruction weights. CLI --lr-reconstruction (default 0.01).",
        )  # fmt: skip
        self.e_iterations = _field(
            "Unrolled iterations", 1, 1000, 4, integer=True, step=1,
            tip="Richardson-Lucy iterations unrolled in the reconstruction. CLI --unrolled-iterations (default 4).",
        )  # fmt: skip
        _form_line(form, "Recon. learning rate", (self.e_lr, 1), "iterations", (self.e_iterations, 1))
        self.e_batch = _field(
            "Batch", 1, 10_000, 2, integer=True, step=1,
            tip="Training phantoms per step (a new batch every step). CLI --batch (default 2).",
        )  # fmt: skip
        self.e_held_out = _field(
            "Held-out phantoms", 1, 10_000, 4, integer=True, step=1,
            tip="Test phantoms scored at the start and the end (never trained on). CLI --held-out (default 4).",
        )  # fmt: skip
        _form_line(form, "Batch", (self.e_batch, 1), "held out", (self.e_held_out, 1))
        self.e_photons = _field(
            "Photons", 1.0, 1e15, TASK_PHOTONS, log_step=True,
            tip=f"Expected photons per image of the phantoms (Poisson noise). CLI --photons (default {TASK_PHOTONS:g}).",
        )  # fmt: skip
        form.addRow("Photons", self.e_photons)
        return self.e2e_box

    def _build_run_view(self) -> QWidget:
        view = QWidget()
        column = QVBoxLayout(view)
        column.setContentsMargins(0, 0, 0, 0)
        self.plot = pg.PlotWidget(background="w")
        item = self.plot.getPlotItem()
        item.showGrid(x=True, y=True, alpha=0.25)
        item.setLabel("bottom", "evaluation")
        for side in ("left", "bottom"):  # values as they are: no "(x0.001)" beside "µm" or "score"
            item.getAxis(side).enableAutoSIPrefix(False)
        # The key is the title's last line (ui.plots.keyed_title): a legend box inside the axes sat
        # over the latest candidates, drawn at the right where the box was.
        self.best_curve = item.plot([], [], pen=pg.mkPen(BEST, width=2))
        self.feasible_dots = item.plot(
            [], [], pen=None, symbol="o", symbolSize=7, symbolBrush=pg.mkBrush(FEASIBLE)
        )
        self.plot.setMinimumHeight(120)
        column.addWidget(self.plot, 2)
        self.table = QTableWidget(0, 0)
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        self.table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.cellDoubleClicked.connect(self._on_double_click)
        column.addWidget(self.table, 3)
        buttons = QHBoxLayout()
        self.load_button = QPushButton("Load into studio")
        self.load_button.setToolTip("Make the selected candidate the design in force (or double-click a row)")
        self.load_button.clicked.connect(self.load_selected)
        self.compare_button = QPushButton("Compare two")
        self.compare_button.setToolTip("Select two candidates (Ctrl+click), then compare them side by side")
        self.compare_button.clicked.connect(self.compare_selected)
        buttons.addWidget(self.load_button)
        buttons.addWidget(self.compare_button)
        buttons.addStretch(1)
        column.addLayout(buttons)
        return view

    def _build_compare_view(self) -> QWidget:
        view = QWidget()
        column = QVBoxLayout(view)
        column.setContentsMargins(0, 0, 0, 0)
        self.compare_title = QLabel("Select two candidates in the Run tab and press “Compare two”.")
        self.compare_title.setWordWrap(True)
        column.addWidget(self.compare_title)
        self.compare_table = QTableWidget(0, 3)
        self.compare_table.setHorizontalHeaderLabels(["Quantity", "A", "B"])
        self.compare_table.verticalHeader().setVisible(False)
        self.compare_table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        fit_columns(self.compare_table)  # values whole ("2.765 µm", not "2.… µm"); the previews give way
        self._compare_split = split = QSplitter(Qt.Orientation.Horizontal)
        split.addWidget(self.compare_table)
        self.psf_views = pg.GraphicsLayoutWidget()
        self.psf_views.setBackground("w")
        self.psf_images = []
        for column_index, name in enumerate(("A", "B")):
            box = self.psf_views.addViewBox(row=1, col=column_index, lockAspect=True, invertY=True)
            box.setMouseEnabled(x=True, y=True)
            image = pg.ImageItem()
            box.addItem(image)
            self.psf_images.append(image)
            self.psf_views.addLabel(f"PSF of {name}", row=0, col=column_index, color="k")
        note = QLabel(f"on-axis point at the native focal plane, √ intensity, central {PREVIEW_CROP}² px")
        note.setWordWrap(True)  # a label in the plot's scene would set the previews' minimum width
        note.setStyleSheet("color: #555; font-size: 8pt; background: white;")
        previews = QWidget()
        previews.setMaximumWidth(420)  # the metrics table keeps the room
        stack = QVBoxLayout(previews)
        stack.setContentsMargins(0, 0, 0, 0)
        stack.setSpacing(0)
        stack.addWidget(self.psf_views, 1)
        stack.addWidget(note)
        split.addWidget(previews)
        split.setStretchFactor(0, 3)
        split.setStretchFactor(1, 2)
        column.addWidget(split, 1)
        return view

    def _fill_parameters(self) -> None:
        """List the design's freeable values; a path listed before keeps its tick and range.

        An unticked row whose kept range no longer holds the design's value (the design changed)
        gets the default range around the new value: a stale range would start a descent outside
        its bounds once ticked.
        """
        kept = {}
        for row in range(self.parameters.rowCount()):
            free = self.parameters.item(row, _FREE)
            cells = [self.parameters.item(row, c).text() for c in (_LOW, _HIGH, _POINTS)]
            kept[free.data(Qt.ItemDataRole.UserRole)] = (free.checkState(), cells)
        fields = freeable_fields(self.state.design)
        self.parameters.setRowCount(len(fields))
        for row, spec in enumerate(fields):
            free = _item("", tip=spec.path)
            free.setFlags(Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsUserCheckable)
            free.setCheckState(Qt.CheckState.Unchecked)
            free.setData(Qt.ItemDataRole.UserRole, spec.path)
            self.parameters.setItem(row, _FREE, free)
            unit = f" ({spec.unit})" if spec.unit else ""
            self.parameters.setItem(row, _LABEL, _item(f"{spec.label}{unit}", tip=spec.path))
            self.parameters.setItem(row, _CURRENT, _item(f"{spec.value:.6g}"))
            low, high = (spec.value * 0.9, spec.value * 1.1) if spec.value else (-1.0, 1.0)
            low, high = min(low, high), max(low, high)
            self.parameters.setItem(row, _LOW, _item(f"{low:.6g}", editable=True))
            self.parameters.setItem(row, _HIGH, _item(f"{high:.6g}", editable=True))
            self.parameters.setItem(row, _POINTS, _item("3", editable=True))
            if spec.path in kept:
                check, cells = kept[spec.path]
                if check != Qt.CheckState.Checked and not _holds(cells, spec.value):
                    continue
                free.setCheckState(check)
                for column, text in zip((_LOW, _HIGH, _POINTS), cells, strict=True):
                    self.parameters.item(row, column).setText(text)

    # ----- the settings as a request -----

    def parameter_row(self, path: str) -> int:
        """The row of the parameter table that frees ``path`` (ValueError if the dock does not offer it)."""
        for row in range(self.parameters.rowCount()):
            if self.parameters.item(row, _FREE).data(Qt.ItemDataRole.UserRole) == path:
                return row
        raise ValueError(f"the Optimise dock cannot free {path!r} for this design.")

    def free(self, path: str, low: float, high: float, points: int) -> None:
        """Tick ``path`` and set its range (what a user does in the table)."""
        row = self.parameter_row(path)
        self.parameters.item(row, _FREE).setCheckState(Qt.CheckState.Checked)
        self.parameters.item(row, _LOW).setText(f"{low:.12g}")
        self.parameters.item(row, _HIGH).setText(f"{high:.12g}")
        self.parameters.item(row, _POINTS).setText(str(points))

    def set_objectives(self, names: list[str]) -> None:
        """Tick exactly ``names`` (in list order, the first ranks), untick the rest."""
        for i in range(self.objectives.count()):
            item = self.objectives.item(i)
            item.setCheckState(Qt.CheckState.Checked if item.text() in names else Qt.CheckState.Unchecked)
        self._objective_order = list(names)

    def checked_objectives(self) -> list[str]:
        checked = [
            self.objectives.item(i).text()
            for i in range(self.objectives.count())
            if self.objectives.item(i).checkState() == Qt.CheckState.Checked
        ]
        order = self._objective_order
        return [n for n in order if n in checked] + [n for n in checked if n not in order]

    def method_key(self) -> str:
        """The method chosen (a key of :data:`~.optimise_model.METHODS`)."""
        return str(self.method.currentData())

    def set_method(self, key: str) -> None:
        """Choose the method ``key`` (what a user does in the Method box)."""
        index = self.method.findData(key)
        if index < 0:
            raise ValueError(f"the Optimise dock has no method {key!r}; it offers {list(METHODS)}.")
        self.method.setCurrentIndex(index)

    def all_option_fields(self) -> list[NumericField]:
        """Every method's number fields, each once (a refusal in any of them shows in the message line)."""
        fields: list[NumericField] = []
        for method in METHODS:
            fields += [f for f in self.option_fields(method) if f not in fields]
        return fields

    def option_fields(self, method: str | None = None) -> list[NumericField]:
        """The number fields of ``method``'s options (default: the method chosen)."""
        method = method or self.method_key()
        if method == "grid":
            return [self.budget, self.c_photons, self.c_background]
        if method == "algorithm2":
            return [self.a2_min_lenslet, self.a2_crop, self.c_photons, self.c_background]
        fields = [self.g_steps, self.g_lr, self.g_crop]
        if method == "gradient-psf":
            return [*fields, self.g_photons, self.g_background]
        return [*fields, self.e_lr, self.e_iterations, self.e_batch, self.e_held_out, self.e_photons]

    def _free_parameters(self, *, points: bool = True) -> list[FreeParameter]:
        free = []
        for row in range(self.parameters.rowCount()):
            if self.parameters.item(row, _FREE).checkState() != Qt.CheckState.Checked:
                continue
            path = self.parameters.item(row, _FREE).data(Qt.ItemDataRole.UserRole)
            low = _number(self.parameters.item(row, _LOW).text(), f"low of {path}")
            high = _number(self.parameters.item(row, _HIGH).text(), f"high of {path}")
            count = 1.0
            if points:
                count = _number(self.parameters.item(row, _POINTS).text(), f"points of {path}")
                if count != int(count) or count < 1:
                    raise ValueError(f"points of {path} must be a whole number >= 1; got {count:g}.")
            free.append(FreeParameter(path, low, high, int(count)))
        return free

    def build_request(self) -> AnyRequest:
        """The run the settings describe (ValueError naming the bad setting and the fix)."""
        method = self.method_key()
        fields = self.option_fields(method)
        if not commit_all(fields):  # a text still being typed counts; a refused one stops the run
            raise ValueError(next(f.error() for f in fields if f.error() is not None))
        if method == "algorithm2":
            return self._algorithm2_request()
        if method.startswith("gradient"):
            return self._gradient_request(method.removeprefix("gradient-"))
        free = self._free_parameters()
        study = self.study_path.text().strip() or None
        request = OptimiseRequest(
            tuple(free), tuple(self.checked_objectives()), sampler=self.sampler.currentText(),
            budget=self.budget.value(), study=study, resume=self.resume.isChecked(),
            crop=auto_crop(self.state.design), crb_photons=float(self.c_photons.value()),
            crb_background=float(self.c_background.value()),
        )  # fmt: skip
        request.space()  # bounds and points checked now, with the parameter's name
        return request

    def _algorithm2_request(self) -> Algorithm2Request:
        crop = int(self.a2_crop.value())
        request = Algorithm2Request(
            objective=self.a2_objective.currentText(), min_lenslet_um=float(self.a2_min_lenslet.value()),
            symmetry=self.a2_symmetry.currentText(), sizes=parse_sizes(self.a2_sizes.text()),
            crop=crop or None, crb_photons=float(self.c_photons.value()),
            crb_background=float(self.c_background.value()),
        )  # fmt: skip
        request.check(self.state.design)
        return request

    def _gradient_request(self, mode: str) -> GradientRequest:
        crop = int(self.g_crop.value())
        psf = mode == "psf"
        request = GradientRequest(
            mode, tuple(self._free_parameters(points=False)),
            objective=self.g_objective.currentText(), steps=int(self.g_steps.value()),
            optimizer=self.g_optimizer.currentText(), lr=float(self.g_lr.value()),
            schedule=self.g_schedule.currentText(), crop=crop or None, check_float64=self.g_check.isChecked(),
            photons=float(self.g_photons.value() if psf else self.e_photons.value()),
            background=float(self.g_background.value()), keep_last=self.g_keep_last.isChecked(),
            reconstruction=self.e_reconstruction.currentText(), freeze_optics=self.e_freeze_optics.isChecked(),
            freeze_reconstruction=self.e_freeze_reconstruction.isChecked(), lr_reconstruction=float(self.e_lr.value()),
            unrolled_iterations=int(self.e_iterations.value()), batch=int(self.e_batch.value()),
            held_out=int(self.e_held_out.value()), phantom=self.e_phantom.currentText(),
        )  # fmt: skip
        request.space()  # low <= high, named by path
        request.check(self.state.design)  # every freed value differentiable
        return request

    # ----- running -----

    def start(self) -> None:
        """Run the optimisation the settings describe (a bad setting is shown, nothing starts)."""
        try:
            request = self.build_request()
        except ValueError as error:
            self.message.setText(f"<span style='color:{INFEASIBLE.name()}'>{error}</span>")
            return
        try:
            info = objective_info(request)
        except ValueError as error:
            self.message.setText(f"<span style='color:{INFEASIBLE.name()}'>{error}</span>")
            return
        labels = column_labels(self.state.design)  # the labels of the design the run starts from
        self._pending = (request, info, labels)  # the rows shown stay until this run delivers its first one
        self._note = resume_note(request)  # read before the run, which then stores the same study
        self.message.setText(f"Running {METHODS[request.method]}…")
        self.run_button.setEnabled(False)
        self.cancel_button.setEnabled(True)
        self.runner.submit(
            JOB_NAME, _JOBS[request.method], self.state.design, request,
            on_result=self._on_result, on_partial=self._on_row,
        )  # fmt: skip

    def cancel(self) -> None:
        """Stop the run after the candidate being evaluated; the candidates shown stay."""
        self.runner.cancel(JOB_NAME)

    def is_running(self) -> bool:
        return self.runner.is_running(JOB_NAME)

    def _adopt(self) -> None:
        """The running job delivered: its request replaces the one whose rows were shown."""
        if self._pending is None:
            return
        request, info, self._labels = self._pending
        self._pending = None
        self.request, self.rows, self.chosen, self.summary = request, [], None, ""
        self._directions = {n: d for n, (d, _) in info.items()}
        self._units = {n: u for n, (_, u) in info.items()}

    def _on_row(self, row: CandidateRow) -> None:
        self._adopt()
        self.rows = [r for r in self.rows if r.number != row.number] + [row]
        self._show_rows()

    def _on_result(self, result: list[CandidateRow] | RunResult) -> None:
        self._adopt()
        if isinstance(result, RunResult):
            self.rows, self.chosen, self.summary = list(result.rows), result.chosen, result.summary
        else:
            self.rows = list(result)
        self._show_rows()

    def _on_progress(self, name: str, _generation: int, done: int, total: int, message: str) -> None:
        if name == JOB_NAME:
            self.message.setText(f"Running: {message}")

    def _on_ended(self, outcome: JobOutcome) -> None:
        if outcome.name != JOB_NAME:
            return
        self.run_button.setEnabled(True)
        self.cancel_button.setEnabled(False)
        count = len(self.rows)
        untouched = self._pending is not None  # the run delivered nothing: the previous results stay
        self._pending = None
        kept = (
            f"the previous results ({count} rows) are kept"
            if untouched
            else f"the {count} rows delivered so far are kept"
        )
        if outcome.state == "done":
            if self.summary:
                self.message.setText(
                    f"Done: {self.summary}. Double-click a row to load it (green: the chosen one)."
                )
                return
            best = self.best()
            if best is None:  # nothing to load: say why instead of inviting a double-click
                self.message.setText(
                    f"Done: {count} candidates, none feasible (reasons in the last column). "
                    "Fix: widen or move the ranges, or change the design."
                    + (f" Note: {self._note}" if self._note else "")
                )
            else:
                self.message.setText(
                    f"Done: {count} candidates, best: candidate {best.number} (double-click a row to load it)."
                    + (f" Note: {self._note}" if self._note else "")
                )
        elif outcome.state == "cancelled":
            if untouched:
                self.message.setText(f"Cancelled: {kept}.")
            else:
                self.message.setText(f"Cancelled: the {count} candidates evaluated so far are kept.")
        else:
            self.message.setText(
                f"<span style='color:{INFEASIBLE.name()}'>Failed: {shown_units_in(str(outcome.error))}</span> ({kept})"
            )

    # ----- showing -----

    @property
    def ranking(self) -> str | None:
        """The objective that ranks the candidates (the first chosen)."""
        return None if self.request is None else self.request.objectives[0]

    def best(self) -> CandidateRow | None:
        """The row the engine chose (Algorithm 2's best layout, a gradient run's final design), else the
        best feasible candidate shown by the ranking objective."""
        if self.chosen is not None:
            return next((r for r in self.rows if r.number == self.chosen), None)
        name = self.ranking
        return None if name is None else best_row(self.rows, name, self._directions[name])

    def _on_field_refused(self, reason: str) -> None:
        self._refusal = reason
        self.message.setText(f"<span style='color:{INFEASIBLE.name()}'>{reason}</span>")

    def _on_field_committed(self, *_: Any) -> None:
        """Clear the refusal on show, unless another field still holds a refused number (then that one)."""
        pending = next((f.error() for f in self.all_option_fields() if f.error() is not None), None)
        if pending is not None:
            self._on_field_refused(pending)
            return
        if self._refusal is not None and self._refusal in self.message.text():
            self.message.setText("")
        self._refusal = None

    def _show_rows(self) -> None:
        request = self.request
        paths = list(request.columns()) if request is not None else []
        names = list(request.objectives) if request is not None else []
        units = {n: shown_unit(self._units.get(n, "")) for n in names}
        headers = [
            "#", *(self._labels.get(p, p) for p in paths), *(f"{n} ({units[n]})" if units[n] else n for n in names),
            "Feasible / reason",
        ]  # fmt: skip
        self.table.setColumnCount(len(headers))
        self.table.setHorizontalHeaderLabels(headers)
        for c, path in enumerate(paths, start=1):  # the path (as in a design space) on hover
            self.table.horizontalHeaderItem(c).setToolTip(path)
        self.table.horizontalHeaderItem(len(headers) - 1).setToolTip(reasons_tip())
        self.table.setRowCount(len(self.rows))
        best = self.best()
        for r, row in enumerate(self.rows):
            cells = [str(row.number)]
            cells += [cell_text(row.params.get(p, float("nan"))) for p in paths]
            cells += [
                "—" if row.values is None else f"{row.values[n]:.6g}" if n in row.values else NOT_EVALUATED
                for n in names
            ]
            note = f" ({row.note})" if row.note else ""
            cells.append(f"yes{note}" if row.feasible else f"no: {row.reason}")
            why = reason_tip(row.reason) if not row.feasible else ""
            for c, text in enumerate(cells):
                tip = row.message or text
                item = _item(text, tip=f"{why}\n{tip}" if why else tip)
                if not row.feasible:
                    item.setForeground(QBrush(INFEASIBLE))
                if best is not None and row.number == best.number:
                    item.setBackground(QBrush(QColor("#e8f5e9")))
                self.table.setItem(r, c, item)
        self._plot_rows()

    def _plot_rows(self) -> None:
        name = self.ranking
        item = self.plot.getPlotItem()
        if name is None:
            for curve in (self.best_curve, self.feasible_dots):
                curve.setData([], [])
            return
        unit = shown_unit(self._units.get(name, ""))
        method = self.request.method if self.request is not None else "grid"
        x_label = X_LABELS["gradient" if method.startswith("gradient") else method]
        item.setLabel("left", unit or "score")  # the name is in the title: a long one was cut on the axis
        item.setLabel("bottom", x_label)
        # Infeasible candidates have no score: not drawn (a mark at some other value read as a score).
        infeasible = sum(not r.feasible for r in self.rows)
        note = f"<br>{infeasible} infeasible, not scored (see the table)" if infeasible else ""
        title = f"{name} ({self._directions[name]}) against {x_label}{note}"
        # A gradient run's steps are one path: join them (the loss curve); candidates stay dots.
        gradient = method.startswith("gradient")
        self.feasible_dots.setPen(pg.mkPen(FEASIBLE, width=1.5) if gradient else None)
        # end to end: the training loss is not measured at the final design (no point drawn there)
        step = "step" if method == "gradient-end-to-end" else "step (final design last)"
        dots_name = {"grid": "candidate", "algorithm2": "layout"}.get(method, step)
        best = best_so_far(self.rows, name, self._directions[name])
        xs = [r.number for r in self.rows]
        # a row whose score was not measured (end to end: the final design) does not extend the line
        scored = [r.values is None or name in r.values for r in self.rows]
        line = [(x, b) for x, b, s in zip(xs, best, scored, strict=True) if b is not None and s]
        self.best_curve.setData([x for x, _ in line], [b for _, b in line])
        dots = [(r.number, r.values[name]) for r in self.rows if r.values is not None and name in r.values]
        self.feasible_dots.setData([x for x, _ in dots], [y for _, y in dots])
        key = [(f'<span style="color:{BEST.name()};">━</span>', "best so far")] if line else []
        key += [(f'<span style="color:{FEASIBLE.name()};">●</span>', dots_name)] if dots else []
        show_title(item, keyed_title(title, key), size="9pt")

    def selected_rows(self) -> list[CandidateRow]:
        picked = sorted({index.row() for index in self.table.selectionModel().selectedRows()})
        return [self.rows[i] for i in picked if i < len(self.rows)]

    # ----- loading and comparing -----

    def load(self, row: CandidateRow) -> bool:
        """Make ``row``'s design the design in force (False, with the reason shown, for an infeasible one)."""
        try:
            design, notes = with_design_warnings(row.design)  # shown as the studio shows design warnings
        except ValueError as error:
            self.message.setText(f"<span style='color:{INFEASIBLE.name()}'>{error}</span>")
            return False
        self.state.set_design(design, warnings=notes)
        warned = (
            f" ({len(notes)} design warning{'s' * (len(notes) != 1)}: see the parameter panel)"
            if notes
            else ""
        )
        self.message.setText(f"Loaded {row.label} into the studio{warned}.")
        return True

    def load_selected(self) -> None:
        rows = self.selected_rows()
        if len(rows) != 1:
            self.message.setText("Select one candidate to load.")
            return
        self.load(rows[0])

    def _on_double_click(self, r: int, _column: int) -> None:
        if 0 <= r < len(self.rows):
            self.load(self.rows[r])

    def compare(self, a: CandidateRow, b: CandidateRow) -> None:
        """Show ``a`` and ``b`` side by side in the Compare tab."""
        try:
            (design_a, _), (design_b, _) = with_design_warnings(a.design), with_design_warnings(b.design)
        except ValueError as error:
            self.message.setText(f"<span style='color:{INFEASIBLE.name()}'>{error}</span>")
            return
        rows = comparison_rows(design_a, design_b)
        self.compare_table.setHorizontalHeaderLabels(
            ["Quantity", f"A: candidate {a.number}", f"B: candidate {b.number}"]
        )
        self.compare_table.setRowCount(len(rows))
        for r, cells in enumerate(rows):
            for c, text in enumerate(cells):
                item = _item(text)
                if text.startswith(("PASS", "FAIL")):
                    item.setForeground(QBrush(BEST if text.startswith("PASS") else INFEASIBLE))
                self.compare_table.setItem(r, c, item)
        params = lambda row: ", ".join(f"{k} = {cell_text(v)}" for k, v in row.params.items())  # noqa: E731
        self.compare_title.setText(f"<b>A</b>: {params(a)}<br><b>B</b>: {params(b)}")
        self.tabs.setCurrentIndex(1)
        give_room(self._compare_split, self.compare_table)
        for image in self.psf_images:
            image.clear()
        self.runner.submit(PREVIEW_JOB, _preview_job, design_a, design_b, on_result=self._on_previews)

    def _on_previews(self, images: tuple[Any, Any]) -> None:
        for item, image in zip(self.psf_images, images, strict=True):
            item.setImage(image.T, levels=(0.0, 1.0))  # pyqtgraph images are (x, y)

    def compare_rows(self) -> list[tuple[str, str, str]]:
        """The Compare table as text (for tests and screen readers)."""
        t = self.compare_table
        return [tuple(t.item(r, c).text() for c in range(3)) for r in range(t.rowCount())]  # type: ignore[misc]

    def compare_selected(self) -> None:
        rows = self.selected_rows()
        if len(rows) != 2:
            self.message.setText("Select exactly two candidates (Ctrl+click) to compare.")
            return
        self.compare(*rows)

    def _browse_study(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self, "Study file", self.study_path.text(), "SQLite study (*.db);;All files (*)",
            options=QFileDialog.Option.DontConfirmOverwrite,
        )  # fmt: skip
        if path:
            self.study_path.setText(path)

    def _on_design_changed(self, _design: Any) -> None:
        self._follow_auto_crop()
        self._fill_parameters()  # current values, and the lenslets of the design in force
        if not self._min_lenslet_edited:
            self.a2_min_lenslet.setValue(default_min_lenslet_um(self.state.design))
        self._show_cells()

    def _follow_auto_crop(self) -> None:
        """The PSF crop fields the user has not edited take the design's automatic crop
        (:func:`auto_crop`: enough sub-images on the crop; 0 = the whole sensor)."""
        crop = auto_crop(self.state.design) or 0
        for crop_field in (self.a2_crop, self.g_crop):
            if id(crop_field) not in self._crop_edited:
                crop_field.setValue(crop)

    def _on_min_lenslet_committed(self, *_: Any) -> None:
        self._min_lenslet_edited = True
        self._show_cells()

    def _show_cells(self) -> None:
        """The number of Algorithm 2 cells per side the minimum lenslet size gives the design in force."""
        try:
            cells = algorithm2_cells(self.state.design, float(self.a2_min_lenslet.value()))
        except ValueError:
            self.a2_cells.setText("")
            return
        self.a2_cells.setText(f"= {cells} cells per side")

    def _on_method_changed(self, *_: Any) -> None:
        """Show the chosen method's options only (the results shown stay until the next run delivers)."""
        method = self.method_key()
        gradient = method.startswith("gradient")
        self.grid_box.setVisible(method == "grid")
        self.algorithm2_box.setVisible(method == "algorithm2")
        self.crb_box.setVisible(method in ("grid", "algorithm2"))
        self.gradient_box.setVisible(gradient)
        self.psf_box.setVisible(method == "gradient-psf")
        self.e2e_box.setVisible(method == "gradient-end-to-end")
        self.parameters.setVisible(method != "algorithm2")
        self.parameters.setColumnHidden(_POINTS, gradient)
        if method == "algorithm2":
            self.parameters_title.setText(
                "<b>Algorithm 2</b>: searches the MLA layout (merged cells of the minimum lenslet size inside the "
                "pupil); the rest of the design stays."
            )
            self._show_cells()
        elif gradient:
            self.parameters_title.setText(
                "<b>Free parameters</b> (tick, then set the bounds low / high; the descent starts from the value now)"
            )
        else:
            self.parameters_title.setText("<b>Free parameters</b> (tick, then set low / high / points)")

    def disconnect_state(self) -> None:
        """Stop observing the state and the runner (on close)."""
        self.state.design_changed.disconnect(self._on_design_changed)
        self.runner.ended.disconnect(self._on_ended)
        self.runner.progressed.disconnect(self._on_progress)
