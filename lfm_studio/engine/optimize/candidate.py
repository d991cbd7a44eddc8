"""One candidate design under evaluation: its PSF stack and imaging setup, built once and timed.

Objectives read what they need from a :class:`Candidate` (the design for closed forms, the
PSF stack for PSF losses, the imaging setup for task scores); the stack is computed on
first use through :func:`~lfm_studio.engine.simulation.simulate_psf` with the evaluator's
per-lenslet cache, so a candidate that moves one lenslet recomputes one lenslet.
``timing`` collects seconds per stage (``psf_s``, ``simulate_s``, ``reconstruct_s``, ``score_s``).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cached_property

from lfm_studio.engine.design import Design
from lfm_studio.engine.optimize.crop import auto_crop
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.simulation import ImagingSetup, design_depths, imaging_setup, simulate_psf
from lfm_studio.engine.systems.lenslet_cache import LensletCache


@dataclass(frozen=True)
class EvaluationSettings:
    """How candidates are simulated (the same for every candidate of a study).

    Attributes
    ----------
    depths_um : depths in micrometres (None: the design's own depth grid).
    crop : camera pixels kept about the axis (``simulate_psf(crop=...)``); None = whole sensor.
    device : torch device name.
    dtype : "float32" / "float64" (None: the design's accuracy setting).
    """

    depths_um: tuple[float, ...] | None = None
    crop: int | None = 256
    device: str = "cpu"
    dtype: str | None = None

    @classmethod
    def for_design(cls, design: Design) -> EvaluationSettings:
        """The settings a study of ``design`` uses when none are given: the defaults with the PSF crop
        chosen for the design (:func:`~lfm_studio.engine.optimize.crop.auto_crop`: the smallest crop
        holding enough sub-images; the fixed 256 px held none of the XLFM preset's 27)."""
        return cls(crop=auto_crop(design))

    def to_dict(self) -> dict:
        return {
            "depths_um": None if self.depths_um is None else list(self.depths_um),
            "crop": self.crop,
            "device": self.device,
            "dtype": self.dtype,
        }


class Candidate:
    """A design being scored, with lazily built (and timed) PSF stack and imaging setup."""

    def __init__(
        self,
        design: Design,
        settings: EvaluationSettings,
        *,
        seed: int = 0,
        cache: LensletCache | None = None,
    ) -> None:
        self.design = design
        self.settings = settings
        self.seed = seed
        self.cache = cache
        self.timing: dict[str, float] = {}
        self.memo: dict[tuple, object] = {}  # results shared by objectives (e.g. reconstructions)

    @contextmanager
    def timed(self, stage: str) -> Iterator[None]:
        """Add the seconds spent in the block to ``timing[stage]``."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self.timing[stage] = self.timing.get(stage, 0.0) + time.perf_counter() - start

    @property
    def depths(self) -> tuple[float, ...]:
        """Simulated depths in metres."""
        if self.settings.depths_um is not None:
            return tuple(z * 1e-6 for z in self.settings.depths_um)
        return design_depths(self.design)

    @cached_property
    def stack(self) -> PSFStack:
        """The candidate's PSF stack (computed once, timed as ``psf_s``)."""
        with self.timed("psf_s"):
            return simulate_psf(
                self.design,
                depths=self.depths,
                device=self.settings.device,
                dtype=self.settings.dtype,
                crop=self.settings.crop,
                cache=self.cache,
            )

    @cached_property
    def setup(self) -> ImagingSetup:
        """Projector and volume grid of :attr:`stack`."""
        stack = self.stack
        with self.timed("psf_s"):
            return imaging_setup(stack)
