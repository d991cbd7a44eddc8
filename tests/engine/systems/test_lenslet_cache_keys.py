"""Per-lenslet cache keys come from the spec objects: every field of a lenslet, the system (with
its objective) and the accuracy either changes the key or is shown not to change the result.

Fields are enumerated with ``dataclasses.fields``, so a field added later is covered here
automatically (and fails loudly until the test knows how to change its value).
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.systems.fourier_psf import (
    KEY_EXEMPT_ACCURACY,
    FourierAccuracy,
    fourier_psf_stack,
    lenslet_key,
)
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.lenslet_cache import spec_key, spec_parts
from lfm_studio.engine.units import mm, nm, um

LENS = Lenslet((0.1 * mm, -0.05 * mm), 0.25 * mm, 5 * mm, "circle")
OTHER = Lenslet((-0.2 * mm, 0.2 * mm), 0.25 * mm, 5 * mm, "square")
SYSTEM = FourierLFMSystem(
    ObjectiveLens(20.0, 0.5, 1.33, 180 * mm),
    60 * mm,
    MicrolensArray((LENS, OTHER)),
    5 * mm,
    8 * um,
    (96, 96),
    525 * nm,
)
ACCURACY = FourierAccuracy(oversampling=2, margin_airy=4)
DEPTHS = (-4 * um, 3 * um)
# Values that keep a spec valid where a generic change would not (or would not be a change).
ALTERNATIVES = {
    "shape": "square",
    "model": "paraxial",
    "pixel_integration": "fourier",
    "method": "per_lenslet",  # from "auto", which resolves to the per-lenslet path here
    "propagator": "asm",
    "depth_chunk": 1,
    "pupil_zernike_waves": ((4, 0.1),),  # from no mask: a defocus term (the design's pupil_phase)
}


def _changed(name: str, value):
    if name in ALTERNATIVES:
        return ALTERNATIVES[name]
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value * 1.01 if value else 1e-7
    if isinstance(value, torch.dtype):
        return torch.float64 if value == torch.float32 else torch.float32
    if isinstance(value, tuple) and value and all(isinstance(v, int | float) for v in value):
        return (_changed(name, value[0]), *value[1:])
    raise AssertionError(f"no way to change field {name!r} ({type(value).__name__}); teach _changed one")


def _edits(spec, skip=()):
    """(dotted field name, spec with that one field changed) for every leaf field, recursively."""
    for field in dataclasses.fields(spec):
        if field.name in skip:
            continue
        value = getattr(spec, field.name)
        if dataclasses.is_dataclass(value):
            for name, inner in _edits(value):
                yield f"{field.name}.{name}", dataclasses.replace(spec, **{field.name: inner})
        else:
            yield field.name, dataclasses.replace(spec, **{field.name: _changed(field.name, value)})


def _key(system=SYSTEM, lens=LENS, depths=DEPTHS, accuracy=ACCURACY, device="cpu") -> str:
    return lenslet_key(system, lens, depths, accuracy, device)


def test_every_lenslet_field_changes_the_key():
    names = []
    for name, lens in _edits(LENS):
        assert _key(lens=lens) != _key(), name
        names.append(name)
    assert names == [f.name for f in dataclasses.fields(Lenslet)]


def test_every_system_field_changes_the_key_except_the_rest_of_the_array():
    names = []
    for name, system in _edits(SYSTEM, skip=("mla",)):
        assert _key(system=system) != _key(), name
        names.append(name)
    assert "objective.numerical_aperture" in names and "wavelength" in names
    assert "pupil_zernike_waves" in names
    assert (
        len(names)
        == len(dataclasses.fields(FourierLFMSystem)) - 1 + len(dataclasses.fields(ObjectiveLens)) - 1
    )
    # The other lenslets are not part of this lenslet's key (editing one recomputes one) ...
    moved = MicrolensArray((LENS, dataclasses.replace(OTHER, center=(-0.3 * mm, 0.2 * mm))))
    assert _key(system=dataclasses.replace(SYSTEM, mla=moved)) == _key()
    # ... and indeed do not change its patch: the sensor around LENS is the same.
    acc = dataclasses.replace(ACCURACY, method="per_lenslet", dtype=torch.float64)
    alone = fourier_psf_stack(
        dataclasses.replace(SYSTEM, mla=MicrolensArray((LENS,))), DEPTHS, accuracy=acc
    ).data
    both = fourier_psf_stack(dataclasses.replace(SYSTEM, mla=moved), DEPTHS, accuracy=acc).data
    rows, cols = slice(30, 66), slice(45, 80)  # LENS's window (centre at row 42, col 60); OTHER is far
    assert torch.allclose(alone[:, rows, cols], both[:, rows, cols], rtol=1e-12, atol=0.0)
    assert float(alone[:, rows, cols].sum()) > 0.9 * float(alone.sum())


def test_every_accuracy_field_changes_the_key_or_provably_not_the_result():
    reference = fourier_psf_stack(SYSTEM, DEPTHS, accuracy=ACCURACY).data
    exempt = []
    for name, accuracy in _edits(ACCURACY):
        if _key(accuracy=accuracy) != _key():
            continue
        exempt.append(name)
        result = fourier_psf_stack(SYSTEM, DEPTHS, accuracy=accuracy).data
        assert torch.allclose(result, reference, rtol=1e-6, atol=1e-7 * float(reference.max())), name
    assert sorted(exempt) == sorted(KEY_EXEMPT_ACCURACY)


def test_depths_and_device_are_in_the_key_and_equal_specs_give_equal_keys():
    assert _key(depths=(-4 * um, 3.5 * um)) != _key()
    assert _key(device="meta") != _key()
    rebuilt = FourierLFMSystem(
        ObjectiveLens(20.0, 0.5, 1.33, 180 * mm),
        60 * mm,
        MicrolensArray((LENS,)),
        5 * mm,
        8 * um,
        (96, 96),
        525 * nm,
    )
    assert _key(system=rebuilt) == _key()
    # A tensor value is keyed by its value (and dtype), never by its identity.
    focal = dataclasses.replace(LENS, focal_length=torch.tensor(5 * mm, dtype=torch.float64))
    again = dataclasses.replace(LENS, focal_length=torch.tensor(5 * mm, dtype=torch.float64))
    assert (
        _key(lens=focal)
        == _key(lens=again)
        != _key(lens=dataclasses.replace(focal, focal_length=torch.tensor(5.1 * mm, dtype=torch.float64)))
    )


def test_spec_parts_refuses_what_it_cannot_key():
    with pytest.raises(TypeError, match="cannot derive a cache key from a object"):
        spec_key(object())
    assert spec_parts({"b": 1.5, "a": (1, "x")}) == (("a", (1, "x")), ("b", 1.5))
