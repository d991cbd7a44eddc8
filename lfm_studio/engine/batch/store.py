"""The OME-Zarr output of a video reconstruction: NGFF 0.5 on Zarr v3, axes t, z, y, x.

Layout of ``run.ome.zarr``::

    zarr.json               group: "ome" multiscales (scales in s and um) + "lfm_studio" run record
    0/, 1/, ...             float32 levels (T, Z, Y / 2**k, X / 2**k), one Zarr chunk per frame
    lfm_studio_status/      a group holding one JSON record per finished frame chunk

A chunk's record (every frame "done" or "failed" with its error) is written atomically after
its frames. A resumed run computes the chunks without a record and, in chunks with one, only the
frames recorded as failed (then replaces that record atomically); a frame recorded as done is
never computed or written again. The store itself appears atomically (built in a hidden
folder next to it, then renamed), so a run that fails before its first chunk leaves nothing.
An overwrite run builds its store at a hidden sibling (``.run.ome.zarr.replacing``) and puts it
in place of the old one only when its run ends: a cancelled or failed replacement leaves the
previous store as it was.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, NotRequired, TypeAlias, TypedDict, TypeGuard

import numpy as np
import numpy.typing as npt

from lfm_studio.engine.atomic_write import atomic_write
from lfm_studio.engine.batch.extras import require_scale
from lfm_studio.engine.batch.pyramid import level_shape, level_transforms, pyramid
from lfm_studio.engine.types import JSONValue

require_scale()

import zarr  # noqa: E402
from ome_zarr.format import FormatV05  # noqa: E402
from ome_zarr.writer import write_multiscales_metadata  # noqa: E402

STATUS_GROUP = "lfm_studio_status"
FRAMES_STAMP = "frames_stamp.json"  # in STATUS_GROUP: the stamp of the frames file(s) last read
RUN_KEY = "lfm_studio"  # our attributes in the root group
AXES = (
    {"name": "t", "type": "time", "unit": "second"},
    {"name": "z", "type": "space", "unit": "micrometer"},
    {"name": "y", "type": "space", "unit": "micrometer"},
    {"name": "x", "type": "space", "unit": "micrometer"},
)


class FrameDone(TypedDict):
    """A chunk record's entry for a reconstructed frame (``attempts``: tries over every run,
    failed ones of earlier runs included; ``digest``: :func:`~.frames.frame_digest` of the frame
    read, absent in records written before it was kept)."""

    status: Literal["done"]
    attempts: int
    digest: NotRequired[str]


class FrameFailed(TypedDict):
    """A chunk record's entry for a frame that failed every attempt (its volume stays 0; a resumed
    run tries it again)."""

    status: Literal["failed"]
    attempts: int
    error: str  # "ExceptionType: message" of the last attempt


FrameStatus: TypeAlias = FrameDone | FrameFailed


class ChunkSeconds(TypedDict):
    """Wall-clock seconds a chunk spent on each step."""

    projector: float
    read: float
    compute: float
    write: float


class ChunkRecord(TypedDict):
    """The JSON record of a finished work chunk (``frames``: frame index as a string -> its status)."""

    chunk: int
    start: int
    stop: int
    frames: dict[str, FrameStatus]
    run_id: str
    worker: str
    seconds: ChunkSeconds


def _is_int(value: object) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_frame_status(value: object) -> TypeGuard[FrameStatus]:
    if not isinstance(value, dict) or not _is_int(value.get("attempts")):
        return False
    status = value.get("status")
    return status == "done" or (status == "failed" and isinstance(value.get("error"), str))


def _is_chunk_record(value: object) -> TypeGuard[ChunkRecord]:
    """True when ``value`` (e.g. read back from a record's JSON) has every field of a :class:`ChunkRecord`."""
    if not isinstance(value, dict):
        return False
    frames, seconds = value.get("frames"), value.get("seconds")
    return (
        all(_is_int(value.get(key)) for key in ("chunk", "start", "stop"))
        and all(isinstance(value.get(key), str) for key in ("run_id", "worker"))
        and isinstance(frames, dict)
        and all(isinstance(t, str) and _is_frame_status(info) for t, info in frames.items())
        and isinstance(seconds, dict)
        and all(isinstance(seconds.get(key), (int, float)) for key in ChunkSeconds.__required_keys__)
    )


def _read_record(path: Path) -> ChunkRecord:
    fix = "Fix: delete it (that chunk is then computed again)."
    try:
        record = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path} is not a readable chunk record of lfm_studio ({error}). {fix}") from None
    if not _is_chunk_record(record):
        raise ValueError(f"{path} is not a chunk record of lfm_studio. {fix}")
    return record


def _json_value(value: object) -> JSONValue:
    """``value`` (a JSON document as zarr or :mod:`json` returns it) as a :data:`JSONValue`
    (mappings become dicts, sequences lists); ValueError for anything JSON cannot hold."""
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    if isinstance(value, Mapping):
        if not all(isinstance(key, str) for key in value):
            raise ValueError(f"a JSON object has a key that is not a string: {value!r}")
        return {key: _json_value(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_value(item) for item in value]
    raise ValueError(f"{value!r} is not a JSON value")


@dataclass(frozen=True)
class VideoStore:
    """Where and how a run writes (small and picklable: tasks carry it)."""

    path: str
    shape: tuple[int, int, int, int]  # level 0 (T, Z, Y, X)
    levels: int
    chunk_frames: int

    def chunks(self) -> list[tuple[int, int]]:
        """``(start, stop)`` frame ranges of the work chunks, in order."""
        count, size = self.shape[0], self.chunk_frames
        return [(start, min(start + size, count)) for start in range(0, count, size)]

    def record_path(self, index: int) -> Path:
        """The JSON record of work chunk ``index``."""
        return Path(self.path) / STATUS_GROUP / f"chunk_{index:06d}.json"

    def write_frames(self, start: int, volumes: npt.NDArray[np.float32], keep: npt.NDArray[np.bool_]) -> None:
        """Frames ``start + i`` for each ``keep[i]``, at every pyramid level (``volumes``: ``(n, Z, Y, X)``)."""
        group = zarr.open_group(self.path, mode="r+")
        for level, data in enumerate(pyramid(volumes, self.levels)):
            array = _array(group, str(level))
            for i in np.flatnonzero(keep):
                array[start + int(i)] = data[i]

    def write_record(self, index: int, record: ChunkRecord, *, replace: bool = False) -> None:
        """Record chunk ``index`` as finished (atomic). An existing record is refused
        (``FileExistsError``) unless ``replace`` (a resumed run that computed its failed frames again)."""
        text = json.dumps(record, indent=1, allow_nan=False).encode()
        atomic_write(self.record_path(index), lambda fh: fh.write(text), overwrite=replace)

    def record(self, index: int) -> ChunkRecord | None:
        """The record of chunk ``index``, or None while it is not finished (ValueError for a malformed one)."""
        try:
            return _read_record(self.record_path(index))
        except FileNotFoundError:
            return None

    def records(self) -> dict[int, ChunkRecord]:
        """Finished chunks: index -> record."""
        return read_records(self.path)

    def frames_stamp(self) -> str | None:
        """The :meth:`~.frames.FrameSource.stamp` of the frames this store's frames were read from
        (None for a store written before it was kept)."""
        try:
            stamp = json.loads((Path(self.path) / STATUS_GROUP / FRAMES_STAMP).read_text()).get("stamp")
        except FileNotFoundError:
            return None
        return stamp if isinstance(stamp, str) else None

    def write_frames_stamp(self, stamp: str) -> None:
        """Keep ``stamp`` (atomic; replaces the one kept before)."""
        text = json.dumps({"stamp": stamp}).encode()
        atomic_write(Path(self.path) / STATUS_GROUP / FRAMES_STAMP, lambda fh: fh.write(text), overwrite=True)

    def attributes(self) -> dict[str, JSONValue]:
        """The run record stored under ``"lfm_studio"`` in the root group."""
        return run_attributes(zarr.open_group(self.path, mode="r"))


def read_records(path: str | os.PathLike) -> dict[int, ChunkRecord]:
    """The finished chunks of the store at ``path``: index -> record (ValueError for a malformed one)."""
    found = {}
    for file in sorted((Path(path) / STATUS_GROUP).glob("chunk_*.json")):
        found[int(file.stem.split("_")[1])] = _read_record(file)
    return found


@dataclass(frozen=True)
class FrameReport:
    """Which frames of a store hold no reconstruction (their volumes are zeros, not data).

    Attributes
    ----------
    failed : frame -> the error recorded when its reconstruction failed.
    missing : frames not computed yet (a cancelled, killed or running run: resume finishes them).
    """

    failed: dict[int, str]
    missing: tuple[int, ...]

    def summary(self) -> str | None:
        """One sentence for a viewer ("frames 3, 7 failed; 4 not computed yet: their volumes are
        zeros"), or None when every frame holds a reconstruction."""
        parts = []
        if self.failed:
            parts.append(f"frame(s) {listed_frames(self.failed)} failed")
        if self.missing:
            parts.append(
                f"frame(s) {listed_frames(self.missing)} not computed yet (resume the run to finish them)"
            )
        return None if not parts else "; ".join(parts) + ": their volumes are zeros, not data."


def listed_frames(frames: Iterable[int], most: int = 8) -> str:
    """``frames`` in order, the first ``most`` named: ``"3, 7, 9 and 12 more"``."""
    ordered = sorted(frames)
    text = ", ".join(str(t) for t in ordered[:most])
    return text + (f" and {len(ordered) - most} more" if len(ordered) > most else "")


def frame_report(path: str | os.PathLike) -> FrameReport:
    """The frames of the store at ``path`` that hold no reconstruction (from its chunk records)."""
    count = int(_array(zarr.open_group(str(path), mode="r"), "0").shape[0])
    failed: dict[int, str] = {}
    recorded: set[int] = set()
    for record in read_records(path).values():
        for key, info in record["frames"].items():
            recorded.add(int(key))
            if info["status"] == "failed":
                failed[int(key)] = info["error"]
    return FrameReport(dict(sorted(failed.items())), tuple(t for t in range(count) if t not in recorded))


def run_attributes(group: zarr.Group) -> dict[str, JSONValue]:
    """The run record stored under :data:`RUN_KEY` in a store's root group (KeyError when absent)."""
    record = _json_value(dict(group.attrs)[RUN_KEY])
    if not isinstance(record, dict):
        raise ValueError(f"the {RUN_KEY!r} attribute is not a record: {record!r}")
    return record


def _array(group: zarr.Group, name: str) -> zarr.Array:
    node = group[name]
    if not isinstance(node, zarr.Array):
        raise ValueError(f"{name} in {group.store} is a group, not an array")
    return node


def _shape4(shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    t, z, y, x = (int(n) for n in shape)
    return t, z, y, x


def _write_layout(
    folder: Path, shape: tuple[int, int, int, int], scale: tuple[float, float, float, float],
    origin: tuple[float, float, float, float], levels: int, name: str, attributes: dict[str, JSONValue],
) -> None:  # fmt: skip
    group = zarr.open_group(str(folder), mode="w-", zarr_format=3)
    datasets = []
    for level in range(levels):
        lshape = level_shape(shape, level)
        group.create_array(
            str(level), shape=lshape, chunks=(1, *lshape[1:]), dtype="float32", fill_value=0.0,
            dimension_names=[axis["name"] for axis in AXES],
        )  # fmt: skip
        datasets.append(
            {"path": str(level), "coordinateTransformations": level_transforms(scale, level, origin)}
        )
    write_multiscales_metadata(group, datasets, fmt=FormatV05(), axes=[dict(a) for a in AXES], name=name)
    group.attrs.update({RUN_KEY: attributes})
    zarr.open_group(str(folder / STATUS_GROUP), mode="w-", zarr_format=3)


def replacement_path(path: str | os.PathLike) -> Path:
    """The hidden sibling of the store ``path`` where an overwrite run builds its replacement."""
    target = Path(path).expanduser().absolute()
    return target.with_name(f".{target.name}.replacing")


def _remove(path: Path) -> None:
    """Delete ``path`` (a folder or a file) when it exists."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def create_store(
    path: str | os.PathLike,
    *,
    shape: tuple[int, int, int, int],
    scale: tuple[float, float, float, float],
    origin: tuple[float, float, float, float],
    levels: int,
    chunk_frames: int,
    attributes: dict[str, JSONValue],
    overwrite: bool = False,
) -> VideoStore:
    """A new empty store at ``path``, created atomically; level-0 ``scale`` ``(t s, z um, y um, x um)``
    and ``origin`` (the coordinates of voxel ``(0, 0, 0, 0)``, same units).

    An existing ``path`` is refused unless ``overwrite``. Then it is left untouched: the new store
    is built at :func:`replacement_path` (a stale one, left by a killed run, is cleared first) and
    the store returned lives there until :func:`replace_store` puts it in place of ``path`` (when
    its run ends) or :func:`discard_store` drops it (the run was cancelled or failed).
    """
    target = Path(path).expanduser().absolute()
    if target.exists() and not overwrite:
        raise FileExistsError(
            f"{target} already exists. Fix: pass resume=True / --resume to finish it, overwrite=True / "
            "--overwrite to replace it, or choose another output."
        )
    if not target.parent.is_dir():
        raise FileNotFoundError(f"folder {target.parent} does not exist. Fix: create it first.")
    location = target
    if target.exists():
        location = replacement_path(target)
        _remove(location)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        shutil.rmtree(staging)  # zarr creates the folder itself (mode "w-")
        _write_layout(staging, shape, scale, origin, levels, target.stem, attributes)
        os.replace(staging, location)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return VideoStore(str(location), shape, levels, chunk_frames)


def _old_path(target: Path) -> Path:
    """Where :func:`replace_store` moves the old store between its two renames."""
    return target.with_name(f".{target.name}.old")


def finish_interrupted_replacement(path: str | os.PathLike) -> str | None:
    """Complete a :func:`replace_store` that a crash stopped between its two renames (the store at
    ``path`` gone, the old one at its hidden ``.old`` sibling); returns what was done, or None.

    The replacement is complete when it is there (``replace_store`` runs only after its run
    ended): it goes in place and the old store is deleted; without it the old store goes back."""
    target = Path(path).expanduser().absolute()
    old, new = _old_path(target), replacement_path(target)
    if target.exists() or not old.is_dir():
        return None
    if new.is_dir():
        os.replace(new, target)
        _remove(old)
        return f"{target}: a replacement stopped between its two renames was completed (the new store is in place)."
    os.replace(old, target)
    return f"{target}: a replacement stopped between its two renames was undone (the previous store is back)."


def replace_store(store: VideoStore, path: str | os.PathLike) -> VideoStore:
    """Put ``store`` (built at :func:`replacement_path` of ``path``) in place of the store at
    ``path``, which is deleted; returns the store at ``path``. A crash between the two renames is
    completed by the next run on ``path`` (:func:`finish_interrupted_replacement`)."""
    target = Path(path).expanduser().absolute()
    trash = _old_path(target)
    _remove(trash)
    if target.exists() or target.is_symlink():
        os.replace(target, trash)
    os.replace(store.path, target)
    _remove(trash)
    return VideoStore(str(target), store.shape, store.levels, store.chunk_frames)


def discard_store(store: VideoStore) -> None:
    """Delete ``store``: an unfinished replacement whose run was cancelled or failed."""
    shutil.rmtree(store.path, ignore_errors=True)


def _stored_int(stored: dict[str, JSONValue], key: str) -> int:
    value = stored[key]
    if not isinstance(value, (int, float, str)):  # what int() took before the record was typed
        raise ValueError(f"the {RUN_KEY!r} attribute {key!r} is not a number: {value!r}")
    return int(value)


RUN_ITEMS = {
    "frames": "the frames (frames= / --image)",
    "projector": "the design or PSF (design_or_psf= / --psf)",
    "options": "the method options (method=, options= / --method, --iterations, ...)",
    "chunk_frames": "chunk_frames= / --chunk-frames",
    "camera": "the camera conversion (camera= / --baseline, --gain, ...)",
    "calibration": "the calibration (calibration=, lenslets= / --calibration, --lenslets)",
}
"""A run record's items in the user's words (Python keyword / command-line option)."""


def _shown(value: JSONValue) -> str | None:
    """``value`` as JSON when it is short enough for a message, else None."""
    text = json.dumps(value)
    return text if len(text) <= 40 else None


def _difference(key: str, stored: JSONValue, now: JSONValue) -> str:
    """How run item ``key`` differs between the store (``stored``) and this run (``now``): named in
    the user's words, with each differing field's two values when they are short."""
    label = RUN_ITEMS.get(key, key)
    if isinstance(stored, dict) and isinstance(now, dict):
        fields = sorted(name for name in {*stored, *now} if stored.get(name) != now.get(name))
        pairs = [(name, stored.get(name), now.get(name)) for name in fields]
    else:
        pairs = [(key, stored, now)]
    details = []
    for name, old, new in pairs:
        shown_old, shown_new = _shown(old), _shown(new)
        if shown_old is None or shown_new is None:
            details.append(f"{name} changed")
        else:
            details.append(f"{name} {shown_old} in the store, {shown_new} now")
    return f"{label} differs ({', '.join(details)})"


def open_store(path: str | os.PathLike, *, run: dict[str, JSONValue]) -> VideoStore:
    """The existing store at ``path``, refused when its run record differs from ``run`` (another
    video, design, method or chunking: resuming would mix two reconstructions)."""
    target = Path(path).expanduser().absolute()
    try:
        group = zarr.open_group(str(target), mode="r")
        stored = run_attributes(group)
        stored_run = stored["run"]
        if not isinstance(stored_run, dict):
            raise ValueError(f"the {RUN_KEY!r} attribute 'run' is not a record: {stored_run!r}")
    except (FileNotFoundError, KeyError, ValueError) as error:
        raise ValueError(
            f"{target} is not an lfm_studio video store ({error}). Fix: choose another output, or pass "
            "overwrite=True / --overwrite to replace it."
        ) from error
    now = {key: json.loads(json.dumps(value)) for key, value in run.items()}
    different = [
        _difference(key, stored_run.get(key), now[key])
        for key in sorted(now)
        if stored_run.get(key) != now[key]
    ]
    if different:
        raise ValueError(
            f"{target} was written by a different run: {'; '.join(different)}. Resuming would mix two "
            "reconstructions. Fix: use the same inputs and options as that run, another output, or "
            "overwrite=True / --overwrite to replace it."
        )
    return VideoStore(
        str(target),
        _shape4(_array(group, "0").shape),
        _stored_int(stored, "levels"),
        _stored_int(stored, "chunk_frames"),
    )
