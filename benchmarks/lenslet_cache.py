"""Per-lenslet cache across optimiser candidates: PSF seconds and cache use per candidate.

    python benchmarks/lenslet_cache.py CROP [DEPTHS] [CACHE_MIB]

``xlfm_cong2017`` (27 lenslets) at a ``CROP`` px sensor crop, its first ``DEPTHS`` depths (of
101; default all), a cache of ``CACHE_MIB`` MiB (default: the evaluator's, a quarter of free
memory), no design constraints; four candidates: lenslet 0's focal length 26, 26, 26.5 and
26 mm (a repeat, a one-lenslet change, a return). Prints the record's cache counts, the PSF
seconds and the objective (total power) per candidate, and what the cache holds at the end.
"""

from __future__ import annotations

import os
import sys

import torch

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.optimize import (
    DesignSpace,
    EvaluationSettings,
    Evaluator,
    Parameter,
    PSFLoss,
    grid_search,
)
from lfm_studio.engine.simulation import design_depths


def main(argv: list[str]) -> None:
    crop = int(argv[0])
    design = load_preset("xlfm_cong2017")
    depths = design_depths(design)
    count = int(argv[1]) if len(argv) > 1 else len(depths)
    depths_um = tuple(z * 1e6 for z in depths[:count])
    space = DesignSpace((Parameter("mla.lenslets[0].focal_length_mm", choices=(26.0, 26.0, 26.5, 26.0)),))
    extra = {"cache_bytes": int(float(argv[2]) * 2**20)} if len(argv) > 2 else {}
    evaluator = Evaluator(
        design, space, [PSFLoss("total_power", lambda s: s.data.double().sum())],
        settings=EvaluationSettings(crop=crop, depths_um=depths_um), constraints=(), **extra,
    )  # fmt: skip
    print(
        f"depths {len(depths_um)}, crop {crop}, cache budget {evaluator.cache.budget_bytes / 2**20:.0f} MiB, "
        f"torch threads {torch.get_num_threads()}, load average {os.getloadavg()}"
    )
    for record in grid_search(evaluator).records:
        print(record.params, record.cache, f"psf_s {record.timing['psf_s']:.2f}", record.values)
    print(f"cache holds {evaluator.cache.nbytes / 2**20:.2f} MiB in {len(evaluator.cache)} entries")


if __name__ == "__main__":
    main(sys.argv[1:])
