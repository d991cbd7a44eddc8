"""The studio's main window: it only assembles the panels, widgets, bindings and menus.

Centre: the PSF / image / reconstruction viewer. Docks: design parameters with the
design metrics against the requirements under them (left, full height), the PSF profile /
RL convergence plots (right, in tabs), the MLA layout editor, the simulate-and-reconstruct
workflow, the Optimise dock and the learned-model training (bottom, tabbed, under viewer and plots). Status bar: the running job with a progress bar and a Cancel button. Closing asks about unsaved changes (refused values on screen included), stops the jobs
and closes the viewer.
"""

from __future__ import annotations

from typing import Any

from qtpy.QtCore import QSettings, Qt
from qtpy.QtGui import QCloseEvent
from qtpy.QtWidgets import QDockWidget, QMainWindow, QTabWidget, QVBoxLayout, QWidget

from lfm_studio.ui import pipeline
from lfm_studio.ui.controllers import MLAEditorBinding, StudioController, ViewerBinding
from lfm_studio.ui.failure_notices import JobFailureNotices
from lfm_studio.ui.file_menu import FileActions
from lfm_studio.ui.optimise_dock import OptimiseDock
from lfm_studio.ui.parameter_fields import ErrorLabel
from lfm_studio.ui.parameter_panel import ParameterPanel
from lfm_studio.ui.plots import ConvergencePlot, ProfilePlots, RequirementsView
from lfm_studio.ui.stale_marks import StaleMarks
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.status_bar import JobStatusBar
from lfm_studio.ui.train_dock import TrainDock
from lfm_studio.ui.widget_factories import unavailable
from lfm_studio.ui.workflow_panel import WorkflowPanel

APP_TITLE = "lfm_studio"
DEFAULT_SIZE = (1600, 1000)
PARAMETERS_WIDTH, PLOTS_WIDTH = 380, 440  # pixels, at the default size
BOTTOM_HEIGHT, PARAMETERS_HEIGHT, REQUIREMENTS_HEIGHT = 430, 620, 330


class MainWindow(QMainWindow):
    """The studio window for ``state``, driven by ``controller``.

    Parameters
    ----------
    state, controller : the application state and its controller.
    editor : an MLA editor (the ``MLAEditor`` contract) or None (a message is shown).
    viewer : a PSF viewer (the ``PSFViewer`` contract) or None.
    settings : where recent files are kept (default: the studio's QSettings).
    """

    def __init__(
        self,
        state: StudioState,
        controller: StudioController,
        *,
        editor: QWidget | None = None,
        viewer: QWidget | None = None,
        settings: QSettings | None = None,
    ) -> None:
        super().__init__()
        self.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        self.resize(*DEFAULT_SIZE)  # before the docks: the first layout pass uses the final size
        self.state, self.controller = state, controller
        self.editor, self.viewer = editor, viewer
        self._bindings: list[Any] = []

        self.setCentralWidget(viewer if viewer is not None else unavailable("PSF viewer"))
        if viewer is not None:
            self._bindings.append(ViewerBinding(state, viewer, self))

        Area = Qt.DockWidgetArea
        # Parameters take the whole left edge; the bottom row (MLA editor) spans viewer and plots.
        # (One tabified dock group only: Qt 6.12 leaves a stray tab bar behind a second one.)
        self.setCorner(Qt.Corner.TopLeftCorner, Area.LeftDockWidgetArea)
        self.setCorner(Qt.Corner.BottomLeftCorner, Area.LeftDockWidgetArea)
        self.setCorner(Qt.Corner.TopRightCorner, Area.RightDockWidgetArea)
        self.setCorner(Qt.Corner.BottomRightCorner, Area.BottomDockWidgetArea)
        self.parameter_panel = ParameterPanel(state)
        params = self._dock("Design parameters", self.parameter_panel, Area.LeftDockWidgetArea)

        self.requirements = RequirementsView(state)
        requirements = self._dock(
            "Design metrics vs larval zebrafish", self.requirements, Area.LeftDockWidgetArea
        )
        self.profiles, self.convergence = ProfilePlots(state), ConvergencePlot(state)
        self.plot_tabs = QTabWidget()
        self.plot_tabs.addTab(self.profiles, "PSF profiles")
        self.plot_tabs.addTab(self.convergence, "RL convergence")
        plots = self._dock("Plots", self.plot_tabs, Area.RightDockWidgetArea)
        self.stale_marks = StaleMarks(  # out-of-date results are marked as such in the views
            state, viewer=viewer, profiles=self.profiles, convergence=self.convergence,
            requirements=self.requirements, parent=self,
        )  # fmt: skip

        mla = QWidget()
        column = QVBoxLayout(mla)
        column.setContentsMargins(0, 0, 0, 0)
        column.addWidget(editor if editor is not None else unavailable("MLA layout editor"), 1)
        self.mla_error = ErrorLabel(mla)
        column.addWidget(self.mla_error)
        mla_dock = self._dock("MLA layout", mla, Area.BottomDockWidgetArea)
        if editor is not None:
            self._bindings.append(MLAEditorBinding(state, editor, self))
        self.workflow_panel = WorkflowPanel(
            state, reconstruction_available=pipeline.reconstruction_available()
        )
        self.workflow_panel.simulate_requested.connect(controller.request_image)
        self.workflow_panel.reconstruct_requested.connect(controller.request_reconstruction)
        workflow = self._dock("Simulate and reconstruct", self.workflow_panel, Area.BottomDockWidgetArea)
        self.tabifyDockWidget(mla_dock, workflow)
        self.optimise = OptimiseDock(state, controller.runner)  # free parameters, run a study, compare
        self.tabifyDockWidget(workflow, self._dock("Optimise", self.optimise, Area.BottomDockWidgetArea))
        self.train_dock = TrainDock(state, controller.runner, viewer)  # learned model from the design
        self.stale_marks.add_layer_marks(self.train_dock.layer_marks, self.train_dock.layer_marks_changed)
        self.tabifyDockWidget(workflow, self._dock("Train", self.train_dock, Area.BottomDockWidgetArea))
        mla_dock.raise_()

        self.resizeDocks([params, plots], [PARAMETERS_WIDTH, PLOTS_WIDTH], Qt.Orientation.Horizontal)
        vertical = Qt.Orientation.Vertical
        self.resizeDocks([params, requirements], [PARAMETERS_HEIGHT, REQUIREMENTS_HEIGHT], vertical)
        self.resizeDocks([mla_dock], [BOTTOM_HEIGHT], vertical)

        self.file_actions = FileActions(state, self, controller.runner, settings=settings)
        self.file_actions.populate(self.menuBar().addMenu("&File"))
        view = self.menuBar().addMenu("&View")
        for dock in self.findChildren(QDockWidget):
            view.addAction(dock.toggleViewAction())

        self.job_status = JobStatusBar(state)
        self.failure_notices = JobFailureNotices(state, self)  # a failed job gets a dialog, not only the bar
        self.job_status.cancel_requested.connect(controller.cancel)
        self.statusBar().addPermanentWidget(self.job_status, 1)

        state.errors_changed.connect(self._on_errors)
        state.dirty_changed.connect(self._update_title)
        state.unsaved_model_changed.connect(self._update_title)  # a trained model not saved is unsaved input
        state.file_path_changed.connect(self._update_title)
        state.design_changed.connect(self._update_title)
        self._update_title()

    def _dock(self, title: str, widget: QWidget, area: Qt.DockWidgetArea) -> QDockWidget:
        dock = QDockWidget(title, self)
        dock.setObjectName(title)
        dock.setWidget(widget)
        dock.setFeatures(
            QDockWidget.DockWidgetFeature.DockWidgetMovable
            | QDockWidget.DockWidgetFeature.DockWidgetFloatable
        )
        self.addDockWidget(area, dock)
        return dock

    def _on_errors(self, errors: dict[str, str]) -> None:
        self.mla_error.show_error(errors.get(MLAEditorBinding.ERROR_KEY))
        self._update_title()  # refused values on screen are unsaved input

    def _update_title(self, *_: Any) -> None:
        state = self.state
        where = state.file_path.name if state.file_path is not None else "not saved"
        # "[*]": where Qt draws the modified mark ("*" while dirty); without it Qt warns on stderr.
        self.setWindowTitle(f"{state.design.name} ({where})[*] — {APP_TITLE}")
        self.setWindowModified(state.unsaved_input)

    def closeEvent(self, event: QCloseEvent) -> None:
        if not self.file_actions.confirm_discard():
            event.ignore()
            return
        self.controller.shutdown()
        state = self.state
        for signal, slot in (
            (state.errors_changed, self._on_errors),
            (state.dirty_changed, self._update_title),
            (state.unsaved_model_changed, self._update_title),
            (state.file_path_changed, self._update_title),
            (state.design_changed, self._update_title),
        ):
            signal.disconnect(slot)
        for part in (*self._bindings, self.parameter_panel, self.workflow_panel, self.train_dock, self.requirements,
                     self.profiles, self.convergence, self.stale_marks, self.file_actions, self.job_status,
                     self.failure_notices, self.optimise):  # fmt: skip
            part.disconnect_state()
        close_viewer = getattr(self.viewer, "close_viewer", None)
        if close_viewer is not None:
            close_viewer()
        event.accept()
        super().closeEvent(event)
