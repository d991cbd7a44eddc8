"""The CLI's tqdm bar: known totals show a fraction, an unknown total (0) counts without one."""

from __future__ import annotations

from lfm_studio.cli.progress import progress_bar


def _last_frame(text: str) -> str:
    return text.replace("\n", "\r").rstrip("\r").split("\r")[-1]


def test_a_known_total_shows_done_of_total(capsys):
    with progress_bar("job", "s") as progress:
        progress(3, 10, "three")
    frame = _last_frame(capsys.readouterr().err)
    assert "3/10" in frame and "three" in frame and "30%" in frame


def test_an_unknown_total_counts_up_instead_of_resetting_to_zero_of_one(capsys):
    with progress_bar("job", "step") as progress:
        for done in range(1, 6):
            progress(done, 0, f"step {done}")
    frame = _last_frame(capsys.readouterr().err)
    assert "5step" in frame.replace(" ", "") and "/1" not in frame and "0%" not in frame
