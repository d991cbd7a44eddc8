"""Preset layouts for the MLA editor (Qt-free), built by the engine's MLASpec builders.

``square`` and ``hex`` are regular arrays of identical lenslets
(:meth:`MLASpec.square_grid`, :meth:`MLASpec.hex_grid`), kept inside the pupil
when its radius is known; ``xlfm`` is the XLFM-like multifocal layout of Cong et
al. 2017 (:meth:`MLASpec.multifocal_hex`, centred between three lenslets, focal
groups alternating around each shell). Every preset builds lenslets of one aperture shape
(:attr:`PresetParams.lenslet_shape`, "circle" or "square"); the preset row reads the shape off
the layout shown, so applying the preset it names rebuilds that layout, squares included.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from pydantic import ValidationError

from lfm_studio.engine.design import LensletSpec, MLASpec
from lfm_studio.engine.design.geometry import candidate_pairs
from lfm_studio.engine.design.lenslet import LensletShape
from lfm_studio.engine.errors import error_text

PresetKind = Literal["square", "hex", "xlfm"]
CUSTOM = "custom"  # a layout no preset rebuilds (shown in the preset row; not a preset to apply)
CUSTOM_LABEL = "Custom (as drawn)"
PRESET_LABELS: dict[str, str] = {
    "square": "Square grid",
    "hex": "Hex grid",
    "xlfm": "XLFM-like (two focal groups)",
}
COUNT_MEANING: dict[str, str] = {
    "square": "lenslets per side",
    "hex": "rings around the centre",
    "xlfm": "lenslets (complete shells: 3, 6, 12, 18, 21, 27, ...)",
}

DEFAULT_COUNTS: dict[str, int] = {"square": 5, "hex": 2, "xlfm": 27}
SHAPE_LABELS: dict[str, str] = {"circle": "circles", "square": "squares"}  # the lenslet apertures


@dataclass(frozen=True)
class PresetParams:
    """Parameters of a preset layout.

    Attributes
    ----------
    pitch_um : lattice spacing, micrometres.
    count : square: lenslets per side; hex: rings; xlfm: number of lenslets.
    focal_lengths_mm : square and hex use the first; xlfm one per focal group, mm.
    aperture_diameter_um : aperture diameter (a square's side) of every lenslet, micrometres.
    lenslet_shape : the aperture shape of every lenslet, "circle" or "square".
    """

    pitch_um: float = 2200.0
    count: int = 27
    focal_lengths_mm: tuple[float, ...] = (26.0, 28.5)
    aperture_diameter_um: float = 1000.0
    lenslet_shape: LensletShape = "circle"


def build_preset(
    kind: PresetKind, params: PresetParams, *, pupil_radius_um: float | None = None
) -> tuple[LensletSpec, ...]:
    """The lenslets of preset ``kind``; raises :class:`ValueError` with the reason if they cannot be built."""
    p = params
    keep = None if pupil_radius_um is None else 2.0 * pupil_radius_um
    try:
        if kind == "square":
            mla = MLASpec.square_grid(
                p.pitch_um,
                p.count,
                p.focal_lengths_mm[0],
                fill_factor=p.aperture_diameter_um / p.pitch_um,
                lenslet_shape=p.lenslet_shape,
                keep_within_diameter_um=keep,
            )
        elif kind == "hex":
            mla = MLASpec.hex_grid(
                p.pitch_um,
                p.focal_lengths_mm[0],
                rings=p.count,
                fill_factor=p.aperture_diameter_um / p.pitch_um,
                lenslet_shape=p.lenslet_shape,
                keep_within_diameter_um=keep,
            )
        elif kind == "xlfm":
            mla = MLASpec.multifocal_hex(
                p.pitch_um,
                p.count,
                p.focal_lengths_mm,
                aperture_diameter_um=p.aperture_diameter_um,
                center="triangle",
                lenslet_shape=p.lenslet_shape,
            )
        else:
            raise ValueError(f"preset must be one of {', '.join(PRESET_LABELS)}; got {kind!r}.")
    except ValidationError as exc:
        raise ValueError(error_text(exc)) from None
    except (ZeroDivisionError, IndexError):
        raise ValueError("preset needs a pitch > 0 µm and at least one focal length.") from None
    return tuple(mla.lenslets)


def estimate_params(lenslets: Sequence[LensletSpec], default: PresetParams = PresetParams()) -> PresetParams:
    """Preset parameters that resemble ``lenslets``: nearest-neighbour pitch, median aperture, focal
    lengths and the most common aperture shape."""
    if not lenslets:
        return default
    diameter = statistics.median(lens.aperture_diameter_um for lens in lenslets)
    focals = sorted({lens.focal_length_mm for lens in lenslets})
    if len(focals) == 1:
        focals.append(round(focals[0] * 1.1, 6))
    sample = list(lenslets[:400])  # enough to see the lattice spacing
    centers = [lens.center_um for lens in sample]
    reach = 4.0 * max(lens.aperture_diameter_um for lens in sample)
    distances = [math.dist(centers[i], centers[j]) for i, j in candidate_pairs(centers, reach)]
    distances = [d for d in distances if d > 1e-3]
    pitch = round(min(distances), 6) if distances else round(2.0 * diameter, 6)
    return PresetParams(
        pitch_um=pitch,
        count=default.count,
        focal_lengths_mm=tuple(focals[:2]),
        aperture_diameter_um=diameter,
        lenslet_shape=statistics.mode(lens.shape for lens in lenslets),
    )


def matching_preset(lenslets: Sequence[LensletSpec]) -> tuple[str, int]:
    """The preset kind and count that rebuild the centres, focal lengths and shapes of ``lenslets``,
    with the parameters :func:`estimate_params` reads off them; ``(CUSTOM, 0)`` when none does."""
    n = len(lenslets)
    if not n:
        return CUSTOM, 0
    estimate = estimate_params(lenslets)
    focals = tuple(sorted({lens.focal_length_mm for lens in lenslets}))
    counts = {
        "square": round(math.sqrt(n)),
        "hex": round((math.sqrt(9.0 + 12.0 * (n - 1)) - 3.0) / 6.0),  # n = 1 + 3 r (r + 1)
        "xlfm": n,
    }
    wanted = sorted(_key(lens) for lens in lenslets)
    for kind, count in counts.items():
        params = PresetParams(
            estimate.pitch_um, count, focals, estimate.aperture_diameter_um, estimate.lenslet_shape
        )
        try:
            built = build_preset(kind, params)  # type: ignore[arg-type]
        except ValueError:
            continue
        if len(built) == n and sorted(_key(lens) for lens in built) == wanted:
            return kind, count
    return CUSTOM, 0


def _key(lens: LensletSpec) -> tuple[float, float, float, str]:
    """What a preset must rebuild of ``lens``: its centre (to 1 nm), focal length and shape."""
    x, y = lens.center_um
    return round(x, 3) + 0.0, round(y, 3) + 0.0, lens.focal_length_mm, lens.shape
