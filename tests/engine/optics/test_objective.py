"""ObjectiveLens validation, derived geometry and the paraxial image map."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from lfm_studio.engine.optics.objective import ObjectiveLens, image_point, resolve_apodization
from lfm_studio.engine.units import mm, um


def water_60x() -> ObjectiveLens:
    return ObjectiveLens(60, 1.2, 1.33, 200 * mm)


def test_derived_geometry():
    obj = water_60x()
    assert math.isclose(obj.focal_length, 200 * mm / 60, rel_tol=1e-15)
    assert math.isclose(obj.pupil_radius, 1.2 * 200 * mm / 60, rel_tol=1e-15)  # Abbe sine condition
    assert math.isclose(obj.half_angle, math.asin(1.2 / 1.33), rel_tol=1e-15)
    assert math.isclose(obj.axial_magnification, 3600 / 1.33, rel_tol=1e-15)


def test_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        water_60x().numerical_aperture = 0.5


@pytest.mark.parametrize(
    ("na", "n", "message"),
    [
        (1.4, 1.33, "numerical_aperture 1.4 exceeds immersion_index 1.33"),
        (1.33, 1.33, "numerical_aperture 1.33 equals immersion_index 1.33"),
        (1.0, 1.0, "numerical_aperture 1 equals immersion_index 1"),
    ],
)
def test_na_must_be_below_immersion_index(na, n, message):
    with pytest.raises(ValueError, match=message):
        ObjectiveLens(40, na, n, 200 * mm)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"magnification": 0.0}, "magnification"),
        ({"numerical_aperture": -0.5}, "numerical_aperture"),
        ({"immersion_index": 0.0}, "immersion_index"),
        ({"tube_lens_focal_length": -200 * mm}, "tube_lens_focal_length"),
        ({"magnification": float("nan")}, "magnification"),
    ],
)
def test_non_positive_values_are_named(kwargs, name):
    args = {
        "magnification": 20,
        "numerical_aperture": 0.5,
        "immersion_index": 1.0,
        "tube_lens_focal_length": 0.2,
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        ObjectiveLens(**args)


def test_tensor_na_keeps_its_graph():
    na = torch.tensor(0.8, dtype=torch.float64, requires_grad=True)
    obj = ObjectiveLens(20, na, 1.0, 200 * mm)
    (grad,) = torch.autograd.grad(obj.half_angle, na)
    assert math.isclose(float(grad), 1.0 / math.sqrt(1.0 - 0.64), rel_tol=1e-14)  # d asin(x)/dx
    with pytest.raises(ValueError, match="exceeds immersion_index"):
        ObjectiveLens(20, torch.tensor(1.1), 1.0, 200 * mm)


def test_image_point_inverts_and_magnifies():
    obj = water_60x()
    x, y, z = 1.0 * um, -2.0 * um, 3.0 * um
    xi, yi, zi = image_point(obj, (x, y, z))
    assert math.isclose(xi, -60 * x, rel_tol=1e-15)
    assert math.isclose(yi, -60 * y, rel_tol=1e-15)
    assert math.isclose(zi, 3600 / 1.33 * z, rel_tol=1e-15)  # axial M^2 n'/n
    assert math.isclose(image_point(obj, (x, y, z), image_index=1.5)[2], 1.5 * 3600 / 1.33 * z, rel_tol=1e-15)


def test_image_point_tensor_batch_matches_tuples():
    obj = water_60x()
    points = torch.tensor([[1.0, 2.0, 3.0], [-4.0, 0.5, -1.0]], dtype=torch.float64) * um
    images = image_point(obj, points)
    assert images.shape == (2, 3)
    for p, q in zip(points, images, strict=True):
        assert torch.allclose(
            q, torch.tensor(image_point(obj, tuple(p.tolist())), dtype=torch.float64), rtol=1e-15
        )
    with pytest.raises(ValueError, match="last dimension of 3"):
        image_point(obj, torch.zeros(2, 2))


def test_apodization_lookup():
    theta = torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64)
    assert torch.allclose(resolve_apodization("aplanatic")(theta), torch.cos(theta).sqrt())
    assert torch.equal(resolve_apodization("flat")(theta), torch.ones(3, dtype=torch.float64))
    custom = resolve_apodization(lambda t: t**2)
    assert torch.equal(custom(theta), theta**2)
    with pytest.raises(ValueError, match="apodization must be one of"):
        resolve_apodization("gaussian")
