"""propagate's contract: padding/cropping, the kernel cache, auto method choice and named errors."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.optics import kernel_cache
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.kernel_cache import KernelCache, KernelKey
from lfm_studio.engine.optics.padding import (
    crop_field,
    crop_reversed,
    crop_to,
    pad_field,
    pad_to,
    padded_shape,
)
from lfm_studio.engine.optics.propagation import choose_method, propagate
from lfm_studio.engine.optics.sources import gaussian_beam
from lfm_studio.engine.units import mm, nm, um

C128 = torch.complex128


# -- padding -------------------------------------------------------------------------------------
@pytest.mark.parametrize(("n", "m"), [(8, 16), (7, 16), (8, 15), (7, 15), (5, 5), (4, 5)])
def test_padding_keeps_the_optical_axis_at_index_n_half_and_crop_inverts_it(n, m):
    grid = Grid((n, n + 1), 1 * um)
    data = torch.zeros((n, n + 1), dtype=C128)
    data[n // 2, (n + 1) // 2] = 1.0
    padded = pad_field(Field(data, grid, 500 * nm), shape=(m, m + 1))
    assert padded.grid.shape == (m, m + 1) and padded.grid.spacing == grid.spacing
    assert padded.data[m // 2, (m + 1) // 2] == 1.0 and float(padded.data.abs().sum()) == 1.0
    assert torch.equal(crop_field(padded, (n, n + 1)).data, data)


@pytest.mark.parametrize(("outer", "inner"), [(16, 8), (16, 7), (15, 8), (5, 4), (6, 6), (7, 1)])
def test_crop_reversed_is_the_centred_crop_of_the_index_reversed_array(outer, inner):
    x = torch.randn((3, outer, outer + 2), dtype=C128, generator=torch.Generator().manual_seed(outer))
    reversed_ = x[..., (-torch.arange(outer)) % outer, :][..., (-torch.arange(outer + 2)) % (outer + 2)]
    assert torch.equal(crop_reversed(x, (inner, inner + 2)), crop_to(reversed_, (inner, inner + 2)))


def test_padded_shape_uses_fast_fft_sizes_and_rejects_factors_below_one():
    assert padded_shape((512, 100), 2.0) == (1024, 200)
    assert padded_shape((97, 64), 2.0) == (196, 128)  # 194 = 2 * 97 is slow; 196 = 2^2 7^2
    assert padded_shape((97, 64), 1.0) == (97, 64)
    with pytest.raises(ValueError, match="padding must be a finite factor >= 1"):
        padded_shape((8, 8), 0.5)
    with pytest.raises(ValueError, match="exactly one of factor or shape"):
        pad_field(Field(torch.ones((4, 4), dtype=C128), Grid(4, 1 * um), 500 * nm))
    with pytest.raises(ValueError, match="smaller than the data"):
        pad_to(torch.ones((4, 4), dtype=C128), (3, 4))


# -- kernel cache --------------------------------------------------------------------------------
def _beam() -> Field:
    return gaussian_beam(Grid(64, 2 * um), 500 * nm, 10 * um, dtype=C128)


@pytest.mark.parametrize("method", ["asm", "bandlimited_asm", "fresnel_tf", "fresnel_ir"])
def test_second_call_hits_the_cache_and_returns_the_same_result(method):
    cache = KernelCache()
    field = _beam()
    first = propagate(field, 200 * um, method=method, cache=cache)
    assert (cache.hits, cache.misses, len(cache)) == (0, 1, 1)
    (key,) = list(cache._entries)
    kernel = cache.get(key)
    second = propagate(field, 200 * um, method=method, cache=cache)
    assert (cache.hits, cache.misses) == (2, 1)  # our get() above and the second propagation
    assert cache.get(key) is kernel  # the very same tensor(s), not a rebuilt copy
    assert torch.equal(first.data, second.data)
    # An uncached build gives the same field (Fresnel: 1D factors applied in turn instead of their
    # cached 2D product, so equal to round-off).
    uncached = propagate(field, 200 * um, method=method, cache=False).data
    assert float((uncached - first.data).norm() / first.data.norm()) < 1e-14


def test_cache_keys_on_every_input_and_skips_differentiable_distances():
    cache = KernelCache()
    field = _beam()
    propagate(field, 200 * um, method="asm", cache=cache)
    propagate(field, 201 * um, method="asm", cache=cache)  # distance
    propagate(field.to(dtype=torch.complex64), 200 * um, method="asm", cache=cache)  # dtype
    propagate(field, 200 * um, method="asm", cache=cache, padding=1.5)  # padded shape
    propagate(field, 200 * um, method="asm", cache=cache, include_constant_phase=False)
    propagate(Field(field.data, field.grid, 500 * nm, 1.33), 200 * um, method="asm", cache=cache)
    assert (cache.hits, cache.misses, len(cache)) == (0, 6, 6)
    z = torch.tensor(200 * um, dtype=torch.float64, requires_grad=True)
    propagate(field, z, method="asm", cache=cache)
    assert (cache.hits, cache.misses) == (0, 6)  # built uncached, differentiable
    propagate(
        field, torch.tensor(200 * um, dtype=torch.float64), method="asm", cache=cache
    )  # no grad: cached
    assert cache.hits == 1


def test_cache_evicts_least_recently_used_within_its_byte_budget_and_clears():
    tensor = torch.zeros(1000, dtype=C128)  # 16 kB
    keys = [
        KernelKey("asm", (8, 8), (16, 16), (1e-6, 1e-6), 5e-7, 1.0, d, "cpu", C128) for d in (1.0, 2.0, 3.0)
    ]
    cache = KernelCache(budget_bytes=2 * tensor.numel() * 16)
    cache.put(keys[0], tensor)
    cache.put(keys[1], tensor.clone())
    assert cache.get(keys[0]) is tensor  # keys[0] is now the most recently used
    cache.put(keys[2], tensor.clone())
    assert keys[1] not in cache and keys[0] in cache and keys[2] in cache
    assert cache.nbytes == 2 * 16000
    cache.put(
        KernelKey("asm", (8, 8), (16, 16), (1e-6, 1e-6), 5e-7, 1.0, 9.0, "cpu", C128), torch.zeros(3000)
    )
    assert len(cache) == 2  # larger than the whole budget: returned by builders, never stored
    cache.clear()
    assert (len(cache), cache.nbytes, cache.hits, cache.misses) == (0, 0, 0, 0)


def test_shared_cache_is_used_by_default_and_clear_empties_it():
    kernel_cache.clear()
    propagate(_beam(), 123 * um, method="asm")
    propagate(_beam(), 123 * um, method="asm")
    shared = kernel_cache.default_cache()
    assert shared.hits >= 1 and len(shared) >= 1
    kernel_cache.clear()
    assert len(shared) == 0 and shared.hits == 0


# -- auto ----------------------------------------------------------------------------------------
def test_auto_picks_fresnel_only_where_it_is_exact_to_1e_3_rad():
    wavelength = 500 * nm
    coarse = gaussian_beam(Grid(128, 20 * um), wavelength, 300 * um)
    # Nyquist 2.5e4 / m: Fresnel phase error pi z l^3 f^4 / 4 = 1.9e-5 rad at 5 mm.
    assert choose_method(coarse, 5 * mm) == "fresnel_tf"
    fine = gaussian_beam(Grid(128, 1 * um), wavelength, 15 * um)
    assert choose_method(fine, 100 * um) == "bandlimited_asm"  # 1.5 rad at Nyquist
    # Beyond the padded critical distance (256 * (20 um)^2 / 0.5 um = 205 mm) Fresnel's chirp aliases.
    assert choose_method(coarse, 300 * mm) == "bandlimited_asm"
    out = propagate(coarse, 5 * mm)
    ref = propagate(coarse, 5 * mm, method="bandlimited_asm")
    # Fresnel = ASM to the phase error at the beam's frequencies (<< 1.9e-5 rad).
    assert float((out.data - ref.data).norm() / ref.data.norm()) < 2e-5


# -- named errors --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("distance", "method", "error", "match"),
    [
        (float("nan"), "asm", ValueError, r"distance must be finite; got nan m"),
        (float("inf"), "bandlimited_asm", ValueError, r"distance must be finite; got inf m"),
        (torch.tensor(float("nan")), "fresnel_tf", ValueError, r"distance must be finite; got nan m"),
        (0.0, "fresnel_ir", ValueError, r"distance must be non-zero for method='fresnel_ir'"),
        (torch.tensor([1e-3, 2e-3]), "asm", ValueError, r"0-d real tensor .* shape \(2,\)"),
        ("1 mm", "asm", TypeError, r"distance must be a float or a 0-d tensor in metres; got str"),
        (1e-3, "angular", ValueError, r"method must be one of \('auto', 'asm'"),
    ],
)
def test_bad_arguments_raise_named_errors(distance, method, error, match):
    with pytest.raises(error, match=match):
        propagate(_beam(), distance, method=method)


def test_bad_padding_and_nan_field_raise_named_errors():
    with pytest.raises(ValueError, match="padding must be a finite factor >= 1"):
        propagate(_beam(), 1 * mm, padding=0.5)
    data = torch.ones((8, 8), dtype=C128)
    data[2, 3] = math.nan
    with pytest.raises(ValueError, match=r"Field.data contains 1 NaN/Inf"):
        propagate(Field(data, Grid(8, 1 * um), 500 * nm), 1 * mm)


def test_zero_distance_is_the_identity_on_propagating_content():
    field = _beam()
    for method in ("asm", "bandlimited_asm", "fresnel_tf"):
        out = propagate(field, 0.0, method=method)
        assert float((out.data - field.data).abs().max()) < 1e-14
