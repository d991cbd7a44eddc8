"""Fixtures for the napari plugin tests (``make_napari_viewer`` from napari's pytest plugin, under pytest-xvfb).

``qapp`` (session)
    From ``tests/conftest.py`` (:func:`lfm_studio.widgets.viewer.napari_embed.prepare_qt_app`).
``bead_layers`` (session)
    The plugin's bead sample, computed once (about 2 s); :func:`add_layers` puts copies into a viewer.
``notes``
    The napari notifications shown during the test (``.message``, ``.severity``).
"""

from __future__ import annotations

import copy

import pytest
from napari.layers import Layer

PLUGIN = "lfm-studio"


@pytest.fixture(scope="session")
def bead_layers():
    from lfm_studio.napari_plugin.sample_data import bead_sample

    return bead_sample()


def add_layers(viewer, layer_data) -> list:
    """Add independent copies of ``layer_data`` (LayerData tuples) to ``viewer``; return the layers."""
    return [
        viewer.add_layer(Layer.create(data.copy(), copy.deepcopy(meta), kind))
        for data, meta, kind in layer_data
    ]


class Notes(list):
    """Notifications captured since the fixture started."""

    def errors(self) -> list[str]:
        return [n.message for n in self if str(n.severity) == "error"]

    def infos(self) -> list[str]:
        return [n.message for n in self if str(n.severity) == "info"]

    def warnings(self) -> list[str]:
        return [n.message for n in self if str(n.severity) == "warning"]


@pytest.fixture
def notes():
    from napari.utils.notifications import notification_manager

    captured = Notes()
    notification_manager.notification_ready.connect(captured.append)
    yield captured
    notification_manager.notification_ready.disconnect(captured.append)
