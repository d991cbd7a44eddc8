"""A design's PSF stack as a :class:`BackgroundTask` (used by the reader, the Simulate PSF widget and the MLA dock)."""

from __future__ import annotations

import threading
from collections.abc import Callable

from qtpy.QtCore import QObject

from lfm_studio.engine.design import Design
from lfm_studio.engine.progress import ProgressCallback
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.napari_plugin.background import BackgroundTask, Outcome
from lfm_studio.napari_plugin.task_controls import TaskControls


def psf_task(
    design: Design, *, depths: tuple[float, ...] | None = None, parent: QObject | None = None
) -> BackgroundTask:
    """A (not yet started) task computing ``design``'s PSF stack at ``depths`` metres (default: the design's).

    Cancel stops between depths / lenslets; the result is a CPU :class:`PSFStack` with the design attached.
    """

    def compute(progress: ProgressCallback, cancel: threading.Event) -> PSFStack:
        stack = simulate_psf(design, depths=depths, progress=progress, cancel=cancel)
        return stack.with_data(stack.data.detach().cpu())

    return BackgroundTask(compute, parent)


def start_psf_task(
    design: Design,
    *,
    parent: QObject,
    controls: TaskControls,
    on_ended: Callable[[Outcome], None],
    message: str,
) -> BackgroundTask:
    """Start :func:`psf_task` for ``design``, followed by ``controls`` (progress, cancel) and ``on_ended``."""
    task = psf_task(design, parent=parent)
    task.ended.connect(on_ended)
    controls.attach(task, message)
    task.start()
    return task
