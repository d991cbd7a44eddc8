"""The studio's one application state: evented (psygnal), Qt-free, main-thread only.

Panels and widgets observe it and render; controllers change it. Results from
background jobs are written here only by the controller, on the GUI thread, and only
when a job succeeded: a failed or cancelled job leaves the previous result in place.

The design in force (:attr:`StudioState.design`) is always a valid
:class:`~lfm_studio.engine.design.Design`: the last valid one. An invalid edit does
not replace it; the reason is recorded per field in :attr:`StudioState.errors`
(field path as in :func:`~lfm_studio.engine.design.evolve`, e.g.
``"objective.numerical_aperture"``) until that field is valid again.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

from psygnal import Signal

from lfm_studio.engine.design import METADATA_FIELDS, Design, spec_hash
from lfm_studio.engine.performance import DesignMetrics
from lfm_studio.ui.results import (
    STAGES,
    ImageResult,
    JobStatus,
    PSFResult,
    ReconstructionResult,
    WorkflowSettings,
)

MAX_RECENT_FILES = 8
_SENSOR_GEOMETRY = ("pixel_pitch_um", "pixel_count")  # the camera fields a PSF depends on


def psf_key(design: Design) -> str:
    """Hash of what a PSF stack depends on: the optics without metadata and camera noise."""
    optics = spec_hash(design, exclude=(*METADATA_FIELDS, "camera"))
    sensor = spec_hash(
        design.camera, exclude=[n for n in type(design.camera).model_fields if n not in _SENSOR_GEOMETRY]
    )
    return optics + sensor


def stages_affected(old: Design, new: Design) -> tuple[str, ...]:
    """The stages a change from ``old`` to ``new`` makes stale (none for a metadata-only change)."""
    if psf_key(old) != psf_key(new):
        return STAGES
    if old.camera != new.camera:
        return ("image", "reconstruction")  # noise parameters: same PSF, new image
    return ()


class StudioState:
    """Everything the studio shows, with a signal per part.

    Parameters
    ----------
    design : the design to start with (valid by construction).
    file_path : the file it came from (None: a preset or a new design).
    """

    design_changed = Signal(object)  # Design (the design in force)
    design_replaced = Signal(object)  # Design: a new document (new / open); results were cleared
    errors_changed = Signal(object)  # dict[str, str]: field path -> reason
    warnings_changed = Signal(object)  # tuple[str, ...]: DesignWarnings of the design in force
    device_changed = Signal(str)
    psf_changed = Signal(object)  # PSFResult | None (full stack)
    preview_changed = Signal(object)  # PSFResult | None (quick preview)
    image_changed = Signal(object)  # ImageResult | None (camera image + ground truth)
    reconstruction_changed = Signal(object)  # ReconstructionResult | None
    convergence_changed = Signal(object)  # (NCC per iteration, relative change per iteration)
    metrics_changed = Signal(object)  # DesignMetrics | None
    workflow_changed = Signal(object)  # WorkflowSettings
    stale_changed = Signal(object)  # frozenset[str] of STAGES (also at a change to stale stages' inputs)
    job_changed = Signal(object)  # JobStatus
    dirty_changed = Signal(bool)
    unsaved_model_changed = Signal(object)  # str | None: what a trained, not yet saved model is
    file_path_changed = Signal(object)  # Path | None
    recent_files_changed = Signal(object)  # tuple[Path, ...]

    def __init__(self, design: Design, *, file_path: str | Path | None = None) -> None:
        if not isinstance(design, Design):
            raise TypeError(f"design must be a Design; got {type(design).__name__}.")
        self._design = design
        self._errors: dict[str, str] = {}
        self._warnings: tuple[str, ...] = ()
        self._device = "cpu"
        self._psf: PSFResult | None = None
        self._preview: PSFResult | None = None
        self._image: ImageResult | None = None
        self._reconstruction: ReconstructionResult | None = None
        self._convergence: tuple[tuple[float, ...], tuple[float, ...]] = ((), ())
        self._metrics: DesignMetrics | None = None
        self._workflow = WorkflowSettings()
        self._stale: frozenset[str] = frozenset(STAGES)
        self._inputs_version = dict.fromkeys(STAGES, 1)  # counts the changes to each stage's inputs
        self._fresh_at = dict.fromkeys(STAGES, 0)  # the inputs version of each stage's fresh result
        self._jobs: dict[str, JobStatus] = {}
        self._dirty = False
        self._unsaved_model: str | None = None
        self._file_path = None if file_path is None else Path(file_path)
        self._recent: tuple[Path, ...] = ()

    # ----- the design -----

    @property
    def design(self) -> Design:
        """The design in force: always valid, the last valid one after an invalid edit."""
        return self._design

    @property
    def last_valid_design(self) -> Design:
        """Same as :attr:`design` (named for readers looking for it)."""
        return self._design

    def set_design(self, design: Design, *, warnings: Iterable[str] = (), dirty: bool = True) -> bool:
        """Put ``design`` in force (an edit); returns False when it equals the current one."""
        if not isinstance(design, Design):
            raise TypeError(f"design must be a Design; got {type(design).__name__}.")
        self.set_warnings(warnings)
        if design == self._design:
            return False
        old, self._design = self._design, design
        self.mark_stale(*stages_affected(old, design))
        self.design_changed.emit(design)
        if dirty:
            self.set_dirty(True)
        return True

    def replace_design(
        self, design: Design, *, file_path: str | Path | None = None, warnings: Iterable[str] = ()
    ) -> None:
        """Start a new document (new from preset, open): clears errors, results and the unsaved model
        (it was trained for the previous design), not dirty."""
        if not isinstance(design, Design):
            raise TypeError(f"design must be a Design; got {type(design).__name__}.")
        self._design = design
        self.clear_errors()
        self.set_warnings(warnings)
        for setter in (self.set_psf, self.set_preview, self.set_image, self.set_reconstruction):
            setter(None)
        self.set_convergence((), ())
        self.set_metrics(None)
        self.mark_stale(*STAGES)
        self.set_file_path(file_path)
        self.set_dirty(False)
        self.set_unsaved_model(None)
        self.design_replaced.emit(design)
        self.design_changed.emit(design)

    @property
    def errors(self) -> dict[str, str]:
        """Why the values shown in some fields are not in force (field path -> message); a copy."""
        return dict(self._errors)

    def set_field_error(self, path: str, message: str | None) -> None:
        """Record (or with None, clear) the reason a field's value was refused."""
        if message is None:
            if path not in self._errors:
                return
            del self._errors[path]
        else:
            if self._errors.get(path) == message:
                return
            self._errors[path] = message
        self.errors_changed.emit(dict(self._errors))

    def clear_errors(self, paths: Iterable[str] | None = None) -> None:
        """Forget the errors of ``paths`` (default: all)."""
        keys = list(self._errors) if paths is None else [p for p in paths if p in self._errors]
        if not keys:
            return
        for key in keys:
            del self._errors[key]
        self.errors_changed.emit(dict(self._errors))

    @property
    def warnings(self) -> tuple[str, ...]:
        """Design warnings of the design in force (valid but questionable choices)."""
        return self._warnings

    def set_warnings(self, warnings: Iterable[str]) -> None:
        value = tuple(warnings)
        if value != self._warnings:
            self._warnings = value
            self.warnings_changed.emit(value)

    @property
    def device(self) -> str:
        """Where the engine computes ("cpu" or "cuda")."""
        return self._device

    def set_device(self, device: str) -> None:
        if device != self._device:
            self._device = device
            self.mark_stale(*STAGES)
            self.device_changed.emit(device)

    # ----- results (written by the controller when a job succeeded) -----

    @property
    def psf(self) -> PSFResult | None:
        """The last full PSF stack (possibly of an older design: see :attr:`stale`)."""
        return self._psf

    def set_psf(self, result: PSFResult | None) -> None:
        self._psf = result
        self.psf_changed.emit(result)

    @property
    def preview(self) -> PSFResult | None:
        """The last quick preview stack."""
        return self._preview

    def set_preview(self, result: PSFResult | None) -> None:
        self._preview = result
        self.preview_changed.emit(result)

    @property
    def image(self) -> ImageResult | None:
        """The last simulated light-field image (with its ground truth)."""
        return self._image

    @property
    def camera_image(self):
        """The camera counts ``(Py, Px)`` of :attr:`image`, or None."""
        return None if self._image is None else self._image.counts

    @property
    def ground_truth(self):
        """The phantom volume ``(Z, Y, X)`` of :attr:`image`, or None."""
        return None if self._image is None else self._image.ground_truth

    def set_image(self, result: ImageResult | None) -> None:
        self._image = result
        self.image_changed.emit(result)

    @property
    def reconstruction(self) -> ReconstructionResult | None:
        return self._reconstruction

    def set_reconstruction(self, result: ReconstructionResult | None) -> None:
        self._reconstruction = result
        self.reconstruction_changed.emit(result)
        if result is not None:
            self.set_convergence(result.ncc_curve, result.change_curve)

    @property
    def convergence(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Richardson-Lucy convergence: NCC with the truth and relative change after each iteration.

        Live while a reconstruction runs; the kept reconstruction's once it ends (done: the new one;
        cancelled or failed: the previous one, :meth:`restore_convergence`).
        """
        return self._convergence

    def set_convergence(self, quality: tuple[float, ...], change: tuple[float, ...]) -> None:
        value = (tuple(quality), tuple(change))
        if value != self._convergence:
            self._convergence = value
            self.convergence_changed.emit(value)

    def restore_convergence(self) -> None:
        """Show the kept reconstruction's curves again (none: empty), after a run that streamed its
        own partial curves was cancelled or failed."""
        kept = self._reconstruction
        self.set_convergence(*((kept.ncc_curve, kept.change_curve) if kept is not None else ((), ())))

    @property
    def metrics(self) -> DesignMetrics | None:
        """Design metrics and zebrafish requirement checks (closed forms, measured once a PSF is in)."""
        return self._metrics

    def set_metrics(self, metrics: DesignMetrics | None) -> None:
        self._metrics = metrics
        self.metrics_changed.emit(metrics)

    @property
    def workflow(self) -> WorkflowSettings:
        return self._workflow

    def set_workflow(self, settings: WorkflowSettings) -> None:
        """New workflow settings; marks the image (or only the reconstruction) stale."""
        old, self._workflow = self._workflow, settings
        if settings == old:
            return
        if settings.image_changed(old):
            self.mark_stale("image", "reconstruction")
        elif settings.reconstruction_changed(old):
            self.mark_stale("reconstruction")
        self.workflow_changed.emit(settings)

    # ----- staleness -----

    @property
    def stale(self) -> frozenset[str]:
        """Stages to compute again: their result (if any) no longer matches the design and settings,
        or a run of them was asked for (:meth:`mark_stale` with ``changed=False``)."""
        return self._stale

    @property
    def outdated(self) -> frozenset[str]:
        """The stale stages whose inputs (design, device or settings) changed since their result was
        made; a stage that is stale only because a run was asked for again is not outdated: what it
        shows still matches the design and settings in force."""
        return frozenset(s for s in self._stale if self._inputs_version[s] != self._fresh_at[s])

    def inputs_version(self, stage: str) -> int:
        """A count that grows at every change to ``stage``'s inputs (a result made at one version is
        out of date once the count differs)."""
        return self._inputs_version[stage]

    def mark_stale(self, *stages: str, changed: bool = True) -> None:
        """``stages`` are to be computed again: their inputs changed (default), or, with
        ``changed=False``, a run was asked for with the same inputs (e.g. a button pressed again)."""
        unknown = set(stages) - set(STAGES)
        if unknown:
            raise ValueError(f"unknown stages {sorted(unknown)}; known: {STAGES}.")
        before = (self._stale, self.outdated)
        if changed:
            for stage in stages:
                self._inputs_version[stage] += 1
        self._stale = self._stale | frozenset(stages)
        if (changed and stages) or (self._stale, self.outdated) != before:  # a new inputs version too
            self.stale_changed.emit(self._stale)

    def mark_fresh(self, stage: str) -> None:
        """``stage``'s result on screen matches the design and settings in force."""
        self._fresh_at[stage] = self._inputs_version[stage]
        if stage in self._stale:
            self._stale = self._stale - {stage}
            self.stale_changed.emit(self._stale)

    # ----- jobs -----

    def job(self, name: str) -> JobStatus:
        """Status of job ``name`` (idle if never run)."""
        return self._jobs.get(name, JobStatus(name))

    @property
    def jobs(self) -> Mapping[str, JobStatus]:
        return dict(self._jobs)

    def set_job(self, status: JobStatus) -> None:
        if self._jobs.get(status.name) != status:
            self._jobs[status.name] = status
            self.job_changed.emit(status)

    @property
    def busy(self) -> bool:
        """Whether any job is running."""
        return any(s.active for s in self._jobs.values())

    # ----- document -----

    @property
    def dirty(self) -> bool:
        """The design has changes not saved to :attr:`file_path`."""
        return self._dirty

    @property
    def unsaved_input(self) -> bool:
        """Something on screen is not in the saved file: changes (:attr:`dirty`), refused values
        (:attr:`errors`), which Save does not write since they are not in the design in force, or a
        trained model not yet saved to a checkpoint (:attr:`unsaved_model`)."""
        return self._dirty or bool(self._errors) or self._unsaved_model is not None

    @property
    def unsaved_model(self) -> str | None:
        """What the trained model that lives only in memory is (e.g. ``"the trained unrolled-rl model
        (60 steps)"``), or None when there is none (none trained, or it was saved)."""
        return self._unsaved_model

    def set_unsaved_model(self, what: str | None) -> None:
        """Record (or with None, clear) a trained model that is not saved to a checkpoint file."""
        if what != self._unsaved_model:
            self._unsaved_model = what
            self.unsaved_model_changed.emit(what)

    def set_dirty(self, dirty: bool) -> None:
        if dirty != self._dirty:
            self._dirty = dirty
            self.dirty_changed.emit(dirty)

    @property
    def file_path(self) -> Path | None:
        return self._file_path

    def set_file_path(self, path: str | Path | None) -> None:
        value = None if path is None else Path(path)
        if value != self._file_path:
            self._file_path = value
            self.file_path_changed.emit(value)

    def mark_saved(self, path: str | Path) -> None:
        """The design was written to ``path``: not dirty, current file, first recent file."""
        self.set_file_path(path)
        self.set_dirty(False)
        self.add_recent_file(path)

    @property
    def recent_files(self) -> tuple[Path, ...]:
        return self._recent

    def set_recent_files(self, paths: Iterable[str | Path]) -> None:
        unique: list[Path] = []
        for p in paths:
            path = Path(p)
            if path not in unique:
                unique.append(path)
        value = tuple(unique[:MAX_RECENT_FILES])
        if value != self._recent:
            self._recent = value
            self.recent_files_changed.emit(value)

    def add_recent_file(self, path: str | Path) -> None:
        """Put ``path`` first in the recent files."""
        self.set_recent_files([Path(path), *self._recent])
