"""PSFStack metadata is JSON; its typed readers return ints or name the key that is not one."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.psf_stack import PSFStack


def _stack(**metadata) -> PSFStack:
    return PSFStack(torch.ones(2, 3, 3), (0.0, 1e-6), 6.5e-6, 20.0, 525e-9, metadata=metadata)


def test_integer_metadata_reads_as_int_including_integral_json_floats():
    stack = _stack(pixels_per_lenslet=13, written_by_json=5.0, lenslets=[4, 6.0])
    assert stack.metadata_int("pixels_per_lenslet") == 13
    assert stack.metadata_int("written_by_json") == 5
    assert stack.metadata_int("absent", 1) == 1
    assert stack.metadata_ints("lenslets") == (4, 6)


@pytest.mark.parametrize(
    ("metadata", "call", "message"),
    [
        ({"q": 2.5}, lambda s: s.metadata_int("q"), r"PSFStack.metadata\['q'\] must be an integer; got 2.5"),
        (
            {"q": True},
            lambda s: s.metadata_int("q"),
            r"PSFStack.metadata\['q'\] must be an integer; got True",
        ),
        ({"q": "13"}, lambda s: s.metadata_int("q"), r"must be an integer; got '13'\. Fix: simulate"),
        ({}, lambda s: s.metadata_int("q"), r"PSFStack.metadata\['q'\] must be an integer; got None"),
        (
            {"r": 3},
            lambda s: s.metadata_ints("r"),
            r"PSFStack.metadata\['r'\] must be a list of integers; got 3",
        ),
        (
            {"r": [1, "x"]},
            lambda s: s.metadata_ints("r"),
            r"PSFStack.metadata\['r'\] must be an integer; got 'x'",
        ),
    ],
    ids=["fraction", "bool", "string", "missing", "not-a-list", "bad-entry"],
)
def test_wrong_metadata_is_a_named_error(metadata, call, message):
    with pytest.raises(ValueError, match=message):
        call(_stack(**metadata))
