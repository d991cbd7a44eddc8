"""A design's pupil_phase: a Zernike mask on the pupil (any term on Fourier designs, m = 0 terms on
conventional ones), in files, hashes and checks."""

from __future__ import annotations

import json

import pytest

from lfm_studio.engine.design import (
    PupilPhaseSpec,
    design_from_json,
    design_to_json,
    load_design,
    optics_hash,
    save_design,
)
from lfm_studio.engine.systems.from_design import conventional_system_of, fourier_system_of


def test_a_pupil_phase_round_trips_through_a_file(tmp_path, fourier):
    design = fourier.updated(pupil_phase={"zernike_waves": {"11": -0.05, "4": 0.1}})
    assert design.pupil_phase == PupilPhaseSpec(zernike_waves={4: 0.1, 11: -0.05})
    path = save_design(design, tmp_path / "masked.json")
    text = path.read_text(encoding="utf-8")
    assert json.loads(text)["pupil_phase"] == {"zernike_waves": {"4": 0.1, "11": -0.05}}  # ascending index
    again = load_design(path)
    assert again == design and design_to_json(again) == text
    assert list(again.pupil_phase.zernike_waves) == [4, 11]
    assert fourier_system_of(again).pupil_zernike_waves == ((4, 0.1), (11, -0.05))


def test_no_pupil_phase_leaves_files_and_hashes_as_before(fourier):
    """A design without a mask writes no pupil_phase key, so its file and hash are those it had
    before the field existed; a mask (even all zero terms) changes the hash."""
    assert "pupil_phase" not in design_to_json(fourier)
    assert "pupil_phase" not in fourier.model_dump(mode="json")
    assert design_from_json(design_to_json(fourier)).pupil_phase is None
    with_mask = fourier.updated(pupil_phase={"zernike_waves": {"4": 0.1}})
    other = fourier.updated(pupil_phase={"zernike_waves": {"4": 0.2}})
    zero = fourier.updated(pupil_phase={"zernike_waves": {"4": 0.0}})
    hashes = {optics_hash(d) for d in (fourier, with_mask, other, zero)}
    assert len(hashes) == 4
    assert fourier_system_of(fourier).pupil_zernike_waves == ()


def test_conventional_designs_take_rotationally_symmetric_terms_only(conventional):
    """m = 0 terms (defocus, spherical) enter the radial Debye integral; any other is refused by name."""
    masked = conventional.updated(pupil_phase={"zernike_waves": {"11": -0.2, "4": 0.1, "22": 0.0}})
    system = conventional_system_of(masked)
    assert system.pupil_zernike_waves == ((4, 0.1), (11, -0.2), (22, 0.0))
    assert conventional_system_of(conventional).pupil_zernike_waves == ()
    assert optics_hash(masked) != optics_hash(conventional)
    assert system != conventional_system_of(conventional) and hash(system) != hash(
        conventional_system_of(conventional)
    )
    for j, n, m in ((2, 1, 1), (5, 2, 2), (8, 3, 1), (12, 4, 2)):
        with pytest.raises(
            ValueError,
            match=rf"pupil_phase.zernike_waves: Noll {j} \(radial order n = {n}, azimuthal frequency m = {m}\) "
            r"is not rotationally symmetric.*kind 'conventional'.*radial Debye integral",
        ):
            conventional.updated(pupil_phase={"zernike_waves": {"4": 0.1, str(j): 0.1}})


def test_bad_terms_are_named(fourier):
    with pytest.raises(
        ValueError, match=r"pupil_phase.zernike_waves: Noll indices must be integers >= 1; got 0"
    ):
        fourier.updated(pupil_phase={"zernike_waves": {"0": 0.1}})
    with pytest.raises(ValueError, match=r"pupil_phase.zernike_waves\[4\] must be a finite number of waves"):
        fourier.updated(pupil_phase={"zernike_waves": {"4": float("nan")}})
    with pytest.raises(ValueError, match="zernike_waves"):
        fourier.updated(pupil_phase={"zernike_waves": {"defocus": 0.1}})
    with pytest.raises(ValueError, match="extra"):
        fourier.updated(pupil_phase={"zernike": {"4": 0.1}})
