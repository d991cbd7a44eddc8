"""Low-level ImageJ hyperstack writing and reading with tifffile (numpy at this boundary).

Writes float32 (uint8/uint16 are kept: ImageJ supports them natively) with the
ImageJ description ``axes``/``spacing``/``unit=um`` and X/YResolution in pixels
per micrometre, which is what Fiji and napari's TIFF readers use for the
physical scale; our JSON header goes into the ImageJ ``Info`` property.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
import torch

from lfm_studio.engine.atomic_write import atomic_write
from lfm_studio.engine.io.calibration import Calibration, read_calibration
from lfm_studio.engine.io.file_checks import InputFileError, check_tiff_name, output_os_error
from lfm_studio.engine.io.metadata import HeaderError
from lfm_studio.engine.units import um

_KEPT_DTYPES = (np.uint8, np.uint16)
SQUARE_TOLERANCE = 1e-6  # relative; ImageJ stores resolutions as rationals


def tiff_array(name: str, data: Any) -> tuple[np.ndarray, str]:
    """``data`` (tensor or array) as a C-contiguous array ImageJ can store, and its source dtype.

    Complex and empty data are refused; uint8/uint16 are kept; bool becomes uint8; every other
    real type (float64, float16, int32, ...) becomes float32, which must stay finite.
    """
    if isinstance(data, torch.Tensor):
        source = str(data.dtype).removeprefix("torch.")
        if data.is_complex():
            raise TypeError(f"{name} is complex ({data.dtype}); TIFF stores real data. Fix: save abs(x)**2.")
        if data.dtype == torch.bfloat16:
            data = data.float()
        array = data.detach().cpu().numpy()
    else:
        array = np.asarray(data)
        source = str(array.dtype)
        if np.iscomplexobj(array):
            raise TypeError(f"{name} is complex ({array.dtype}); TIFF stores real data. Fix: save abs(x)**2.")
    if array.dtype == np.bool_:
        array = array.astype(np.uint8)
    elif array.dtype.type not in _KEPT_DTYPES:
        if array.dtype.kind not in "fiu":
            raise TypeError(f"{name} has dtype {array.dtype}; expected a real numeric tensor.")
        with np.errstate(over="ignore", invalid="ignore"):
            converted = array.astype(np.float32)
        if not np.isfinite(converted).all():
            bad = int((~np.isfinite(converted)).sum())
            raise ValueError(
                f"{name} has {bad} value(s) that are NaN/Inf or outside the float32 range (|x| < 3.4e38) "
                "used in the TIFF. Fix: clean or rescale the data before saving."
            )
        array = converted
    if array.size == 0:
        raise ValueError(
            f"{name} is empty (shape {array.shape}): a TIFF holds at least one pixel. Nothing was written. "
            "Fix: check the data (a crop or slice that selected nothing?)."
        )
    return np.ascontiguousarray(array), source


def write_hyperstack(
    path: str | os.PathLike,
    array: np.ndarray,
    *,
    axes: str,
    pixel_size: tuple[float, float],
    z_spacing: float | None,
    labels: list[str] | None,
    info: str,
    overwrite: bool,
) -> Path:
    """Write ``array`` (axes e.g. ``"TZYX"``) as an ImageJ hyperstack, atomically.

    ``pixel_size`` is ``(dy, dx)`` and ``z_spacing`` the ImageJ slice spacing, in metres.
    ``path`` must end in ``.tif`` or ``.tiff`` (:func:`check_tiff_name`).
    """
    check_tiff_name(path)
    metadata: dict[str, Any] = {"axes": axes, "unit": "um", "Info": info}
    if z_spacing is not None:
        metadata["spacing"] = z_spacing / um
    if labels:
        metadata["Labels"] = labels
    resolution = (um / pixel_size[1], um / pixel_size[0])  # pixels per um, (x, y)

    def write(fh) -> None:
        tifffile.imwrite(fh, array, imagej=True, resolution=resolution, metadata=metadata)

    try:
        return atomic_write(path, write, overwrite=overwrite)
    except (FileExistsError, IsADirectoryError, FileNotFoundError):
        raise
    except OSError as error:  # read-only folder, full disk: atomic_write left nothing behind
        raise output_os_error(Path(path).expanduser(), error) from error


@dataclass(frozen=True)
class RawTiff:
    """What a TIFF holds: its first series, the series axes, the ImageJ Info text, its spacing."""

    array: np.ndarray
    axes: str
    info: str | None
    calibration: Calibration


_TRUNCATED_FIX = "Fix: write or copy the file again (an interrupted copy or download leaves it short)."
_UNREADABLE = (tifffile.TiffFileError, ValueError, OSError, EOFError, IndexError, struct.error)


def _unreadable(source: Path, error: BaseException) -> InputFileError:
    return InputFileError(
        f"{source} is truncated or corrupt, or not a TIFF ({type(error).__name__}: {error}). {_TRUNCATED_FIX}"
    )


@contextlib.contextmanager
def _tifffile_log_held() -> Iterator[None]:
    """Hold tifffile's log records while a file is read: dropped when we refuse the file with our own
    error (which says more, e.g. "ImageJ series metadata invalid" before "truncated"), passed on when
    the read succeeds."""
    held: list[logging.LogRecord] = []
    logger = logging.getLogger("tifffile")

    class _Hold(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            held.append(record)

    handler, propagate = _Hold(), logger.propagate
    logger.addHandler(handler)
    logger.propagate = False
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate
    for record in held:  # only reached when the read succeeded
        logger.handle(record)


def read_hyperstack(path: str | os.PathLike) -> RawTiff:
    """Read the first image series of any TIFF, with its ImageJ Info and calibration.

    A file that tifffile cannot parse or whose data ends early raises :class:`InputFileError`
    naming it (not tifffile's "failed to read N bytes"), and tifffile's own warnings about it
    are not printed beside that error.
    """
    source = Path(path).expanduser()
    if not source.is_file():
        raise FileNotFoundError(f"No such TIFF file: {source}")
    with _tifffile_log_held():
        return _read_series(source)


def _read_series(source: Path) -> RawTiff:
    try:
        tif = tifffile.TiffFile(source)
    except PermissionError as error:  # an OSError, but not a damaged file: say so
        raise InputFileError(
            f"{source} is not readable (permission denied). Fix: change its permissions or copy it somewhere "
            "you can read."
        ) from error
    except _UNREADABLE as error:
        raise _unreadable(source, error) from error
    with tif:
        try:
            series = tif.series[0]
            array = series.asarray()
            info = (tif.imagej_metadata or {}).get("Info") if tif.is_imagej else None
        except _UNREADABLE as error:
            raise _unreadable(source, error) from error
        announced = (tif.imagej_metadata or {}).get("images") if tif.is_imagej else None
        planes = math.prod(n for n, axis in zip(series.shape, series.axes, strict=True) if axis not in "YXS")
        if isinstance(announced, int) and planes < announced:  # tifffile fell back to the pages it could read
            raise InputFileError(
                f"{source} is truncated: its ImageJ header announces {announced} images but only {planes} "
                f"could be read ({source.stat().st_size} bytes on disk). {_TRUNCATED_FIX}"
            )
        return RawTiff(array=array, axes=series.axes, info=info, calibration=read_calibration(tif))


def to_tensor(
    array: np.ndarray, dtype: torch.dtype, device: torch.device | str | None, *, name: str = "the TIFF"
) -> torch.Tensor:
    """numpy -> real floating tensor of ``dtype`` on ``device``; complex data (``name`` is the file) is refused."""
    if np.iscomplexobj(array):
        raise InputFileError(
            f"{name} holds complex data ({array.dtype}); images, volumes and PSF stacks are real intensities "
            "(the real part alone would be a silently wrong result). Fix: save the intensity |x|^2."
        )
    if not dtype.is_floating_point:
        raise TypeError(f"dtype must be a real floating torch dtype (float32, float64); got {dtype}.")
    numpy_type = np.float64 if dtype == torch.float64 else np.float32
    return torch.from_numpy(np.ascontiguousarray(array, dtype=numpy_type)).to(device=device, dtype=dtype)


def as_stack(raw: RawTiff, path: str, *, min_ndim: int, max_ndim: int, what: str) -> np.ndarray:
    """A foreign series as ``(..., Y, X)`` with ``min_ndim..max_ndim`` dims (singletons squeezed).

    Channels (``C``) and interleaved colour samples (``...YXS``) of size > 1 are refused:
    a volume or a PSF stack is one fluorescence channel.
    """
    array, axes = raw.array, raw.axes if len(raw.axes) == raw.array.ndim else ""
    if axes.endswith("S") and array.shape[-1] == 1:
        array, axes = array[..., 0], axes[:-1]
    keep = [i for i, n in enumerate(array.shape) if n > 1 or i >= array.ndim - 2]
    array = array.reshape([array.shape[i] for i in keep])
    axes = "".join(axes[i] for i in keep) if axes else ""
    # A leading (planar) S is what a plain tifffile.imwrite of a (3 or 4, Y, X) array gives:
    # read it as a stack axis. A trailing (interleaved) S is a colour image: refuse it.
    for found, meaning in (("C" in axes[:-2], "channels"), (axes.endswith("S"), "colour samples (RGB)")):
        if found:
            raise ValueError(
                f"{path} has {meaning} (axes {raw.axes}, shape {raw.array.shape}); a {what} is one "
                "grayscale channel. Fix: split the channels (e.g. in Fiji) and read one."
            )
    while array.ndim < min_ndim:
        array = array[None]
    if array.ndim > max_ndim:
        raise ValueError(
            f"{path} holds a {array.ndim}-D series (axes {raw.axes}, shape {raw.array.shape}); a {what} "
            f"has at most {max_ndim} dimensions. Fix: save one {what} per file."
        )
    return array


def mean_step(depths: tuple[float, ...]) -> float | None:
    """ImageJ's single slice spacing for a (possibly non-uniform) depth list, metres."""
    if len(depths) < 2:
        return None
    return abs(depths[-1] - depths[0]) / (len(depths) - 1)


def depth_labels(depths: tuple[float, ...], frames: int) -> list[str]:
    """ImageJ slice labels ``"z=-12.5 um"``, repeated for every frame."""
    return [f"z={z / um:.6g} um" for z in depths] * frames


def square_pixel(dy: float | None, dx: float | None, path: str) -> float | None:
    """The file's lateral pixel size, refusing non-square pixels."""
    if dy is None or dx is None:
        return dx if dy is None else dy
    if abs(dy - dx) > SQUARE_TOLERANCE * max(dy, dx):
        raise ValueError(
            f"{path} has non-square pixels (dy={dy / um:.6g} um, dx={dx / um:.6g} um); PSF stacks and "
            "images need square pixels. Fix: resample the file, or pass pixel_size explicitly."
        )
    return dx


def reshape_to_header(array: np.ndarray, shape: list[int], path: str) -> np.ndarray:
    """The stored series in the shape our header recorded (tifffile squeezes singletons)."""
    if array.size != math.prod(shape):
        raise HeaderError(
            f"{path}: the data ({array.shape}) no longer matches its lfm_studio header (shape {shape}); "
            "the file was probably edited in another program. Fix: re-export it from lfm_studio, or "
            "remove the Info property (Fiji: Image > Show Info) so it is read as a foreign TIFF."
        )
    return array.reshape(shape)
