"""The worker mechanism: results, progress, cancel (previous result kept), superseded results dropped."""

from __future__ import annotations

import sys
import threading

import pytest
from qtpy.QtCore import QThreadPool

from lfm_studio.engine.progress import checkpoint
from lfm_studio.widgets.jobs import JobRunner

TIMEOUT_MS = 60_000  # generous: only a hang should reach it (CI may share its cores)


@pytest.fixture
def runner(qtbot):
    runner = JobRunner()
    yield runner
    assert runner.shutdown(5000)


def _counting(ctx, steps, gate=None):
    """An engine-like loop: progress + cancel checkpoints; optionally blocks on ``gate`` first."""
    if gate is not None:
        gate.wait(60)
    for i in range(steps):
        checkpoint(ctx.cancel, ctx.progress, i, steps, f"step {i + 1}/{steps}")
    checkpoint(ctx.cancel, ctx.progress, steps, steps, "done")
    return f"result of {steps}"


def _blocking(ctx, started, release):
    started.set()
    while not release.is_set():  # waits for the test, stopping at cancel like an engine loop
        checkpoint(ctx.cancel, None, 0, 1, "waiting")
        release.wait(0.01)
    return "late"


def _ignores_cancel(ctx, gate, value, entered=None):
    """A job that misses its cancel checkpoints (e.g. one long FFT), released by ``gate``."""
    if entered is not None:
        entered.set()
    gate.wait(60)
    return value


def _fails(ctx):
    raise ValueError("bad input: x must be > 0 m; got -1 m")


def test_a_job_delivers_its_result_and_progress(qtbot, runner):
    results, statuses = [], []
    runner.status_changed.connect(statuses.append)
    runner.submit("psf", _counting, 3, on_result=results.append)
    qtbot.waitUntil(lambda: bool(results), timeout=TIMEOUT_MS)
    assert results == ["result of 3"]
    assert statuses[0].state == "running" and statuses[-1].state == "done"
    assert any(s.total == 3 and s.message.startswith("step") for s in statuses)
    assert not runner.is_running("psf")


def test_cancel_stops_the_job_and_the_previous_result_stays(qtbot, runner):
    results = ["previous"]
    started, release = threading.Event(), threading.Event()
    statuses = []
    runner.status_changed.connect(statuses.append)
    runner.submit("psf", _blocking, started, release, on_result=results.append)
    assert started.wait(60)
    runner.cancel("psf")
    qtbot.waitUntil(lambda: statuses[-1].state == "cancelled", timeout=TIMEOUT_MS)
    release.set()
    assert results == ["previous"]
    assert [s.state for s in statuses if s.state != "running"] == ["cancelling", "cancelled"]


def test_a_superseded_result_is_dropped_even_when_it_arrives_last(qtbot, runner):
    results, dropped = [], []
    runner.result_dropped.connect(lambda name, generation: dropped.append((name, generation)))
    gate, entered = threading.Event(), threading.Event()
    first = runner.submit("psf", _ignores_cancel, gate, "old parameters", entered, on_result=results.append)
    assert entered.wait(60)  # running (a job superseded before it starts is skipped altogether)
    second = runner.submit("psf", _counting, 2, on_result=results.append)
    assert (first, second) == (1, 2)
    qtbot.waitUntil(lambda: bool(results), timeout=TIMEOUT_MS)
    gate.set()  # the old job finishes after the new one
    qtbot.waitUntil(lambda: bool(dropped), timeout=TIMEOUT_MS)
    assert results == ["result of 2"]
    assert dropped == [("psf", 1)] and runner.dropped == 1


def test_a_superseded_result_is_dropped_when_it_arrives_first(qtbot, runner):
    results = []
    gate_old, gate_new, entered = threading.Event(), threading.Event(), threading.Event()
    runner.submit("psf", _ignores_cancel, gate_old, "old parameters", entered, on_result=results.append)
    assert entered.wait(60)
    runner.submit("psf", _ignores_cancel, gate_new, "new parameters", on_result=results.append)
    gate_old.set()
    qtbot.waitUntil(lambda: runner.dropped == 1, timeout=TIMEOUT_MS)
    gate_new.set()
    qtbot.waitUntil(lambda: bool(results), timeout=TIMEOUT_MS)
    assert results == ["new parameters"]


def test_a_failed_job_reports_and_keeps_the_previous_result(qtbot, runner):
    results, errors, statuses = ["previous"], [], []
    runner.status_changed.connect(statuses.append)
    runner.submit("image", _fails, on_result=results.append, on_error=errors.append)
    qtbot.waitUntil(lambda: bool(errors), timeout=TIMEOUT_MS)
    assert results == ["previous"]
    assert isinstance(errors[0].error, ValueError) and "Traceback" in errors[0].details
    assert statuses[-1].state == "failed" and "x must be > 0 m" in statuses[-1].message


def _refuses_in_um(ctx):
    raise ValueError("the window (5 um) must hold the number of pixels (maximum 3 um); see /data/um/a.tif")


def test_a_failure_line_writes_micrometres_as_the_studio_does(qtbot, runner):
    """Engine refusals (shared with the CLI) say "um"; the studio's own text says "µm"."""
    errors, statuses = [], []
    runner.status_changed.connect(statuses.append)
    runner.submit("image", _refuses_in_um, on_error=errors.append)
    qtbot.waitUntil(lambda: bool(errors), timeout=TIMEOUT_MS)
    assert statuses[-1].message == (
        "failed: the window (5 µm) must hold the number of pixels (maximum 3 µm); see /data/um/a.tif"
    )


def test_a_result_the_gui_cannot_take_fails_the_job_instead_of_saying_done(qtbot, runner, monkeypatch):
    # The KeyError 'PSF' case: the job succeeded but showing its result raised (inside a
    # psygnal emission, which wraps it). The stage must read "failed" with the cause, not "done".
    from psygnal import Signal

    class Emitter:
        changed = Signal(object)

    emitter = Emitter()

    def broken_view(value):
        raise KeyError("PSF")

    emitter.changed.connect(broken_view)
    hooked, errors, statuses = [], [], []
    monkeypatch.setattr(sys, "excepthook", lambda t, value, tb: hooked.append(value))
    runner.status_changed.connect(statuses.append)
    runner.submit("psf", _counting, 1, on_result=emitter.changed.emit, on_error=errors.append)
    qtbot.waitUntil(lambda: bool(errors), timeout=TIMEOUT_MS)
    assert isinstance(errors[0].error, KeyError) and errors[0].state == "failed"
    assert statuses[-1].state == "failed" and statuses[-1].message == "failed: KeyError: 'PSF'"
    assert "done" not in [s.state for s in statuses]
    assert len(hooked) == 1  # still reported like any exception escaping a slot


def test_a_job_superseded_before_it_starts_never_runs(qtbot, runner):
    results, ran = [], []
    blockers = [threading.Event() for _ in range(QThreadPool.globalInstance().maxThreadCount())]
    for i, gate in enumerate(blockers):  # occupy every thread of the pool
        runner.submit(f"busy{i}", _ignores_cancel, gate, i)
    runner.submit("psf", lambda ctx: ran.append("old") or "old", on_result=results.append)
    runner.submit("psf", _counting, 1, on_result=results.append)
    for gate in blockers:
        gate.set()
    qtbot.waitUntil(lambda: bool(results), timeout=TIMEOUT_MS)
    qtbot.waitUntil(lambda: not runner.running_names(), timeout=TIMEOUT_MS)
    assert results == ["result of 1"] and ran == []


def test_jobs_with_different_names_run_side_by_side(qtbot, runner):
    results = {}
    gate = threading.Event()
    runner.submit("psf", _counting, 2, gate, on_result=lambda v: results.setdefault("psf", v))
    runner.submit("image", _counting, 1, on_result=lambda v: results.setdefault("image", v))
    qtbot.waitUntil(lambda: "image" in results, timeout=TIMEOUT_MS)
    assert runner.is_running("psf") and "psf" not in results  # not superseded by another name
    gate.set()
    qtbot.waitUntil(lambda: "psf" in results, timeout=TIMEOUT_MS)
