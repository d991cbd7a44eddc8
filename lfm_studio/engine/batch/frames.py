"""Camera frames ``(T, Y, X)`` read lazily from a multi-page TIFF, a folder of TIFFs or a Zarr array.

A :class:`FrameSource` is a small picklable description (path and shape): each Dask task
opens it and reads only its own frames, so frame data never travels through the task graph
and a long video is never held in memory. :meth:`FrameSource.to_dask` gives the lazy
``dask.array`` view of the same frames.
"""

from __future__ import annotations

import hashlib
import os
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lfm_studio.engine.batch.extras import require_scale
from lfm_studio.engine.types import NumpyArray

require_scale()

import dask  # noqa: E402
import dask.array as da  # noqa: E402
import tifffile  # noqa: E402
import zarr  # noqa: E402
from tifffile.zarr import ZarrStore  # noqa: E402

TIFF_SUFFIXES = (".tif", ".tiff")
KINDS = ("tiff", "tiff-folder", "zarr")
OPEN_LIMIT = 2  # TIFF videos kept open per process
# Per-process open TIFFs: a TIFF's pages are a linked list, so opening it walks the page index;
# opening once per worker (not once per task) keeps a run linear in its length, and closing what
# is evicted keeps file handles and page indexes from piling up. Keyed by path, size and mtime:
# a rewritten file is opened afresh.
_OPEN: OrderedDict[tuple[str, int, int], tuple[ZarrStore, zarr.Array]] = OrderedDict()


def _open_tiff(path: str) -> zarr.Array:
    info = os.stat(path)
    key = (path, info.st_size, info.st_mtime_ns)
    if key in _OPEN:
        _OPEN.move_to_end(key)
        return _OPEN[key][1]
    store = tifffile.imread(path, aszarr=True)
    array = zarr.open(store, mode="r")
    if not isinstance(array, zarr.Array):
        store.close()
        raise ValueError(
            f"{path} holds a series of images, not one stack. Fix: pass one series (a multi-page TIFF)."
        )
    _OPEN[key] = (store, array)
    while len(_OPEN) > OPEN_LIMIT:
        old_store, _ = _OPEN.popitem(last=False)[1]
        old_store.close()
    return _OPEN[key][1]


def _zarr_array(path: Path) -> zarr.Array:
    """The array at ``path``: a Zarr array, or level 0 of an OME-Zarr image group."""
    node = zarr.open(str(path), mode="r")
    if isinstance(node, zarr.Array):
        return node
    level0 = node[_level0_path(dict(node.attrs), path)]
    if not isinstance(level0, zarr.Array):
        raise ValueError(f"{path}: the first multiscale dataset is a group, not an array.")
    return level0


def _first(value: object) -> object:
    """``value[0]`` of a non-empty JSON list, else None."""
    return value[0] if isinstance(value, Sequence) and not isinstance(value, str) and value else None


def _field(value: object, key: str) -> object:
    """``value[key]`` of a JSON object, else None."""
    return value.get(key) if isinstance(value, Mapping) else None


def _level0_path(attributes: Mapping[str, object], path: Path) -> str:
    """``multiscales[0]["datasets"][0]["path"]`` of an OME-Zarr group's ``attributes`` (NGFF 0.5 nests
    them under "ome")."""
    ome = attributes.get("ome")
    multiscales = (ome if isinstance(ome, Mapping) else attributes).get("multiscales")
    if not multiscales:
        raise ValueError(
            f"{path} is a Zarr group without OME 'multiscales' metadata, so it names no frame array. "
            "Fix: pass the array inside it (e.g. path/to/group/0)."
        )
    level0 = _field(_first(_field(_first(multiscales), "datasets")), "path")
    if level0 is None:
        raise ValueError(f"{path}: its OME 'multiscales' metadata names no dataset path.")
    return str(level0)


def frame_digest(frame: NumpyArray) -> str:
    """A 128-bit BLAKE2b digest of one frame's pixels, shape and dtype (a chunk record keeps it for
    each frame done, so a resume can tell whether the recording under it changed)."""
    data = np.ascontiguousarray(frame)
    digest = hashlib.blake2b(f"{data.shape}{data.dtype.str}".encode(), digest_size=16)
    digest.update(data.tobytes())
    return digest.hexdigest()


def _folder_files(path: Path) -> list[Path]:
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in TIFF_SUFFIXES and p.is_file())
    if not files:
        raise ValueError(f"frames folder {path} holds no .tif/.tiff files. Fix: point at the frames' folder.")
    return files


@dataclass(frozen=True)
class FrameSource:
    """Frames ``(T, Y, X)`` at ``path`` (``kind`` one of :data:`KINDS`), read on demand."""

    path: str
    kind: str
    shape: tuple[int, int, int]
    dtype: str

    @property
    def count(self) -> int:
        """Number of frames ``T``."""
        return self.shape[0]

    def _array(self) -> zarr.Array:
        return _open_tiff(self.path) if self.kind == "tiff" else _zarr_array(Path(self.path))

    def read(self, start: int, stop: int) -> NumpyArray:
        """Frames ``start:stop`` as a ``(stop - start, Y, X)`` array (only those pages are read)."""
        if not 0 <= start < stop <= self.count:
            raise ValueError(f"frames {start}:{stop} are outside 0:{self.count} of {self.path}.")
        if self.kind == "tiff-folder":
            files = _folder_files(Path(self.path))[start:stop]
            return np.stack([tifffile.imread(f) for f in files]).reshape(stop - start, *self.shape[1:])
        array = self._array()
        if array.ndim == 2:  # one (Y, X) frame: the source is (1, Y, X), so start:stop is 0:1
            return np.asarray(array[:, :]).reshape(1, *self.shape[1:])
        return np.asarray(array[start:stop]).reshape(stop - start, *self.shape[1:])

    def stamp(self) -> str:
        """SHA-256 of the names, sizes and modification times (ns) of the files holding the frames:
        changes when the recording is rewritten (a resume then checks the frames already done)."""
        root = Path(self.path)
        if self.kind == "tiff":
            files = [root]
        elif self.kind == "tiff-folder":
            files = _folder_files(root)
        else:
            files = sorted(p for p in root.rglob("*") if p.is_file())
        digest = hashlib.sha256()
        for file in files:
            info = file.stat()
            name = file.name if file == root else file.relative_to(root).as_posix()
            digest.update(f"{name}\0{info.st_size}\0{info.st_mtime_ns}\n".encode())
        return digest.hexdigest()

    def to_dask(self) -> da.Array:
        """The frames as a lazy ``dask.array`` (one chunk per frame for a folder)."""
        if self.kind == "tiff-folder":
            read = dask.delayed(tifffile.imread, pure=True)
            frames = [
                da.from_delayed(read(f), shape=self.shape[1:], dtype=self.dtype)
                for f in _folder_files(Path(self.path))
            ]
            return da.stack(frames)
        return da.from_zarr(self._array()).reshape(self.shape)


def _checked_shape(shape: tuple[int, ...], path: Path) -> tuple[int, int, int]:
    if len(shape) == 2:
        return (1, *shape)
    if len(shape) != 3:
        raise ValueError(
            f"{path} holds an array of shape {shape}; frames must be (T, Y, X) or one (Y, X) frame. "
            "Fix: save the video as (T, Y, X)."
        )
    t, y, x = (int(n) for n in shape)
    return t, y, x


def open_frames(path: str | os.PathLike) -> FrameSource:
    """Describe the frames at ``path``: a (multi-page) TIFF, a folder of single-frame TIFFs (sorted
    by name) or a Zarr/OME-Zarr array; nothing but the shape is read."""
    source = Path(path).expanduser().absolute()  # workers may run elsewhere: no relative paths
    if not source.exists():
        raise FileNotFoundError(f"frames {source} do not exist. Fix: check the path.")
    if source.is_file() and source.suffix.lower() in TIFF_SUFFIXES:
        with tifffile.TiffFile(source) as tif:
            series = tif.series[0]
            shape, dtype = _checked_shape(tuple(series.shape), source), str(series.dtype)
        return FrameSource(str(source), "tiff", shape, dtype)
    if source.is_dir() and any((source / name).exists() for name in ("zarr.json", ".zarray", ".zgroup")):
        array = _zarr_array(source)
        return FrameSource(str(source), "zarr", _checked_shape(tuple(array.shape), source), str(array.dtype))
    if source.is_dir():
        files = _folder_files(source)
        with tifffile.TiffFile(files[0]) as tif:
            first = tuple(tif.series[0].shape)
            dtype = str(tif.series[0].dtype)
        if len(first) != 2:
            raise ValueError(
                f"{files[0]} has shape {first}; a frames folder holds one (Y, X) frame per file. "
                "Fix: save one frame per file, or pass a multi-page TIFF."
            )
        return FrameSource(str(source), "tiff-folder", (len(files), *first), dtype)
    raise ValueError(
        f"frames {source} are not a .tif/.tiff file, a folder of TIFFs or a Zarr array. Fix: convert them."
    )
