"""Forward and back projection speed of the Fourier projector: this checkout against a git revision.

    python benchmarks/projector_versions.py [--rev cc4a686] [--depths 8] [--pixels 2048] [--volume 339] \
        [--threads 1] [--repeats 5]

Loads ``lfm_studio/engine/operators/shift_invariant.py`` as it was at ``--rev`` (``git show``)
next to the current one, builds both projectors on the same random PSF stack (``pixels^2``
camera, ``volume^2`` voxels per depth: the XLFM preset at 2048 px has a 339^2 field of view),
checks that they agree and times ``forward`` and ``adjoint`` alternately (other jobs share
this machine); prints medians and the ratio old / new measured in the same run.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads, engine/threads.py)
import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from lfm_studio.engine.allocator import keep_freed_memory
from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.threads import describe_threads, torch_threads

MODULE = "lfm_studio/engine/operators/shift_invariant.py"


def projector_at(rev: str):
    """``ShiftInvariantProjector`` class of ``MODULE`` at git revision ``rev``."""
    root = Path(__file__).resolve().parents[1]
    source = subprocess.run(
        ["git", "show", f"{rev}:{MODULE}"], cwd=root, capture_output=True, text=True, check=True
    ).stdout
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as handle:
        handle.write(source)
    spec = importlib.util.spec_from_file_location(f"shift_invariant_{rev}", handle.name)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module.ShiftInvariantProjector


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rev", default="cc4a686", help="git revision to compare with")
    parser.add_argument("--depths", type=int, default=8)
    parser.add_argument("--pixels", type=int, default=2048)
    parser.add_argument("--volume", type=int, default=339)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    keep_freed_memory()  # as the CLI does
    generator = torch.Generator().manual_seed(0)
    psf = torch.rand((args.depths, args.pixels, args.pixels), generator=generator)
    lateral = (args.volume, args.volume)
    x = torch.rand((args.depths, *lateral), generator=generator)
    y = torch.rand((args.pixels, args.pixels), generator=generator)
    with torch_threads(args.threads):
        print(describe_threads())
        old, new = projector_at(args.rev)(psf, lateral), ShiftInvariantProjector(psf, lateral)
        for name in ("forward", "adjoint"):
            a, b = (
                getattr(old, name)(x if name == "forward" else y),
                getattr(new, name)(x if name == "forward" else y),
            )
            print(f"{name}: max relative difference {float((a - b).abs().max() / a.abs().max()):.1e}")
        calls = {
            ("forward", "old"): lambda: old.forward(x),
            ("forward", "new"): lambda: new.forward(x),
            ("adjoint", "old"): lambda: old.adjoint(y),
            ("adjoint", "new"): lambda: new.adjoint(y),
        }
        times = {key: [] for key in calls}
        for _ in range(args.repeats):
            for key, call in calls.items():
                start = time.perf_counter()
                call()
                times[key].append(time.perf_counter() - start)
    print(
        f"camera {args.pixels}^2, volume {args.depths} x {args.volume}^2, FFT window {new.fft_shape}, "
        f"float32, median of {args.repeats}"
    )
    print(f"| operation | {args.rev} s | this checkout s | {args.rev} / this |")
    print("|---|---|---|---|")
    for name in ("forward", "adjoint"):
        t_old, t_new = (statistics.median(times[(name, v)]) for v in ("old", "new"))
        print(f"| {name} | {t_old:.3f} | {t_new:.3f} | {t_old / t_new:.2f} |")


if __name__ == "__main__":
    main()
