"""Design-space parameters as differentiable tensors of the Fourier fast path.

:func:`bind_space` maps every :class:`~.space.Parameter` of a :class:`~.space.DesignSpace`
onto a field of :class:`~lfm_studio.engine.systems.fourier_parameters.FourierParameters`
(the tensor overrides the per-lenslet Fourier PSF differentiates), and
:meth:`SpaceBinding.psf_stack` computes the PSF stack of a point given as a tensor of
design values (the space's units: mm, um, nm, unitless), so that gradients reach it.

Differentiable paths (:data:`DIFFERENTIABLE_PATHS`; ``i`` may be an index, ``*`` or a
comma list, as everywhere in a design space):

- ``objective.numerical_aperture`` (the NA enters through an antialiased pupil rim),
- ``relay.focal_length_mm``, ``mla_to_camera_distance_mm``, ``wavelength_nm``,
- ``mla.lenslets[i].focal_length_mm``, ``mla.lenslets[i].aperture_diameter_um``,
  ``mla.lenslets[i].center_um[0]`` / ``[1]`` (a list MLA),
- a regular MLA: ``mla.focal_length_mm`` and ``mla.lenslet_aperture_diameter_um`` (every
  lenslet), ``mla.pitch_um`` (every centre scales about the offset; the apertures follow the
  pitch when the design leaves ``lenslet_aperture_diameter_um`` unset) and ``mla.offset_um[0|1]``
  (every centre shifts). The lenslet count and lattice stay as they are.
- ``pupil_phase.zernike_waves.<noll>``: a Zernike coefficient (waves) of the pupil phase mask
  (thesis 5.2.2 PSF engineering); a term the design's ``pupil_phase`` does not list starts at 0
  waves (no mask) and is written in with the result; it overrides
  :attr:`FourierParameters.zernike_waves`.

A conventional LFM (:data:`CONVENTIONAL_PATHS`) is differentiable in ``objective.numerical_aperture``,
``mla_to_camera_distance_mm``, ``wavelength_nm``, ``mla.focal_length_mm`` and
``mla.lenslet_aperture_diameter_um`` (the tensor overrides of
:func:`~lfm_studio.engine.systems.conventional_patterns.conventional_patterns`; the NA as a
tensor in the system's objective). Its stack is planned (reach, grids, sample counts) from the
design with the values written in, so the plan follows the point; the tensors carry the
gradient. Its pitch, pixel and voxel counts stay fixed.

Anything else (counts, layouts, choices, integer parameters) is refused with
:class:`NotDifferentiableError`, which lists the paths of the design's kind. The optimiser works on
``u`` in ``[0, 1]`` per parameter (``value = low + (high - low) u``), so the bounds are a box
and the projection is a clamp.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

import torch

from lfm_studio.engine.design import Design, RegularMLASpec
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.design.space import DesignSpace, Parameter, _indices
from lfm_studio.engine.dtypes import real_dtype_named
from lfm_studio.engine.optimize.candidate import EvaluationSettings
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.simulation import design_depths
from lfm_studio.engine.systems.conventional_psf import conventional_psf_stack
from lfm_studio.engine.systems.fourier_parameters import FourierParameters
from lfm_studio.engine.systems.fourier_psf import fourier_psf_stack
from lfm_studio.engine.systems.from_design import (
    conventional_accuracy_of,
    conventional_system_of,
    fourier_accuracy_of,
    fourier_system_of,
    virtual_pixel_count,
)
from lfm_studio.engine.systems.kinds import CONVENTIONAL, SystemKind, kind_of
from lfm_studio.engine.systems.kinds_fourier import FOURIER

DIFFERENTIABLE_PATHS: tuple[str, ...] = (
    "objective.numerical_aperture",
    "relay.focal_length_mm",
    "mla_to_camera_distance_mm",
    "wavelength_nm",
    "mla.lenslets[i].focal_length_mm",
    "mla.lenslets[i].aperture_diameter_um",
    "mla.lenslets[i].center_um[0]",
    "mla.lenslets[i].center_um[1]",
    "mla.focal_length_mm",
    "mla.pitch_um",
    "mla.lenslet_aperture_diameter_um",
    "mla.offset_um[0]",
    "mla.offset_um[1]",
    "pupil_phase.zernike_waves.<noll>",
)
"""The design paths the gradient optimiser can free in a Fourier LFM (``i``: an index, ``*`` or a comma list)."""

CONVENTIONAL_PATHS: tuple[str, ...] = (
    "objective.numerical_aperture",
    "mla_to_camera_distance_mm",
    "wavelength_nm",
    "mla.focal_length_mm",
    "mla.lenslet_aperture_diameter_um",
)
"""The design paths the gradient optimiser can free in a conventional LFM."""

_SI = {"mm": 1e-3, "um": 1e-6, "nm": 1e-9, "": 1.0, "waves": 1.0}
_SCALAR_FIELDS = {
    ("objective", "numerical_aperture"): "numerical_aperture",
    ("relay", "focal_length_mm"): "fourier_focal_length",
    ("mla_to_camera_distance_mm",): "mla_to_camera",
    ("wavelength_nm",): "wavelength",
}
_CONVENTIONAL_FIELDS = {
    ("objective", "numerical_aperture"): "numerical_aperture",
    ("mla_to_camera_distance_mm",): "mla_to_camera",
    ("wavelength_nm",): "wavelength",
    ("mla", "focal_length_mm"): "lenslet_focal_length",
    ("mla", "lenslet_aperture_diameter_um"): "lenslet_aperture",
}
_LENSLET_FIELDS = {"focal_length_mm": "focal_lengths", "aperture_diameter_um": "aperture_diameters"}
_REGULAR_FIELDS: dict[tuple[str, ...], tuple[str, int | None]] = {
    ("mla", "focal_length_mm"): ("focal_lengths", None),
    ("mla", "lenslet_aperture_diameter_um"): ("aperture_diameters", None),
    ("mla", "pitch_um"): ("pitch", None),
    ("mla", "offset_um", "0"): ("offset", 0),
    ("mla", "offset_um", "1"): ("offset", 1),
}


class NotDifferentiableError(ValueError):
    """A design-space parameter the differentiable fast path cannot take a gradient of."""


@dataclass(frozen=True)
class Binding:
    """Where parameter ``index`` of the space goes: a :class:`FourierParameters` field, the
    lenslets it sets (``()`` for a 0-d field), the centre coordinate (``None`` otherwise),
    the factor from the design unit to SI and, for ``zernike_waves``, the Noll index."""

    parameter: Parameter
    field: str
    lenslets: tuple[int, ...]
    coordinate: int | None
    to_si: float
    noll: int | None = None


def _refuse(
    param: Parameter, why: str, paths: tuple[str, ...] = DIFFERENTIABLE_PATHS
) -> NotDifferentiableError:
    return NotDifferentiableError(
        f"parameter {param.path!r} cannot be optimised by gradient: {why}. Differentiable paths: "
        f"{', '.join(paths)}. Fix: free one of those, or use grid search / a sampler."
    )


def _bind_conventional(param: Parameter) -> Binding:
    if param.choices is not None or param.integer:
        raise _refuse(param, "it takes discrete values (choices or integer)", CONVENTIONAL_PATHS)
    parts = tuple(param.parts)
    if parts not in _CONVENTIONAL_FIELDS:
        raise _refuse(param, "the conventional-LFM patterns have no tensor for it", CONVENTIONAL_PATHS)
    return Binding(param, _CONVENTIONAL_FIELDS[parts], (), None, _SI[param.unit])


def _bind(param: Parameter, design: Design) -> Binding:
    if param.choices is not None or param.integer:
        raise _refuse(param, "it takes discrete values (choices or integer)")
    parts = tuple(param.parts)
    to_si = _SI.get(param.unit)
    if to_si is None:
        raise _refuse(param, f"unit {param.unit!r} is not a length or unitless")
    if parts in _SCALAR_FIELDS:
        return Binding(param, _SCALAR_FIELDS[parts], (), None, to_si)
    if len(parts) == 3 and parts[:2] == ("pupil_phase", "zernike_waves"):
        if not parts[2].isdigit() or int(parts[2]) < 1:
            raise _refuse(param, f"{parts[2]!r} is not one Noll index (an integer >= 1)")
        return Binding(param, "zernike_waves", (), None, to_si, noll=int(parts[2]))
    count = len(design.mla.lenslets)
    if design.mla.layout == "regular" and parts in _REGULAR_FIELDS:
        field, coordinate = _REGULAR_FIELDS[parts]
        lenslets = tuple(range(count)) if field in ("focal_lengths", "aperture_diameters") else ()
        return Binding(param, field, lenslets, coordinate, to_si)
    if len(parts) >= 4 and parts[:2] == ("mla", "lenslets") and design.mla.layout == "lenslets":
        try:
            items = tuple(i % count for i in _indices(parts[2], count))
        except ValueError as error:
            raise _refuse(param, f"{parts[2]!r} is not a lenslet index") from error
        if len(parts) == 4 and parts[3] in _LENSLET_FIELDS:
            return Binding(param, _LENSLET_FIELDS[parts[3]], items, None, to_si)
        if len(parts) == 5 and parts[3] == "center_um" and parts[4] in ("0", "1"):
            return Binding(param, "centers", items, int(parts[4]), to_si)
    raise _refuse(param, "the Fourier fast path has no tensor for it")


@dataclass(frozen=True)
class SpaceBinding:
    """A design space bound to the differentiable PSF of a design (see the module docstring);
    ``kind``: the design's system kind (:data:`FOURIER` or :data:`CONVENTIONAL`)."""

    space: DesignSpace
    bindings: tuple[Binding, ...]
    low: torch.Tensor  # (P,) float64, design units
    high: torch.Tensor
    kind: SystemKind = FOURIER

    @property
    def span(self) -> torch.Tensor:
        return self.high - self.low

    def values(self, u: torch.Tensor) -> torch.Tensor:
        """Design values ``low + (high - low) u`` (differentiable in ``u``), clamped to
        ``[low, high]``: at ``u = 1`` rounding could otherwise land one ulp past a bound that a
        design check enforces (an aperture freed up to the pitch)."""
        low, high = self.low.to(u.dtype), self.high.to(u.dtype)
        return torch.clamp(low + (high - low) * u, min=low, max=high)

    def normalised(self, values: torch.Tensor) -> torch.Tensor:
        """``u`` of design values (0 where a parameter has ``low == high``)."""
        span = self.span
        return torch.where(span > 0, (values - self.low) / torch.where(span > 0, span, 1.0), 0.0)

    def point(self, values: torch.Tensor) -> dict[str, float]:
        """The space point (``{path: value}``, plain floats) of design values."""
        flat = values.detach().to(torch.float64).tolist()
        return {b.parameter.path: float(v) for b, v in zip(self.bindings, flat, strict=True)}

    def values_and_point(self, u: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        """The design values ``(P,)`` float64 of normalised ``u`` (detached: a snapshot of the
        descent's leaf) and their space point (``{path: value}`` in the parameters' units)."""
        values = self.values(u.detach().to(torch.float64))
        return values, self.point(values)

    def values_of(self, design: Design) -> torch.Tensor:
        """The design's current values at the space's paths, ``(P,)`` float64 (an unset regular
        lenslet aperture reads as the pitch it defaults to)."""
        point = dict(self.space.values_of(design))
        if point.get("mla.lenslet_aperture_diameter_um", 0.0) is None:
            point["mla.lenslet_aperture_diameter_um"] = design.mla.lenslet_aperture_um  # type: ignore[union-attr]
        return torch.tensor([float(point[p]) for p in self.space.names], dtype=torch.float64)

    def parameters(self, design: Design, values: torch.Tensor) -> FourierParameters:
        """:class:`FourierParameters` overriding the design's optics with ``values`` (design units)."""
        lenslets = design.mla.lenslets
        si = values.to(torch.float64)
        fields: dict[str, torch.Tensor] = {}
        lattice: dict[str, torch.Tensor] = {}  # a regular MLA's pitch and offset
        zernike: dict[int, torch.Tensor] = {}
        for k, b in enumerate(self.bindings):
            value = si[k] * b.to_si
            if b.noll is not None:
                zernike[b.noll] = value
                continue
            if b.field in ("pitch", "offset"):
                if b.field == "pitch":
                    lattice["pitch"] = value
                else:
                    if "offset" not in lattice:
                        lattice["offset"] = torch.tensor(design.mla.offset_um, dtype=torch.float64) * 1e-6  # type: ignore[union-attr]
                    lattice["offset"] = lattice["offset"].index_put((torch.tensor(b.coordinate),), value)
                continue
            if not b.lenslets:
                fields[b.field] = value
                continue
            if b.field not in fields:
                if b.field == "centers":
                    base = [[lens.center[0], lens.center[1]] for lens in lenslets]
                else:
                    attr = "focal_length" if b.field == "focal_lengths" else "aperture_diameter"
                    base = [getattr(lens, attr) for lens in lenslets]
                fields[b.field] = torch.tensor(base, dtype=torch.float64)
            target = fields[b.field]
            index = torch.tensor(b.lenslets)
            if b.coordinate is None:
                fields[b.field] = target.index_put((index,), value.expand(len(b.lenslets)))
            else:
                column = torch.full_like(index, b.coordinate)
                fields[b.field] = target.index_put((index, column), value.expand(len(b.lenslets)))
        if lattice:
            fields.update(_lattice_fields(design, lattice, "aperture_diameters" in fields))
        return FourierParameters(
            focal_lengths=fields.get("focal_lengths"),
            aperture_diameters=fields.get("aperture_diameters"),
            centers=fields.get("centers"),
            wavelength=fields.get("wavelength"),
            numerical_aperture=fields.get("numerical_aperture"),
            mla_to_camera=fields.get("mla_to_camera"),
            fourier_focal_length=fields.get("fourier_focal_length"),
            zernike_waves=zernike or None,
        )

    def psf_stack(self, design: Design, values: torch.Tensor, settings: EvaluationSettings) -> PSFStack:
        """The PSF stack of ``design`` with ``values`` written in as tensors (gradients reach them).

        Fourier LFM: the differentiable per-lenslet path, with overlapping lenslet footprints
        summed coherently (``per_lenslet_coherent``, the path the design's "auto" evaluates with
        gradients), never the full field. Conventional LFM: the pattern stack
        ``(S, S, Z, H, H)`` (one PSF per voxel sub-position; the PSF losses average over them),
        planned from the design with the values written in. ``settings`` gives the depths, crop
        (for a conventional LFM: the lenslets that fit in ``crop`` pixels), device and dtype.
        """
        depths = (
            tuple(z * 1e-6 for z in settings.depths_um)
            if settings.depths_um is not None
            else design_depths(design)
        )
        if self.kind is CONVENTIONAL:
            return self._conventional_stack(design, values, settings, depths)
        refine = design.accuracy.volume_oversampling
        system = fourier_system_of(design, refine=refine)
        if settings.crop is not None:
            ny, nx = design.camera.pixel_count
            crop = settings.crop
            shape = (virtual_pixel_count(min(crop, ny), refine), virtual_pixel_count(min(crop, nx), refine))
            system = dataclasses.replace(system, sensor_shape=shape)
        # "auto": per lenslet, coherent groups where lenslet footprints overlap (with parameters
        # fourier_psf_stack never takes the full field), i.e. the PSF grid search evaluates.
        accuracy = dataclasses.replace(fourier_accuracy_of(design), method="auto")
        if settings.dtype is not None:
            accuracy = dataclasses.replace(accuracy, dtype=real_dtype_named(settings.dtype))
        stack = fourier_psf_stack(
            system,
            depths,
            accuracy=accuracy,
            device=settings.device,
            design=design,
            parameters=self.parameters(design, values),
        )
        return dataclasses.replace(stack, volume_oversampling=refine)

    def _conventional_stack(
        self, design: Design, values: torch.Tensor, settings: EvaluationSettings, depths: tuple[float, ...]
    ) -> PSFStack:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DesignWarning)
            at = self.space.apply(design, self.point(values))
        mla = at.mla
        lenslets = None
        if settings.crop is not None and isinstance(mla, RegularMLASpec):  # (as CONVENTIONAL.psf_stack)
            count = max(1, int(settings.crop * at.camera.pixel_pitch / (mla.pitch_um * 1e-6)))
            lenslets = (min(count, mla.shape[0]), min(count, mla.shape[1]))
        system = conventional_system_of(at, lenslets=lenslets)
        accuracy = conventional_accuracy_of(at, system)
        if settings.dtype is not None:
            accuracy = dataclasses.replace(accuracy, dtype=real_dtype_named(settings.dtype))
        si = values.to(torch.float64)
        tensors = {b.field: si[k] * b.to_si for k, b in enumerate(self.bindings)}
        na = tensors.pop("numerical_aperture", None)
        if na is not None:
            system = dataclasses.replace(
                system, objective=dataclasses.replace(system.objective, numerical_aperture=na)
            )
        return conventional_psf_stack(
            system,
            depths,
            accuracy=accuracy,
            device=settings.device,
            design=at,
            lenslet_focal_length=tensors.get("lenslet_focal_length"),
            mla_to_camera=tensors.get("mla_to_camera"),
            wavelength=tensors.get("wavelength"),
            lenslet_aperture=tensors.get("lenslet_aperture"),
        )


def _lattice_fields(
    design: Design, lattice: dict[str, torch.Tensor], apertures_bound: bool
) -> dict[str, torch.Tensor]:
    """Centres (and apertures that default to the pitch) of a regular MLA with a tensor pitch / offset:
    ``centre = offset + k pitch`` with each lenslet's lattice coordinates ``k`` (square or hex)."""
    mla = design.mla
    pitch0 = mla.pitch_um * 1e-6  # type: ignore[union-attr]
    offset0 = torch.tensor(mla.offset_um, dtype=torch.float64) * 1e-6  # type: ignore[union-attr]
    centres0 = torch.tensor([lens.center for lens in mla.lenslets], dtype=torch.float64)
    steps = (centres0 - offset0) / pitch0
    pitch = lattice.get("pitch", torch.tensor(pitch0, dtype=torch.float64))
    offset = lattice.get("offset", offset0)
    out = {"centers": offset + steps * pitch}
    if "pitch" in lattice and not apertures_bound and mla.lenslet_aperture_diameter_um is None:  # type: ignore[union-attr]
        out["aperture_diameters"] = pitch.expand(len(mla.lenslets))
    return out


def bind_space(space: DesignSpace, design: Design) -> SpaceBinding:
    """Bind every parameter of ``space`` (:class:`NotDifferentiableError` for one that cannot be)."""
    kind = kind_of(design)
    if kind is CONVENTIONAL:
        space.check_paths(design)
        bindings = tuple(_bind_conventional(p) for p in space.parameters)
    elif kind is FOURIER:
        space.check_paths(design)
        bindings = tuple(_bind(p, design) for p in space.parameters)
    else:
        raise NotDifferentiableError(
            f"gradient optimisation needs a Fourier or conventional LFM; the design is a {kind.title}. "
            "Fix: use grid search or a sampler for this design."
        )
    seen: dict[tuple[str, int, int | None, int | None], str] = {}
    for b in bindings:
        for i in b.lenslets or (-1,):
            key = (b.field, i, b.coordinate, b.noll)
            if key in seen:
                raise ValueError(
                    f"parameters {seen[key]!r} and {b.parameter.path!r} both set {b.field}"
                    f"{'' if i < 0 else f' of lenslet {i}'}. Fix: free each value once."
                )
            seen[key] = b.parameter.path
    low = torch.tensor([float(b.parameter.low) for b in bindings], dtype=torch.float64)  # type: ignore[arg-type]
    high = torch.tensor([float(b.parameter.high) for b in bindings], dtype=torch.float64)  # type: ignore[arg-type]
    return SpaceBinding(space, bindings, low, high, kind)
