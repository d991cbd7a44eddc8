"""The registry of reconstruction methods: what the CLI, the napari plugin and the studio offer.

Each :class:`Method` carries its name, a label for menus, a one-line description, an options
schema (:class:`Option`: name, type, default, bounds, units, help), whether it is differentiable
(gradients flow from its output to the frame and the projector's tensors), which projectors it
takes (``"any"`` or ``"shift-invariant"``: a projector with cached OTFs) and the devices it runs
on, and the callable that runs it::

    run(projector, frame, options, progress, cancel) -> volume (Z, Y, X)

``options`` holds every option of the method, checked against its schema and completed with the
defaults (:meth:`Method.resolve`). Every method takes :data:`BACKGROUND` (expected background
per pixel, in the frame's units), added to its own options by :func:`register`; front ends add
the camera's noise floor to it. A new method (e.g. a learned model) plugs in with
:func:`register` and appears in every front end without editing them::

    register(Method("backprojection", "Back projection", "normalised adjoint A^T y / A^T 1",
                    options=(), run=my_run))

The built-in methods (Richardson-Lucy, its accelerated form, Wiener, Tikhonov) are registered by
:mod:`.builtin_methods` when :mod:`lfm_studio.engine.reconstruct` is imported.
"""

from __future__ import annotations

import importlib
import math
import numbers
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Protocol

import torch

from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.operators.protocol import FourierProjector, Projector
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.reconstruct.guards import is_integer_data, warn_if_raw_counts
from lfm_studio.engine.types import OptionValue

if TYPE_CHECKING:
    from lfm_studio.engine.systems.kinds_base import SystemKind

PROJECTOR_KINDS = ("any", "shift-invariant", "periodic")
DEVICES = ("cpu", "cuda")
_KINDS: dict[type, str] = {
    int: "an integer",
    float: "a finite number",
    str: "a string",
    bool: "true or false",
}


class MethodRun(Protocol):
    """``run(projector, frame, options, progress, cancel) -> volume``: one camera frame ``(Py, Px)``
    (photons, baseline removed) to a volume ``(Z, Y, X)`` on the projector's device and dtype."""

    def __call__(
        self,
        projector: Projector,
        frame: torch.Tensor,
        options: Mapping[str, OptionValue],
        progress: ProgressCallback | None,
        cancel: CancelToken,
    ) -> torch.Tensor: ...


class Step(Protocol):
    """One iterate of an iterative method (what the studio plots while it runs)."""

    @property
    def estimate(self) -> torch.Tensor: ...
    @property
    def relative_change(self) -> float: ...


class IteratesRun(Protocol):
    """``iterates(projector, frame, options, progress, cancel)``: the iterates of an iterative method."""

    def __call__(
        self,
        projector: Projector,
        frame: torch.Tensor,
        options: Mapping[str, OptionValue],
        progress: ProgressCallback | None,
        cancel: CancelToken,
    ) -> Iterator[Step]: ...


@dataclass(frozen=True)
class Option:
    """One option of a method's schema.

    Attributes
    ----------
    name : Python identifier (``iterations``); the CLI flag is ``--iterations``, ``tv_weight`` gives
        ``--tv-weight``.
    kind : ``int``, ``float``, ``str`` or ``bool``.
    default : the value used when none is given (``None`` only when ``optional``).
    help : one line for tooltips and ``--help``.
    units : e.g. ``"photons per pixel"``; ``""`` for a pure number.
    minimum, maximum : bounds (numbers), ``None`` for none.
    exclusive_minimum, exclusive_maximum : whether the bound itself is refused.
    optional : ``None`` is a valid value (e.g. no early-stop tolerance).
    choices : the allowed values of a ``str`` option, or ``None``.
    file_filter : a ``str`` option that names an input file: the file dialog's filter (e.g.
        ``"Checkpoints (*.safetensors)"``); the apps show a path field with a browse button.
    """

    name: str
    kind: type
    default: OptionValue
    help: str
    units: str = ""
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    exclusive_maximum: bool = False
    optional: bool = False
    choices: tuple[str, ...] | None = None
    file_filter: str | None = None

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(
                f"Option name must be a Python identifier; got {self.name!r}. Fix: e.g. 'tv_weight'."
            )
        if self.kind not in _KINDS:
            raise ValueError(
                f"Option {self.name!r}: kind must be one of int, float, str, bool; got {self.kind!r}."
            )
        if self.default is not None or not self.optional:
            self.check(self.default, owner="the default of")

    def requirement(self) -> str:
        """What a valid value is, in words (``"an integer >= 1"``)."""
        text = _KINDS[self.kind]
        bounds = []
        if self.minimum is not None:
            bounds.append(f"{'>' if self.exclusive_minimum else '>='} {self.minimum:g}")
        if self.maximum is not None:
            bounds.append(f"{'<' if self.exclusive_maximum else '<='} {self.maximum:g}")
        if self.choices is not None:
            text = "one of " + ", ".join(repr(c) for c in self.choices)
        text += (" " + " and ".join(bounds)) if bounds else ""
        text += f" ({self.units})" if self.units else ""
        return text + (" or None" if self.optional else "")

    def check(self, value: object, *, owner: str = "", label: str | None = None) -> OptionValue:
        """``value`` as this option's kind, or a ``ValueError`` naming the option, the value and a fix.

        ``label`` names the option in the message (e.g. the CLI flag ``--iterations``; default its name).
        """
        if value is None and self.optional:
            return None
        converted: OptionValue = None
        ok = False
        if isinstance(value, bool):  # a bool is an int to Python, never to an option
            ok, converted = self.kind is bool, value
        elif self.kind is int and isinstance(value, numbers.Integral):
            ok, converted = True, int(value)
        elif self.kind is int and isinstance(value, numbers.Real):
            number = float(value)
            ok, converted = (
                math.isfinite(number) and number.is_integer(),
                int(number) if math.isfinite(number) else None,
            )
        elif self.kind is float and isinstance(value, numbers.Real):
            number = float(value)
            ok, converted = math.isfinite(number), number
        elif self.kind is str and isinstance(value, str):
            ok, converted = self.choices is None or value in self.choices, value
        if ok and isinstance(converted, (int, float)) and not isinstance(converted, bool):
            ok = self._in_bounds(converted)
        if not ok:
            where = f"{owner} " if owner else ""
            name = label or self.name
            example = f"{name} {self.example()}" if name.startswith("-") else f"{name}={self.example()!r}"
            raise ValueError(
                f"{where}{name} must be {self.requirement()}; got {value!r}. Fix: e.g. {example} ({self.help})."
            )
        return converted

    def example(self) -> OptionValue:
        """A valid value to quote in a fix (the default, else the lower bound's neighbourhood)."""
        if self.default is not None:
            return self.default
        if self.kind in (int, float) and self.minimum is not None:
            return self.kind(self.minimum + (1 if self.exclusive_minimum else 0))
        return self.choices[0] if self.choices else self.kind()

    def _in_bounds(self, value: float) -> bool:
        if self.minimum is not None and (
            value < self.minimum or (self.exclusive_minimum and value == self.minimum)
        ):
            return False
        return self.maximum is None or not (
            value > self.maximum or (self.exclusive_maximum and value == self.maximum)
        )


BACKGROUND = Option(
    "background",
    float,
    0.0,
    "expected background per pixel: Richardson-Lucy models it, one-step methods subtract it (no clipping)",
    units="photons per pixel",
    minimum=0.0,
)
"""The option every method takes (added by :func:`register`)."""


@dataclass(frozen=True)
class Method:
    """A reconstruction method (see the module docstring).

    Attributes
    ----------
    name : the key (``"rl-accelerated"``), used by ``--method`` and saved in volume metadata.
    label : short text for a combo box.
    description : one line.
    options : the schema (:class:`Option`), without :data:`BACKGROUND` (added by :func:`register`).
    run : the callable (:class:`MethodRun`).
    differentiable : gradients reach the frame (and the projector's tensors) through ``run``.
    projectors : ``"any"``, ``"shift-invariant"`` (needs a projector with cached OTFs, ``otf``) or
        ``"periodic"`` (shift-invariant, or periodic in the lenslet lattice: a conventional-LFM
        :class:`~lfm_studio.engine.operators.lenslet_lattice.LensletLatticeProjector`).
    devices : where it runs, subset of ``("cpu", "cuda")``.
    iterative : ``run`` reports one progress step per iteration; the method then has an
        ``iterations`` option.
    iterates : optional generator ``(projector, frame, options, progress, cancel) -> Iterator`` of
        objects with ``estimate`` and ``relative_change`` (the studio's live convergence plot).
    """

    name: str
    label: str
    description: str
    options: tuple[Option, ...]
    run: MethodRun
    differentiable: bool = False
    projectors: str = "any"
    devices: tuple[str, ...] = DEVICES
    iterative: bool = False
    iterates: IteratesRun | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not self.name or self.name != self.name.strip() or " " in self.name:
            raise ValueError(
                f"Method name must be a non-empty word; got {self.name!r}. Fix: e.g. 'backprojection'."
            )
        if self.projectors not in PROJECTOR_KINDS:
            raise ValueError(
                f"Method {self.name!r}: projectors must be one of {PROJECTOR_KINDS}; got {self.projectors!r}."
            )
        unknown = set(self.devices) - set(DEVICES)
        if not self.devices or unknown:
            raise ValueError(
                f"Method {self.name!r}: devices must be a non-empty subset of {DEVICES}; got {self.devices!r}."
            )
        names = [o.name for o in self.options]
        if len(set(names)) != len(names):
            raise ValueError(f"Method {self.name!r}: option names repeat in {names}.")
        if self.iterative and "iterations" not in names:
            raise ValueError(
                f"Method {self.name!r} is iterative but has no 'iterations' option. Fix: add one."
            )

    def option(self, name: str) -> Option | None:
        """The option ``name`` of this method, or None."""
        return next((o for o in self.options if o.name == name), None)

    def defaults(self) -> dict[str, OptionValue]:
        """Every option at its default."""
        return {o.name: o.default for o in self.options}

    def resolve(self, given: Mapping[str, OptionValue] | None = None) -> dict[str, OptionValue]:
        """``given`` checked against the schema and completed with the defaults.

        Raises ``ValueError`` for an option this method does not take (naming the ones it
        takes) and for a value outside an option's type or bounds (naming option, value, fix).
        """
        given = dict(given or {})
        unknown = sorted(set(given) - {o.name for o in self.options})
        if unknown:
            takes = ", ".join(o.name for o in self.options)
            raise ValueError(
                f"method {self.name!r} takes no option {', '.join(repr(u) for u in unknown)}; its options are "
                f"{takes}. Fix: leave {'it' if len(unknown) == 1 else 'them'} out, or choose a method that takes "
                f"{'it' if len(unknown) == 1 else 'them'}."
            )
        return {o.name: o.check(given[o.name]) if o.name in given else o.default for o in self.options}

    def supports(self, projector: Projector) -> bool:
        """Whether ``projector`` is a kind this method takes."""
        if self.projectors == "periodic" and isinstance(projector, LensletLatticeProjector):
            return True
        return self.projectors == "any" or isinstance(projector, FourierProjector)

    def supports_kind(self, kind: SystemKind) -> bool:
        """Whether this method takes the projector a design of ``kind`` is reconstructed with (a
        shift-invariant one for a kind with ``shift_invariant``, else a lenslet-lattice one)."""
        return self.projectors != "shift-invariant" or kind.shift_invariant

    def needs(self) -> str:
        """The projectors this method takes, in words (no class names)."""
        needs = "laterally shift-invariant (Fourier LFM) projector with cached OTFs"
        if self.projectors == "periodic":
            needs += " or a conventional-LFM lenslet-lattice projector"
        return needs

    def steps(self, options: Mapping[str, OptionValue]) -> int:
        """Progress units of one run: the iterations of an iterative method, else 1."""
        iterations = options["iterations"] if self.iterative else 1
        return iterations if isinstance(iterations, int) else 1

    def __call__(
        self,
        projector: Projector,
        frame: torch.Tensor,
        options: Mapping[str, OptionValue] | None = None,
        progress: ProgressCallback | None = None,
        cancel: CancelToken = None,
    ) -> torch.Tensor:
        """Check ``options`` and the projector kind, then run (volume ``(Z, Y, X)``).

        An integer ``frame`` (raw camera counts?) is warned about (:func:`.guards.warn_if_raw_counts`)
        and handed to ``run`` in the projector's dtype, like every float frame."""
        resolved = self.resolve(options)
        self.check_projector(projector)
        if is_integer_data(frame):
            warn_if_raw_counts("frame", frame)
            frame = torch.as_tensor(frame).to(device=projector.device, dtype=projector.dtype)
        return self.run(projector, frame, resolved, progress, cancel)

    def check_projector(self, projector: Projector) -> None:
        """A ``ValueError`` naming the method and a fix when it cannot take ``projector``."""
        if not self.supports(projector):
            choices = ", ".join(supporting(projector))  # what takes this one
            raise ValueError(
                f"method {self.name!r} ({self.label}) needs a {self.needs()}; got {_projector_words(projector)}. "
                f"Fix: choose {choices}."
            )


def _projector_words(projector: Projector) -> str:
    """What ``projector`` is, in a user's words (a message names no internal class)."""
    if isinstance(projector, LensletLatticeProjector):
        return "a conventional-LFM projector (periodic in the lenslet lattice, not shift-invariant)"
    return "a projector without cached OTFs (not laterally shift-invariant)"


_REGISTRY: dict[str, Method] = {}
_DEFAULT = ["rl-accelerated"]

PROVIDERS = ["lfm_studio.engine.learned.method"]
"""Modules that register more methods (engine plug-ins: the learned models), imported by name the
first time a front end asks for the methods, so the registry does not import its own clients."""
_PROVIDERS_LOADED: list[str] = []


def _load_providers() -> None:
    for module in PROVIDERS:
        if module not in _PROVIDERS_LOADED:
            _PROVIDERS_LOADED.append(module)  # first: a provider that asks for the methods does not recurse
            importlib.import_module(module)


def register(method: Method, *, overwrite: bool = False) -> Method:
    """Add ``method`` (with :data:`BACKGROUND` prepended to its options) and return the stored entry.

    A name already registered is refused unless ``overwrite``. An option sharing its name with
    another method's must have the same kind and units (one flag, one meaning, in every front end).
    """
    if method.name in _REGISTRY and not overwrite:
        raise ValueError(
            f"a reconstruction method named {method.name!r} is registered already. Fix: choose another name, "
            "or register(..., overwrite=True)."
        )
    own = tuple(o for o in method.options if o.name != BACKGROUND.name)
    stored = replace(method, options=(BACKGROUND, *own))
    for other in _REGISTRY.values():
        if other.name == method.name:
            continue
        for option in own:
            twin = other.option(option.name)
            if twin is not None and (twin.kind, twin.units) != (option.kind, option.units):
                raise ValueError(
                    f"method {method.name!r}: option {option.name!r} is a {option.kind.__name__} in "
                    f"{option.units or 'no units'}, but method {other.name!r} has it as a {twin.kind.__name__} in "
                    f"{twin.units or 'no units'}. Fix: rename it, or use the same type and units."
                )
    _REGISTRY[method.name] = stored
    return stored


def unregister(name: str) -> None:
    """Remove the method ``name`` (tests and plug-ins that go away); unknown names are an error."""
    get(name)
    del _REGISTRY[name]


def is_registered(name: str) -> bool:
    """Whether ``name`` is registered now (providers not loaded: what registration itself asks)."""
    return name in _REGISTRY


def get(name: str) -> Method:
    """The method ``name``; a ``ValueError`` listing the registered names otherwise."""
    _load_providers()
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"method must be one of {names()}; got {name!r}. Fix: e.g. {default_method()!r}."
        ) from None


def methods() -> tuple[Method, ...]:
    """Every registered method, in registration order."""
    _load_providers()
    return tuple(_REGISTRY.values())


def supporting(projector: Projector) -> list[str]:
    """The names of the registered methods that take ``projector`` (:meth:`Method.supports`), in
    registration order: what a refusal of another method offers instead."""
    return [m.name for m in methods() if m.supports(projector)]


def names() -> list[str]:
    """The registered method names, in registration order."""
    _load_providers()
    return list(_REGISTRY)


def default_method() -> str:
    """The method the apps start with (``"rl-accelerated"``)."""
    return _DEFAULT[0]


def all_options() -> dict[str, Option]:
    """Every option name over all methods, each with the first method's :class:`Option` (same kind
    and units everywhere, :func:`register`); what a front end builds one field or flag for."""
    found: dict[str, Option] = {}
    for method in methods():
        for option in method.options:
            found.setdefault(option.name, option)
    return found
