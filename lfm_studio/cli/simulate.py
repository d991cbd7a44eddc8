"""``lfm-studio simulate`` and ``lfm-studio image``: PSF stacks and simulated light-field images.

``image`` writes what a camera writes: integer ADU (uint16 for a bit depth <= 16) with
the camera in the metadata (baseline, gain, QE, read noise, bit depth, full well,
photon budget, seed), so ``reconstruct`` turns it back into photons without flags.
``--truth`` is in photons per voxel, the unit a reconstruction comes out in;
``--expected`` adds the noise-free image in ADU. Without ``--photons`` the image is the
noise-free expected image in photons (no camera).
"""

from __future__ import annotations

import argparse
import difflib
import re
import sys
from pathlib import Path

from lfm_studio.cli.input_files import require_file
from lfm_studio.cli.interrupts import watching
from lfm_studio.cli.progress import progress_bar
from lfm_studio.engine.errors import require_device

#: The phantoms ``image --phantom`` makes itself; any other value is a volume TIFF's path.
PHANTOMS = ("beads", "cells")

#: A value that starts with '-' but is a number or a START:STOP:STEP range, not an option.
NEGATIVE_VALUE = re.compile(
    r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?([:,][-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)*$"
)


def allow_negative_values(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Let ``parser`` take ``--depths -40:40:10`` or ``--depths -10,20`` (a space, then a leading '-') as
    well as ``--depths=-40:40:10``.

    argparse reads a token that starts with '-' as an option unless it looks like a
    negative number; a range such as ``-40:40:10`` does not, so argparse said "expected
    one argument". This widens argparse's (private, but stable since Python 2.7) "looks
    like a negative number" pattern to numbers and ranges; no option of ours starts with a
    digit, so nothing else changes. tests/cli/test_range_options.py guards it.
    """
    parser._negative_number_matcher = NEGATIVE_VALUE
    return parser


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
    require_device(name, name="--device", fix="use --device cpu.")
    return name


def _design_file(design: str) -> str | None:
    """The design argument when it is a file (an input the outputs must not replace)."""
    return design if Path(design).expanduser().is_file() else None


@watching("out")
def run_simulate(args: argparse.Namespace) -> int:
    from lfm_studio.engine.design import resolve_design
    from lfm_studio.engine.io import check_output, write_psf_stack
    from lfm_studio.engine.simulation import depth_grid, design_depths, simulate_psf

    depths_given = None if args.depths is None else depth_grid(args.depths, "--depths")
    out = check_output(args.out, overwrite=args.overwrite, inputs=[_design_file(args.design)], tiff=True)
    design = resolve_design(args.design)
    depths = design_depths(design) if depths_given is None else depths_given
    with progress_bar(f"PSF stack ({design.kind}, {len(depths)} depths)") as progress:
        stack = simulate_psf(
            design, depths=depths, device=resolve_device(args.device), dtype=args.dtype, progress=progress
        )
    write_psf_stack(out, stack.to("cpu"), overwrite=args.overwrite)
    print(
        f"wrote {out}: PSF stack {tuple(stack.data.shape)}, depths {depths[0] * 1e6:g}..{depths[-1] * 1e6:g} um"
    )
    return 0


def _outputs(args: argparse.Namespace) -> dict[str, Path]:
    """The checked output paths by flag (``--out``, ``--truth``, ``--expected``), all distinct."""
    from lfm_studio.engine.io import OutputError, check_output

    phantom = args.phantom if args.phantom not in PHANTOMS else None
    inputs = [args.psf, phantom, _design_file(args.design)]
    given = {"--out": args.out, "--truth": args.truth, "--expected": args.expected}
    outputs = {
        flag: check_output(path, overwrite=args.overwrite, inputs=inputs, flag=flag, tiff=True)
        for flag, path in given.items()
        if path
    }
    resolved = [path.resolve() for path in outputs.values()]
    if len(set(resolved)) != len(resolved):
        raise OutputError(
            f"two outputs name the same file ({', '.join(f'{k} {v}' for k, v in outputs.items())}). "
            "Fix: give each output its own file name."
        )
    return outputs


def _check_image_inputs(args: argparse.Namespace) -> None:
    """Refuse a missing ``--psf``, a ``--phantom`` that is neither a phantom name nor a file, and a
    ``--count`` below 1 (a phantom without objects images to all zeros), naming the option."""
    require_file("--psf", args.psf, "a PSF stack TIFF from 'lfm-studio simulate'")
    if args.phantom not in PHANTOMS and not Path(args.phantom).expanduser().is_file():
        close = difflib.get_close_matches(args.phantom, PHANTOMS, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise FileNotFoundError(
            f"--phantom {args.phantom}: neither a phantom name nor an existing file{hint}. "
            f"Fix: --phantom {' or '.join(PHANTOMS)}, or the path to a volume TIFF."
        )
    if args.count is not None and args.count < 1:
        raise ValueError(
            f"--count {args.count}: a phantom needs at least 1 bead (0 images to an all-zero frame). "
            "Fix: --count 1 or more, or leave --count out for the default (50, or what fits)."
        )


@watching("out", "truth", "expected")
def run_image(args: argparse.Namespace) -> int:
    from lfm_studio.engine.design import resolve_design
    from lfm_studio.engine.io import camera_metadata, read_psf_stack, read_volume, write_image, write_volume
    from lfm_studio.engine.io.camera_counts import ADU, PHOTONS, adu_array
    from lfm_studio.engine.optics.camera import simulate_sensor
    from lfm_studio.engine.simulation import (
        camera_of,
        imaging_setup,
        light_field_image,
        make_phantom,
        photons_per_unit,
    )

    _check_image_inputs(args)
    outputs = _outputs(args)
    if args.photons is not None and not args.photons > 0:
        raise ValueError(f"--photons must be > 0 (expected photons in the image); got {args.photons}.")
    design = resolve_design(args.design)
    device = resolve_device(args.device)
    stack = read_psf_stack(args.psf, device=device)
    setup = imaging_setup(stack)
    if args.phantom in PHANTOMS:
        volume, info = make_phantom(args.phantom, setup, seed=args.seed, count=args.count)
        volume = volume.to(device)
    else:
        loaded = read_volume(args.phantom, device=device)
        volume, info = loaded.data, {"phantom": str(args.phantom)}
        if tuple(volume.shape) != setup.volume_shape:
            raise ValueError(
                f"{args.phantom} has shape {tuple(volume.shape)} but this PSF stack images volumes of shape "
                f"{setup.volume_shape} (Z, Y, X) with voxels {tuple(v * 1e6 for v in setup.voxel_size)} um. "
                "Fix: resample the volume to that grid."
            )
    if "note" in info:
        print(f"lfm-studio image: note: {info['note']}", file=sys.stderr)
    camera = camera_of(design)
    with progress_bar("light-field image") as progress:
        progress(0, 1, "projecting")
        counts, expected = light_field_image(setup, volume, camera, photons=args.photons, seed=args.seed)
        progress(1, 1, "done")
    noisy = args.photons is not None
    meta = {
        **info,
        "photons": args.photons,
        "psf": str(args.psf),
        "design": design.name,
        "units": ADU if noisy else PHOTONS,
        "camera": camera_metadata(camera, photons=args.photons, seed=args.seed) if noisy else None,
    }
    image = adu_array(counts, camera.bit_depth) if noisy else counts.detach()
    write_image(
        outputs["--out"], image.cpu(), pixel_size=stack.pixel_size, metadata=meta, overwrite=args.overwrite
    )
    kind = f"{str(image.dtype).removeprefix('torch.')} ADU" if noisy else "noise-free, photons"
    print(f"wrote {args.out}: light-field image {tuple(counts.shape)} ({kind})")
    if "--expected" in outputs:
        mean = (
            simulate_sensor(expected, camera, photons=args.photons, shot_noise=False, read_noise=False,
                            quantize=False, saturate=False)
            if noisy else expected
        )  # fmt: skip
        expected_meta = {**meta, "expected": True, "units": f"{meta['units']} (noise-free expected value)"}
        write_image(
            outputs["--expected"], mean.detach().float().cpu(), pixel_size=stack.pixel_size,
            metadata=expected_meta, overwrite=args.overwrite,
        )  # fmt: skip
        print(f"wrote {args.expected}: noise-free expected image (float32, {meta['units']})")
    if "--truth" in outputs:
        truth = (volume * photons_per_unit(expected, args.photons)).cpu()
        truth_meta = {**meta, "units": "photons per voxel"}
        write_volume(
            outputs["--truth"], truth, voxel_size=setup.voxel_size, depths=stack.depths,
            metadata=truth_meta, overwrite=args.overwrite,
        )  # fmt: skip
        print(f"wrote {args.truth}: ground truth {tuple(volume.shape)} (photons per voxel)")
    return 0


def add_simulate_parsers(sub: argparse._SubParsersAction) -> None:
    """Register ``simulate`` and ``image``."""
    sim = allow_negative_values(
        sub.add_parser("simulate", help="compute a design's PSF stack and save it as TIFF")
    )
    sim.add_argument("design", help="design file (.json) or preset name")
    sim.add_argument("--out", required=True, help="output TIFF (ImageJ hyperstack with metadata)")
    sim.add_argument(
        "--depths",
        type=parse_depths,
        default=None,
        help="START:STOP:STEP in um, e.g. --depths -40:40:10 (default: the design's)",
    )
    sim.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    sim.add_argument("--dtype", choices=("float32", "float64"), default=None)
    sim.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    sim.set_defaults(handler=run_simulate)

    img = allow_negative_values(
        sub.add_parser(
            "image",
            help="simulate a noisy light-field image of a phantom through a PSF stack",
            description="Writes integer camera counts (ADU; uint16 for a bit depth <= 16) with the camera "
            "(baseline, gain, QE, read noise, bit depth, photon budget, seed) in the TIFF metadata, so "
            "'lfm-studio reconstruct' converts them back to photons without flags. Without --photons the "
            "image is the noise-free expected image in photons.",
        )
    )
    img.add_argument("design", help="design file (.json) or preset name (camera noise parameters)")
    img.add_argument("--psf", required=True, help="PSF stack TIFF from 'lfm-studio simulate'")
    img.add_argument("--phantom", default="beads", help="'beads', 'cells' or a volume TIFF")
    img.add_argument(
        "--count",
        type=int,
        default=None,
        help="number of beads (phantom 'beads'; default 50, or as many as fit in a small volume)",
    )
    img.add_argument(
        "--photons",
        type=float,
        default=None,
        help="expected photons reaching the camera in the image (omit: noise-free image in photons)",
    )
    img.add_argument("--seed", type=int, default=0)
    img.add_argument("--out", required=True, help="output light-field image TIFF (ADU)")
    img.add_argument(
        "--truth", default=None, help="also save the ground-truth volume TIFF (photons per voxel)"
    )
    img.add_argument(
        "--expected", default=None, help="also save the noise-free expected image TIFF (float32, ADU)"
    )
    img.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    img.add_argument("--overwrite", action="store_true", help="replace existing output files")
    img.set_defaults(handler=run_image)
