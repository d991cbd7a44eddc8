"""Placeholder main window shown until the studio (issue "Studio app") lands."""

from __future__ import annotations

from qtpy.QtCore import Qt
from qtpy.QtWidgets import QLabel, QMainWindow

from lfm_studio import __version__

_TEXT = """<h2>lfm_studio {version}</h2>
<p>The wave-optics engine is in place: fields, angular-spectrum and Fresnel
propagation, Fourier and thin lenses, microlens arrays, phase masks, the Debye
objective and the camera model (<code>import lfm_studio.engine</code>).</p>
<p>Coming next: designs and presets, Fourier-LFM and conventional-LFM PSF stacks,
reconstruction, and this studio (parameter panel, MLA layout editor, napari viewer).</p>
<p>Design requested: <b>{design}</b></p>"""


class PlaceholderWindow(QMainWindow):
    """A window that states what the engine does today and what comes next."""

    def __init__(self, design: str | None = None) -> None:
        super().__init__()
        self.setWindowTitle("lfm_studio")
        label = QLabel(_TEXT.format(version=__version__, design=design or "bundled default"))
        label.setWordWrap(True)
        label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        label.setMargin(24)
        self.setCentralWidget(label)
        self.resize(640, 360)
