"""The studio's "Optimise" dock: free parameters, pick objectives and a budget, run, plot, load, compare.

Left: the freeable design values (:func:`~.optimise_model.freeable_fields`; tick a row and
give low / high / points), the objectives (:func:`~lfm_studio.engine.optimize.objective_names`;
the first ticked one ranks the candidates), the sampler, the budget (number of candidates)
and an optional SQLite study file (store; tick "Resume" to continue it). Right, in tabs:
"Run" (a live plot of the first objective against the evaluation number, each candidate a
dot, infeasible ones a red cross on the best-so-far line, the best-so-far line itself, and
the table of candidates with parameters, scores and feasibility or reason) and "Compare"
(closed-form metrics and requirement checks of two candidates side by side).

The run is the job ``"optimise"`` of the studio's shared :class:`~lfm_studio.widgets.jobs.JobRunner`
(progress and Cancel in the status bar too); each stored candidate arrives as a partial
result, so the table and plot fill in while the GUI stays responsive. Cancel or a failure
keeps the candidates already shown. Double-click a candidate (or "Load into studio") to
make its design the design in force (an edit: the document becomes unsaved; the studio
has no undo).
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
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.optimize import objective_named, objective_names
from lfm_studio.ui.optimise_model import (
    PREVIEW_CROP,
    SAMPLERS,
    CandidateRow,
    FreeParameter,
    OptimiseRequest,
    best_row,
    best_so_far,
    comparison_rows,
    freeable_fields,
    psf_preview,
    run_optimisation,
)
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.jobs import JobOutcome, JobRunner
from lfm_studio.widgets.numeric_field import NumericField
from lfm_studio.widgets.numeric_text import NumberRule

JOB_NAME = "optimise"
PREVIEW_JOB = "optimise_psf"  # the Compare tab's PSF previews of A and B
DEFAULT_OBJECTIVE = "lateral_resolution"
FEASIBLE, INFEASIBLE, BEST = QColor("#1565c0"), QColor("#c62828"), QColor("#2e7d32")
_FREE, _LABEL, _CURRENT, _LOW, _HIGH, _POINTS = range(6)


def _run_job(ctx: Any, base: Any, request: OptimiseRequest) -> list[CandidateRow]:
    """Worker-thread body of the ``"optimise"`` job (each stored candidate goes out as a partial)."""
    return run_optimisation(base, request, on_row=ctx.partial, progress=ctx.progress, cancel=ctx.cancel)


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


def _number(text: str, what: str) -> float:
    try:
        return float(text.strip())
    except ValueError:
        raise ValueError(f"{what} must be a number; got {text.strip()!r}. Fix: type a number.") from None


class OptimiseDock(QWidget):
    """The "Optimise" dock of ``state``, running on ``runner`` (the studio controller's).

    ``rows`` holds the candidates shown (in trial order); ``selected_rows()`` the selection.
    """

    def __init__(self, state: StudioState, runner: JobRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.state, self.runner = state, runner
        self.rows: list[CandidateRow] = []
        self.request: OptimiseRequest | None = None
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
        self._fill_parameters()

    # ----- building -----

    def _build_setup(self) -> QWidget:
        box = QWidget()
        column = QVBoxLayout(box)
        column.setContentsMargins(0, 0, 0, 0)
        column.addWidget(QLabel("<b>Free parameters</b> (tick, then set low / high / points)"))
        self.parameters = QTableWidget(0, 6)
        self.parameters.setHorizontalHeaderLabels(["Free", "Parameter", "Now", "Low", "High", "Points"])
        self.parameters.verticalHeader().setVisible(False)
        header = self.parameters.horizontalHeader()
        header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(_LABEL, QHeaderView.ResizeMode.Stretch)
        column.addWidget(self.parameters, 3)

        form = QFormLayout()
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
        line = QHBoxLayout()
        line.addWidget(self.sampler)
        line.addWidget(self.budget, 1)
        form.addRow("Sampler, budget", line)
        self.study_path = QLineEdit()
        self.study_path.setPlaceholderText("none: not stored")
        browse = QPushButton("…")
        browse.setMaximumWidth(32)
        browse.setToolTip("Choose a SQLite study file to store the candidates in (and resume later)")
        browse.clicked.connect(self._browse_study)
        self.resume = QCheckBox("Resume")
        line = QHBoxLayout()
        line.addWidget(self.study_path, 1)
        line.addWidget(browse)
        line.addWidget(self.resume)
        form.addRow("Study file", line)
        column.addLayout(form)

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
        self._refusal: str | None = None  # the budget field's refusal on show (cleared by its next commit)
        self.budget.refused.connect(self._on_budget_refused)
        self.budget.committed.connect(self._on_budget_committed)
        return box

    def _build_run_view(self) -> QWidget:
        view = QWidget()
        column = QVBoxLayout(view)
        column.setContentsMargins(0, 0, 0, 0)
        self.plot = pg.PlotWidget(background="w")
        item = self.plot.getPlotItem()
        item.showGrid(x=True, y=True, alpha=0.25)
        item.setLabel("bottom", "evaluation")
        item.addLegend(offset=(-10, 10))
        self.best_curve = item.plot([], [], pen=pg.mkPen(BEST, width=2), name="best so far")
        self.feasible_dots = item.plot(
            [], [], pen=None, symbol="o", symbolSize=7, symbolBrush=pg.mkBrush(FEASIBLE), name="candidate"
        )
        self.infeasible_marks = item.plot(
            [], [], pen=None, symbol="x", symbolSize=10, symbolBrush=pg.mkBrush(INFEASIBLE),
            symbolPen=pg.mkPen(INFEASIBLE), name="infeasible",
        )  # fmt: skip
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
        header = self.compare_table.horizontalHeader()
        header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        for section in (1, 2):
            header.setSectionResizeMode(section, QHeaderView.ResizeMode.Stretch)
        split = QSplitter(Qt.Orientation.Horizontal)
        split.addWidget(self.compare_table)
        self.psf_views = pg.GraphicsLayoutWidget()
        self.psf_views.setBackground("w")
        self.psf_views.setMaximumWidth(420)  # the metrics table keeps the room
        self.psf_images = []
        for column_index, name in enumerate(("A", "B")):
            box = self.psf_views.addViewBox(row=1, col=column_index, lockAspect=True, invertY=True)
            box.setMouseEnabled(x=True, y=True)
            image = pg.ImageItem()
            box.addItem(image)
            self.psf_images.append(image)
            self.psf_views.addLabel(f"PSF of {name}", row=0, col=column_index, color="k")
        self.psf_views.addLabel(
            f"on-axis point at the native focal plane, √ intensity, central {PREVIEW_CROP}² px", row=2, col=0, colspan=2,
            color="#555", size="8pt",
        )  # fmt: skip
        split.addWidget(self.psf_views)
        split.setStretchFactor(0, 3)
        split.setStretchFactor(1, 2)
        column.addWidget(split, 1)
        return view

    def _fill_parameters(self) -> None:
        """List the design's freeable values; a path listed before keeps its tick and range."""
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

    def build_request(self) -> OptimiseRequest:
        """The run the settings describe (ValueError naming the bad setting and the fix)."""
        free = []
        for row in range(self.parameters.rowCount()):
            if self.parameters.item(row, _FREE).checkState() != Qt.CheckState.Checked:
                continue
            path = self.parameters.item(row, _FREE).data(Qt.ItemDataRole.UserRole)
            low = _number(self.parameters.item(row, _LOW).text(), f"low of {path}")
            high = _number(self.parameters.item(row, _HIGH).text(), f"high of {path}")
            points = _number(self.parameters.item(row, _POINTS).text(), f"points of {path}")
            if points != int(points) or points < 1:
                raise ValueError(f"points of {path} must be a whole number >= 1; got {points:g}.")
            free.append(FreeParameter(path, low, high, int(points)))
        study = self.study_path.text().strip() or None
        request = OptimiseRequest(
            tuple(free), tuple(self.checked_objectives()), sampler=self.sampler.currentText(),
            budget=self.budget.value(), study=study, resume=self.resume.isChecked(),
        )  # fmt: skip
        request.space()  # bounds and points checked now, with the parameter's name
        return request

    # ----- running -----

    def start(self) -> None:
        """Run the optimisation the settings describe (a bad setting is shown, nothing starts)."""
        try:
            request = self.build_request()
        except ValueError as error:
            self.message.setText(f"<span style='color:{INFEASIBLE.name()}'>{error}</span>")
            return
        self.request = request
        built = [objective_named(n) for n in request.objectives]
        self._directions = {n: o.direction for n, o in zip(request.objectives, built, strict=True)}
        self._units = {n: o.unit for n, o in zip(request.objectives, built, strict=True)}
        self.rows = []
        self._show_rows()
        self.message.setText("Running…")
        self.run_button.setEnabled(False)
        self.cancel_button.setEnabled(True)
        self.runner.submit(
            JOB_NAME, _run_job, self.state.design, request,
            on_result=self._on_result, on_partial=self._on_row,
        )  # fmt: skip

    def cancel(self) -> None:
        """Stop the run after the candidate being evaluated; the candidates shown stay."""
        self.runner.cancel(JOB_NAME)

    def is_running(self) -> bool:
        return self.runner.is_running(JOB_NAME)

    def _on_row(self, row: CandidateRow) -> None:
        self.rows = [r for r in self.rows if r.number != row.number] + [row]
        self._show_rows()

    def _on_result(self, rows: list[CandidateRow]) -> None:
        self.rows = list(rows)
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
        if outcome.state == "done":
            best = self.best()
            where = "no feasible candidate" if best is None else f"best: candidate {best.number}"
            self.message.setText(f"Done: {count} candidates, {where} (double-click a row to load it).")
        elif outcome.state == "cancelled":
            self.message.setText(f"Cancelled: the {count} candidates evaluated so far are kept.")
        else:
            self.message.setText(
                f"<span style='color:{INFEASIBLE.name()}'>Failed: {outcome.error}</span> "
                f"(the {count} candidates evaluated so far are kept)"
            )

    # ----- showing -----

    @property
    def ranking(self) -> str | None:
        """The objective that ranks the candidates (the first chosen)."""
        return None if self.request is None else self.request.objectives[0]

    def best(self) -> CandidateRow | None:
        """The best feasible candidate shown, by the ranking objective."""
        name = self.ranking
        return None if name is None else best_row(self.rows, name, self._directions[name])

    def _on_budget_refused(self, reason: str) -> None:
        self._refusal = reason
        self.message.setText(f"<span style='color:{INFEASIBLE.name()}'>{reason}</span>")

    def _on_budget_committed(self, *_: Any) -> None:
        if self._refusal is not None and self._refusal in self.message.text():
            self.message.setText("")
        self._refusal = None

    def _show_rows(self) -> None:
        request = self.request
        paths = [p.path for p in request.parameters] if request is not None else []
        names = list(request.objectives) if request is not None else []
        headers = ["#", *paths, *names, "Feasible / reason"]
        self.table.setColumnCount(len(headers))
        self.table.setHorizontalHeaderLabels(headers)
        self.table.setRowCount(len(self.rows))
        best = self.best()
        for r, row in enumerate(self.rows):
            cells = [str(row.number)]
            cells += [f"{row.params.get(p, float('nan')):.6g}" for p in paths]
            cells += ["—" if row.values is None else f"{row.values[n]:.6g}" for n in names]
            cells.append("yes" if row.feasible else f"no: {row.reason}")
            for c, text in enumerate(cells):
                item = _item(text, tip=row.message or text)
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
            for curve in (self.best_curve, self.feasible_dots, self.infeasible_marks):
                curve.setData([], [])
            return
        unit = self._units.get(name, "")
        item.setLabel("left", f"{name} ({unit})" if unit else name)
        item.setTitle(f"{name} ({self._directions[name]}) against evaluation", color="k", size="9pt")
        best = best_so_far(self.rows, name, self._directions[name])
        xs = [r.number for r in self.rows]
        line = [(x, b) for x, b in zip(xs, best, strict=True) if b is not None]
        self.best_curve.setData([x for x, _ in line], [b for _, b in line])
        dots = [(r.number, r.values[name]) for r in self.rows if r.values is not None]
        self.feasible_dots.setData([x for x, _ in dots], [y for _, y in dots])
        floor = min((y for _, y in dots), default=0.0)  # infeasible: on the best-so-far line (or the floor)
        marks = [
            (x, floor if b is None else b)
            for x, b, r in zip(xs, best, self.rows, strict=True)
            if not r.feasible
        ]
        self.infeasible_marks.setData([x for x, _ in marks], [y for _, y in marks])

    def selected_rows(self) -> list[CandidateRow]:
        picked = sorted({index.row() for index in self.table.selectionModel().selectedRows()})
        return [self.rows[i] for i in picked if i < len(self.rows)]

    # ----- loading and comparing -----

    def load(self, row: CandidateRow) -> bool:
        """Make ``row``'s design the design in force (False, with the reason shown, for an infeasible one)."""
        try:
            design = row.design()
        except ValueError as error:
            self.message.setText(f"<span style='color:{INFEASIBLE.name()}'>{error}</span>")
            return False
        self.state.set_design(design)
        self.message.setText(f"Loaded candidate {row.number} into the studio.")
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
            design_a, design_b = a.design(), b.design()
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
        params = lambda row: ", ".join(f"{k} = {v:.6g}" for k, v in row.params.items())  # noqa: E731
        self.compare_title.setText(f"<b>A</b>: {params(a)}<br><b>B</b>: {params(b)}")
        self.tabs.setCurrentIndex(1)
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
        self._fill_parameters()  # current values, and the lenslets of the design in force

    def disconnect_state(self) -> None:
        """Stop observing the state and the runner (on close)."""
        self.state.design_changed.disconnect(self._on_design_changed)
        self.runner.ended.disconnect(self._on_ended)
        self.runner.progressed.disconnect(self._on_progress)
