"""Every option taking a START:STOP:STEP range accepts a negative START with a space or with '='."""

from __future__ import annotations

import pytest

from lfm_studio.cli import build_parser

RANGE_OPTIONS = [
    ["simulate", "flfm_guo2019", "--out", "psf.tif"],
    ["reconstruct", "--psf", "psf.tif", "--image", "lf.tif", "--out", "vol.tif"],
]


@pytest.mark.parametrize("command", RANGE_OPTIONS, ids=lambda c: c[0])
@pytest.mark.parametrize("text", ["-40:40:10", "-2.5:2.5:0.5", "-1e1:1e1:5", "-40:-10:10"])
def test_depths_parse_with_a_space_and_with_equals(command, text):
    parser = build_parser()
    spaced = parser.parse_args([*command, "--depths", text])
    joined = parser.parse_args([*command, f"--depths={text}"])
    start, stop, step = (float(v) for v in text.split(":"))
    assert spaced.depths == joined.depths == (start, stop, step)
    # options after the range are still options
    after = parser.parse_args([*command, "--depths", text, "--overwrite"])
    assert after.overwrite and after.depths == spaced.depths


@pytest.mark.parametrize("command", RANGE_OPTIONS, ids=lambda c: c[0])
def test_a_missing_value_is_still_an_error(command, capsys):
    with pytest.raises(SystemExit) as caught:
        build_parser().parse_args([*command, "--depths", "--overwrite"])
    assert caught.value.code == 2 and "--depths: expected one argument" in capsys.readouterr().err


def test_a_malformed_range_names_the_option(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args([*RANGE_OPTIONS[0], "--depths", "-40:40"])
    assert "--depths must be START:STOP:STEP in um" in capsys.readouterr().err


def test_resolution_takes_a_negative_first_depth_after_a_space():
    from lfm_studio.cli import build_parser

    for argv in (
        ["resolution", "xlfm_cong2017", "--depths", "-10,20"],
        ["resolution", "xlfm_cong2017", "--depths=-10,20"],
    ):
        assert build_parser().parse_args(argv).depths == pytest.approx((-10e-6, 20e-6))
