"""Video reconstruction on Dask: frames per second against the serial loop, overhead, memory per worker.

    python benchmarks/batch.py [--quick] [--frames 32] [--crop 256] [--iterations 10] [--repeats 2]
        [--long-frames 200 2000]

Every run prints its thread settings. Workers run 1 torch thread each; the serial loop and the
in-process (synchronous) run use 1 thread too, so the rows compare like with like.

(a) Speed: FLFM preset with 3 depths, the sensor cropped to ``--crop`` px, ``--frames`` seeded
    noisy frames in a TIFF, ``--iterations`` accelerated-RL iterations. Rows, interleaved over
    ``--repeats`` (other jobs share this machine; medians reported):
    serial:    build the projector once, ``reconstruct_frame`` per frame, results kept in memory;
    video x1:  ``reconstruct_video`` in this process (synchronous scheduler) into OME-Zarr;
    video x2:  the same on a LocalCluster of 2 one-thread worker processes (cluster start-up
               timed separately; each run builds the projector once per worker).
    Overhead of video x1 against serial = (its time - serial time) / serial time; its parts from
    the per-chunk records: reading frames, writing levels (compression included) and the rest
    (scheduler, store set-up, records) as fractions of the compute time.
(b) Memory: a long synthetic video of cheap frames (Wiener, 128 px crop) at each ``--long-frames``
    length on 2 workers; each worker's RSS after importing the engine, then its peak RSS
    (``ru_maxrss``) after 10 %, 50 % and 100 % of the frames: bounded means the peak stops growing
    once the projector is built and the first chunks are done, whatever the length.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads)
import argparse
import json
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile
import torch

from lfm_studio.engine.allocator import keep_freed_memory
from lfm_studio.engine.batch import get_client, reconstruct_video
from lfm_studio.engine.batch.projectors import cached_projector, projector_spec
from lfm_studio.engine.design import load_preset
from lfm_studio.engine.reconstruct.dispatch import reconstruct_frame
from lfm_studio.engine.threads import describe_threads

METHOD = "rl-accelerated"


def _design():
    design = load_preset("flfm_guo2019")
    return design.updated(depths=type(design.depths)(depth_range_um=(-20.0, 20.0), depth_step_um=20.0))


def _frames(design, crop: int, count: int, path: Path) -> np.ndarray:
    setup = cached_projector(projector_spec(design, crop=crop)).setup
    volume = (torch.rand(setup.volume_shape, generator=torch.Generator().manual_seed(3)) > 0.9995).float()
    expected = setup.projector.forward(volume).numpy()
    expected *= 2000.0 / expected.max()
    frames = np.stack([np.random.default_rng(s).poisson(expected).astype(np.float32) for s in range(count)])
    tifffile.imwrite(path, frames)
    return frames


def _serial(design, crop: int, frames: np.ndarray, iterations: int) -> float:
    began = time.perf_counter()
    setup = cached_projector(projector_spec(design, crop=crop)).setup  # cached: as a worker's second run
    for frame in frames:
        reconstruct_frame(setup.projector, torch.from_numpy(frame), method=METHOD, iterations=iterations)
    return time.perf_counter() - began


def _video(design, crop, tiff, iterations, out: Path, client=None, **kwargs) -> tuple[float, dict]:
    shutil.rmtree(out, ignore_errors=True)
    began = time.perf_counter()
    result = reconstruct_video(
        tiff, design, method=METHOD, iterations=iterations, crop=crop, output=out, client=client, **kwargs
    )
    elapsed = time.perf_counter() - began
    parts = {"read": 0.0, "compute": 0.0, "write": 0.0, "projector": 0.0}
    for record in (out / "lfm_studio_status").glob("chunk_*.json"):
        for key, value in json.loads(record.read_text())["seconds"].items():
            parts[key] += value
    assert len(result.computed) == result.frame_count and not result.failed
    return elapsed, parts


def speed(args, folder: Path) -> None:
    design = _design()
    tiff = folder / "frames.tif"
    frames = _frames(design, args.crop, args.frames, tiff)
    torch.set_num_threads(1)
    started = time.perf_counter()
    client = get_client(workers=2)
    client.wait_for_workers(2, timeout=300)
    startup = time.perf_counter() - started
    _warm_workers(client)
    # cold start (first run: FFT set-up here, projector build on each worker), timed apart from the rows
    few = folder / "few.tif"
    tifffile.imwrite(few, frames[:2])
    _serial(design, args.crop, frames[:1], args.iterations)
    cold1, _ = _video(design, args.crop, few, args.iterations, folder / "c1.ome.zarr")
    cold2, _ = _video(design, args.crop, few, args.iterations, folder / "c2.ome.zarr", client=client)
    rows: dict[str, list[float]] = {"serial": [], "video x1": [], "video x2": []}
    parts1: list[dict] = []
    try:
        for _ in range(args.repeats):
            rows["serial"].append(_serial(design, args.crop, frames, args.iterations))
            elapsed, parts = _video(design, args.crop, tiff, args.iterations, folder / "x1.ome.zarr")
            rows["video x1"].append(elapsed)
            parts1.append(parts)
            elapsed, _ = _video(
                design, args.crop, tiff, args.iterations, folder / "x2.ome.zarr", client=client
            )
            rows["video x2"].append(elapsed)
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()
    print(f"\n(a) {args.frames} frames, {args.crop} px crop, 3 depths, {METHOD} x {args.iterations}; "
          f"LocalCluster start-up {startup:.1f} s; first 2-frame runs (cold) x1 {cold1:.2f} s, x2 {cold2:.2f} s "
          "(not in the rows)")  # fmt: skip
    print(f"{'run':<10} {'median s':>9} {'frames/s':>9} {'vs serial':>10}")
    serial = statistics.median(rows["serial"])
    for name, times in rows.items():
        median = statistics.median(times)
        print(f"{name:<10} {median:>9.2f} {args.frames / median:>9.2f} {serial / median:>9.2f}x")
    best = min(parts1, key=lambda p: p["compute"])
    x1 = statistics.median(rows["video x1"])
    rest = x1 - sum(best.values())
    print(
        f"video x1 overhead vs serial: {(x1 - serial) / serial:+.1%}; as fractions of its compute "
        f"({best['compute']:.2f} s): read {best['read'] / best['compute']:.1%}, write+compression "
        f"{best['write'] / best['compute']:.1%}, scheduler/store/records {rest / best['compute']:.1%}"
    )


def _warm_workers(client) -> None:
    """Import the engine in every worker (torch included), so memory and speed rows exclude it."""

    def load() -> None:
        import lfm_studio.engine.batch.tasks  # noqa: F401

    client.run(load)


def _worker_rss(client, *, peak: bool) -> list[float]:
    def rss(peak: bool = peak) -> float:
        import resource

        import psutil

        if peak:
            return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB (Linux: KiB)
        return psutil.Process().memory_info().rss / 2**20

    return list(client.run(rss).values())


def memory(args, folder: Path) -> None:
    design = _design()
    built = cached_projector(projector_spec(design, crop=128))
    z, y, x = built.setup.volume_shape
    chunk = 4 * (4 * 128 * 128 + 4 * z * y * x + 4 * z * y * x)  # frames, volumes, a level-0 copy
    psf = built.setup.projector
    otf_bytes = sum(t.numel() * t.element_size() for t in vars(psf).values() if isinstance(t, torch.Tensor))
    print(f"\n(b) cheap frames (wiener, 128 px, volume {z}x{y}x{x}), 2 workers, chunks of 4 frames: one chunk "
          f"~{chunk / 2**20:.1f} MiB, projector tensors ~{otf_bytes / 2**20:.1f} MiB; worker RSS after importing "
          "the engine, then its peak (ru_maxrss) after 10 %, 50 % and 100 % of the frames (MiB, max over workers)")  # fmt: skip
    print(
        f"{'frames':>7} {'before':>7} {'peak 10%':>9} {'peak 50%':>9} {'peak 100%':>10} {'10% -> 100%':>12}"
    )
    for count in args.long_frames:
        tiff = folder / f"long{count}.tif"
        _frames(design, 128, count, tiff)
        client = get_client(workers=2)
        samples: dict[int, float] = {}
        marks = {max(4, count // 10 // 4 * 4): 10, max(4, count // 2 // 4 * 4): 50}

        def progress(
            done: int, total: int, message: str, client=client, marks=marks, samples=samples
        ) -> None:
            if done in marks and marks[done] not in samples:
                samples[marks[done]] = max(_worker_rss(client, peak=True))

        try:
            client.wait_for_workers(2, timeout=300)
            _warm_workers(client)
            before = max(_worker_rss(client, peak=False))
            out = folder / "long.ome.zarr"
            shutil.rmtree(out, ignore_errors=True)
            reconstruct_video(
                tiff, design, method="wiener", crop=128, output=out, client=client, chunk_frames=4,
                progress=progress,
            )  # fmt: skip
            samples[100] = max(_worker_rss(client, peak=True))
        finally:
            cluster = client.cluster
            client.close()
            cluster.close()
        p10, p50, p100 = (samples.get(k, float("nan")) for k in (10, 50, 100))
        print(f"{count:>7} {before:>7.0f} {p10:>9.0f} {p50:>9.0f} {p100:>10.0f} {p100 - p10:>+12.1f}")
        tiff.unlink()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--quick", action="store_true", help="8 frames, 128 px, 1 repeat, 100/400 long frames"
    )
    parser.add_argument("--frames", type=int, default=32)
    parser.add_argument("--crop", type=int, default=256)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--long-frames", type=int, nargs="+", default=[200, 2000])
    parser.add_argument("--only", choices=("speed", "memory"), default=None, help="run one part")
    args = parser.parse_args()
    if args.quick:
        args.frames, args.crop, args.repeats, args.long_frames = 8, 128, 1, [100, 400]
    if args.frames < 2:
        parser.error("--frames must be >= 2")
    torch.set_num_threads(1)
    keep_freed_memory()  # as the CLI and the workers do (engine/allocator.py)
    print(describe_threads())
    with tempfile.TemporaryDirectory(prefix="lfm-batch-bench-") as folder:
        if args.only != "memory":
            speed(args, Path(folder))
        if args.only != "speed":
            memory(args, Path(folder))


if __name__ == "__main__":
    main()
