"""Grid search finds a known optimum; a candidate that changes one lenslet recomputes one lenslet."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.optimize import (
    Candidate,
    DesignSpace,
    EvaluationSettings,
    Evaluator,
    Parameter,
    PSFLoss,
    grid_search,
    objective_named,
)
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.engine.systems.lenslet_cache import LensletCache


def test_grid_search_finds_the_largest_feasible_aperture(flfm):
    """Effective NA of an FLFM = D M / (2 f_relay) grows with the lenslet aperture D; apertures wider
    than the 600 um pitch overlap, so the optimum is D = 600 um, NA_eff = 600 um x 40 / 150 mm = 0.16."""
    space = DesignSpace((Parameter("mla.lenslets[*].aperture_diameter_um", 300, 750, step=75),))
    evaluator = Evaluator(flfm, space, [objective_named("effective_numerical_aperture")])
    result = grid_search(evaluator)
    assert len(result.records) == 7
    assert result.best.params == {"mla.lenslets[*].aperture_diameter_um": 600.0}
    assert result.best.values["effective_numerical_aperture"] == pytest.approx(
        600e-6 * 40 / (2 * 75e-3), rel=1e-9
    )
    infeasible = {
        r.params["mla.lenslets[*].aperture_diameter_um"]: r.infeasible.reason for r in result.infeasible
    }
    assert infeasible == {675.0: "lenslet_overlap", 750.0: "lenslet_overlap"}
    values = [r.values["effective_numerical_aperture"] for r in result.records if r.values]
    assert values == sorted(values)  # monotone in D, as the closed form says


def test_minimising_direction_picks_the_smallest(flfm):
    space = DesignSpace((Parameter("mla.lenslets[*].aperture_diameter_um", 300, 600, step=150),))
    result = grid_search(Evaluator(flfm, space, [objective_named("lateral_resolution")]))
    # Lateral resolution 0.61 lambda / NA_eff falls as D grows: the best is the largest aperture.
    assert result.best.params["mla.lenslets[*].aperture_diameter_um"] == 600.0
    by_d = {
        r.params["mla.lenslets[*].aperture_diameter_um"]: r.values["lateral_resolution"]
        for r in result.records
    }
    assert by_d[300.0] == pytest.approx(2 * by_d[600.0], rel=1e-9)


def _total_power(stack) -> torch.Tensor:
    return stack.data.double().sum()


def test_moving_one_lenslet_recomputes_one_lenslet(xlfm):
    """XLFM: 27 lenslets on the per-lenslet path; on a 256 px crop the light of 3 of them
    (lenslet 0 among them) reaches the sensor, the other 24 are skipped (not computed, not cached).
    The first candidate computes the 3; changing lenslet 0's focal length computes only lenslet 0
    and reuses 2 from the cache."""
    space = DesignSpace((Parameter("mla.lenslets[0].focal_length_mm", choices=(26.0, 26.5)),))
    settings = EvaluationSettings(crop=256)
    evaluator = Evaluator(xlfm, space, [PSFLoss("total_power", _total_power)], settings=settings)
    first, second = grid_search(evaluator).records
    assert first.cache == {"hits": 0, "misses": 3}
    assert second.cache == {"hits": 2, "misses": 1}
    assert first.timing["psf_s"] > 0 and second.timing["psf_s"] > 0
    assert second.values is not None and second.values["total_power"] > 0
    # The cached result equals a fresh, uncached simulation of the second design.
    design = space.apply(xlfm, second.params)
    fresh = simulate_psf(design, depths=Candidate(design, settings).depths, crop=256)
    assert second.values["total_power"] == pytest.approx(float(fresh.data.double().sum()), rel=1e-6)
    cached = Candidate(design, settings, cache=evaluator.cache).stack
    assert torch.allclose(cached.data, fresh.data, rtol=1e-5, atol=1e-12)


def test_cache_is_rebuilt_when_the_evaluator_is_pickled(flfm):
    import pickle

    space = DesignSpace((Parameter("objective.numerical_aperture", 0.9, 0.95, step=0.05),))
    evaluator = Evaluator(flfm, space, [objective_named("lateral_resolution")])
    copy = pickle.loads(pickle.dumps(evaluator))
    assert isinstance(copy.cache, LensletCache) and copy.cache is not evaluator.cache
    assert copy(next(iter(space.grid()))).values == evaluator(next(iter(space.grid()))).values


def test_grid_search_over_the_lattice_records_every_choice(flfm):
    """A tiny FLFM with a regular array of 600 um lenslets, shape 3 x 3: square (9 lenslets), hex (9)
    and rings (7) at 600 um pitch are all valid; at 1100 um pitch the square and hex corner lenslets
    reach beyond the pupil image (radius NA f_relay / M = 1781 um; they reach 1856 and 1973 um) and
    are recorded with that reason, while the rings' outer apertures reach 1400 um. Every point is
    recorded, none crashes."""
    from lfm_studio.engine.design import LATTICES, RegularMLASpec

    design = flfm.updated(
        mla=RegularMLASpec(
            pitch_um=600.0, shape=(3, 3), focal_length_mm=16.8, lenslet_aperture_diameter_um=600.0
        ),
        camera=type(flfm.camera)(**{**flfm.camera.model_dump(), "pixel_count": (512, 512)}),
    )
    space = DesignSpace(
        (Parameter("mla.lattice", choices=LATTICES), Parameter("mla.pitch_um", choices=(600.0, 1100.0)))
    )
    settings = EvaluationSettings(crop=64, depths_um=(0.0,))
    evaluator = Evaluator(
        design, space, [objective_named("effective_numerical_aperture"), PSFLoss("total_power", _total_power)],
        settings=settings,
    )  # fmt: skip
    result = grid_search(evaluator)
    assert len(result.records) == 6
    outcome = {
        (r.params["mla.lattice"], r.params["mla.pitch_um"]): (r.infeasible.reason if r.infeasible else "ok")
        for r in result.records
    }
    assert outcome == {
        ("square", 600.0): "ok", ("hex", 600.0): "ok", ("rings", 600.0): "ok",
        ("square", 1100.0): "outside_pupil", ("hex", 1100.0): "outside_pupil", ("rings", 1100.0): "ok",
    }  # fmt: skip
    counts = {
        r.params["mla.lattice"]: space.apply(design, r.params).mla.count for r in result.records if r.values
    }
    assert counts == {"square": 9, "hex": 9, "rings": 7}
    for record in result.records:
        if record.values:
            assert record.values["total_power"] > 0


def test_grid_search_over_a_zernike_coefficient(flfm):
    """A tiny FLFM with a pupil phase mask: a grid over the defocus coefficient (waves) evaluates a
    PSF objective for every value; zero defocus gives the in-focus power distribution of the design
    without a mask (equal PSFs: the same total power), and every candidate is feasible."""
    design = flfm.updated(
        camera=type(flfm.camera)(**{**flfm.camera.model_dump(), "pixel_count": (512, 512)}),
        pupil_phase={"zernike_waves": {"4": 0.0}},
    )
    space = DesignSpace((Parameter("pupil_phase.zernike_waves.4", -0.5, 0.5, points=3),))
    settings = EvaluationSettings(crop=64, depths_um=(0.0,))

    def peak(stack) -> torch.Tensor:
        return stack.data.double().amax()

    evaluator = Evaluator(design, space, [PSFLoss("peak", peak)], settings=settings)
    result = grid_search(evaluator)
    assert [r.params["pupil_phase.zernike_waves.4"] for r in result.records] == [-0.5, 0.0, 0.5]
    assert not result.infeasible
    peaks = {r.params["pupil_phase.zernike_waves.4"]: r.values["peak"] for r in result.records}
    plain = simulate_psf(flfm.updated(camera=design.camera), depths=(0.0,), crop=64)
    assert peaks[0.0] == pytest.approx(float(plain.data.double().amax()), rel=1e-6)
    # Defocus lowers the central sub-image's peak either way (0.5 wave over the whole pupil is a
    # small defocus for one lenslet, ~1/6 of the pupil across: a few per mille here).
    assert peaks[-0.5] < peaks[0.0] and peaks[0.5] < peaks[0.0]


def test_a_rings_shape_that_breaks_the_rule_is_recorded_as_invalid(flfm):
    from lfm_studio.engine.design import RegularMLASpec

    design = flfm.updated(
        mla=RegularMLASpec(
            lattice="rings",
            pitch_um=600.0,
            shape=(3, 3),
            focal_length_mm=16.8,
            lenslet_aperture_diameter_um=600.0,
        )
    )
    space = DesignSpace(
        (Parameter("mla.shape[0]", choices=(3, 4)), Parameter("mla.shape[1]", choices=(3, 4)))
    )
    result = grid_search(Evaluator(design, space, [objective_named("effective_numerical_aperture")]))
    reasons = {(r.params["mla.shape[0]"], r.params["mla.shape[1]"]): r.infeasible for r in result.records}
    assert reasons[(3, 3)] is None
    for pair in ((3, 4), (4, 3), (4, 4)):
        assert reasons[pair].reason == "invalid_design"
        assert "shape must be (2 r + 1, 2 r + 1) for lattice 'rings'" in reasons[pair].message
