"""Gradient PSF engineering (optimize.gradient.optimize_psf) on the tiny five-lenslet FLFM."""

from __future__ import annotations

import dataclasses
import warnings

import pytest
import torch

from lfm_studio.engine.design import RegularMLASpec
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize import DesignSpace, FocalLengthCatalogue, Infeasible, Parameter
from lfm_studio.engine.optimize.candidate import EvaluationSettings
from lfm_studio.engine.optimize.gradient import optimize_psf, psf_objective
from lfm_studio.engine.optimize.gradient_params import NotDifferentiableError, bind_space
from lfm_studio.engine.optimize.study import load_study, record_of
from lfm_studio.engine.optimize.study_report import trial_rows
from lfm_studio.engine.systems.fourier_psf import fourier_psf_stack
from lfm_studio.engine.systems.from_design import fourier_accuracy_of, fourier_system_of

from .conftest import tiny_flfm

SPACE = DesignSpace(
    (
        Parameter("mla.lenslets[*].focal_length_mm", 12.0, 24.0),
        Parameter("mla_to_camera_distance_mm", 14.0, 20.0),
    )
)
SETTINGS = EvaluationSettings(crop=None)


@pytest.fixture(scope="module")
def poor_start():
    """Lenslets of 22 mm focal length with the camera 15 mm behind them: far out of focus."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return SPACE.apply(
            tiny_flfm(), {"mla.lenslets[*].focal_length_mm": 22.0, "mla_to_camera_distance_mm": 15.0}
        )


def _inside(point):
    for param in SPACE.parameters:
        assert param.low <= point[param.path] <= param.high, (param.path, point)


def test_adam_lowers_the_axial_crb_and_every_step_respects_the_bounds(poor_start, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = optimize_psf(
            poor_start, SPACE, "axial_crb", steps=10, lr=0.1, schedule="cosine", settings=SETTINGS,
            constraints=(), study=str(tmp_path / "study.db"), seed=3,
        )  # fmt: skip
    values = [h.value for h in result.history]
    assert len(values) == 10 and all(v > 0 for v in values)
    assert result.final_value < 0.8 * result.start_value, values  # measured: 1.51 um -> 0.35 um
    for step in result.history:
        _inside(step.point)
    final = SPACE.values_of(result.design)
    _inside({k: float(v) for k, v in final.items()})
    # float32 start gradient against float64, stated tolerance 1e-3 (measured about 1e-7)
    assert result.check is not None and result.check.passed, result.check
    assert result.check.relative_error < 1e-3
    # the study reads back: one complete trial per step and one for the last point, with the
    # design JSON and the seed
    study = load_study(str(tmp_path / "study.db"))
    rows = trial_rows(study)
    assert len(rows) == 11 and all(r.state == "complete" for r in rows)
    last = record_of(study.trials[-1])["gradient"]
    assert last["last"] is True and last["step"] == 10
    assert study.trials[-1].values[0] == pytest.approx(result.last_value)
    assert study.user_attrs["sampler"] == "gradient-adam"
    assert study.user_attrs["gradient"]["final_value"] == pytest.approx(result.final_value)
    first = record_of(study.trials[0])
    assert first["seed"] == 3 and '"mla_to_camera_distance_mm": 15.0' in first["design_json"]
    assert [t.values[0] for t in study.trials[:10]] == pytest.approx(values)
    assert first["gradient"]["step"] == 0 and first["timing"]["total_s"] >= 0


def test_lbfgs_with_a_catalogue_reports_the_value_before_and_after_snapping(poor_start):
    catalogue = FocalLengthCatalogue((10.0, 16.8, 20.0, 26.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = optimize_psf(
            poor_start, SPACE, "axial_crb", steps=4, optimizer="lbfgs", lr=0.5, settings=SETTINGS,
            constraints=(), catalogue=catalogue, check_float64=False,
        )  # fmt: skip
    assert result.final_value < result.start_value
    for step in result.history:
        _inside(step.point)
    assert result.snapped_value is not None and result.unsnapped_design is not None
    assert {lens.focal_length_mm for lens in result.design.mla.lenslets} <= set(catalogue.focal_lengths_mm)
    assert result.summary()["snapped_value"] == result.snapped_value


def test_the_objective_gradient_passes_gradcheck_in_float64(poor_start):
    binding = bind_space(SPACE, poor_start)
    loss = psf_objective("depth_dissimilarity")
    settings = EvaluationSettings(crop=None, dtype="float64")

    def objective(u: torch.Tensor) -> torch.Tensor:
        return loss.loss(binding.psf_stack(poor_start, binding.values(u), settings))

    u = binding.normalised(binding.values_of(poor_start)).clone().requires_grad_(True)
    assert torch.autograd.gradcheck(objective, (u,), eps=1e-6, atol=1e-7, rtol=1e-4)
    (gradient,) = torch.autograd.grad(objective(u), u)
    assert (gradient != 0).all()  # a flat (constant) objective would pass gradcheck too


def test_soft_mtf_support_is_maximised(poor_start):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = optimize_psf(
            poor_start, SPACE, "mtf_support", steps=4, lr=0.1, settings=SETTINGS, constraints=(),
            check_float64=False,
        )  # fmt: skip
    assert result.history[0].loss == pytest.approx(-result.history[0].value)
    assert result.final_value > result.start_value


def test_parameters_the_fast_path_cannot_differentiate_are_refused_by_name():
    design = tiny_flfm()
    for param in (
        Parameter("camera.pixel_pitch_um", 5.0, 7.0),
        Parameter("mla.lenslets[0].shape", choices=("circle", "square")),
        Parameter("mla.lenslets[0].center_um[0]", 0.0, 3.0, integer=True),
    ):
        with pytest.raises(
            NotDifferentiableError, match=r"Differentiable paths: objective\.numerical_aperture"
        ):
            bind_space(DesignSpace((param,)), design)
    with pytest.raises(ValueError, match="differentiable PSF objective"):
        psf_objective("lateral_resolution")


class _CameraWithin:
    """A constraint that is not a box: the camera at most ``limit_mm`` behind the MLA."""

    name = "camera_within"

    def __init__(self, limit_mm: float) -> None:
        self.limit_mm = limit_mm

    def check(self, design):
        if design.mla_to_camera_distance_mm <= self.limit_mm:
            return None
        return Infeasible("camera_too_far", f"{design.mla_to_camera_distance_mm} mm > {self.limit_mm} mm")


def test_a_step_breaking_a_constraint_is_backtracked_and_float64_runs(poor_start):
    """From 15 mm the descent pulls the camera back (to about 17 mm unconstrained); a 15.5 mm limit holds."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = optimize_psf(
            poor_start, SPACE, "axial_crb", steps=4, lr=0.2, settings=SETTINGS,
            constraints=(_CameraWithin(15.5),), check_float64=False, dtype="float64",
        )  # fmt: skip
    distances = [h.point["mla_to_camera_distance_mm"] for h in result.history]
    assert all(d <= 15.5 for d in distances), distances
    assert result.design.mla_to_camera_distance_mm <= 15.5
    assert any(h.backtracks > 0 and "camera_too_far" in h.infeasible for h in result.history)
    assert result.final_value < result.start_value


@pytest.mark.parametrize("name", ["axial_crb", "mtf_support"])
def test_every_kind_of_bound_parameter_passes_gradcheck_in_float64(name):
    """NA (its rim cuts the outer lenslets at 0.45), relay and lenslet focal lengths, a lenslet
    centre (lenslet 3, 20 um clear of the central one), tied apertures and the wavelength."""
    space = DesignSpace(
        (
            Parameter("objective.numerical_aperture", 0.4, 0.5),
            Parameter("relay.focal_length_mm", 70.0, 80.0),
            Parameter("mla.lenslets[3].center_um[0]", 580.0, 620.0),
            Parameter("mla.lenslets[0,3].aperture_diameter_um", 500.0, 600.0),
            Parameter("mla.lenslets[4].focal_length_mm", 15.0, 19.0),
            Parameter("wavelength_nm", 600.0, 700.0),
        )
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        design = space.apply(
            tiny_flfm(),
            {"objective.numerical_aperture": 0.45, "mla.lenslets[0,3].aperture_diameter_um": 560.0},
        )
    binding = bind_space(space, design)
    assert [b.field for b in binding.bindings] == [
        "numerical_aperture", "fourier_focal_length", "centers", "aperture_diameters", "focal_lengths",
        "wavelength",
    ]  # fmt: skip
    loss = psf_objective(name)
    settings = EvaluationSettings(crop=None, dtype="float64")

    def objective(u: torch.Tensor) -> torch.Tensor:
        return loss.loss(binding.psf_stack(design, binding.values(u), settings))

    u = binding.normalised(binding.values_of(design)).clone().requires_grad_(True)
    objective(u).backward()
    assert int((u.grad != 0).sum()) == 6, u.grad  # every parameter moves the objective
    u.grad = None
    assert torch.autograd.gradcheck(objective, (u,), eps=1e-6, atol=1e-7, rtol=1e-4)


def test_cancel_stops_before_the_first_step(poor_start):
    from lfm_studio.engine.progress import CancelledError

    seen = []
    with pytest.raises(CancelledError):
        optimize_psf(
            poor_start, SPACE, steps=3, settings=SETTINGS, constraints=(), check_float64=False,
            progress=lambda done, total, message: seen.append((done, total)), cancel=lambda: True,
        )  # fmt: skip
    assert seen == [(0, 3)]


@pytest.fixture(scope="module")
def regular_row():
    """The tiny FLFM with a regular MLA: one row of three square 600 um lenslets (aperture = pitch)."""
    design = tiny_flfm()
    mla = RegularMLASpec(pitch_um=600.0, shape=(1, 3), focal_length_mm=16.8, lenslet_shape="square")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return design.updated(mla=mla)


REGULAR = DesignSpace(
    (
        Parameter("mla.pitch_um", 560.0, 620.0),
        Parameter("mla.offset_um[0]", -20.0, 20.0),
        Parameter("mla.focal_length_mm", 15.0, 19.0),
    )
)


def test_regular_mla_pitch_offset_and_focal_length_match_the_design_written_with_them(regular_row):
    binding = bind_space(REGULAR, regular_row)
    point = {"mla.pitch_um": 590.0, "mla.offset_um[0]": 7.0, "mla.focal_length_mm": 17.5}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        applied = REGULAR.apply(regular_row, point)
    params = binding.parameters(regular_row, torch.tensor(list(point.values()), dtype=torch.float64))
    expected = torch.tensor([lens.center for lens in applied.mla.lenslets], dtype=torch.float64)
    assert torch.allclose(params.centers, expected, rtol=0, atol=1e-12)
    assert torch.allclose(params.aperture_diameters, torch.full((3,), 590e-6, dtype=torch.float64))
    settings = EvaluationSettings(crop=None, dtype="float64")
    through = binding.psf_stack(regular_row, binding.values_of(applied), settings).data
    system = fourier_system_of(applied)
    # The gradient path sums touching lenslets' fields coherently (what "auto" does with gradients).
    accuracy = dataclasses.replace(
        fourier_accuracy_of(applied), method="per_lenslet_coherent", dtype=torch.float64
    )
    plain = fourier_psf_stack(system, (-20e-6, 0.0, 20e-6), accuracy=accuracy).data
    assert float((through - plain).abs().max() / plain.max()) < 1e-9


def test_regular_mla_parameters_pass_gradcheck(regular_row):
    binding = bind_space(REGULAR, regular_row)
    loss = psf_objective("depth_dissimilarity")
    settings = EvaluationSettings(crop=None, dtype="float64")

    def objective(u: torch.Tensor) -> torch.Tensor:
        return loss.loss(binding.psf_stack(regular_row, binding.values(u), settings))

    u = torch.tensor([0.5, 0.6, 0.4], dtype=torch.float64, requires_grad=True)
    objective(u).backward()
    assert int((u.grad != 0).sum()) == 3, u.grad
    u.grad = None
    assert torch.autograd.gradcheck(objective, (u,), eps=1e-6, atol=1e-7, rtol=1e-4)


def test_a_conventional_design_refuses_a_fourier_only_path_by_name():
    from lfm_studio.engine.design import list_presets, load_preset
    from lfm_studio.engine.systems.kinds import CONVENTIONAL, kind_of
    from lfm_studio.engine.systems.kinds_fourier import FOURIER

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        designs = [load_preset(name) for name in list_presets()]
    conventional = next(d for d in designs if kind_of(d) is not FOURIER)
    assert (
        bind_space(DesignSpace((Parameter("objective.numerical_aperture", 0.3, 0.5),)), conventional).kind
        is CONVENTIONAL
    )
    space = DesignSpace((Parameter("mla.pitch_um", 140.0, 160.0),))
    with pytest.raises(NotDifferentiableError, match="conventional-LFM patterns have no tensor"):
        bind_space(space, conventional)
