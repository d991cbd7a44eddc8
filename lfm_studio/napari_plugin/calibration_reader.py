"""Calibration files (``lfm-studio calibrate``) open as an overlay of the fitted lenslet grid.

Two Points layers in the radiometry frame's pixel coordinates (``(y, x)``, scale 1, so they
lie over the radiometry or raw frame opened at its pixel scale):

- ``<stem> fitted grid``: where the fitted lattice puts each lenslet (or where the design,
  registered to the frame, puts each Fourier sub-image). Its ``features`` hold per point the
  ``residual_px`` (measured centroid minus fitted site), the ``flags`` (comma-separated:
  ``edge``, ``dim``, ``residual``; empty when the point was used in the fit), ``used`` and
  the ``measured_y_px`` / ``measured_x_px`` centroid. Used points are green, flagged ones red.
- ``<stem> measured centres``: the measured centroids, small and cyan.

The file is claimed when it is JSON whose ``format`` is the calibration format; the layers'
metadata hold ``kind: "calibration"``, the file path and the calibration summary, so the
Reconstruct widget can take the calibration from the overlay.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from lfm_studio.engine.calibration import CalibrationFileError, grid_overlay, load_calibration
from lfm_studio.engine.calibration.calibration_io import FORMAT
from lfm_studio.napari_plugin.layer_data import LayerData
from lfm_studio.napari_plugin.notify import report_error

MAX_CALIBRATION_BYTES = 256 * 2**20  # a 2048² calibration is ~2 MB of JSON
CALIBRATION_KIND = "calibration"
USED_COLOUR, FLAGGED_COLOUR, MEASURED_COLOUR = "lime", "red", "cyan"
NOTHING: list[Any] = [(None,)]  # napari's "read, but no layer" sentinel


_FORMAT_TAG = re.compile(r'"format"\s*:\s*"' + re.escape(FORMAT) + '"')


def is_calibration_file(path: Path) -> bool:
    """Whether ``path`` is a JSON calibration file of ours, by the ``"format"`` tag near its top (not its
    name). Only the first 4 KiB are read: the reader parses and checks the whole file once, when it loads it."""
    if path.suffix.lower() != ".json":
        return False
    try:
        if path.stat().st_size > MAX_CALIBRATION_BYTES:
            return False
        with path.open("rb") as handle:
            head = handle.read(4096).decode("utf-8", errors="replace")
    except OSError:
        return False
    return _FORMAT_TAG.search(head) is not None


def overlay_layer_data(calibration: Any, *, name: str, source: str | None = None) -> list[LayerData]:
    """The fitted-grid and measured-centre Points layers of ``calibration`` (see the module docstring)."""
    overlay = grid_overlay(calibration)
    fitted = overlay.fitted.detach().cpu().numpy().astype(np.float64)
    measured = overlay.measured.detach().cpu().numpy().astype(np.float64)
    used = np.array([not flags for flags in overlay.flags], dtype=bool)
    metadata = {"kind": CALIBRATION_KIND, "source": source, "summary": calibration.summary()}
    features = {
        "residual_px": overlay.residual.detach().cpu().numpy().astype(np.float64),
        "flags": np.array([",".join(flags) for flags in overlay.flags], dtype=object),
        "used": used,
        "measured_y_px": measured[:, 0],
        "measured_x_px": measured[:, 1],
    }
    size = _marker_size(calibration)
    grid = {
        "name": f"{name} fitted grid",
        "features": features,
        "face_color": np.where(used, USED_COLOUR, FLAGGED_COLOUR).tolist(),
        "border_color": "transparent",
        "size": size,
        "opacity": 0.8,
        "metadata": metadata,
    }
    centres = {
        "name": f"{name} measured centres",
        "face_color": MEASURED_COLOUR,
        "border_color": "transparent",
        "size": 0.5 * size,
        "metadata": dict(metadata),
    }
    return [(fitted, grid, "points"), (measured, centres, "points")]


def _marker_size(calibration: Any) -> float:
    """A marker a quarter of the lenslet pitch (conventional) or 4 px (Fourier)."""
    if calibration.grid is None:
        return 4.0
    return max(1.0, 0.25 * min(calibration.grid.lattice.pitch))


def read_calibration(path: Any) -> list[LayerData]:
    """napari reader function for a calibration file: its grid overlay, or an error notification."""
    source = Path(path[0] if isinstance(path, (list, tuple)) else path)
    try:
        calibration = load_calibration(source)
    except (CalibrationFileError, ValueError, OSError, KeyError, TypeError) as error:
        report_error(f"lfm-studio could not open the calibration {source.name}: {error}")
        return NOTHING
    return overlay_layer_data(calibration, name=source.stem, source=str(source))


def calibration_source(layer: Any) -> str | None:
    """The calibration file a layer was opened from (its overlay's ``source``), or None for other layers."""
    metadata = getattr(layer, "metadata", None) or {}
    source = metadata.get("source")
    return str(source) if metadata.get("kind") == CALIBRATION_KIND and source else None
