"""Architecture guards: the engine is headless, the CLI starts, resources resolve."""

from __future__ import annotations

import subprocess
import sys

GUI_MODULES = ("PySide6", "PyQt5", "PyQt6", "qtpy", "napari", "pyqtgraph", "superqt", "vispy", "matplotlib")

_PROBE = """
import importlib, pkgutil, sys
import lfm_studio.engine as engine
for info in pkgutil.walk_packages(engine.__path__, "lfm_studio.engine."):
    importlib.import_module(info.name)
gui = sorted({name.split(".")[0] for name in sys.modules} & set(sys.argv[1:]))
print(",".join(gui))
"""


def test_importing_every_engine_module_loads_no_gui_package():
    result = subprocess.run(
        [sys.executable, "-c", _PROBE, *GUI_MODULES], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "", f"engine imported GUI packages: {result.stdout.strip()}"


def test_cli_help_runs_in_a_fresh_interpreter():
    for command in ([sys.executable, "-m", "lfm_studio", "--help"],):
        result = subprocess.run(command, capture_output=True, text=True, check=True)
        assert "usage: lfm-studio" in result.stdout


def test_cli_help_does_not_import_qt():
    probe = (
        "import sys; from lfm_studio.cli import build_parser; build_parser();"
        "print(','.join(m for m in ('PySide6','qtpy','napari') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == ""


def test_resources_resolve_through_the_accessor():
    from lfm_studio.resources_access import resource_path

    assert resource_path("designs").is_dir()
