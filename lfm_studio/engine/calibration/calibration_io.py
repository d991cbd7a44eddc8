"""Calibration files: versioned JSON with the arrays embedded as lists.

A UTF-8 JSON file (``calib.json``): the format tag and version, a summary a person reads
first, the fitted lattice or sub-image registration, the per-lenslet table (indices,
measured centres, residuals, light, outlier flags), the flat-field envelope (or the per-sub-image gains of a Fourier LFM), the defective
pixels, and the nominal design. Positions are stored to 1e-6 px. When a dark frame was
given, it is stored beside the JSON as ``calib.dark.<16 hex digits>.npz`` (float32,
compressed; the digits begin its SHA-256), named in the JSON with its SHA-256 so that a
missing or different file is caught on loading. Files written before this naming used
``calib.dark.npz``; they load as before.

Replacing a calibration (``overwrite=True``) is safe at every instant: the new dark frame
goes to its own, content-addressed file, the JSON (which names it) replaces the old JSON
atomically last, and only then is the old dark frame removed. An interrupt at any point
leaves the old calibration or the new one loadable, never neither (at worst an unused
``.npz`` stays behind).
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lfm_studio import __version__
from lfm_studio.engine.atomic_write import atomic_write
from lfm_studio.engine.calibration.grid_fit import FLAG_NAMES, LatticeFit
from lfm_studio.engine.calibration.lattice import LensletLattice
from lfm_studio.engine.calibration.record import CALIBRATION_VERSION, Calibration
from lfm_studio.engine.calibration.sub_image_flat import SubImageFlat
from lfm_studio.engine.calibration.sub_images import SubImageFit

FORMAT = "lfm_studio.calibration"
_DIGITS = 6


class CalibrationFileError(ValueError):
    """A calibration file that cannot be read (not JSON, wrong format, newer version, missing keys)."""


def _rounded(tensor: torch.Tensor) -> list[Any]:
    return torch.round(tensor.to(torch.float64), decimals=_DIGITS).tolist()


def calibration_to_dict(calibration: Calibration) -> dict[str, Any]:
    """The JSON document of ``calibration``."""
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": calibration.version,
        "written_by": f"lfm_studio {__version__}",
        "kind": calibration.kind,
        "summary": calibration.summary(),
        "frame_shape": list(calibration.frame_shape),
        "dark_level_adu": calibration.dark_level,
        "pixels_per_lenslet": calibration.pixels_per_lenslet,
        "lenslet_block": None if calibration.block is None else list(calibration.block),
        "flat_field_coefficients": None if calibration.envelope is None else calibration.envelope.tolist(),
        "flag_bits": {str(bit): name for bit, name in FLAG_NAMES.items()},
        "defects_yx": calibration.defects.tolist(),
        "design": calibration.design,
    }
    if calibration.grid is not None:
        grid = calibration.grid
        doc["lattice"] = grid.lattice.to_dict()
        doc["lenslets"] = {
            "index_ij": grid.indices.tolist(),
            "measured_yx_px": _rounded(grid.measured),
            "residual_px": _rounded(grid.residual),
            "light": _rounded(grid.mass),
            "flags": grid.flags.tolist(),
        }
    if calibration.sub_images is not None:
        fit = calibration.sub_images
        doc["sub_images"] = {
            "nominal_yx_px": _rounded(fit.nominal),
            "measured_yx_px": _rounded(fit.measured),
            "residual_px": _rounded(fit.residual),
            "light": _rounded(fit.light),
            "flags": fit.flags.tolist(),
            "scale": fit.scale,
            "rotation_rad": fit.rotation,
            "shift_yx_px": list(fit.shift),
        }
        flat = calibration.sub_image_flat
        if flat is not None:
            doc["sub_images"]["flat_field"] = {
                "radius_px": flat.radius,
                "coefficients": flat.coefficients.tolist(),
            }
    return doc


def _tensor(values: Any, dtype: torch.dtype, width: int | None = None) -> torch.Tensor:
    tensor = torch.tensor(values, dtype=dtype)
    if width is not None and tensor.numel() == 0:
        tensor = tensor.reshape(0, width)
    return tensor


def calibration_from_dict(
    doc: dict[str, Any], *, origin: str = "calibration", dark_frame: torch.Tensor | None = None
) -> Calibration:
    """Inverse of :func:`calibration_to_dict` (the dark frame, stored apart, is passed in).

    Raises :class:`CalibrationFileError` naming ``origin``.
    """
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise CalibrationFileError(
            f"{origin} is not an lfm_studio calibration (its 'format' is not {FORMAT!r}). "
            "Fix: give the .json written by `lfm-studio calibrate`."
        )
    version = doc.get("version")
    if not isinstance(version, int) or version > CALIBRATION_VERSION or version < 1:
        raise CalibrationFileError(
            f"{origin} has calibration version {version!r}; this lfm_studio reads versions 1 to "
            f"{CALIBRATION_VERSION}. Fix: upgrade lfm_studio, or calibrate again with this one."
        )
    try:
        grid = None
        if "lattice" in doc:
            table = doc["lenslets"]
            grid = LatticeFit(
                lattice=LensletLattice.from_dict(doc["lattice"]),
                indices=_tensor(table["index_ij"], torch.int64, 2),
                measured=_tensor(table["measured_yx_px"], torch.float64, 2),
                residual=_tensor(table["residual_px"], torch.float64),
                mass=_tensor(table["light"], torch.float64),
                flags=_tensor(table["flags"], torch.int64),
            )
        sub, flat = None, None
        if "sub_images" in doc:
            s = doc["sub_images"]
            sub = SubImageFit(
                nominal=_tensor(s["nominal_yx_px"], torch.float64, 2),
                measured=_tensor(s["measured_yx_px"], torch.float64, 2),
                residual=_tensor(s["residual_px"], torch.float64),
                light=_tensor(s["light"], torch.float64),
                flags=_tensor(s["flags"], torch.int64),
                scale=float(s["scale"]),
                rotation=float(s["rotation_rad"]),
                shift=tuple(float(v) for v in s["shift_yx_px"]),  # type: ignore[arg-type]
            )
            if s.get("flat_field") is not None:
                flat = SubImageFlat(
                    coefficients=_tensor(s["flat_field"]["coefficients"], torch.float64),
                    radius=float(s["flat_field"]["radius_px"]),
                )
        coefficients = doc["flat_field_coefficients"]
        block = doc["lenslet_block"]
        return Calibration(
            kind=doc["kind"],
            frame_shape=tuple(int(v) for v in doc["frame_shape"]),  # type: ignore[arg-type]
            design=doc["design"],
            dark_level=float(doc["dark_level_adu"]),
            defects=_tensor(doc["defects_yx"], torch.int64, 2),
            envelope=None if coefficients is None else torch.tensor(coefficients, dtype=torch.float64),
            pixels_per_lenslet=doc["pixels_per_lenslet"],
            block=None if block is None else tuple(int(v) for v in block),  # type: ignore[arg-type]
            grid=grid,
            sub_images=sub,
            dark_frame=dark_frame,
            sub_image_flat=flat,
            version=version,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationFileError(
            f"{origin} is damaged or incomplete ({type(exc).__name__}: {exc}). Fix: calibrate again."
        ) from exc


_HASH_DIGITS = 16


def dark_frame_name(path: str | os.PathLike[str], sha256: str) -> str:
    """File name of the dark frame with SHA-256 ``sha256`` for the calibration ``path``.

    ``calib.json`` -> ``calib.dark.<first 16 hex digits>.npz``: a new dark frame never
    overwrites the one the existing JSON names.
    """
    return f"{Path(path).stem}.dark.{sha256[:_HASH_DIGITS]}.npz"


def _recorded_dark(target: Path) -> Path | None:
    """The dark-frame file the existing calibration ``target`` names, or None (no file,
    unreadable, no dark frame, or a name outside ``target``'s folder)."""
    try:
        entry = json.loads(target.read_text(encoding="utf-8")).get("dark_frame")
        name = str(entry["file"])
    except (OSError, UnicodeDecodeError, ValueError, AttributeError, TypeError, KeyError):
        return None
    if Path(name).name != name or not name.startswith(f"{target.stem}.dark") or not name.endswith(".npz"):
        return None  # never touch a file this calibration does not own
    return target.with_name(name)


def calibration_files(path: str | os.PathLike[str]) -> list[Path]:
    """The existing files of the calibration ``path``: the JSON and the dark frame it names.

    Empty when ``path`` does not exist; what to name before asking to replace a calibration.
    """
    target = Path(path).expanduser()
    if not target.exists():
        return []
    dark = _recorded_dark(target)
    return [target] + ([dark] if dark is not None and dark.exists() else [])


def _npz_bytes(frame: torch.Tensor) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, dark=frame.detach().cpu().to(torch.float32).numpy())
    return buffer.getvalue()


def _write_dark(target: Path, payload: bytes) -> dict[str, str]:
    """Write the dark frame ``payload`` (npz bytes) beside ``target`` under its content-addressed
    name; returns the JSON's ``dark_frame`` entry. A file of that name holds the same bytes
    (same SHA-256), so replacing it is harmless."""
    digest = hashlib.sha256(payload).hexdigest()
    sidecar = target.with_name(dark_frame_name(target, digest))
    atomic_write(sidecar, lambda fh: fh.write(payload), overwrite=True)
    return {"file": sidecar.name, "sha256": digest}


def save_calibration(
    calibration: Calibration, path: str | os.PathLike[str], *, overwrite: bool = False
) -> Path:
    """Write ``calibration`` to ``path`` (JSON, plus the dark frame beside it) atomically.

    Raises ``FileExistsError`` before writing anything when ``path`` exists and
    ``overwrite`` is False. With ``overwrite``, the old calibration stays loadable until
    the new JSON replaces it (module docstring); its dark frame is removed afterwards.
    """
    target = Path(path).expanduser()
    if target.exists() and not overwrite:
        raise FileExistsError(
            errno.EEXIST,
            f"{target} already exists. Fix: pass overwrite=True (--overwrite) or choose another name",
            str(target),
        )
    doc = calibration_to_dict(calibration)
    old_dark = _recorded_dark(target)
    if calibration.dark_frame is not None:
        doc["dark_frame"] = _write_dark(target, _npz_bytes(calibration.dark_frame))
    text = json.dumps(doc, indent=1) + "\n"
    atomic_write(target, lambda fh: fh.write(text.encode("utf-8")), overwrite=overwrite)
    if old_dark is not None and old_dark.name != doc.get("dark_frame", {}).get("file"):
        old_dark.unlink(missing_ok=True)  # the new JSON no longer names it
    return target


def _load_dark(entry: Any, folder: Path, origin: str) -> torch.Tensor:
    sidecar = folder / str(entry["file"])
    try:
        payload = sidecar.read_bytes()
    except OSError as exc:
        raise CalibrationFileError(
            f"{origin} needs its dark frame {sidecar}, which cannot be read ({exc.strerror}). "
            "Fix: keep the .npz file the .json names next to it (copy both), or calibrate again."
        ) from exc
    if hashlib.sha256(payload).hexdigest() != entry["sha256"]:
        raise CalibrationFileError(
            f"dark frame {sidecar} is not the one {origin} was written with (SHA-256 differs). "
            "Fix: restore the matching .npz file, or calibrate again."
        )
    with np.load(io.BytesIO(payload)) as data:
        return torch.from_numpy(data["dark"].copy())


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read a calibration file written by :func:`save_calibration`."""
    target = Path(path).expanduser()
    try:
        doc = json.loads(target.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CalibrationFileError(
            f"{target} is not a JSON calibration file ({exc}). Fix: give the .json "
            "written by `lfm-studio calibrate`."
        ) from exc
    dark = None
    if isinstance(doc, dict) and isinstance(doc.get("dark_frame"), dict):
        dark = _load_dark(doc["dark_frame"], target.parent, str(target))
    return calibration_from_dict(doc, origin=str(target), dark_frame=dark)
