"""Scale-out: light-field video reconstruction on Dask into resumable OME-Zarr stores.

Needs the optional ``scale`` extra (``pip install "lfm-studio[scale]"``: dask[distributed],
zarr, ome-zarr); importing this package without it raises
:class:`~lfm_studio.engine.batch.extras.MissingExtraError` with that line. The rest of the
engine never imports it.

- :func:`reconstruct_video`: frames (TIFF, TIFF folder, Zarr) -> ``run.ome.zarr``;
- :func:`get_client`: in-process, LocalCluster or remote Dask client (shared with design studies);
- :func:`open_frames`: a lazy, picklable description of a video's frames.
"""

from lfm_studio.engine.batch.extras import INSTALL_HINT, MissingExtraError, require_scale

require_scale()

from lfm_studio.engine.batch.client import client_for, dashboard_link, get_client  # noqa: E402
from lfm_studio.engine.batch.frames import FrameSource, open_frames  # noqa: E402
from lfm_studio.engine.batch.options import ReconstructionOptions  # noqa: E402
from lfm_studio.engine.batch.video import VideoResult, reconstruct_video  # noqa: E402

__all__ = [
    "INSTALL_HINT",
    "FrameSource",
    "MissingExtraError",
    "ReconstructionOptions",
    "VideoResult",
    "client_for",
    "dashboard_link",
    "get_client",
    "open_frames",
    "reconstruct_video",
    "require_scale",
]
