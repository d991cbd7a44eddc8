"""Shared test settings: our own warnings are errors unless a test expects them (pyproject).

``qapp`` (session)
    Overrides pytest-qt's fixture (``qtbot`` uses it) for every test directory: the
    application comes from :func:`lfm_studio.widgets.viewer.napari_embed.prepare_qt_app`, so OpenGL
    context sharing is on before the QApplication exists, as in the studio. Whichever test
    first needs Qt (a UI test, a napari plugin test, the bench's PNG plot) creates the one
    application all later tests share, so it must be this one.
"""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def qapp(qapp_args, pytestconfig):
    from lfm_studio.widgets.viewer import napari_embed  # imports Qt: only when a test asks for it

    return napari_embed.prepare_qt_app(qapp_args, name=pytestconfig.getini("qt_qapp_name"))
