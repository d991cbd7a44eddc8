"""Typed text -> number, with one policy for every numeric field of the studio (Qt-free).

The policy (:func:`parse_number`):

- the decimal mark is ``.`` or ``,`` whatever the locale (``0,5`` is 0.5 under C and
  de_DE alike): a comma is never a thousands separator, and a number with two marks
  (``1,000.5``) is refused rather than guessed;
- a trailing unit (the field's own, e.g. ``mm``; ``um`` and ``µm`` alike) is allowed; a length
  field also converts another length unit (``0.0065 mm`` in a µm field is 6.5);
- anything that is not a plain decimal number (``abc``, ``1_000``, ``0x10``, ``''``) is
  refused with the reason; ``nan`` and ``inf`` are refused by name;
- out of range is refused with the range, never clamped; ``1e308`` is 1e308;
- integer fields refuse fractions (``2.5``) but take ``1e3`` as 1000.

Every refusal is a :class:`ValueError` naming the parameter, the text typed and the fix.
:func:`format_number` writes a value back with the locale's decimal mark; :func:`shown_units_in`
writes an engine message's "um" as the studio's "µm".
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_NOT_FINITE = re.compile(r"[+-]?(nan|inf|infinity)", re.IGNORECASE)
_UNIT_ALIASES = {"µm": "um", "μm": "um", "e⁻ rms": "e- rms"}
_MINUS_SIGNS = ("\u2212", "\u2013")  # typographic minus and en dash, as pasted from documents
#: Length units a length field converts from, in micrometres (the canonical spelling of ``µm`` is ``um``).
LENGTH_UNITS = {"nm": 1e-3, "um": 1.0, "mm": 1e3, "m": 1e6}
_SHOWN = {"um": "µm"}
_TRAILING_UNIT = re.compile(r"\s*([a-zA-Z]+)$")


@dataclass(frozen=True)
class NumberRule:
    """What a field accepts.

    Attributes
    ----------
    name : the parameter as the user reads it (used in messages), e.g. "Pixel pitch".
    minimum, maximum : inclusive range, in ``unit``.
    unit : shown after the number ("mm", "µm", "" ...); may be typed after it.
    integer : whole numbers only.
    special_text : a word shown and accepted for ``minimum`` (e.g. "none", "off").
    example : a valid value for the "Fix:" part of messages (default: inside the range).
    """

    name: str
    minimum: float
    maximum: float
    unit: str = ""
    integer: bool = False
    special_text: str = ""
    example: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.minimum) and math.isfinite(self.maximum) and self.minimum <= self.maximum):
            raise ValueError(
                f"NumberRule {self.name!r}: minimum {self.minimum} and maximum {self.maximum} must be finite "
                "with minimum <= maximum."
            )

    def range_text(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        kind = "a whole number" if self.integer else "a number"
        return f"{kind} from {format_number(self.minimum)} to {format_number(self.maximum)}{unit}"

    def fix(self) -> str:
        value = self.example if self.example is not None else _inside(self)
        return f"Fix: type {self.range_text()}, e.g. {format_number(value)}."


def _inside(rule: NumberRule) -> float:
    if rule.minimum <= 1.0 <= rule.maximum:
        return 1.0
    return rule.minimum if rule.minimum != 0 or rule.maximum == 0 else rule.maximum


def _strip_unit(text: str, unit: str) -> tuple[str, float]:
    """The number's text without its unit, and the factor that takes the typed unit to the field's.

    A length field takes any length unit of :data:`LENGTH_UNITS` ("0.0065 mm" in a µm field is 6.5).
    """
    if not unit:
        return text, 1.0
    for alias, canonical in _UNIT_ALIASES.items():
        text, unit = text.replace(alias, canonical), unit.replace(alias, canonical)
    if text.endswith(unit):
        return text[: -len(unit)].rstrip(), 1.0
    typed = _TRAILING_UNIT.search(text)
    if unit in LENGTH_UNITS and typed is not None and typed.group(1) in LENGTH_UNITS:
        return text[: typed.start()].rstrip(), LENGTH_UNITS[typed.group(1)] / LENGTH_UNITS[unit]
    return text, 1.0


def _accepted_units(unit: str) -> str:
    """ " (units: µm, nm, mm, m)" for a length field in µm, " (unit: fold)" for others, "" without a unit."""
    canonical = _UNIT_ALIASES.get(unit, unit)
    if canonical in LENGTH_UNITS:
        others = ", ".join(_SHOWN.get(u, u) for u in LENGTH_UNITS if u != canonical)
        return f" (units: {unit}, {others})"
    return f" (unit: {unit})" if unit else ""


def parse_number(text: str, rule: NumberRule) -> float | int:
    """The value ``text`` means under ``rule``; :class:`ValueError` with the reason and the fix if none.

    Returns an ``int`` for integer rules, else a ``float``.
    """
    typed = str(text)
    body, factor = _strip_unit(typed.strip(), rule.unit.strip())
    for sign in _MINUS_SIGNS:
        body = body.replace(sign, "-")
    if rule.special_text and body.lower() == rule.special_text.lower():
        return int(rule.minimum) if rule.integer else float(rule.minimum)
    if not body:
        raise ValueError(f"{rule.name} is empty. {rule.fix()}")
    if _NOT_FINITE.fullmatch(body):
        word = "NaN (not a number)" if "nan" in body.lower() else "infinity"
        raise ValueError(f"{rule.name} cannot be {word}; got {typed!r}. {rule.fix()}")
    marks = body.count(".") + body.count(",")
    if marks > 1:
        raise ValueError(
            f"{rule.name}: {typed!r} has {marks} decimal marks; '.' and ',' both mark decimals here "
            f"(no thousands separators). {rule.fix()}"
        )
    body = body.replace(",", ".")
    if not _NUMBER.fullmatch(body):
        raise ValueError(
            f"{rule.name} must be a number; got {typed!r}{_accepted_units(rule.unit.strip())}. {rule.fix()}"
        )
    value = float(body) * factor
    if not math.isfinite(value):
        raise ValueError(f"{rule.name}: {typed!r} is too large to represent. {rule.fix()}")
    if rule.integer and not value.is_integer():
        raise ValueError(f"{rule.name} must be a whole number; got {typed!r}. {rule.fix()}")
    if not rule.minimum <= value <= rule.maximum:
        raise ValueError(f"{rule.name} {format_number(value)} is out of range. {rule.fix()}")
    return int(value) if rule.integer else value


def format_number(value: float, decimal_point: str = ".") -> str:
    """``value`` as typed back (10 significant digits, no trailing zeros), with ``decimal_point``."""
    if isinstance(value, int) or (isinstance(value, float) and value.is_integer() and abs(value) < 1e15):
        text = str(int(value))
    else:
        text = f"{value:.10g}"
    return text.replace(".", decimal_point) if decimal_point != "." else text


# The unit token "um" (or "um^2") alone: not inside a word ("number", "maximum"), a key ("center_um"),
# a path ("/data/um/x") or a file name ("a.um", "um.tif").
_UM_TOKEN = re.compile(r"(?<![\w/\\.])um(\^2)?(?![\w/\\^]|\.\w)")


def shown_units_in(text: str) -> str:
    """``text`` (an engine message, which writes ``um``) with the unit as the studio shows it:
    ``"got 0 um"`` -> ``"got 0 µm"``, ``"(um)"`` -> ``"(µm)"``, ``"um^2"`` -> ``"µm²"``; words that
    contain "um" (``number``, ``maximum``), keys (``depth_step_um``) and paths are left alone."""
    return _UM_TOKEN.sub(lambda m: "µm²" if m.group(1) else "µm", text)
