"""napari reader for OME-Zarr images (NGFF 0.4/0.5), e.g. the stores of ``reconstruct_video``.

The levels open lazily as ``dask.array`` s (napari loads only the chunks it shows), as one
multiscale layer with the level-0 scale and translation (um, and s for time), axis labels
and units from the file. Needs the ``scale`` extra (``pip install "lfm-studio[scale]"``);
without it, or for a Zarr store that is not an OME image, :func:`get_zarr_reader` returns
None so napari asks its other readers (e.g. napari-ome-zarr).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lfm_studio.napari_plugin.layer_data import LayerData

UNIT_NAMES = {"micrometer": "um", "second": "s", "millisecond": "ms", "nanometer": "nm"}


def _multiscales(path: Path) -> list[dict[str, Any]] | None:
    """The OME ``multiscales`` of the group at ``path`` (Zarr v3 ``zarr.json`` or v2 ``.zattrs``)."""
    for name, key in (("zarr.json", "attributes"), (".zattrs", None)):
        file = path / name
        if file.is_file():
            try:
                document = json.loads(file.read_text())
            except (OSError, json.JSONDecodeError):
                return None
            attributes = document.get(key, {}) if key else document
            found = attributes.get("ome", attributes).get("multiscales")
            return found if isinstance(found, list) and found else None
    return None


def get_zarr_reader(path: Any) -> Callable[[Any], list[LayerData]] | None:
    """:func:`read_ome_zarr` for a folder holding an OME-Zarr image, else None."""
    if isinstance(path, (list, tuple)):
        if len(path) != 1:
            return None
        path = path[0]
    if not isinstance(path, (str, Path)) or not Path(path).is_dir() or _multiscales(Path(path)) is None:
        return None
    try:
        import dask.array  # noqa: F401
        import zarr  # noqa: F401
    except ImportError:
        return None
    return read_ome_zarr


def _transform(transforms: list[dict[str, Any]], kind: str, default: float, n: int) -> tuple[float, ...]:
    for transform in transforms:
        if transform.get("type") == kind:
            return tuple(float(v) for v in transform[kind])
    return (default,) * n


def read_ome_zarr(path: Any) -> list[LayerData]:
    """One lazy multiscale image layer of the OME-Zarr image at ``path``; a video store whose failed
    or not yet computed frames hold zeros says so in a warning, the layer name and its metadata."""
    return ome_zarr_layers(path, warn=True)


def _frame_report(folder: Path) -> Any:
    """The store's :class:`~lfm_studio.engine.batch.store.FrameReport`, or None where it cannot be read."""
    try:
        from lfm_studio.engine.batch.store import frame_report

        return frame_report(folder)
    except (ImportError, OSError, ValueError, KeyError):  # no scale extra, or not a video store of ours
        return None


def ome_zarr_layers(path: Any, *, warn: bool) -> list[LayerData]:
    """:func:`read_ome_zarr`; ``warn=False`` leaves the warning on zero frames to the caller."""
    import dask.array as da
    import zarr

    folder = Path(path[0] if isinstance(path, (list, tuple)) else path)
    multiscale = (_multiscales(folder) or [{}])[0]
    group = zarr.open_group(str(folder), mode="r")
    datasets = multiscale["datasets"]
    levels = [da.from_zarr(group[d["path"]]) for d in datasets]
    ndim = levels[0].ndim
    transforms = datasets[0].get("coordinateTransformations", [])
    axes = multiscale.get("axes", [])
    names = [a["name"] if isinstance(a, dict) else str(a) for a in axes] or [f"axis {i}" for i in range(ndim)]
    units = [UNIT_NAMES.get(a.get("unit", ""), a.get("unit") or "pixel") for a in axes if isinstance(a, dict)]
    ours = dict(group.attrs).get("lfm_studio")
    meta: dict[str, Any] = {
        "name": multiscale.get("name") or folder.stem,
        "scale": _transform(transforms, "scale", 1.0, ndim),
        "translate": _transform(transforms, "translation", 0.0, ndim),
        "axis_labels": tuple(names),
        "multiscale": len(levels) > 1,
        "colormap": "inferno",
        "metadata": {
            "kind": "volume video" if ours else "ome-zarr",
            "lfm_studio": ours,
            "source": str(folder),
        },
    }
    if len(units) == ndim:
        meta["units"] = tuple(units)
    report = _frame_report(folder) if ours else None
    if report is not None and (report.failed or report.missing):
        meta["metadata"] |= {"failed_frames": report.failed, "missing_frames": list(report.missing)}
        counts = [
            f"{n} {what}"
            for n, what in ((len(report.failed), "failed"), (len(report.missing), "not computed"))
            if n
        ]
        meta["name"] = f"{meta['name']} ({', '.join(counts)})"
        if warn:
            from lfm_studio.napari_plugin.notify import report_warning

            report_warning(f"{folder.name}: {report.summary()}")
    return [(levels if len(levels) > 1 else levels[0], meta, "image")]
