"""pyolaf's LFM operator build on the configuration of issue 17, timed (run by an interpreter that has pyolaf).

    /path/to/pyolaf-python benchmarks/pyolaf_build.py [--depths 31]

Called by ``conventional_build.py --pyolaf-python PATH`` in a fresh process under
``/usr/bin/time -v``; needs only pyolaf and its dependencies (numpy, scipy, pyyaml), not lfm_studio.
Tested with pyolaf 0.2.1.

The configuration, in pyolaf's units (micrometres): 10x / NA 0.3 in air, 200 mm tube lens, regular
grid of 125 um square lenslets (``uLensMask`` 1) of focal length 1.875 mm with the sensor in their
focal plane (``plenoptic`` 1), 525 nm, 15 px per lenslet (pixel 8.333 um), 5 voxels per lenslet
(``superResFactor`` 5), a simulated 41 x 41-lenslet sensor (615 x 615 px), ``--depths`` depths over
+-150 um. Timed: ``LFM_setCameraParams`` + ``LFM_computeGeometryParameters`` +
``LFM_computeLFMatrixOperators`` (Debye NIP fields, forward patterns ``H`` and backward patterns
``Ht``); the backward part is also reported alone. pyolaf samples the NIP field and the
propagation on the sensor pixels (15 samples per pitch, one per pixel, no sub-pixel integration)
and computes 9 of 25 sub-positions per depth (quarter symmetry).
"""

import argparse
import json
import os
import tempfile
import time

import numpy as np
import yaml


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--depths", type=int, default=31)
    args = parser.parse_args()
    import pyolaf.lf as lf
    from pyolaf.geometry import LFM_computeGeometryParameters, LFM_setCameraParams

    backward = {"seconds": 0.0}
    original = lf.LFM_computeBackwardPatterns

    def timed_backward(*a, **k):
        start = time.perf_counter()
        try:
            return original(*a, **k)
        finally:
            backward["seconds"] += time.perf_counter() - start

    lf.LFM_computeBackwardPatterns = timed_backward  # called by name inside pyolaf.lf
    config = dict(
        gridType="reg", focus="single", plenoptic=1, M=10.0, NA=0.3, ftl=200000.0, lensPitch=125.0,
        pixelPitch=125.0 / 15, fm=1875.0, mla2sensor=1875.0, tube2mla=200000.0, uLensMask=1, n=1.0,
        WaveLength=0.525,
    )  # fmt: skip
    path = os.path.join(tempfile.mkdtemp(), "camera.yaml")
    with open(path, "w") as handle:
        yaml.safe_dump(config, handle)
    start = time.perf_counter()
    camera = LFM_setCameraParams(path, 15)
    step = 300.0 / max(1, args.depths - 1)
    centers, resolution, _, _ = LFM_computeGeometryParameters(
        camera, np.array([]), [-150.0, 150.0], step, 5, imgSize=[41 * 15, 41 * 15]
    )
    lf.LFM_computeLFMatrixOperators(camera, resolution, centers)
    seconds = time.perf_counter() - start
    print(
        json.dumps(
            {"seconds": seconds, "backward_seconds": backward["seconds"], "depths": len(resolution["depths"])}
        )
    )


if __name__ == "__main__":
    main()
