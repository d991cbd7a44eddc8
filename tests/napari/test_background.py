"""The plugin's BackgroundTask is one job of the shared JobRunner: outcomes, progress, cancel; one mechanism."""

from __future__ import annotations

import ast
import threading
from pathlib import Path

import pytest

import lfm_studio
from lfm_studio.engine.progress import checkpoint
from lfm_studio.napari_plugin.background import BackgroundTask

TIMEOUT_MS = 60_000  # only a hang reaches it


def _ended(qtbot, task: BackgroundTask):
    with qtbot.waitSignal(task.ended, timeout=TIMEOUT_MS) as blocker:
        task.start()
    return blocker.args[0]


def test_a_task_reports_progress_and_its_value(qtbot):
    def count(progress, cancel):
        for i in range(3):
            checkpoint(cancel, progress, i + 1, 3, f"step {i + 1}/3")
        return "value"

    task = BackgroundTask(count)
    reports = []
    task.progressed.connect(lambda *args: reports.append(args))
    outcome = _ended(qtbot, task)
    assert (outcome.state, outcome.value, outcome.message) == ("done", "value", "")
    qtbot.waitUntil(lambda: len(reports) == 3, timeout=TIMEOUT_MS)  # queued: may trail the end
    assert reports == [(1, 3, "step 1/3"), (2, 3, "step 2/3"), (3, 3, "step 3/3")]
    assert task.outcome is outcome and not task.running
    with pytest.raises(RuntimeError, match="runs once"):
        task.start()


@pytest.mark.parametrize(
    ("error", "message"),
    [
        (
            ValueError("pixel size must be > 0 um; got -1. Fix: 6.5"),
            "pixel size must be > 0 um; got -1. Fix: 6.5",
        ),
        (KeyError("PSF"), "KeyError: 'PSF'"),
    ],
)
def test_a_failed_task_names_the_error_and_carries_no_value(qtbot, error, message):
    def fail(progress, cancel):
        raise error

    outcome = _ended(qtbot, BackgroundTask(fail))
    assert (outcome.state, outcome.value, outcome.message) == ("failed", None, message)
    assert "Traceback" in outcome.details


def test_cancel_stops_a_running_task_without_a_value(qtbot):
    started = threading.Event()

    def wait(progress, cancel):
        started.set()
        while True:  # an engine loop: stops at its next checkpoint
            checkpoint(cancel, progress, 0, 1, "waiting")
            cancel.wait(0.01)

    task = BackgroundTask(wait)
    with qtbot.waitSignal(task.ended, timeout=TIMEOUT_MS) as blocker:
        task.start()
        assert started.wait(60)
        task.cancel()
    assert blocker.args[0].state == "cancelled" and blocker.args[0].value is None and task.cancel_requested


def test_a_task_cancelled_before_it_starts_never_runs(qtbot):
    ran = []
    task = BackgroundTask(lambda progress, cancel: ran.append(1) or "value")
    task.cancel()
    assert _ended(qtbot, task).state == "cancelled" and ran == []


def test_a_task_that_finishes_after_cancel_counts_as_cancelled(qtbot):
    gate, entered = threading.Event(), threading.Event()

    def ignores_cancel(progress, cancel):  # one long step without checkpoints
        entered.set()
        gate.wait(60)
        return "late"

    task = BackgroundTask(ignores_cancel)
    with qtbot.waitSignal(task.ended, timeout=TIMEOUT_MS) as blocker:
        task.start()
        assert entered.wait(60)
        task.cancel()
        gate.set()
    assert blocker.args[0].state == "cancelled" and blocker.args[0].value is None


THREAD_STARTERS = {"create_worker", "thread_worker", "QRunnable", "Thread", "QThread"}


def _names_used(path: Path) -> set[str]:
    """Names and attributes the code of ``path`` uses or imports (docstrings and comments do not count)."""
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
        elif isinstance(node, ast.alias):
            names.add(node.name.split(".")[-1])
    return names


def test_one_worker_mechanism_serves_both_front_ends():
    """Only lfm_studio/widgets/jobs.py starts worker threads (the studio and the plugin both go through it);
    the PSF viewer only asks which thread it is on (QThread.currentThread)."""
    root = Path(lfm_studio.__file__).parent
    starting = {
        str(path.relative_to(root)): sorted(_names_used(path) & THREAD_STARTERS)
        for path in root.rglob("*.py")
    }
    starting = {path: names for path, names in starting.items() if names}
    assert starting == {"widgets/jobs.py": ["create_worker"], "widgets/psf_viewer.py": ["QThread"]}, starting
