"""The manifest: discovered under the distribution name, every command imports, every contribution is declared."""

from __future__ import annotations

import importlib

from npe2 import PluginManager, PluginManifest

from tests.napari.conftest import PLUGIN

WIDGETS = {"Simulate PSF", "Reconstruct light field", "MLA editor", "Calibrate", "Reconstruct video"}


def test_manifest_validates_with_imports():
    """What ``npe2 validate --imports lfm-studio`` checks, in-process: the installed manifest imports."""
    manifest = PluginManifest.from_distribution(PLUGIN)
    assert manifest.name == PLUGIN
    manifest.validate_imports()  # raises on a python_name that does not import


def test_every_command_resolves_to_a_callable():
    manifest = PluginManifest.from_distribution(PLUGIN)
    commands = manifest.contributions.commands
    assert len(commands) == 9
    for command in commands:
        module, _, attribute = command.python_name.partition(":")
        assert callable(getattr(importlib.import_module(module), attribute)), command.python_name


def test_plugin_is_discovered_with_all_contributions():
    pm = PluginManager.instance()
    pm.discover()
    manifest = pm.get_manifest(PLUGIN)
    contributions = manifest.contributions
    assert {w.display_name for w in contributions.widgets} == WIDGETS
    assert [s.key for s in contributions.sample_data] == ["beads"]
    reader, zarr_reader = contributions.readers
    assert set(reader.filename_patterns) == {"*.tif", "*.tiff", "*.json"}
    assert list(zarr_reader.filename_patterns) == ["*.zarr"] and zarr_reader.accepts_directories
    (writer,) = contributions.writers
    assert list(writer.layer_types) == ["image"]
    assert set(writer.filename_extensions) == {".tif", ".tiff"}


def test_importing_the_plugin_package_imports_no_qt_binding_itself():
    """The package's modules import Qt only through qtpy (no binding named in the source)."""
    import pathlib

    import lfm_studio.napari_plugin as plugin

    for path in pathlib.Path(plugin.__file__).parent.glob("*.py"):
        text = path.read_text(encoding="utf-8")
        for binding in ("PySide6", "PyQt5", "PyQt6", "PySide2"):
            assert f"import {binding}" not in text and f"from {binding}" not in text, (path.name, binding)
