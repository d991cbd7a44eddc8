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


# ----- system kinds: the design-file word is read in one place -----

KIND_WORDS = frozenset({"fourier", "conventional"})
KIND_WORD_ALLOWED = (
    "engine/design/",  # the design-file parser and its checks
    "engine/calibration/record.py",  # the calibration file stores the word (parsed there)
    "engine/systems/kinds",  # the kind objects and kind_of / kind_named
    "engine/systems/from_design.py",  # the design -> engine-system builders refuse the other kind's design
    "engine/io/metadata.py",  # the PSF file layout of a conventional pattern stack
)


def _is_kind_word(node) -> bool:
    import ast

    return isinstance(node, ast.Constant) and node.value in KIND_WORDS


def _kind_decisions(tree) -> list[int]:
    """Lines comparing with a kind word (``== "fourier"``, ``in ("fourier", ...)``), comparing two ``.kind``
    attributes (``design.kind != calibration.kind``), or keying a dict by a kind word."""
    import ast

    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            containers = [o.elts for o in operands if isinstance(o, ast.Tuple | ast.List | ast.Set)]
            if (
                any(_is_kind_word(o) for o in operands)
                or any(_is_kind_word(e) for elts in containers for e in elts)
                or sum(isinstance(o, ast.Attribute) and o.attr == "kind" for o in operands) >= 2
            ):
                lines.append(node.lineno)
        elif isinstance(node, ast.Dict) and any(_is_kind_word(key) for key in node.keys):
            lines.append(node.lineno)
    return lines


def test_the_system_kind_word_decides_nothing_outside_the_kind_objects():
    # Callers ask kind_of(design) / stack_kind(stack) for the kind object and use its capability flags.
    import ast
    from pathlib import Path

    import lfm_studio

    root = Path(lfm_studio.__file__).parent
    found = []
    for path in sorted(root.rglob("*.py")):
        relative = path.relative_to(root).as_posix()
        if relative.startswith(KIND_WORD_ALLOWED):
            continue
        found += [
            f"{relative}:{line}" for line in _kind_decisions(ast.parse(path.read_text(encoding="utf-8")))
        ]
    assert found == [], (
        "system-kind decisions by the design-file word; use kind_of(design) / stack_kind(stack) and the "
        f"kind's flags (lfm_studio/engine/systems/kinds.py) instead: {found}"
    )


def test_the_kind_guard_sees_the_decisions_it_is_meant_to_catch():
    import ast

    samples = {
        'if design.kind == "fourier": pass': 1,
        'ok = "conventional" != kind': 1,
        'ok = word in ("fourier", "conventional")': 1,
        "ok = calibration.kind == design.kind": 1,
        'ok = array.dtype.kind in "fiu"': 0,
        'table = {"fourier": 1}': 1,
        'ok = method == "midpoint"': 0,
        "ok = kind_of(design) is FOURIER": 0,
        'label = f"{design.kind} LFM"': 0,
    }
    for source, count in samples.items():
        assert len(_kind_decisions(ast.parse(source))) == count, source
