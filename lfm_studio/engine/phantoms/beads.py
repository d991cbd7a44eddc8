"""Fluorescent beads: points or small spheres at random, well-separated positions."""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.errors import require_finite
from lfm_studio.engine.phantoms.phantom import (
    Phantom,
    centre_index,
    check_count,
    check_dtype,
    check_shape,
    check_triple,
    make_generator,
)
from lfm_studio.engine.phantoms.placement import place_separated
from lfm_studio.engine.phantoms.stamping import nearest_voxel, stamp_ellipsoids, stamp_points
from lfm_studio.engine.units import um


def beads(
    shape: tuple[int, int, int],
    *,
    count: int,
    voxel_size: tuple[float, float, float],
    seed: int | torch.Generator,
    radius: float = 0.0,
    intensity: float = 1.0,
    margin: float | None = None,
    min_separation: float | None = None,
    subvoxel: bool = False,
    allow_fewer: bool = False,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Phantom:
    """Random beads in a volume, with their ground-truth positions.

    Parameters
    ----------
    shape : (Z, Y, X)
        Volume size in voxels.
    count : int >= 0
        Number of beads.
    voxel_size : (dz, dy, dx)
        Voxel size in metres.
    seed : int or CPU ``torch.Generator``
        Same seed, same beads (on every device).
    radius : float
        Bead radius in metres; 0 draws single-voxel points at voxel centres, > 0 draws
        spheres with partial-volume edges.
    intensity : float
        Value at a bead centre (> 0).
    margin : float, optional
        Minimum distance in metres from a bead centre to the outermost voxel centres;
        default ``radius`` (spheres stay whole).
    min_separation : float, optional
        Minimum centre-to-centre distance in metres; default ``2 * radius + 2 * max(voxel_size)``
        so every bead is a separate peak. 0 allows overlaps (coinciding points keep one value).
    subvoxel : bool
        Place sphere centres anywhere (not only at voxel centres); needs ``radius > 0``.
    allow_fewer : bool
        Place as many as fit (``Phantom.count`` may then be below ``count``) instead of
        raising :class:`~lfm_studio.engine.phantoms.placement.PlacementError`.
    dtype, device : of the volume.

    Returns
    -------
    Phantom
        ``data`` ``(Z, Y, X)``; ``positions`` (metres, centred convention) and ``indices``
        (nearest voxel, which holds the bead's peak) of each bead.
    """
    check_dtype(dtype)
    shape = check_shape(shape)
    count = check_count(count)
    d = check_triple(
        "voxel_size", voxel_size, hint="give (dz, dy, dx) in metres, e.g. (2 * um, 1 * um, 1 * um)."
    )
    require_finite("radius", radius, "m")
    if radius < 0:
        raise ValueError(f"radius must be >= 0 m; got {radius:.6g} m. Fix: 0 for point beads.")
    require_finite("intensity", intensity, "")
    if intensity <= 0:
        raise ValueError(f"intensity must be > 0; got {intensity:.6g}.")
    if subvoxel and radius == 0:
        raise ValueError("subvoxel=True needs radius > 0: point beads sit at voxel centres.")
    margin = float(radius if margin is None else margin)
    separation = float(2 * radius + 2 * max(d) if min_separation is None else min_separation)
    for name, value in (("margin", margin), ("min_separation", separation)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and >= 0 m; got {value:.6g} m.")

    generator = make_generator(seed)
    spacing = torch.tensor(d, dtype=torch.float64)
    centre = centre_index(shape)
    n = torch.tensor(shape, dtype=torch.float64)
    lo, hi = margin / spacing, n - 1 - margin / spacing  # allowed index range per axis
    if not subvoxel:
        lo, hi = torch.ceil(lo - 1e-9), torch.floor(hi + 1e-9)
    if bool((lo > hi).any()):
        raise ValueError(
            f"margin {margin / um:.6g} um leaves no room for beads in a volume of {shape} voxels of "
            f"{tuple(v / um for v in d)} um. Fix: lower margin or radius, or enlarge the volume."
        )

    def sample(k: int) -> tuple[torch.Tensor, torch.Tensor]:
        u = torch.rand((k, 3), generator=generator, dtype=torch.float64)
        # Continuous indices for sub-voxel spheres, whole voxel indices otherwise.
        index = lo + u * (hi - lo) if subvoxel else torch.minimum(lo + torch.floor(u * (hi - lo + 1)), hi)
        return (index - centre) * spacing, torch.ones(k, dtype=torch.float64)

    scale = torch.full((3,), separation, dtype=torch.float64) if separation > 0 else None
    positions, _ = place_separated(
        count, sample, low=(lo - centre) * spacing, high=(hi - centre) * spacing, scale=scale,
        allow_fewer=allow_fewer,
    )  # fmt: skip
    placed = int(positions.shape[0])
    indices = nearest_voxel(positions, shape, spacing)
    values = torch.full((placed,), float(intensity), dtype=torch.float64)
    semi_axes = torch.full((placed, 3), float(radius), dtype=torch.float64)
    if radius == 0:
        data = stamp_points(shape, indices, values, dtype=dtype, device=device)
    else:
        data = stamp_ellipsoids(shape, d, positions, semi_axes, values, dtype=dtype, device=device)
    return Phantom(data, d, positions, indices, semi_axes, values)


#: Beads in a default phantom when the volume has room for them.
DEFAULT_BEADS = 50
#: Fraction of the volume the beads' exclusion spheres fill by default: random sequential
#: placement stalls near 0.3 (3-D) and fills thin slabs less, so a third of that always fits.
DEFAULT_FILL = 0.1


def default_bead_count(
    shape: tuple[int, int, int], voxel_size: tuple[float, float, float], *, cap: int = DEFAULT_BEADS
) -> int:
    """How many point beads a default phantom holds: ``cap``, or fewer when the volume is small.

    The count fills :data:`DEFAULT_FILL` of the volume with exclusion spheres of the
    default separation ``2 max(voxel_size)`` (the space around the allowed centres
    included), so a preset with few depths or a small field of view gets what fits
    instead of a placement error. At least 1.
    """
    shape, d = check_shape(shape), check_triple("voxel_size", voxel_size, hint="(dz, dy, dx) in metres.")
    separation = 2 * max(d)
    room = math.prod((n - 1) * step + separation for n, step in zip(shape, d, strict=True))
    sphere = math.pi / 6 * separation**3
    return int(max(1, min(cap, math.floor(DEFAULT_FILL * room / sphere))))
