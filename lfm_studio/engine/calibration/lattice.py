"""The lenslet lattice on a raw camera frame: where each lenslet's centre falls, in pixels.

Pixel convention (the whole calibration package): pixel ``(r, c)`` of a frame covers
``[r - 0.5, r + 0.5] x [c - 0.5, c + 0.5]``, so integer coordinates are pixel centres;
points are ``(y, x)`` = (row, column), in pixels.

A lattice is an affine map from lenslet indices ``(i, j)`` (row, column) to frame
coordinates: ``centre(i, j) = origin + i * row_vector + j * col_vector``. A square MLA
imaged with per-axis scale and a rotation ``theta`` has
``col_vector = pitch_x (sin theta, cos theta)`` and ``row_vector = pitch_y (cos theta, -sin theta)``;
a measured lattice may also carry a small shear, which :attr:`shear` reports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

Vector = tuple[float, float]


@dataclass(frozen=True)
class LensletLattice:
    """Lenslet centres on a frame, pixels (see the module docstring for the convention).

    Attributes
    ----------
    origin : (y, x) centre of lenslet ``(0, 0)``, px.
    row_vector : (dy, dx) step from lenslet ``(i, j)`` to ``(i + 1, j)``, px.
    col_vector : (dy, dx) step from lenslet ``(i, j)`` to ``(i, j + 1)``, px.
    """

    origin: Vector
    row_vector: Vector
    col_vector: Vector

    def __post_init__(self) -> None:
        for name in ("origin", "row_vector", "col_vector"):
            value = tuple(float(v) for v in getattr(self, name))
            if len(value) != 2 or not all(math.isfinite(v) for v in value):
                raise ValueError(
                    f"LensletLattice.{name} must be two finite numbers (y, x) px; got {value!r}."
                )
            object.__setattr__(self, name, value)
        if abs(self.determinant) < 1e-9:
            raise ValueError(
                f"LensletLattice vectors are parallel (row {self.row_vector}, col {self.col_vector}); "
                "Fix: give two independent lattice vectors."
            )

    @classmethod
    def from_geometry(
        cls, pitch: tuple[float, float], rotation: float, origin: Vector = (0.0, 0.0)
    ) -> LensletLattice:
        """A rectangular lattice: ``pitch = (pitch_y, pitch_x)`` px, ``rotation`` in radians."""
        py, px = (float(p) for p in pitch)
        if not (py > 0 and px > 0):
            raise ValueError(f"pitch must be two positive numbers (y, x) px; got {pitch!r}.")
        s, c = math.sin(rotation), math.cos(rotation)
        return cls(origin=origin, row_vector=(py * c, -py * s), col_vector=(px * s, px * c))

    @property
    def pitch(self) -> tuple[float, float]:
        """``(pitch_y, pitch_x)``: lengths of the row and column vectors, px."""
        return (math.hypot(*self.row_vector), math.hypot(*self.col_vector))

    @property
    def rotation(self) -> float:
        """Mean rotation of the two lattice axes from the frame axes, radians (counter-clockwise in x, y)."""
        theta_col = math.atan2(self.col_vector[0], self.col_vector[1])
        theta_row = math.atan2(-self.row_vector[1], self.row_vector[0])
        return 0.5 * (theta_col + theta_row)

    @property
    def shear(self) -> float:
        """Departure of the two axes from perpendicular, radians (0 for a rectangular lattice)."""
        theta_col = math.atan2(self.col_vector[0], self.col_vector[1])
        theta_row = math.atan2(-self.row_vector[1], self.row_vector[0])
        return theta_row - theta_col

    @property
    def determinant(self) -> float:
        """Area of one lattice cell, px^2 (positive for the usual orientation)."""
        (ry, rx), (cy, cx) = self.row_vector, self.col_vector
        return ry * cx - rx * cy

    def matrix(self, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """``A`` of shape (2, 2) with ``(y, x) = origin + A @ (i, j)``."""
        (ry, rx), (cy, cx) = self.row_vector, self.col_vector
        return torch.tensor([[ry, cy], [rx, cx]], dtype=dtype)

    def centres(self, indices: torch.Tensor) -> torch.Tensor:
        """Centres ``(..., 2)`` (y, x) px of lenslets ``indices`` ``(..., 2)`` (i, j)."""
        a = self.matrix(torch.float64)
        origin = torch.tensor(self.origin, dtype=torch.float64)
        return indices.to(torch.float64) @ a.T + origin

    def lattice_coordinates(self, points: torch.Tensor) -> torch.Tensor:
        """Continuous lenslet coordinates ``(..., 2)`` (i, j) of frame points ``(..., 2)`` (y, x)."""
        a_inv = torch.linalg.inv(self.matrix(torch.float64))
        origin = torch.tensor(self.origin, dtype=torch.float64)
        return (points.to(torch.float64) - origin) @ a_inv.T

    def recentred(self, point: Vector) -> LensletLattice:
        """The same lattice with ``origin`` moved to the lattice site nearest ``point`` (y, x)."""
        ij = self.lattice_coordinates(torch.tensor(point, dtype=torch.float64)).round()
        centre = self.centres(ij)
        return LensletLattice(
            origin=(float(centre[0]), float(centre[1])),
            row_vector=self.row_vector,
            col_vector=self.col_vector,
        )

    def indices_inside(self, shape: tuple[int, int], margin: float = 0.5) -> torch.Tensor:
        """Indices ``(L, 2)`` (i, j) of lenslets whose cell lies inside a frame of ``shape``.

        A lenslet is kept when its centre is at least ``margin`` lattice cells (in each
        lattice direction, measured by the cell's half-diagonal extent) inside the frame.
        """
        ny, nx = shape
        corners = torch.tensor([[-0.5, -0.5], [-0.5, nx - 0.5], [ny - 0.5, -0.5], [ny - 0.5, nx - 0.5]])
        ij = self.lattice_coordinates(corners)
        lo = torch.floor(ij.min(dim=0).values) - 1
        hi = torch.ceil(ij.max(dim=0).values) + 1
        ii = torch.arange(int(lo[0]), int(hi[0]) + 1)
        jj = torch.arange(int(lo[1]), int(hi[1]) + 1)
        grid = torch.stack(torch.meshgrid(ii, jj, indexing="ij"), dim=-1).reshape(-1, 2)
        centres = self.centres(grid)
        (ry, rx), (cy, cx) = self.row_vector, self.col_vector
        reach_y = margin * (abs(ry) + abs(cy))
        reach_x = margin * (abs(rx) + abs(cx))
        inside = (
            (centres[:, 0] - reach_y >= -0.5)
            & (centres[:, 0] + reach_y <= ny - 0.5)
            & (centres[:, 1] - reach_x >= -0.5)
            & (centres[:, 1] + reach_x <= nx - 0.5)
        )
        return grid[inside]

    def to_dict(self) -> dict[str, object]:
        """JSON-ready description (vectors plus the derived pitch and rotation, for people)."""
        return {
            "origin_yx_px": list(self.origin),
            "row_vector_yx_px": list(self.row_vector),
            "col_vector_yx_px": list(self.col_vector),
            "pitch_yx_px": list(self.pitch),
            "rotation_deg": math.degrees(self.rotation),
            "shear_deg": math.degrees(self.shear),
        }

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> LensletLattice:
        """Inverse of :meth:`to_dict` (the derived keys are ignored)."""
        return cls(
            origin=tuple(data["origin_yx_px"]),  # type: ignore[arg-type]
            row_vector=tuple(data["row_vector_yx_px"]),  # type: ignore[arg-type]
            col_vector=tuple(data["col_vector_yx_px"]),  # type: ignore[arg-type]
        )
