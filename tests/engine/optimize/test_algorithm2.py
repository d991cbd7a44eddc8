"""Thesis Algorithm 2 on small MLA planes: determinism, symmetry, no overlaps, known optima."""

from __future__ import annotations

import math
import threading
import warnings

import pytest
import torch

from lfm_studio.engine.design import evolve, load_preset
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla import mla_transmission
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optimize.algorithm1 import concatenate, mask_coordinates
from lfm_studio.engine.optimize.algorithm2 import algorithm2
from lfm_studio.engine.optimize.mla_cells import SYMMETRIES, Block, MLAPlane, merge, orbit
from lfm_studio.engine.performance import closed_form_metrics
from lfm_studio.engine.progress import CancelledError


@pytest.fixture(scope="module")
def xlfm():
    return load_preset("xlfm_cong2017")


@pytest.fixture(scope="module")
def plane(xlfm):
    return MLAPlane.from_design(xlfm, 2000.0)  # 8 x 8 cells of 2 mm over the 16 mm pupil


def central_aperture(design) -> float:
    """Toy score: aperture (um) of the lenslet centred on the axis (0 if none)."""
    return max(
        (lens.aperture_diameter_um for lens in design.mla.lenslets if lens.center_um == (0.0, 0.0)),
        default=0.0,
    )


def lopsided(design) -> float:
    """An asymmetric toy score: rewards large lenslets on the right (+x) and top (+y)."""
    return sum(
        lens.aperture_diameter_um**2 * (1.0 + 1e-4 * lens.center_um[0] + 3e-5 * lens.center_um[1])
        for lens in design.mla.lenslets
        if lens.aperture_diameter_um > 2000.0
    )


def closed_form_score(design) -> float:
    """Cheap real score (higher is better): minus the sum of lateral and axial resolution, um."""
    metrics = closed_form_metrics(design)
    axial = metrics.axial_resolution if metrics.axial_resolution is not None else 1e-3
    return -(metrics.lateral_resolution + axial) / 1e-6


def test_finds_the_one_big_central_lenslet(xlfm, plane):
    records = []
    result = algorithm2(xlfm, central_aperture, plane=plane, record=records.append)
    # Largest centred block inside the 16 mm pupil among sizes 1..7: 6 cells (12 mm), since
    # a centred block needs an even size on an 8-cell grid and 8 cells is not tried by default.
    assert result.score == 12000.0
    assert Block(1, 1, 6) in result.blocks
    assert all(b.size == 1 for b in result.blocks if b != Block(1, 1, 6))
    assert result.history == (0.0, 4000.0, 8000.0, 12000.0)
    accepted = [(c.params["size"], c.params["i"], c.params["j"]) for c in records if c.accepted]
    assert accepted == [(1, None, None), (2, 3, 3), (4, 2, 2), (6, 1, 1)]
    # With size 8 allowed, one lenslet over the whole pupil wins.
    whole = algorithm2(xlfm, central_aperture, plane=plane, sizes=range(1, 9))
    assert whole.blocks == (Block(0, 0, 8),) and whole.score == 16000.0


def test_minimize_direction_prefers_small_central_lenslets(xlfm, plane):
    result = algorithm2(xlfm, lambda d: -central_aperture(d), plane=plane, direction="minimize")
    assert Block(1, 1, 6) in result.blocks and result.score == -12000.0


def test_is_deterministic(xlfm, plane):
    runs = []
    for _ in range(2):
        records = []
        algorithm2(xlfm, lopsided, plane=plane, record=records.append)
        runs.append([(c.params, c.blocks, c.score, c.reason, c.accepted) for c in records])
    assert runs[0] == runs[1] and len(runs[0]) > 50


@pytest.mark.parametrize("symmetry", SYMMETRIES)
def test_respects_symmetry_and_never_overlaps(xlfm, plane, symmetry):
    records = []
    result = algorithm2(xlfm, lopsided, plane=plane, symmetry=symmetry, record=records.append)
    assert len(result.history) >= 2  # something was merged
    state = set(result.blocks)
    for block in state:
        assert set(orbit(block, plane.cells, symmetry)) <= state
    for candidate in records:
        blocks = candidate.blocks
        for k, a in enumerate(blocks):
            assert not any(a.overlaps(b) for b in blocks[k + 1 :]), candidate.params
        if candidate.reason:
            assert candidate.score is None and not candidate.accepted
            assert candidate.blocks == ()  # refused merges (pupil, conflicts) have no layout
        else:
            assert candidate.design.mla.count == len(blocks)  # lenslets = blocks, each inside the pupil
            assert all(not plane.outside_reason(b) for b in blocks)
    # Every lenslet of the initial layout is still covered by exactly one block.
    covered = [b for b in result.blocks for c in plane.initial_blocks() if b.contains(c)]
    assert len(covered) == len(plane.initial_blocks())


def test_a_conflicting_better_merge_replaces_the_last_one(xlfm, plane):
    # Block(1, 1, 2) is accepted first; Block(2, 1, 2) cuts through it and scores higher, so the
    # thesis' lines 8-9 retry it on T_last (the layout before the first merge) and it replaces it.
    def score(design):
        apertures = {lens.center_um: lens.aperture_diameter_um for lens in design.mla.lenslets}
        value = 0.0
        if apertures.get((-4000.0, -4000.0)) == 4000.0:  # Block(1, 1, 2)
            value = 1.0
        if apertures.get((-2000.0, -4000.0)) == 4000.0:  # Block(2, 1, 2)
            value = 2.0
        return value

    records = []
    result = algorithm2(xlfm, score, plane=plane, sizes=[2], record=records.append)
    assert result.score == 2.0
    assert Block(2, 1, 2) in result.blocks and Block(1, 1, 2) not in result.blocks
    replaced = next(c for c in records if c.accepted and c.score == 2.0)
    assert replaced.params == {"size": 2, "i": 2, "j": 1, "base": "last"}


def test_infeasible_candidates_are_recorded_with_a_reason(xlfm, plane):
    def picky(design):
        if design.mla.count < 32:
            raise ValueError("too few views for this score")
        return float(design.mla.count)

    records = []
    result = algorithm2(xlfm, picky, plane=plane, sizes=[2, 7], record=records.append)
    assert result.blocks == plane.initial_blocks() and result.score == 32.0
    reasons = [c.reason for c in records[1:]]
    assert reasons and all(reasons)  # every merge is infeasible, none crashed the run
    assert any("beyond the pupil radius" in r for r in reasons)
    assert any(r == "score failed: too few views for this score" for r in reasons)
    failed = [c for c in records if c.reason.startswith("score failed")]
    assert all(c.design is not None and c.score is None and not c.accepted for c in failed)
    assert result.infeasible == len(reasons) and result.evaluated == 1 + len(failed)


def test_real_small_run_improves_a_closed_form_score(xlfm, plane):
    records = []
    result = algorithm2(xlfm, closed_form_score, plane=plane, symmetry="mirror-xy", record=records.append)
    initial = records[0]
    assert initial.params["base"] == "initial" and initial.score == result.history[0]
    assert result.score > initial.score + 0.5  # at least half a micrometre better
    scored = [c.score for c in records if c.score is not None]
    assert result.score == max(scored)  # greedy acceptance keeps the best ever scored
    assert closed_form_score(result.design) == pytest.approx(result.score, rel=1e-12)
    # 2 mm lenslets 2 mm apart: their 2.2 mm sub-images overlap, a design warning kept per candidate.
    assert any("sub-images overlap" in note for note in initial.warnings)
    assert result.evaluated == len(scored) + sum(
        1 for c in records if c.design is not None and c.score is None
    )


def test_progress_and_cancel(xlfm, plane):
    calls = []
    algorithm2(xlfm, central_aperture, plane=plane, sizes=[2, 3], progress=lambda *a: calls.append(a))
    total = 7 * 7 + 6 * 6
    assert calls[-1][:2] == (total, total)
    assert [c[0] for c in calls] == sorted(c[0] for c in calls)
    flag = threading.Event()

    def score(design):
        flag.set()  # cancel after the first evaluation
        return central_aperture(design)

    with pytest.raises(CancelledError):
        algorithm2(xlfm, score, plane=plane, cancel=flag)


def test_bad_arguments(xlfm, plane):
    with pytest.raises(ValueError, match="exactly one of plane and min_lenslet_um"):
        algorithm2(xlfm, central_aperture)
    with pytest.raises(ValueError, match="sizes must be whole numbers"):
        algorithm2(xlfm, central_aperture, plane=plane, sizes=[9])
    with pytest.raises(ValueError, match="direction"):
        algorithm2(xlfm, central_aperture, plane=plane, direction="up")
    result = algorithm2(xlfm, central_aperture, min_lenslet_um=4000.0, sizes=[2])
    assert result.blocks == (Block(1, 1, 2),) and math.isclose(result.score, 8000.0)


# ----- Algorithm 1: the literal concatenation agrees with the engine's MLA element -----


@pytest.mark.parametrize("shape", ["circle", "square"])
def test_algorithm1_matches_the_engine_mla_transmission(shape):
    # 5 x 5 cells of 50 um, 7 pixels each: K = 35 (odd), so the mask's pixel centres are the
    # engine Grid's and no pixel centre falls on a lenslet edge or rim.
    small = MLAPlane(50.0, 5, 400.0, (5.0, 6.0), shape)
    blocks, reason = merge(small.initial_blocks(), [Block(0, 0, 2), Block(2, 2, 3)])
    assert reason == "" and {b.size for b in blocks} == {1, 2, 3}
    assert {small.focal_length_mm(b) for b in blocks} == {5.0, 6.0}
    mask = concatenate(small, blocks, pixels_per_cell=7, wavelength_nm=500.0, refractive_index=1.0)
    pixel = 50e-6 / 7
    grid = Grid(35, pixel)
    assert torch.allclose(mask_coordinates(small, 7), grid.axes(dtype=torch.float64)[1], atol=1e-15)
    lenslets = tuple(
        Lenslet(lens.center, lens.aperture_diameter, lens.focal_length, lens.shape)
        for lens in small.lenslets(blocks)
    )
    engine = mla_transmission(MicrolensArray(lenslets), grid, 500e-9, dtype=torch.complex128)
    assert torch.equal(mask != 0, engine != 0)  # the same pixels are inside the apertures
    assert torch.allclose(mask, engine, atol=1e-9)
    # Independent spot check: the 3 x 3-cell lenslet's centre pixel has phase 0, a pixel 10 away
    # along x has -k (10 px)^2 / (2 f).
    centre_row = centre_col = 2 * 7 + (3 * 7) // 2
    assert mask[centre_row, centre_col] == pytest.approx(1.0)
    k = 2 * math.pi / 500e-9
    expected = -k * (10 * pixel) ** 2 / (2 * small.focal_length_mm(Block(2, 2, 3)) * 1e-3)
    got = torch.angle(mask[centre_row, centre_col + 10]).item()
    assert math.remainder(got - expected, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_algorithm1_refuses_bad_input():
    small = MLAPlane(50.0, 5, 400.0, (5.0,))
    with pytest.raises(ValueError, match="pixels_per_cell"):
        concatenate(small, small.initial_blocks(), pixels_per_cell=0, wavelength_nm=500.0)
    with pytest.raises(ValueError, match="wavelength_nm"):
        concatenate(small, small.initial_blocks(), pixels_per_cell=3, wavelength_nm=-1.0)
    with pytest.raises(ValueError, match="blocks must be lenslets of the plane"):
        concatenate(small, [Block(4, 4, 2)], pixels_per_cell=3, wavelength_nm=500.0)


def test_layouts_the_design_checks_refuse_are_recorded_and_never_scored(xlfm):
    # An 11 mm sensor keeps the hand design (views within 5.5 mm) but not 1.5 mm cells centred
    # 6.75 mm off the axis: their sub-images would be centred off the sensor (a DesignError).
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the hand design's outer sub-images are clipped
        narrow = evolve(xlfm, "camera.pixel_count", (1700, 1700))
    plane = MLAPlane.from_design(narrow, 1500.0)
    calls, records = [], []
    result = algorithm2(
        narrow, lambda d: calls.append(d) or 1.0, plane=plane, sizes=[2], record=records.append
    )
    assert calls == []  # every layout still holds an off-sensor cell
    assert (
        records[0].reason.startswith("design refused") and "sub-images must be centred" in records[0].reason
    )
    assert (
        result.design is None
        and result.score == -math.inf
        and result.evaluated == len(records) - sum(1 for c in records if c.blocks == ())
    )


@pytest.mark.slow
def test_psf_scored_run_on_a_small_fourier_design():
    # Algorithm 2 scored by the mean axial Cramer-Rao bound of the simulated PSF (section 5.2.2):
    # FLFM preset, 5 x 5 cells, 8-fold symmetry, 3 depths, sensor cut to 480 x 480 pixels
    # (3.1 mm: every view of the 3.56 mm pupil stays on it).
    from lfm_studio.engine.optimize.psf_losses import axial_crb
    from lfm_studio.engine.simulation import simulate_psf

    design = load_preset("flfm_guo2019")
    plane = MLAPlane.from_design(design, design.pupil_diameter_at_mla / 1e-6 / 5)
    depths = (-10e-6, 0.0, 10e-6)
    z = torch.tensor(depths, dtype=torch.float64)

    def mean_crb(candidate):
        stack = simulate_psf(candidate, depths=depths, crop=480).data.double()
        return axial_crb(stack, z, photons=1000.0, background=1.0).mean().item()

    records = []
    result = algorithm2(
        design, mean_crb, plane=plane, symmetry="8-fold", direction="minimize", record=records.append
    )
    scored = [c for c in records if c.score is not None]
    # The start (13 minimum lenslets) and the centred 3 x 3-cell lenslet with its 4 neighbours
    # are the only 8-fold layouts inside the pupil.
    assert [c.design.mla.count for c in scored] == [13, 5]
    assert all(0.0 < c.score < 1e-6 for c in scored)  # sub-micrometre bounds at 1000 photons
    # Trading 9 small views for one big central lens (no parallax) loses axial information.
    assert scored[1].score > scored[0].score and not scored[1].accepted
    assert result.blocks == plane.initial_blocks() and result.score == scored[0].score
