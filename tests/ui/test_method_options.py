"""MethodOptions: the registry's methods and option fields; defaults follow the method, typed values stay."""

from __future__ import annotations

import pytest

from lfm_studio.engine.reconstruct import registry
from lfm_studio.engine.systems.kinds import CONVENTIONAL, FOURIER
from lfm_studio.widgets.method_options import OFF, MethodOptions


@pytest.fixture
def form(qtbot):
    widget = MethodOptions(exclude=("background",))
    qtbot.addWidget(widget)
    return widget


def test_every_registered_method_is_offered_and_the_default_is_chosen(form):
    assert [form.method.itemData(i) for i in range(form.method.count())] == registry.names()
    assert form.method_name() == registry.default_method()
    assert set(form.option_names()) == set(registry.all_options()) - {"background"}
    assert form.values() == {"iterations": 30, "rtol": None, "tv_weight": 0.0}  # accelerated RL's defaults


def test_fields_follow_the_method_and_a_typed_value_stays(form):
    edits = []
    form.edited.connect(lambda: edits.append(1))
    form.set_method("wiener")
    assert form.values() == {"snr": 100.0} and edits
    assert not form.field("iterations").isEnabled() and form.field("snr").isEnabled()
    form.set_method("tikhonov")  # SNR still at Wiener's default: moves to Tikhonov's
    assert form.values() == {"snr": 1000.0, "refine": 0}
    form.field("snr").setText("50")
    assert form.field("snr").commit()
    form.set_method("wiener")  # a value the user typed is kept
    assert form.values() == {"snr": 50.0}
    with pytest.raises(ValueError, match="method must be one of"):
        form.set_method("lucy")


def test_an_optional_option_reads_off_as_none_and_display_emits_nothing(form):
    edits = []
    form.edited.connect(lambda: edits.append(1))
    form.display("rl", {"rtol": 1e-3, "iterations": 7})
    assert edits == [] and form.method_name() == "rl"
    assert form.values() == {"iterations": 7, "rtol": 1e-3, "tv_weight": 0.0}
    form.display("rl", {"rtol": None})
    assert form.field("rtol").text() == OFF and form.values()["rtol"] is None
    form.field("tv_weight").setText("0.5")  # above the TV bound (0.211): refused by the field
    assert not form.field("tv_weight").commit() and form.values()["tv_weight"] == 0.0
    registry.get("rl").resolve(form.values())  # what the form gives passes the schema


def test_the_learned_method_takes_a_checkpoint_path_typed_or_browsed(form, monkeypatch, tmp_path):
    from lfm_studio.widgets import method_options

    form.set_method("learned")
    field = form.field("model")
    assert isinstance(field, method_options.PathField) and field.isEnabled()
    assert not form.field("iterations").isEnabled()
    assert form.values() == {"model": None}  # empty: None, and the method then names the missing file
    field.line.setText(str(tmp_path / "typed.safetensors"))
    field.line.editingFinished.emit()
    assert form.values() == {"model": str(tmp_path / "typed.safetensors")}
    picked = str(tmp_path / "picked.safetensors")
    monkeypatch.setattr(method_options.QFileDialog, "getOpenFileName", lambda *a, **k: (picked, ""))
    edits = []
    form.edited.connect(lambda: edits.append(1))
    field._browse()
    assert form.values() == {"model": picked} and edits


def test_methods_that_do_not_take_a_kinds_projector_are_disabled_with_the_reason(form):
    """A conventional design: Wiener (shift-invariant projectors only) is disabled, its tooltip says
    why in words (no class name); Tikhonov and Richardson-Lucy stay; a chosen Wiener is replaced."""
    form.set_method("wiener")
    form.restrict_to_kind(CONVENTIONAL)
    item = form.method.model().item(form.method.findData("wiener"))
    assert not item.isEnabled()
    assert item.toolTip().startswith(
        "Not for a Conventional LFM design: it needs a laterally shift-invariant"
    )
    assert "Projector" not in item.toolTip()
    enabled = {
        form.method.itemData(i) for i in range(form.method.count()) if form.method.model().item(i).isEnabled()
    }
    assert {"rl", "rl-accelerated", "tikhonov"} <= enabled and "wiener" not in enabled
    assert form.method_name() == registry.default_method()
    form.restrict_to_kind(FOURIER)
    assert form.method.model().item(form.method.findData("wiener")).isEnabled()
