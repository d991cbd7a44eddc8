"""reconstruct_video on a LocalCluster (2 one-thread worker processes): same output as the serial
loop, one projector per worker, a killed worker or a killed run loses nothing that was recorded.

Small and load-robust: no timing assertions, generous timeouts, every cluster closed."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import tifffile
import zarr

from lfm_studio.engine.batch import get_client, reconstruct_video
from lfm_studio.engine.batch.frames import frame_digest
from lfm_studio.engine.batch.projectors import projector_spec
from lfm_studio.engine.batch.store import STATUS_GROUP
from lfm_studio.engine.design import save_design
from tests.engine.batch.conftest import CROP, FRAMES, ITERATIONS, METHOD

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture
def client():
    client = get_client(workers=2)
    client.wait_for_workers(2, timeout=120)
    yield client
    cluster = client.cluster
    client.close()
    cluster.close()


def _level0(path) -> np.ndarray:
    return np.asarray(zarr.open_group(str(path), mode="r")["0"][:])


def _builds_per_worker(client, key: str) -> list[int]:
    def builds(key=key):
        from lfm_studio.engine.batch.projectors import BUILDS

        return BUILDS[key]

    return list(client.run(builds).values())


def test_two_workers_equal_the_serial_loop_and_build_one_projector_each(video, client, tmp_path):
    result = reconstruct_video(
        video.tiff, video.design, method=METHOD, iterations=ITERATIONS, crop=CROP,
        output=tmp_path / "run.ome.zarr", chunk_frames=1, client=client,
    )  # fmt: skip
    assert result.computed == tuple(range(FRAMES)) and result.failed == {} and result.unfinished == ()
    assert np.array_equal(_level0(result.path), video.reference)  # bit for bit, 1 thread each
    records = [json.loads(p.read_text()) for p in (Path(result.path) / STATUS_GROUP).glob("chunk_*.json")]
    pids = {str(pid) for pid in client.run(os.getpid).values()}
    assert {r["worker"].rsplit(":", 1)[1] for r in records} <= pids  # computed in the workers
    builds = _builds_per_worker(client, projector_spec(video.design, crop=CROP).key)
    assert all(n <= 1 for n in builds) and sum(builds) >= 1  # once per worker that ran a chunk


def test_a_killed_worker_loses_no_recorded_chunk(video, client, tmp_path):
    out = tmp_path / "run.ome.zarr"
    pids = list(client.run(os.getpid).values())
    seen: dict[str, bytes] = {}

    def progress(done, total, message):
        if "done" in message and not seen:  # after the first chunk: kill one worker (SIGKILL)
            seen.update({p.name: p.read_bytes() for p in (out / STATUS_GROUP).glob("chunk_*.json")})
            os.kill(pids[0], signal.SIGKILL)

    result = reconstruct_video(
        video.tiff, video.design, method=METHOD, iterations=ITERATIONS, crop=CROP,
        output=out, chunk_frames=1, client=client, progress=progress,
    )  # fmt: skip
    assert seen, "no chunk finished before the kill"
    missing = [t for t in range(FRAMES) if t not in result.computed]
    if missing:  # lost for good (Dask gave up on them): a resume finishes exactly those
        assert sorted(result.unfinished) == missing
        result = reconstruct_video(
            video.tiff, video.design, method=METHOD, iterations=ITERATIONS, crop=CROP, output=out,
            chunk_frames=1,
        )  # fmt: skip
        assert result.computed == tuple(missing)
    for name, text in seen.items():  # chunks recorded before the kill were not rewritten
        assert (out / STATUS_GROUP / name).read_bytes() == text
    assert np.array_equal(_level0(out), video.reference)


RUN_THEN_DIE = textwrap.dedent(
    """
    import os, signal, sys
    from lfm_studio.engine.batch import reconstruct_video

    frames, design, out = sys.argv[1:4]

    def progress(done, total, message):
        if done >= 4:  # two chunks recorded: kill this run, its cluster and workers (no clean-up)
            os.killpg(os.getpgid(0), signal.SIGKILL)

    reconstruct_video(frames, design, method="{method}", iterations={iterations}, crop={crop},
                      output=out, chunk_frames=2, workers=2, progress=progress)
    """
)


def test_resume_after_killing_the_whole_run_computes_only_the_missing_frames(video, tmp_path):
    design = tmp_path / "design.json"
    save_design(video.design, design)
    out = tmp_path / "run.ome.zarr"
    script = RUN_THEN_DIE.format(method=METHOD, iterations=ITERATIONS, crop=CROP)
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen(
        [sys.executable, "-c", script, str(video.tiff), str(design), str(out)],
        env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        _, stderr = process.communicate(timeout=300)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == -signal.SIGKILL, stderr.decode()[-2000:]
    recorded = sorted(p.name for p in (out / STATUS_GROUP).glob("chunk_*.json"))
    done = [t for name in recorded for t in range(2 * int(name[6:12]), 2 * int(name[6:12]) + 2)]
    assert 4 <= len(done) < FRAMES, recorded
    result = reconstruct_video(
        video.tiff, design, method=METHOD, iterations=ITERATIONS, crop=CROP, output=out, chunk_frames=2
    )
    assert result.skipped == tuple(done)
    assert result.computed == tuple(t for t in range(FRAMES) if t not in done)
    assert np.array_equal(_level0(out), video.reference)


def test_a_video_and_a_design_study_run_on_one_client(video, client, tmp_path):
    """The scale-out promise: one Dask cluster reconstructs a video and evaluates a design study
    (the study database the only shared state); the study's values equal an in-process run."""
    pytest.importorskip("optuna")
    from lfm_studio.engine.optimize import DesignSpace, Evaluator, Parameter, objective_named
    from lfm_studio.engine.optimize.study import run_study

    result = reconstruct_video(
        video.tiff, video.design, method=METHOD, iterations=ITERATIONS, crop=CROP,
        output=tmp_path / "run.ome.zarr", chunk_frames=2, client=client,
    )  # fmt: skip
    assert result.computed == tuple(range(FRAMES)) and result.failed == {}
    na = video.design.objective.numerical_aperture
    space = DesignSpace((Parameter("objective.numerical_aperture", choices=(round(0.9 * na, 3), na)),))

    def evaluator() -> Evaluator:
        return Evaluator(video.design, space, [objective_named("lateral_resolution")])

    def values(study) -> dict[str, tuple[float, ...]]:
        done = [t for t in study.get_trials(deepcopy=False) if t.state.name == "COMPLETE"]
        return {json.dumps(t.params, sort_keys=True): tuple(t.values) for t in done}

    shared = run_study(evaluator(), f"sqlite:///{tmp_path / 'shared.db'}", client=client)
    alone = run_study(evaluator(), f"sqlite:///{tmp_path / 'alone.db'}")
    assert len(values(shared)) == 2 and values(shared) == values(alone)
    assert np.array_equal(_level0(result.path), video.reference)  # the video is untouched by the study


def test_a_frame_that_failed_on_the_cluster_is_recomputed_on_resume(video, client, tmp_path):
    frames = video.frames.copy()
    frames[2, 30, 30] = np.nan
    tiff = tmp_path / "frames.tif"
    tifffile.imwrite(tiff, frames)
    out = tmp_path / "run.ome.zarr"
    options = {"method": METHOD, "iterations": ITERATIONS, "crop": CROP, "output": out, "chunk_frames": 2}
    first = reconstruct_video(tiff, video.design, client=client, **options)
    assert list(first.failed) == [2] and "NaN" in first.failed[2]
    folder = out / STATUS_GROUP
    untouched = {p.name: p.read_bytes() for p in folder.glob("chunk_*.json") if p.name != "chunk_000001.json"}

    tifffile.imwrite(tiff, video.frames)  # the frame repaired in place: same file, same shape
    result = reconstruct_video(tiff, video.design, client=client, **options)
    assert result.failed == {} and result.retried == (2,) and result.computed == (2,)
    assert result.skipped == tuple(t for t in range(FRAMES) if t != 2)
    assert np.array_equal(_level0(out), video.reference)  # bit for bit, 1 thread each
    assert {p.name: p.read_bytes() for p in folder.glob("chunk_*.json") if p.name in untouched} == untouched
    record = json.loads((folder / "chunk_000001.json").read_text())
    assert record["frames"]["2"] == {"status": "done", "attempts": 3, "digest": frame_digest(video.frames[2])}
    assert record["frames"]["3"] == {"status": "done", "attempts": 1, "digest": frame_digest(video.frames[3])}
