"""The conventional build on worker threads: same stack as in turn, progress and cancel on the
caller's thread, in turn whenever a gradient is recorded, named errors.

Small system of ``test_conventional.py`` (10x/0.3, 125 um lenslets, 5 x 5 lenslets, 5 px and 3
voxels per lenslet); depths over two reaches, two depths per Debye chunk, so both item lists
(NIP-field chunks, depths) have several items.
"""

from __future__ import annotations

import dataclasses
import threading

import pytest
import torch

from lfm_studio.engine.progress import CancelledError
from lfm_studio.engine.systems import conventional_psf
from lfm_studio.engine.systems.conventional_psf import (
    ConventionalAccuracy,
    conventional_projector,
    conventional_psf_stack,
)
from lfm_studio.engine.threads import torch_threads
from lfm_studio.engine.units import mm, um
from tests.engine.systems.test_conventional import SYSTEM

DEPTHS = (-60 * um, -20 * um, 0.0, 20 * um, 45 * um, 60 * um)
ACCURACY = ConventionalAccuracy(depth_chunk=2)


@pytest.fixture(autouse=True)
def _two_threads():
    with torch_threads(2):
        yield


@pytest.fixture
def worker_counts(monkeypatch) -> list[int]:
    """The worker counts the build hands to run_in_workers (one per item list)."""
    counts: list[int] = []
    run = conventional_psf.run_in_workers

    def spy(task, items, workers, **kwargs):
        counts.append(workers)
        return run(task, items, workers, **kwargs)

    monkeypatch.setattr(conventional_psf, "run_in_workers", spy)
    return counts


def test_two_workers_give_the_stack_of_one(worker_counts):
    one = conventional_psf_stack(SYSTEM, DEPTHS, accuracy=ACCURACY, workers=1)
    two = conventional_psf_stack(SYSTEM, DEPTHS, accuracy=ACCURACY, workers=2)
    default = conventional_psf_stack(SYSTEM, DEPTHS, accuracy=ACCURACY)  # torch's 2 threads
    assert worker_counts == [1, 1, 2, 2, 2, 2]
    assert len(set(one.patterns.reach)) == 2 and one.patterns == two.patterns
    scale = float(one.data.abs().max())
    for stack in (two, default):
        torch.testing.assert_close(stack.data, one.data, rtol=1e-6, atol=1e-6 * scale)
    A, _ = conventional_projector(SYSTEM, DEPTHS[:2], accuracy=ACCURACY, workers=2)
    assert A.volume_shape[0] == 2 and worker_counts[-1] == 2


def test_progress_is_monotonic_on_the_callers_thread_and_cancel_drops_the_rest(monkeypatch):
    caller = threading.current_thread()
    calls: list[tuple[int, int, bool]] = []

    def progress(done: int, total: int, message: str) -> None:
        calls.append((done, total, threading.current_thread() is caller))

    conventional_psf_stack(SYSTEM, DEPTHS, accuracy=ACCURACY, workers=2, progress=progress)
    chunks = len(conventional_psf.depth_chunks(SYSTEM, DEPTHS, 2))
    total = chunks + len(DEPTHS)
    assert [done for done, _, _ in calls] == [0, *range(1, total + 1), total]
    assert {t for _, t, _ in calls} == {total} and all(on_caller for _, _, on_caller in calls)

    started: list[float] = []
    patterns = conventional_psf.conventional_patterns
    stop, seen = threading.Event(), []

    def held_after_two(system, depths, **kw):  # depths 3 and on wait for the cancel: no race with the load
        started.append(depths[0])
        if len(started) > 2:
            stop.wait(10.0)
        return patterns(system, depths, **kw)

    monkeypatch.setattr(conventional_psf, "conventional_patterns", held_after_two)

    def stop_after_two_depths(done: int, total: int, message: str) -> None:
        seen.append(done)
        if done == chunks + 2:
            stop.set()

    with pytest.raises(CancelledError):
        conventional_psf_stack(
            SYSTEM, DEPTHS, accuracy=ACCURACY, workers=2, progress=stop_after_two_depths, cancel=stop
        )
    assert seen[-1] == chunks + 2  # nothing reported (and no stack returned) after the cancel
    assert len(started) <= 4 < len(DEPTHS)  # the two done, at most two running: the rest dropped


def _tensor(value: float) -> torch.Tensor:
    return torch.tensor(value, dtype=torch.float64, requires_grad=True)


def test_a_recorded_gradient_takes_the_serial_path_and_flows(worker_counts):
    small = dataclasses.replace(SYSTEM, lenslets=(3, 3))
    d = _tensor(SYSTEM.mla_to_camera / mm)
    stack = conventional_psf_stack(
        small, (0.0, 20 * um), dtype=torch.float64, mla_to_camera=d * mm, workers=2
    )
    stack.data.square().sum().backward()
    assert d.grad is not None and torch.isfinite(d.grad) and float(d.grad) != 0.0
    na = _tensor(0.3)
    objective = dataclasses.replace(SYSTEM.objective, numerical_aperture=na)
    tensor_na = dataclasses.replace(small, objective=objective)
    conventional_psf_stack(tensor_na, (0.0,), dtype=torch.float64, workers=2)
    assert worker_counts == [1, 1, 1, 1]
    with torch.no_grad():  # no graph recorded: the workers may run
        conventional_psf_stack(
            tensor_na, (0.0, 20 * um), dtype=torch.float64, mla_to_camera=d * mm, workers=2
        )
    assert worker_counts[-2:] == [2, 2]


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_bad_worker_counts_are_named(bad):
    with pytest.raises(ValueError, match=r"workers must be a positive integer; got .*Fix"):
        conventional_psf_stack(SYSTEM, DEPTHS, workers=bad)
