"""Per-lenslet cache: entries hold only the sensor's part of a patch, and a cache smaller than one
design's lenslets keeps what fits (a repeated stack still hits) and says so once."""

from __future__ import annotations

import dataclasses
import warnings

import pytest
import torch

from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optics.kernel_cache import KernelCache
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.systems import lenslet_cache
from lfm_studio.engine.systems.fourier_psf import (
    FourierAccuracy,
    FourierPSFReport,
    fourier_psf_stack,
    lenslet_key,
    resolve_method,
)
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.lenslet_cache import LensletCache, LensletCacheWarning, default_cache_bytes
from lfm_studio.engine.units import mm, nm, um

LENSES = (
    Lenslet((0.1 * mm, -0.05 * mm), 0.25 * mm, 5 * mm, "circle"),
    Lenslet((-0.2 * mm, 0.2 * mm), 0.25 * mm, 5 * mm, "square"),
)
SYSTEM = FourierLFMSystem(
    ObjectiveLens(20.0, 0.5, 1.33, 180 * mm),
    60 * mm,
    MicrolensArray(LENSES),
    5 * mm,
    8 * um,
    (96, 96),
    525 * nm,
)
ACCURACY = FourierAccuracy(oversampling=2, margin_airy=4)
DEPTHS = (-4 * um, 0.0, 3 * um)


def _stack(system=SYSTEM, cache=None, report=None):
    return fourier_psf_stack(system, DEPTHS, accuracy=ACCURACY, cache=cache, report=report).data


def test_an_entry_holds_only_the_part_of_its_window_on_the_sensor():
    """48 x 48 px sensor: lenslet 0's 15 px window lies on it, lenslet 1's starts at pixel
    (42, -8), so 6 x 7 of its pixels are kept; real float32, one plane per depth."""
    system = dataclasses.replace(SYSTEM, sensor_shape=(48, 48))
    _, windows = resolve_method(system, DEPTHS, ACCURACY)
    assert [(w.pixels(2), w.first_pixel) for w in windows] == [(15, (10, 29)), (15, (42, -8))]
    cache = LensletCache(2**20)
    data = _stack(system, cache)
    entries = [cache.get(lenslet_key(system, lens, DEPTHS, ACCURACY, "cpu")) for lens in LENSES]
    assert [tuple(e.shape) for e in entries] == [(3, 15, 15), (3, 6, 7)]
    assert all(e.dtype == torch.float32 and e.is_contiguous() for e in entries)
    assert cache.nbytes == 3 * (15 * 15 + 6 * 7) * 4 == sum(e.untyped_storage().nbytes() for e in entries)
    assert torch.equal(data, _stack(system))  # the same as without a cache
    # A lenslet whose light misses the sensor is neither computed nor stored.
    tiny = dataclasses.replace(SYSTEM, sensor_shape=(8, 8))
    cache, report = LensletCache(2**20), FourierPSFReport()
    with pytest.warns(DesignWarning, match="PSF is zero"):
        assert not _stack(tiny, cache, report).any()
    assert cache.nbytes == 0 and len(cache) == 0 and cache.counters() == (0, 0, 0)
    assert report.lenslets_off_sensor == [0, 1] and not report.lenslets_computed


def test_a_cache_smaller_than_one_design_still_hits_on_a_repeat_and_says_so_once():
    """Room for one of two patches: plain LRU would evict the patch needed next on every miss
    (zero hits); this cache keeps the first, hits it on the repeat and warns once."""
    patch = 3 * 15 * 15 * 4
    cache = LensletCache(patch + 100)
    reference = _stack()
    first, second = FourierPSFReport(), FourierPSFReport()
    with pytest.warns(LensletCacheWarning, match=r"smaller than one design's lenslet patches"):
        assert torch.equal(_stack(cache=cache, report=first), reference)
    assert first.lenslets_computed == [0, 1] and cache.not_stored == 1 and cache.nbytes == patch
    before = cache.counters()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once per cache
        assert torch.equal(_stack(cache=cache, report=second), reference)
    assert second.lenslets_cached == [0] and second.lenslets_computed == [1]
    assert cache.use_since(before) == {
        "hits": 1,
        "misses": 1,
        "not_stored": 1,
        "needed_bytes": 2 * patch,
        "budget_bytes": patch + 100,
    }
    # A later design that moves lenslet 0 evicts its stale patch (from an earlier stack) to store the new one.
    moved = MicrolensArray((dataclasses.replace(LENSES[0], center=(0.12 * mm, -0.05 * mm)), LENSES[1]))
    third = FourierPSFReport()
    _stack(dataclasses.replace(SYSTEM, mla=moved), cache, third)
    assert third.lenslets_computed == [0, 1] and len(cache) == 1 and cache.not_stored == 3


def test_a_stack_that_raises_abandons_its_round_without_a_warning_and_unpins_its_entries(monkeypatch):
    """Room for one of two patches; the stack fails after lenslet 1 was computed and not stored.
    The round is closed anyway: no "smaller than one design" warning from a partial stack, its
    not-stored count dropped, and lenslet 0's patch no longer protected (before, the round stayed
    open and pinned it until the next stack); the next stack then runs as a first one."""
    from lfm_studio.engine.systems import fourier_psf

    patch = 3 * 15 * 15 * 4
    cache = LensletCache(patch + 100)
    placed = fourier_psf._place
    calls = []

    def place_then_fail(out, value, first):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("lenslet 1 refused")
        placed(out, value, first)

    monkeypatch.setattr(fourier_psf, "_place", place_then_fail)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the abandoned round does not warn
        with pytest.raises(RuntimeError, match="lenslet 1 refused"):
            _stack(cache=cache)
    assert cache.counters() == (0, 2, 1) and len(cache) == 1 and not cache.warned
    assert cache._round_not_stored == 0  # the abandoned round's count is gone
    assert cache.put("other", torch.zeros(3, 15, 15))  # lenslet 0's patch is evictable again
    assert len(cache) == 1 and "other" in cache
    monkeypatch.setattr(fourier_psf, "_place", placed)
    report = FourierPSFReport()
    with pytest.warns(LensletCacheWarning, match="smaller than one design"):
        assert torch.equal(_stack(cache=cache, report=report), _stack())
    assert report.lenslets_computed == [0, 1] and cache.round_bytes == 2 * patch


def test_a_cache_that_fits_reports_only_hits_and_misses():
    cache = LensletCache(2**20)
    before = cache.counters()
    _stack(cache=cache)
    _stack(cache=cache)
    assert cache.use_since(before) == {"hits": 2, "misses": 2}
    assert cache.stats()["not_stored"] == 0 and not cache.warned


def test_kernel_cache_is_still_plain_lru():
    cache = KernelCache(budget_bytes=2 * 4 * 10)
    tensors = [torch.zeros(10) for _ in range(3)]
    assert cache.put("a", tensors[0]) and cache.put("b", tensors[1])
    assert cache.get("a") is tensors[0]
    assert cache.put("c", tensors[2])  # evicts b, the least recently used
    assert "b" not in cache and "a" in cache and "c" in cache
    assert not cache.put("big", torch.zeros(30)) and len(cache) == 2


def test_default_budget_is_a_quarter_of_free_memory_within_bounds(monkeypatch):
    for free, expected in [
        (None, lenslet_cache.UNKNOWN_MEMORY_BYTES),
        (2**30, lenslet_cache.DEFAULT_MIN_BYTES),
        (8 * 2**30, 2 * 2**30),
        (2**40, lenslet_cache.DEFAULT_MAX_BYTES),
    ]:
        monkeypatch.setattr(lenslet_cache, "available_bytes", lambda device, free=free: free)
        assert default_cache_bytes() == expected
        assert LensletCache().budget_bytes == expected
