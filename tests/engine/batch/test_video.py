"""reconstruct_video in-process (synchronous scheduler): equal to the serial loop, resumable, safe."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import tifffile
import zarr

from lfm_studio.engine.batch import reconstruct_video
from lfm_studio.engine.batch import video as video_module
from lfm_studio.engine.batch.frames import frame_digest
from lfm_studio.engine.batch.projectors import BUILDS, cached_projector, projector_spec
from lfm_studio.engine.batch.store import STATUS_GROUP
from lfm_studio.engine.io import OutputError
from lfm_studio.engine.progress import CancelledError
from tests.engine.batch.conftest import CROP, FRAMES, ITERATIONS, METHOD


def _run(video, out, **kwargs):
    options = {"method": METHOD, "iterations": ITERATIONS, "crop": CROP, "output": out, "chunk_frames": 3}
    return reconstruct_video(video.tiff, video.design, **{**options, **kwargs})


def _level(path, level=0) -> np.ndarray:
    return np.asarray(zarr.open_group(str(path), mode="r")[str(level)][:])


def test_output_equals_the_serial_loop_bit_for_bit(video, tmp_path):
    result = _run(video, tmp_path / "run.ome.zarr")
    assert result.computed == tuple(range(FRAMES)) and result.failed == {} and result.skipped == ()
    out = _level(result.path)
    assert out.dtype == np.float32 and out.shape == video.reference.shape
    assert np.array_equal(out, video.reference)  # bit for bit
    assert out.std() > 0.1 * out.mean() > 0  # not a trivial (zero/constant) volume
    # level 1: 2 x 2 lateral means of level 0 (odd last row/column dropped), computed here directly
    ny, nx = (out.shape[-2] // 2) * 2, (out.shape[-1] // 2) * 2
    blocks = out[..., :ny, :nx].astype(np.float64).reshape(*out.shape[:2], ny // 2, 2, nx // 2, 2)
    np.testing.assert_allclose(_level(result.path, 1), blocks.mean(axis=(3, 5)), rtol=1e-6, atol=1e-6)


def test_projector_is_built_once_per_process(video, tmp_path):
    spec = projector_spec(video.design, crop=CROP)
    before = BUILDS[spec.key]
    cached_projector(spec)
    after_first = BUILDS[spec.key]
    _run(video, tmp_path / "run.ome.zarr", chunk_frames=1)  # 8 tasks, same process
    assert after_first - before <= 1 and BUILDS[spec.key] == after_first


def test_a_nan_frame_is_reported_and_the_run_goes_on(video, tmp_path):
    frames = video.frames.copy()
    frames[5, 40, 17] = np.nan
    tiff = tmp_path / "nan.tif"
    tifffile.imwrite(tiff, frames)
    result = reconstruct_video(
        tiff, video.design, method=METHOD, iterations=ITERATIONS, crop=CROP,
        output=tmp_path / "run.ome.zarr", chunk_frames=3,
    )  # fmt: skip
    assert list(result.failed) == [5] and "frame 5" in result.failed[5] and "NaN" in result.failed[5]
    assert "Fix: replace them" in result.failed[5]
    good = [t for t in range(FRAMES) if t != 5]
    assert result.computed == tuple(good)  # the failed frame is not also "computed"
    out = _level(result.path)
    assert np.array_equal(out[good], video.reference[good])  # the others, in the same chunk too
    assert not out[5].any()  # left at the fill value, not half-written
    record = json.loads((tmp_path / "run.ome.zarr" / STATUS_GROUP / "chunk_000001.json").read_text())
    assert record["frames"]["5"]["status"] == "failed" and record["frames"]["5"]["attempts"] == 2
    assert record["frames"]["4"] == {"status": "done", "attempts": 1, "digest": frame_digest(frames[4])}


def test_cancel_then_resume_computes_only_the_missing_frames(video, tmp_path):
    out = tmp_path / "run.ome.zarr"
    stop_after = {"chunks": 0}

    def progress(done, total, message):
        stop_after["chunks"] += "done" in message

    with pytest.raises(CancelledError):
        _run(video, out, progress=progress, cancel=lambda: stop_after["chunks"] >= 2)
    folder = out / STATUS_GROUP
    first = {p.name: p.read_bytes() for p in folder.glob("chunk_*.json")}
    assert sorted(first) == ["chunk_000000.json", "chunk_000001.json"]  # frames 0-5 of 8
    data_before = _level(out)[:6].copy()

    result = _run(video, out)  # resume=True by default
    assert result.skipped == tuple(range(6)) and result.computed == (6, 7)
    for name, text in first.items():  # completed chunks were not rewritten
        assert (folder / name).read_bytes() == text
    assert np.array_equal(_level(out)[:6], data_before)
    assert np.array_equal(_level(out), video.reference)
    again = _run(video, out)
    assert again.computed == () and again.skipped == tuple(range(FRAMES))


def test_existing_output_is_refused_or_checked(video, tmp_path):
    out = tmp_path / "run.ome.zarr"
    _run(video, out, chunk_frames=4)
    with pytest.raises(FileExistsError, match="resume"):
        _run(video, out, chunk_frames=4, resume=False)
    with pytest.raises(
        ValueError, match=r"the method options .* differs \(iterations \d+ in the store, \d+ now\)"
    ):
        _run(video, out, chunk_frames=4, iterations=ITERATIONS + 1)
    replaced = _run(video, out, chunk_frames=4, iterations=1, overwrite=True)
    assert replaced.computed == tuple(range(FRAMES))
    assert (
        json.loads((out / "zarr.json").read_text())["attributes"]["lfm_studio"]["options"]["iterations"] == 1
    )


def _tree(path) -> dict[str, bytes]:
    """Every file under ``path``: relative name -> bytes."""
    return {p.relative_to(path).as_posix(): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


class _CrashError(Exception):
    pass


@pytest.mark.parametrize("stop", ["cancel", "error", "interrupt"])
def test_a_stopped_overwrite_leaves_the_previous_store_as_it_was(video, tmp_path, monkeypatch, stop):
    out = tmp_path / "run.ome.zarr"
    _run(video, out)
    before = _tree(out)
    assert any(name.startswith(STATUS_GROUP + "/chunk_") for name in before)
    chunks = {"n": 0}
    real = video_module.process_chunk

    def counted(task):
        chunks["n"] += 1
        if chunks["n"] == 2 and stop != "cancel":
            raise _CrashError("worker crashed") if stop == "error" else KeyboardInterrupt
        return real(task)

    monkeypatch.setattr(video_module, "process_chunk", counted)
    raised = {"cancel": CancelledError, "error": _CrashError, "interrupt": KeyboardInterrupt}[stop]
    with pytest.raises(raised):
        _run(video, out, iterations=1, overwrite=True, cancel=lambda: stop == "cancel" and chunks["n"] >= 1)
    assert chunks["n"] >= 1  # the new run had started writing its own store
    assert _tree(out) == before  # level-0 data, records and metadata byte-identical
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.ome.zarr"]  # no hidden store left


def test_a_finished_overwrite_replaces_the_store_and_clears_a_stale_replacement(video, tmp_path):
    out = tmp_path / "run.ome.zarr"
    _run(video, out)
    stale = tmp_path / ".run.ome.zarr.replacing"  # left by a killed overwrite run
    stale.mkdir()
    (stale / "junk").write_text("x")
    result = _run(video, out, iterations=1, overwrite=True)
    assert result.path == str(out) and result.computed == tuple(range(FRAMES))
    assert (
        json.loads((out / "zarr.json").read_text())["attributes"]["lfm_studio"]["options"]["iterations"] == 1
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.ome.zarr"]
    assert len(list((out / STATUS_GROUP).glob("chunk_*.json"))) == 3
    assert _run(video, out, iterations=1).skipped == tuple(range(FRAMES))  # the store resumes at its name


def test_bad_arguments_name_the_parameter(video, tmp_path):
    with pytest.raises(ValueError, match="chunk_frames"):
        _run(video, tmp_path / "a.ome.zarr", chunk_frames=0)
    with pytest.raises(ValueError, match="method"):
        _run(video, tmp_path / "a.ome.zarr", method="magic")
    with pytest.raises(ValueError, match=r"workers must be an integer >= 1; got 0"):
        _run(video, tmp_path / "a.ome.zarr", workers=0)
    with pytest.raises(ValueError, match="both given"):
        _run(video, tmp_path / "a.ome.zarr", workers=2, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(ValueError, match=r"\(64, 64\) pixels but the projector images \(128, 128\)"):
        tifffile.imwrite(tmp_path / "small.tif", video.frames[:, :64, :64])
        reconstruct_video(tmp_path / "small.tif", video.design, crop=CROP, output=tmp_path / "a.ome.zarr")
    assert not (tmp_path / "a.ome.zarr").exists()  # refused before anything was written


def test_frames_of_another_shape_are_refused_before_the_design_psf_is_simulated(video, tmp_path, monkeypatch):
    tifffile.imwrite(tmp_path / "small.tif", video.frames[:, :64, :64])

    def no_build(spec):
        raise AssertionError("the projector was built before the frames were checked")

    monkeypatch.setattr("lfm_studio.engine.batch.video.cached_projector", no_build)
    other = video.design.updated(name="another design, so no cached projector")
    with pytest.raises(
        ValueError, match=r"are \(64, 64\) pixels but the projector images \(128, 128\) pixels\. Fix"
    ):
        reconstruct_video(tmp_path / "small.tif", other, crop=CROP, output=tmp_path / "a.ome.zarr")


def test_an_output_that_is_not_a_zarr_name_is_refused(video, tmp_path):
    with pytest.raises(
        OutputError, match=r"output .*out\.tif does not end in \.zarr.*Fix: output='out\.ome\.zarr'"
    ):
        _run(video, tmp_path / "out.tif")
    assert not list(tmp_path.iterdir())


def test_a_frame_that_failed_is_recomputed_on_resume_and_the_good_frames_are_not(
    video, tmp_path, monkeypatch
):
    from lfm_studio.engine.batch import tasks

    real = tasks._reconstruct
    calls: list[int] = []

    def fail_frame_4(task, projector, frame, t):
        calls.append(t)
        if t == 4:
            raise RuntimeError("injected failure of frame 4")
        return real(task, projector, frame, t)

    out = tmp_path / "run.ome.zarr"
    monkeypatch.setattr(tasks, "_reconstruct", fail_frame_4)
    first = _run(video, out)  # chunks of 3: frame 4 is in chunk 1 (frames 3-5)
    assert first.failed == {4: "RuntimeError: injected failure of frame 4"}
    assert first.computed == (0, 1, 2, 3, 5, 6, 7) and first.retried == ()
    assert not _level(out)[4].any()  # nothing stored for the failed frame
    folder = out / STATUS_GROUP
    records = {p.name: p.read_bytes() for p in folder.glob("chunk_*.json")}
    good_data = _level(out)[[0, 1, 2, 3, 5, 6, 7]].copy()

    calls.clear()
    monkeypatch.setattr(tasks, "_reconstruct", lambda task, projector, frame, t: calls.append(t) or real(
        task, projector, frame, t))  # fmt: skip
    reports = []
    result = _run(video, out, progress=lambda done, total, message: reports.append((done, total)))
    assert calls == [4]  # only the failed frame is reconstructed again
    assert reports[0] == (FRAMES - 1, FRAMES) and reports[-1] == (FRAMES, FRAMES)
    assert result.failed == {} and result.computed == (4,) and result.retried == (4,)
    assert result.skipped == (0, 1, 2, 3, 5, 6, 7)
    np.testing.assert_allclose(_level(out)[4], video.reference[4], rtol=1e-6, atol=1e-6)
    assert np.array_equal(_level(out)[[0, 1, 2, 3, 5, 6, 7]], good_data)
    for name in ("chunk_000000.json", "chunk_000002.json"):  # chunks without a failure: untouched
        assert (folder / name).read_bytes() == records[name]
    record = json.loads((folder / "chunk_000001.json").read_text())
    digests = [frame_digest(frame) for frame in video.frames]  # of the frames read
    assert record["frames"]["4"] == {"status": "done", "attempts": 3, "digest": digests[4]}  # 2 failed, 1 now
    assert record["frames"]["3"] == {"status": "done", "attempts": 1, "digest": digests[3]}
    again = _run(video, out)
    assert calls == [4] and again.computed == () and again.skipped == tuple(range(FRAMES))


def test_a_frame_that_fails_again_on_resume_stays_failed_with_its_new_error(video, tmp_path, monkeypatch):
    from lfm_studio.engine.batch import tasks

    real = tasks._reconstruct

    def failing(message):
        def reconstruct(task, projector, frame, t):
            if t == 6:
                raise RuntimeError(message)
            return real(task, projector, frame, t)

        return reconstruct

    out = tmp_path / "run.ome.zarr"
    monkeypatch.setattr(tasks, "_reconstruct", failing("first"))
    _run(video, out)
    monkeypatch.setattr(tasks, "_reconstruct", failing("second"))
    result = _run(video, out)
    assert result.failed == {6: "RuntimeError: second"} and result.retried == (6,) and result.computed == ()
    record = json.loads((out / STATUS_GROUP / "chunk_000002.json").read_text())
    assert record["frames"]["6"]["attempts"] == 4 and record["frames"]["7"]["status"] == "done"
    assert not _level(out)[6].any()


def test_a_resume_on_another_recording_at_the_same_path_is_refused_naming_the_frames(video, tmp_path):
    """Same path, same shape, other pixels: resuming would mix two recordings in one store. The
    frames recorded as done are compared with their digests once the file's stamp changed."""
    tiff = tmp_path / "frames.tif"
    tifffile.imwrite(tiff, video.frames)
    out = tmp_path / "run.ome.zarr"
    options = {"method": METHOD, "iterations": ITERATIONS, "crop": CROP, "output": out, "chunk_frames": 3}
    first = reconstruct_video(tiff, video.design, **options)
    (out / STATUS_GROUP / "chunk_000002.json").unlink()  # as if stopped before the last chunk
    stored = _level(out).copy()
    other = video.frames.copy()
    other[1] *= 2.0  # another recording: frame 1 differs
    tifffile.imwrite(tiff, other)
    with pytest.raises(ValueError, match=r"changed since .*frame\(s\) 1 differ .*Fix: overwrite the store"):
        reconstruct_video(tiff, video.design, **options)
    assert np.array_equal(_level(out), stored) and first.failed == {}  # nothing computed or written
    tifffile.imwrite(tiff, video.frames)  # the same pixels again (a new file, so a new stamp): resumes
    assert reconstruct_video(tiff, video.design, **options).computed == (6, 7)


def test_a_store_written_before_digests_resumes_with_a_warning(video, tmp_path):
    from lfm_studio.engine.batch.store import FRAMES_STAMP
    from lfm_studio.engine.batch.video import FramesUncheckedWarning

    out = tmp_path / "run.ome.zarr"
    _run(video, out)
    (out / STATUS_GROUP / FRAMES_STAMP).unlink()  # as an earlier version wrote it
    with pytest.warns(FramesUncheckedWarning, match="cannot be detected"):
        again = _run(video, out)
    assert again.skipped == tuple(range(FRAMES)) and (out / STATUS_GROUP / FRAMES_STAMP).is_file()


@pytest.mark.parametrize("replacement_done", [True, False])
def test_a_crash_between_the_replacements_two_renames_is_completed_by_the_next_run(
    video, tmp_path, replacement_done
):
    """replace_store moves the old store to a hidden ``.old`` sibling, then the new one in place; a
    crash between the two left no store at the path. The next run puts the finished replacement in
    place (or the old store back) before anything else, and says so."""
    import shutil

    from lfm_studio.engine.batch.store import replacement_path
    from lfm_studio.engine.batch.video import RecoveredStoreWarning

    out = tmp_path / "run.ome.zarr"
    _run(video, out)
    old = tmp_path / ".run.ome.zarr.old"
    if replacement_done:  # the replacement (a finished run) waited at its hidden path
        shutil.copytree(out, replacement_path(out))
        (replacement_path(out) / STATUS_GROUP / "marker").write_text("new")
    os.replace(out, old)  # the crash: the old store moved aside, the new one not yet in place
    with pytest.warns(RecoveredStoreWarning, match="completed" if replacement_done else "undone"):
        again = _run(video, out)
    assert again.skipped == tuple(range(FRAMES)) and again.computed == ()  # resumed, nothing lost
    assert (out / STATUS_GROUP / "marker").exists() == replacement_done
    assert not old.exists() and not replacement_path(out).exists()
    np.testing.assert_array_equal(_level(out), video.reference)
