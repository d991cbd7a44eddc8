"""Chunk records and run attributes read back from disk are checked before they are used."""

from __future__ import annotations

import json

import pytest

from lfm_studio.engine.batch.store import STATUS_GROUP, VideoStore

GOOD = {
    "chunk": 0,
    "start": 0,
    "stop": 2,
    "frames": {
        "0": {"status": "done", "attempts": 1},
        "1": {"status": "failed", "attempts": 2, "error": "E: x"},
    },
    "run_id": "abc",
    "worker": "host:1",
    "seconds": {"projector": 0.5, "read": 0.0, "compute": 1.25, "write": 0.1},
}


@pytest.fixture
def store(tmp_path):
    (tmp_path / STATUS_GROUP).mkdir()
    return VideoStore(str(tmp_path), (4, 1, 16, 16), 1, 2)


def test_a_chunk_record_reads_back_as_written(store):
    store.write_record(0, GOOD)
    assert store.record(0) == GOOD and store.records() == {0: GOOD}
    assert store.record(1) is None


@pytest.mark.parametrize(
    "broken",
    [
        [],
        {**GOOD, "stop": "2"},
        {key: value for key, value in GOOD.items() if key != "seconds"},
        {**GOOD, "frames": {"0": {"status": "failed", "attempts": 2}}},  # a failure without its error
        {**GOOD, "frames": {"0": {"status": "maybe", "attempts": 1}}},
    ],
)
def test_a_malformed_chunk_record_is_refused_by_name(store, broken):
    store.record_path(1).write_text(json.dumps(broken))
    with pytest.raises(ValueError, match=r"chunk_000001\.json is not a chunk record"):
        store.record(1)
    with pytest.raises(ValueError, match="not a chunk record"):
        store.records()


def test_a_truncated_chunk_record_is_refused_by_name(store):
    """A truncated file (not JSON at all) names the file and the fix, not a bare JSONDecodeError."""
    store.record_path(1).write_text('{"chunk": 1, "sta')
    with pytest.raises(
        ValueError, match=r"chunk_000001\.json is not a readable chunk record .*Fix: delete it"
    ):
        store.record(1)
    with pytest.raises(ValueError, match="not a readable chunk record"):
        store.records()
