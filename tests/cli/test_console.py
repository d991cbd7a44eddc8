"""The CLI on a terminal: design warnings as one-line notes, and a reader that leaves early (``| head``)."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

from lfm_studio.cli.console import design_notes
from lfm_studio.cli.errors import BROKEN_PIPE
from lfm_studio.engine.design import DesignWarning, design_to_json, load_preset
from lfm_studio.engine.learned.method import LearnedOutputWarning

ROOT = Path(__file__).resolve().parents[2]


def _cli(*argv: str, **popen) -> subprocess.Popen:
    """``python -m lfm_studio ARGV`` on this checkout, one thread."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-m", "lfm_studio", *argv], env=env, **popen)


def test_design_warnings_become_notes_and_others_go_to_the_default(monkeypatch):
    passed_on = []
    monkeypatch.setattr(warnings, "showwarning", lambda *args: passed_on.append(args))
    before = warnings.showwarning
    buffer = io.StringIO()
    with design_notes("simulate"):
        warnings.showwarning(
            DesignWarning("sub-images are cut. Fix: x."), DesignWarning, "checks.py", 185, buffer
        )
        warnings.showwarning(UserWarning("other"), UserWarning, "elsewhere.py", 7, buffer, "source line")
        warnings.showwarning(
            LearnedOutputWarning("too bright. Fix: y."), LearnedOutputWarning, "method.py", 9, buffer
        )
    assert warnings.showwarning is before  # restored: only the command line's run is affected
    assert buffer.getvalue() == (
        "lfm-studio simulate: note: sub-images are cut. Fix: x.\n"
        "lfm-studio simulate: warning: too bright. Fix: y.\n"
    )
    assert [args[1:4] for args in passed_on] == [(UserWarning, "elsewhere.py", 7)]  # Python's own format


def test_a_cropped_design_warns_in_one_line_without_file_or_source(tmp_path):
    design = load_preset("flfm_guo2019")
    data = json.loads(design_to_json(design))
    data["camera"]["pixel_count"] = [200, 200]  # the outer sub-images are cut by the sensor's edge
    path = tmp_path / "cropped.json"
    path.write_text(json.dumps(data))
    proc = _cli("info", str(path), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = proc.communicate(timeout=120)
    assert out.strip(), err  # the table
    assert proc.returncode == 0, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("lfm-studio info: note: sub-images"), err
    assert "are cut by the edge of the" in err and "DesignWarning" not in err and "warn_design(" not in err


def test_a_reader_that_leaves_early_ends_the_command_quietly():
    """stdout's reader is gone before anything is written (``| head -0``): no traceback, exit 141.

    The pipe's read end is closed before the command starts, so every write fails whatever the
    timing (closing it after the start would race the child's first write into the pipe buffer)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = _cli("info", "xlfm_cong2017", "--json", stdout=write_end, stderr=subprocess.PIPE)
    finally:
        os.close(write_end)
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.wait(timeout=120) == BROKEN_PIPE, err
    assert "Traceback" not in err and "BrokenPipeError" not in err and "Exception ignored" not in err, err
