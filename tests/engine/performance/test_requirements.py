"""Requirement checks: direction of each comparison, margins, undecided cases."""

from __future__ import annotations

import pytest

from lfm_studio.engine.performance import ZEBRAFISH_LARVA, Requirement, check_requirements
from lfm_studio.engine.performance.requirements import check, overall
from lfm_studio.engine.units import um


def by_quantity(checks):
    return {c.quantity: c for c in checks}


def test_zebrafish_requirements_are_the_thesis_numbers():
    limits = {r.quantity: (r.comparison, r.limit) for r in ZEBRAFISH_LARVA}
    assert limits == {
        "field_of_view": (">=", pytest.approx(800 * um)),
        "depth_of_field": (">=", pytest.approx(200 * um)),
        "lateral_resolution": ("<=", pytest.approx(3 * um)),
        "axial_resolution": ("<=", pytest.approx(5 * um)),
    }


def test_pass_and_fail_with_signed_margins():
    values = {
        "field_of_view": 900 * um,  # 100 um to spare
        "depth_of_field": 150 * um,  # 50 um short
        "lateral_resolution": 2.5 * um,  # finer than 3 um: passes
        "axial_resolution": 6 * um,  # coarser than 5 um: fails
    }
    checks = by_quantity(check_requirements(values))
    assert checks["field_of_view"].passed and checks["field_of_view"].margin == pytest.approx(100 * um)
    assert checks["field_of_view"].relative_margin == pytest.approx(0.125)
    assert checks["depth_of_field"].passed is False and checks["depth_of_field"].margin == pytest.approx(
        -50 * um
    )
    assert checks["lateral_resolution"].passed and checks["lateral_resolution"].margin == pytest.approx(
        0.5 * um
    )
    assert checks["axial_resolution"].passed is False and checks["axial_resolution"].margin == pytest.approx(
        -1 * um
    )
    assert overall(tuple(checks.values())) is False


def test_exactly_at_the_limit_passes():
    assert check(Requirement("field_of_view", ">=", 800 * um, ""), 800 * um, "closed_form").passed is True
    assert check(Requirement("lateral_resolution", "<=", 3 * um, ""), 3 * um, "closed_form").passed is True


def test_undefined_values_and_short_lower_bounds_are_undecided():
    missing = check(Requirement("axial_resolution", "<=", 5 * um, ""), None, "closed_form")
    assert missing.passed is None and missing.margin is None and missing.relative_margin is None
    req = Requirement("depth_of_field", ">=", 200 * um, "")
    assert check(req, 150 * um, "measured", lower_bound=True).passed is None  # the true DoF may be larger
    assert check(req, 250 * um, "measured", lower_bound=True).passed is True  # a lower bound that passes
    assert overall((missing,)) is None
    assert overall((check(req, 250 * um, "measured"),)) is True


def test_quantities_not_given_are_skipped_and_basis_is_recorded():
    checks = check_requirements({"depth_of_field": 300 * um}, basis="measured")
    assert [(c.quantity, c.basis, c.passed) for c in checks] == [("depth_of_field", "measured", True)]
