"""Typed numbers: the parsing policy, the field, and a fuzz of every numeric input of the studio window.

The fuzz builds the window as ``lfm-studio gui`` does (default preset, real MLA editor
and viewer; only the debounce is long, so no PSF job starts), finds every
:class:`NumericField` generically, and types ``nan, inf, -1, 0, 1e308, '', 'abc', '0,5',
'0.5'`` into each under the C and de_DE locales. After each Enter the value in force is
either the typed number (read by the reference below, independently of the parser) or
the previous one with a visible reason (red border, tooltip, the host's message), the
typed text is kept character for character, and no exception reaches a slot.
"""

from __future__ import annotations

import math
import sys
from collections import Counter

import pytest
from qtpy.QtCore import QLocale, QSettings, Qt
from qtpy.QtTest import QTest
from qtpy.QtWidgets import QAbstractSpinBox, QApplication

from lfm_studio.ui.edits import read_path
from lfm_studio.widgets.numeric_field import NumericField
from lfm_studio.widgets.numeric_text import NumberRule, format_number, parse_number

FUZZ = ("nan", "inf", "-1", "0", "1e308", "", "abc", "0,5", "0.5")
# What each fuzz text means as a number (None: not a finite number), written out by hand.
MEANING = {"nan": None, "inf": None, "-1": -1.0, "0": 0.0, "1e308": 1e308, "": None, "abc": None,
           "0,5": 0.5, "0.5": 0.5}  # fmt: skip
LOCALES = ("C", "de_DE")
# Parameter panel 14 fields (two of them pairs) = 16; workflow 4 + the registry's method options
# (rtol, tv_weight, snr, refine); MLA editor 5 + 2 + 2.
EXPECTED_FIELDS = 18 + 4 + 4 + 9 + 4 + 15  # parameter panel (incl. the two volume-grid settings), workflow,
# MLA editor, Train dock (minutes, max steps, seed, optics jitter), Optimise dock (grid budget; axial_crb
# photons and background for grid search and Algorithm 2; Algorithm 2: minimum lenslet, crop; gradient:
# steps, learning rate, crop, photons, background; end to end: learning rate, iterations, batch,
# held-out, photons)
# Fields that do not apply to the default (Fourier) design, or to the default method (accelerated RL),
# are shown disabled and cannot be typed into.
DISABLED_ON_FOURIER = {"accuracy.voxels_per_lenslet", "snr", "refine"}


@pytest.fixture
def locale(request):
    QLocale.setDefault(QLocale(request.param))
    yield request.param
    QLocale.setDefault(QLocale.c())


def _expected(rule: NumberRule, text: str) -> float | None:
    """The number a field must put in force for ``text``, or None if it must refuse it."""
    number = MEANING[text]
    if number is None or (rule.integer and number != int(number)):
        return None
    return number if rule.minimum <= number <= rule.maximum else None


def _type(field: NumericField, text: str) -> None:
    """What a user does: select all, type, Enter."""
    field.setFocus()
    field.selectAll()
    QTest.keyClick(field, Qt.Key.Key_Backspace)
    QTest.keyClicks(field, text)
    QTest.keyClick(field, Qt.Key.Key_Return)


# ----- the policy -----


@pytest.mark.parametrize(
    ("text", "value"),
    [("0,5", 0.5), ("0.5", 0.5), (" 2,25 mm", 2.25), ("-1", -1.0), ("\u22123", -3.0), ("1e3", 1000.0),
     ("1E-2", 0.01), (".5", 0.5), ("5.", 5.0), ("12 um", 12.0), ("12 µm", 12.0), ("+4", 4.0)],
)  # fmt: skip
def test_numbers_are_read_with_either_decimal_mark(text, value):
    rule = NumberRule("width", -10.0, 1e4, "mm" if "mm" in text else "µm")
    assert parse_number(text, rule) == pytest.approx(value, rel=1e-15)


@pytest.mark.parametrize(
    ("text", "reason"),
    [("nan", "cannot be NaN"), ("-inf", "cannot be infinity"), ("Infinity", "cannot be infinity"),
     ("", "is empty"), ("abc", "must be a number; got 'abc'"), ("1,000.5", "has 2 decimal marks"),
     ("1.000,5", "has 2 decimal marks"), ("1_000", "must be a number"), ("0x10", "must be a number"),
     ("1e308", "1e+308 is out of range"), ("1e309", "too large"), ("-1", "-1 is out of range"),
     ("5 kg", "must be a number; got '5 kg'"), ("2.5", None)],
)  # fmt: skip
def test_anything_else_is_refused_with_the_reason_and_the_fix(text, reason):
    rule = NumberRule("Pixel pitch", 0.0, 1e3, "µm", example=6.5)
    if reason is None:
        assert parse_number(text, rule) == 2.5
        return
    with pytest.raises(ValueError, match="Pixel pitch") as error:
        parse_number(text, rule)
    assert reason in str(error.value)
    assert "Fix: type a number from 0 to 1000 µm, e.g. 6.5." in str(error.value)


@pytest.mark.parametrize(
    ("text", "unit", "value"),
    [("0.0065 mm", "µm", 6.5), ("0,0065mm", "um", 6.5), ("6500 nm", "µm", 6.5), ("6.5e-6 m", "µm", 6.5),
     ("0.2 m", "mm", 200.0), ("0.68 µm", "nm", 680.0)],
)  # fmt: skip
def test_a_length_field_converts_another_length_unit(text, unit, value):
    """ "0.0065 mm" in the pixel pitch (µm) was refused as not a number while "6.5 um" was taken."""
    assert parse_number(text, NumberRule("Pixel pitch", 0.0, 1e3, unit)) == pytest.approx(value, rel=1e-12)


def test_a_unit_the_field_cannot_take_is_refused_naming_the_units_it_takes():
    with pytest.raises(ValueError, match=r"got '5 kg' \(units: µm, nm, mm, m\)"):
        parse_number("5 kg", NumberRule("Pixel pitch", 0.0, 1e3, "µm"))
    with pytest.raises(ValueError, match=r"got '5 mm' \(unit: fold\)"):
        parse_number("5 mm", NumberRule("rotation", 1, 12, "fold", integer=True))


def test_integers_refuse_fractions_and_special_words_mean_the_minimum():
    rule = NumberRule("rotation", 1, 12, "fold", integer=True, special_text="off")
    assert parse_number("1e1", rule) == 10 and isinstance(parse_number("3", rule), int)
    assert parse_number("OFF", rule) == 1 and parse_number("6 fold", rule) == 6
    with pytest.raises(ValueError, match="must be a whole number; got '2,5'"):
        parse_number("2,5", rule)


def test_format_round_trips_through_the_parser():
    rule = NumberRule("x", -1e300, 1e300)
    for value in (0.1 + 0.2, 525.0, -1e-7, 1e15, 123456.789, 2.0 / 3.0):
        for mark in (".", ","):
            text = format_number(value, mark)
            assert parse_number(text, rule) == pytest.approx(value, rel=1e-9)
    assert format_number(0.5, ",") == "0,5" and format_number(1e6) == "1000000"


# ----- the field -----


@pytest.mark.parametrize("locale", LOCALES, indirect=True)
def test_the_field_commits_valid_text_only_and_keeps_refused_text(qtbot, locale):
    rule = NumberRule("Read noise", 0.0, 100.0, "e⁻")
    field = NumericField(rule, 2.0, step=0.5)
    qtbot.addWidget(field)
    committed, refused = [], []
    field.committed.connect(committed.append)
    field.refused.connect(refused.append)
    mark = QLocale().decimalPoint()
    assert field.text() == "2 e⁻" and mark == {"C": ".", "de_DE": ","}[locale]
    _type(field, "0,5")
    assert committed == [0.5] and field.value() == 0.5 and field.text() == f"0{mark}5 e⁻"
    _type(field, "-1")
    assert field.value() == 0.5 and field.text() == "-1"  # no character dropped, nothing clamped
    assert committed == [0.5] and len(refused) == 1 and "out of range" in refused[0]
    assert field.error() == refused[0] == field.toolTip() and "border" in field.styleSheet()
    field.setValue(0.5)  # the same value in force (another field changed): the text waits to be corrected
    assert field.text() == "-1" and field.error() is not None
    _type(field, "0.5")  # corrected to the value in force: valid again, and the host hears of it
    assert committed == [0.5, 0.5] and field.error() is None and field.styleSheet() == ""
    field.setValue(3.0)  # state -> view: no signal
    assert committed == [0.5, 0.5] and field.text() == "3 e⁻"
    QTest.keyClick(field, Qt.Key.Key_Up)
    assert committed[-1] == 3.5 and field.value() == 3.5
    field.setValue(99.8)
    QTest.keyClick(field, Qt.Key.Key_PageUp)  # +5 would leave the range: stops at the maximum
    assert field.value() == 100.0
    field.set_invalid("the design refuses it")
    assert field.toolTip() == "the design refuses it" and field.property("invalid") is True
    field.set_invalid(None)
    assert field.property("invalid") is False and field.styleSheet() == ""


def test_a_photon_field_steps_by_decades(qtbot):
    field = NumericField(NumberRule("Photon budget", 1.0, 1e15, "photons"), 2e5, log_step=True, tip="x10")
    qtbot.addWidget(field)
    assert field.toolTip() == "x10" and field.property("invalid") is False  # the tip from the start
    field.stepBy(1)
    assert field.value() == 1e6
    field.stepBy(-7)
    assert field.value() == 1.0  # the minimum, not 1e-1


# ----- the whole window -----


@pytest.fixture
def window(qtbot, tmp_path, locale):
    from lfm_studio.ui.app import build_studio

    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    window = build_studio(settings=settings, debounce_ms=3_600_000)  # as `lfm-studio gui`, no PSF job
    window.show()
    qtbot.waitExposed(window)
    yield window
    window.state.replace_design(window.state.design)  # not dirty: no unsaved-changes prompt
    with qtbot.waitSignal(window.destroyed, timeout=30_000):
        window.close()
    QApplication.sendPostedEvents(None, 0)


def _hosts(window):
    """Each field with (what it sets, the value in force, the host's message and whether it is visible)."""
    state, panel, flow, editor = window.state, window.parameter_panel, window.workflow_panel, window.editor
    hosts = {}
    for path, quantity in panel.inputs.items():
        for i, box in enumerate(quantity.boxes):

            def in_force(path=path, i=i, spec=quantity.spec):
                value = read_path(state.design, path)
                value = value[i] if spec.parts == 2 else value
                return spec.minimum if value is None else value

            hosts[box] = (path, in_force, lambda path=path: _shown(panel.error_labels[path]))
    for name in ("bead_count", "photons", "seed", "iterations"):
        in_force = lambda name=name: getattr(state.workflow, name)  # noqa: E731
        hosts[getattr(flow, name)] = (name, in_force, lambda: _shown(flow.input_error))
    for field in flow.method_options.numeric_fields():  # the method's options, from the registry
        name = next(n for n in flow.method_options.option_names() if flow.method_options.field(n) is field)

        def option_in_force(name=name, field=field):
            value = dict(state.workflow.method_options).get(name)
            return field.rule.minimum if value is None else value  # None: "off"

        hosts[field] = (name, option_in_force, lambda: _shown(flow.input_error))
    train = window.train_dock
    for name in (
        "minutes",
        "max_steps",
        "seed",
        "jitter",
    ):  # read when Train is pressed: the field holds the value in force
        field = getattr(train, name)
        hosts[field] = (name, field.value, lambda: _shown(train.message))
    optimise = window.optimise
    for field in optimise.all_option_fields():  # read when Run is pressed: the field holds the value in force
        hosts[field] = (field.rule.name, field.value, lambda: _shown(optimise.message))
    bar = editor.symmetry_bar
    for field in editor.numeric_fields():
        in_force = (lambda: editor.symmetry().rotation) if field is bar.rotation else field.value
        hosts[field] = (field.rule.name, in_force, lambda: (editor.status_text(), editor.status.isVisible()))
    return hosts


def _shown(label):
    return label.text(), label.isVisible()


@pytest.mark.parametrize("locale", LOCALES, indirect=True)
def test_every_numeric_widget_takes_the_number_typed_or_keeps_the_previous_with_a_reason(window, monkeypatch):
    errors = []
    monkeypatch.setattr(sys, "excepthook", lambda kind, value, tb: errors.append(value))
    spin_boxes = window.findChildren(QAbstractSpinBox)
    ours = [w for w in spin_boxes if not type(w).__module__.startswith("napari")]  # napari's: its fps boxes
    assert ours == [], "a raw spin box bypasses the numeric-field policy: use NumericField"
    fields = window.findChildren(NumericField)
    hosts = _hosts(window)
    assert len(fields) == EXPECTED_FIELDS and set(fields) == set(hosts)
    window.editor.set_snap(100.0)  # the snap pitch is in force
    state, outcomes = window.state, Counter()
    for field in fields:
        name, in_force, message = hosts[field]
        if name in DISABLED_ON_FOURIER:
            assert not field.isEnabled(), name
            continue
        assert field.isEnabled(), name
        for text in FUZZ:
            before = in_force()
            _type(field, text)
            expected = _expected(field.rule, text)
            case = f"{name} <- {text!r}"
            outcomes["refused" if expected is None else "design" if state.errors.get(name) else "taken"] += 1
            if expected is None:  # refused by the field: the previous value, the text, the reason
                assert in_force() == before, case
                assert field.text() == text and field.error(), case
                assert field.toolTip() == field.error() and field.property("invalid") is True, case
                assert message() == (message()[0], True) and field.error() in message()[0], case
            elif state.errors.get(name):  # a number the design checks refuse: shown, not in force
                assert in_force() == before and field.value() == pytest.approx(expected), case
                assert field.property("invalid") is True and message()[1], case
            else:
                assert in_force() == pytest.approx(expected, rel=1e-12, abs=1e-300), case
                assert field.error() is None and field.property("invalid") is False, case
            reason = field.reason()
            _type(field, format_number(before, QLocale().decimalPoint()))  # back to the value before
            assert in_force() == pytest.approx(before, rel=1e-9), case
            shown, visible = message()
            assert (
                field.error() is None and not state.errors and not (reason and visible and reason in shown)
            ), case
            assert not (math.isnan(field.value()) or math.isinf(field.value())), case
    assert errors == []
    assert (
        sum(outcomes.values()) == (EXPECTED_FIELDS - len(DISABLED_ON_FOURIER)) * len(FUZZ)
        and min(outcomes.values()) >= 10
    ), outcomes


def test_the_workflow_buttons_do_not_run_with_a_refused_number(qtbot):
    from lfm_studio.ui.state import StudioState
    from lfm_studio.ui.workflow_panel import WorkflowPanel
    from tests.ui.standins import small_fourier_design

    state = StudioState(small_fourier_design())
    panel = WorkflowPanel(state)
    qtbot.addWidget(panel)
    requests = []
    panel.simulate_requested.connect(lambda: requests.append("simulate"))
    panel.photons.setText("nan")  # typed, not yet committed
    panel.simulate_button.click()
    assert requests == [] and state.workflow.photons == 1e6  # not 1e15, not noise-free
    assert "Photon budget cannot be NaN" in panel.input_error.text() and not panel.input_error.isHidden()
    _type(panel.iterations, "12,0")
    _type(panel.photons, "2e5")
    assert state.workflow.photons == 2e5 and state.workflow.iterations == 12 and panel.input_error.isHidden()
    panel.simulate_button.click()
    assert requests == ["simulate"]
    panel.disconnect_state()
