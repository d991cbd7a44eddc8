"""Design files (``*.json``) open as a PSF stack layer computed in the background.

napari readers are synchronous, and a design's PSF stack takes seconds to minutes, so
reading a design inside a viewer returns napari's "read, no layer yet" sentinel at
once and starts a background task (progress in napari's activity dock); the PSF layer
is added to that viewer when the task ends (a failure is an error notification).
Without a viewer (e.g. ``npe2`` used from a script) the stack is computed before
returning. The file is claimed only when it looks like a design: a JSON object with an
integer ``schema_version``, ``kind`` "fourier" or "conventional", and ``mla``.
For depth ranges, accuracy or cancel, use the *Simulate PSF* widget.
"""

from __future__ import annotations

import json
import weakref
from pathlib import Path
from typing import Any

from napari.layers import Layer
from napari.utils import progress as napari_progress
from qtpy.QtCore import QObject

from lfm_studio.engine.design import Design, load_design
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.engine.systems.kinds import KIND_NAMES
from lfm_studio.napari_plugin.background import Outcome
from lfm_studio.napari_plugin.layer_data import LayerData, psf_layer_data
from lfm_studio.napari_plugin.notify import design_warnings_collected, report_error, report_info
from lfm_studio.napari_plugin.psf_task import psf_task

MAX_DESIGN_BYTES = 16 * 2**20  # larger JSON files are not designs (a design is a few kB)
DESIGN_KINDS = KIND_NAMES  # the design-file words of the system kinds
NOTHING: list[Any] = [(None,)]  # napari's "read, but no layer" sentinel

_RUNNING: set[DesignPSFJob] = set()  # keeps running jobs alive until they end


def is_design_file(path: Path) -> bool:
    """Whether ``path`` is a JSON file holding an lfm_studio design (by its keys, not its name alone)."""
    if path.suffix.lower() != ".json":
        return False
    try:
        if path.stat().st_size > MAX_DESIGN_BYTES:
            return False
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return (
        isinstance(data, dict)
        and isinstance(data.get("schema_version"), int)
        and data.get("kind") in DESIGN_KINDS
        and "mla" in data
    )


def layer_name(path: Path) -> str:
    return f"{path.stem} PSF"


class DesignPSFJob(QObject):
    """Computes a design's PSF stack in the background and adds it to ``viewer`` when done."""

    def __init__(self, design: Design, name: str, viewer: Any, *, source: str | None = None) -> None:
        super().__init__()
        self.name, self.source = name, source
        self._viewer = weakref.ref(viewer)
        self.task = psf_task(design, parent=self)
        self.task.progressed.connect(self._on_progress)
        self.task.ended.connect(self._on_ended)
        self._bar: Any = None

    def start(self) -> None:
        _RUNNING.add(self)
        self._bar = napari_progress(total=0, desc=f"lfm-studio: {self.name}")
        self.task.start()

    def _on_progress(self, done: int, total: int, message: str) -> None:
        bar = self._bar
        if bar is None:
            return
        if bar.total != total:
            bar.total = total
        # Updating napari's progress can process Qt events, and with them a queued ``ended``
        # that closes the bar (seen on a loaded machine): describe it only if it is still open.
        bar.update(done - bar.n)
        if self._bar is bar:
            bar.set_description(f"lfm-studio: {self.name}: {message}")

    def _on_ended(self, outcome: Outcome) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        _RUNNING.discard(self)
        viewer = self._viewer()
        if outcome.state == "failed":
            report_error(f"lfm-studio could not compute the PSF of {self.name}: {outcome.message}")
        elif outcome.state == "done" and viewer is not None:
            viewer.add_layer(Layer.create(*psf_layer_data(outcome.value, name=self.name, source=self.source)))
            report_info(f"{self.name}: PSF stack computed in {outcome.seconds:.1f} s.")


def running_jobs() -> tuple[DesignPSFJob, ...]:
    """Design PSF jobs still running (tests wait for them)."""
    return tuple(_RUNNING)


def read_design(path: Any) -> list[LayerData]:
    """napari reader function for a design file (see the module docstring)."""
    import napari

    source = Path(path[0] if isinstance(path, (list, tuple)) else path)
    try:
        with design_warnings_collected():
            design = load_design(source)
    except (ValueError, OSError) as error:
        report_error(f"lfm-studio could not open the design {source.name}: {error}")
        return NOTHING
    viewer = napari.current_viewer()
    if viewer is None:
        return [psf_layer_data(simulate_psf(design), name=layer_name(source), source=str(source))]
    depths = design.depths.count
    report_info(f"Computing the PSF stack of {design.name!r} ({depths} depths) in the background.")
    DesignPSFJob(design, layer_name(source), viewer, source=str(source)).start()
    return NOTHING
