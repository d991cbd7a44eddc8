"""Start the desktop studio: ``lfm-studio`` / ``lfm-studio gui [design]`` / ``./scripts/studio.sh``.

Opens the main window on the bundled XLFM-like preset (or the given design file or
preset) and starts the PSF stack in the background: a quick preview (a few depths,
binned sensor, preview accuracy) first, then the full stack.
"""

from __future__ import annotations

import os
from pathlib import Path

from lfm_studio.engine.threads import available_cores

DEFAULT_PRESET = "xlfm_cong2017"


def _environment() -> None:
    os.environ.setdefault("QT_API", "pyside6")
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")


def build_studio(
    design=None,
    *,
    file_path: str | Path | None = None,
    settings=None,
    editor_factory=None,
    viewer_factory=None,
    preview: bool = True,
    debounce_ms: int | None = None,
):
    """State, controller and main window on ``design`` (default: the bundled preset); returns the window.

    ``editor_factory(design)`` / ``viewer_factory()`` build the MLA editor and the viewer
    (default: the real widgets from :mod:`lfm_studio.widgets`, when present); tests pass
    stand-ins. The window's ``state`` and ``controller`` attributes give access to the rest.
    """
    _environment()
    from lfm_studio.engine.design import load_preset
    from lfm_studio.ui import widget_factories
    from lfm_studio.ui.controllers import DEBOUNCE_MS, StudioController
    from lfm_studio.ui.edits import design_warnings, with_design_warnings
    from lfm_studio.ui.main_window import MainWindow
    from lfm_studio.ui.state import StudioState

    if design is None:
        design, warnings = with_design_warnings(load_preset, DEFAULT_PRESET)
    else:
        warnings = design_warnings(design)
    state = StudioState(design, file_path=file_path)
    state.set_warnings(warnings)
    controller = StudioController(
        state, debounce_ms=DEBOUNCE_MS if debounce_ms is None else debounce_ms, preview=preview
    )
    editor = (editor_factory or widget_factories.make_mla_editor)(design)
    viewer = (viewer_factory or widget_factories.make_psf_viewer)()
    window = MainWindow(state, controller, editor=editor, viewer=viewer, settings=settings)
    controller.setParent(window)
    if file_path is not None:
        state.add_recent_file(Path(file_path).resolve())
    return window


def _open(name_or_path: str | None):
    """The design to open and the file it came from (None for a preset)."""
    from lfm_studio.engine.design import list_presets, resolve_design
    from lfm_studio.ui.edits import with_design_warnings

    name = name_or_path or DEFAULT_PRESET
    design, _ = with_design_warnings(resolve_design, name)
    is_file = name not in list_presets() and Path(name).expanduser().is_file()
    return design, (Path(name).expanduser().resolve() if is_file else None)


def _leave_a_core_for_the_gui() -> None:
    """Background PSF jobs use the thread policy's count (``lfm-studio --threads``) less one core, so the window stays responsive (on the
    2-core machines this was measured on, 2 torch threads plus the GUI stalled it for seconds)."""
    import torch

    cores = available_cores()  # the process's CPU affinity, as the engine's thread policy counts
    torch.set_num_threads(max(1, min(torch.get_num_threads(), cores - 1)))


def launch_studio(design: str | None = None):
    """Everything ``lfm-studio gui`` does before the event loop; returns the shown main window.

    Opens ``design`` (a file or preset; default: the bundled XLFM-like preset), builds the
    window with the real widgets, shows it and starts the PSF stack (preview first). A design
    that cannot be read raises before any window opens (the command line prints the reason).
    """
    _environment()
    loaded, path = _open(design)  # errors surface before Qt starts
    _leave_a_core_for_the_gui()
    from lfm_studio.ui.widget_factories import prepare_qt_app, warm_up_viewer

    prepare_qt_app()
    window = build_studio(loaded, file_path=path)
    warm_up_viewer(window.viewer)
    window.show()
    window.controller.start()
    return window


def _event_loop(app, window) -> int:
    """Run Qt's event loop until the last window closes (``window`` is kept alive meanwhile)."""
    return int(app.exec())


def run_studio(design: str | None = None) -> int:
    """Open the studio window on ``design`` (see :func:`launch_studio`) and run the event loop.

    Returns the Qt event loop's exit status.
    """
    window = launch_studio(design)
    from qtpy.QtWidgets import QApplication

    return _event_loop(QApplication.instance(), window)
