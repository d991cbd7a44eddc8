"""``lfm-studio simulate`` and ``lfm-studio image``: PSF stacks and simulated light-field images."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from lfm_studio.cli_progress import progress_bar


def parse_depths(text: str | None) -> tuple[float, float, float] | None:
    if text is None:
        return None
    parts = text.split(":")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(
            f"--depths must be START:STOP:STEP in um (e.g. -100:100:5); got {text!r}"
        )
    try:
        return tuple(float(p) for p in parts)  # type: ignore[return-value]
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"--depths must hold three numbers in um; got {text!r}") from error


def resolve_device(name: str) -> str:
    if name == "cuda" and not torch.cuda.is_available():
        raise SystemExit("--device cuda: no CUDA device is available here. Fix: use --device cpu.")
    return name


def run_simulate(args: argparse.Namespace) -> int:
    from lfm_studio.engine.design import resolve_design
    from lfm_studio.engine.io import write_psf_stack
    from lfm_studio.engine.simulation import design_depths, simulate_psf

    design = resolve_design(args.design)
    depths = design_depths(design, args.depths)
    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise SystemExit(f"{out} exists. Fix: choose another --out or pass --overwrite.")
    with progress_bar(f"PSF stack ({design.kind}, {len(depths)} depths)") as progress:
        stack = simulate_psf(
            design, depths=depths, device=resolve_device(args.device), dtype=args.dtype, progress=progress
        )
    write_psf_stack(out, stack.to("cpu"), overwrite=args.overwrite)
    print(
        f"wrote {out}: PSF stack {tuple(stack.data.shape)}, depths {depths[0] * 1e6:g}..{depths[-1] * 1e6:g} um"
    )
    return 0


def run_image(args: argparse.Namespace) -> int:
    from lfm_studio.engine.design import resolve_design
    from lfm_studio.engine.io import read_psf_stack, read_volume, write_image, write_volume
    from lfm_studio.engine.simulation import camera_of, imaging_setup, light_field_image, make_phantom

    design = resolve_design(args.design)
    for path in (args.out, args.truth):
        if path and Path(path).exists() and not args.overwrite:
            raise SystemExit(f"{path} exists. Fix: choose another file name or pass --overwrite.")
    device = resolve_device(args.device)
    stack = read_psf_stack(args.psf, device=device)
    setup = imaging_setup(stack)
    if args.phantom in ("beads", "cells"):
        volume, info = make_phantom(args.phantom, setup, seed=args.seed, count=args.count)
        volume = volume.to(device)
    else:
        loaded = read_volume(args.phantom, device=device)
        volume, info = loaded.data, {"phantom": str(args.phantom)}
        if tuple(volume.shape) != setup.volume_shape:
            raise SystemExit(
                f"{args.phantom} has shape {tuple(volume.shape)} but this PSF stack images volumes of shape "
                f"{setup.volume_shape} (Z, Y, X) with voxels {tuple(v * 1e6 for v in setup.voxel_size)} um. "
                "Fix: resample the volume to that grid."
            )
    with progress_bar("light-field image") as progress:
        progress(0, 1, "projecting")
        counts, _ = light_field_image(setup, volume, camera_of(design), photons=args.photons, seed=args.seed)
        progress(1, 1, "done")
    meta = {**info, "photons": args.photons, "psf": str(args.psf), "design": design.name}
    counts, volume = counts.cpu(), volume.cpu()
    write_image(args.out, counts, pixel_size=stack.pixel_size, metadata=meta, overwrite=args.overwrite)
    print(f"wrote {args.out}: light-field image {tuple(counts.shape)}")
    if args.truth:
        depths = stack.depths
        write_volume(
            args.truth,
            volume,
            voxel_size=setup.voxel_size,
            depths=depths,
            metadata=meta,
            overwrite=args.overwrite,
        )
        print(f"wrote {args.truth}: ground truth {tuple(volume.shape)}")
    return 0


def add_simulate_parsers(sub: argparse._SubParsersAction) -> None:
    """Register ``simulate`` and ``image``."""
    sim = sub.add_parser("simulate", help="compute a design's PSF stack and save it as TIFF")
    sim.add_argument("design", help="design file (.json) or preset name")
    sim.add_argument("--out", required=True, help="output TIFF (ImageJ hyperstack with metadata)")
    sim.add_argument(
        "--depths", type=parse_depths, default=None, help="START:STOP:STEP in um (default: the design's)"
    )
    sim.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    sim.add_argument("--dtype", choices=("float32", "float64"), default=None)
    sim.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    sim.set_defaults(handler=run_simulate)

    img = sub.add_parser("image", help="simulate a noisy light-field image of a phantom through a PSF stack")
    img.add_argument("design", help="design file (.json) or preset name (camera noise parameters)")
    img.add_argument("--psf", required=True, help="PSF stack TIFF from 'lfm-studio simulate'")
    img.add_argument("--phantom", default="beads", help="'beads', 'cells' or a volume TIFF")
    img.add_argument("--count", type=int, default=50, help="number of beads (phantom 'beads')")
    img.add_argument(
        "--photons", type=float, default=None, help="expected photons in the image (omit: noise-free)"
    )
    img.add_argument("--seed", type=int, default=0)
    img.add_argument("--out", required=True, help="output light-field image TIFF")
    img.add_argument("--truth", default=None, help="also save the ground-truth volume TIFF")
    img.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    img.add_argument("--overwrite", action="store_true")
    img.set_defaults(handler=run_image)
