"""The installed Qt binding keeps its references: PySide6 6.12.0 on Python < 3.12 does not.

That release drops a reference to ``None`` on every void Qt call and to ``True`` on
every signal emit; after a few thousand calls the interpreter aborts with
``none_dealloc`` (seen opening the MLA editor on an 11,236-lenslet design).
pyproject excludes it; this guards the environment the tests run in. Each probe runs
in a subprocess, so a bad binding fails the test instead of killing the test run.
"""

from __future__ import annotations

import os
import subprocess
import sys

_PROBE = """
import sys
from qtpy.QtCore import QObject, QRect, Signal
from qtpy.QtWidgets import QApplication
app = QApplication.instance() or QApplication([])
rect = QRect(0, 0, 1, 1)
before = sys.getrefcount(None)
for _ in range(500):
    rect.setWidth(2)
none_lost = before - sys.getrefcount(None)
class Emitter(QObject):
    fired = Signal(int)
emitter = Emitter()
emitter.fired.connect(lambda value: None)
before = sys.getrefcount(True)
for _ in range(500):
    emitter.fired.emit(1)
print(none_lost, before - sys.getrefcount(True))
"""


def test_void_calls_and_emits_keep_references_to_none_and_true():
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "QT_API": "pyside6"}
    result = subprocess.run(
        [sys.executable, "-c", _PROBE], capture_output=True, text=True, env=env, timeout=120
    )
    assert result.returncode == 0, result.stderr[-2000:]
    none_lost, true_lost = (int(v) for v in result.stdout.split()[-2:])
    # A correct binding loses nothing; the broken one loses exactly one per call (500).
    assert abs(none_lost) < 50 and abs(true_lost) < 50, (none_lost, true_lost)
