"""``--method`` and the method option flags of ``lfm-studio reconstruct``, read from the registry.

The choices and their help come from :mod:`lfm_studio.engine.reconstruct.registry`, and every
option of every registered method (except ``background``, which has its own flag) becomes one
flag: ``iterations`` -> ``--iterations``, ``tv_weight`` -> ``--tv-weight``. A flag left out takes
the chosen method's default; a flag the chosen method does not take is ignored with a warning.
A method registered before the parser is built (a plug-in, a learned model) appears here
without editing this module.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from lfm_studio.engine.reconstruct import registry

_BACKGROUND = registry.BACKGROUND.name


def flag(option: registry.Option) -> str:
    """The CLI flag of ``option`` (``--tv-weight`` for ``tv_weight``)."""
    return "--" + option.name.replace("_", "-")


def _parse_bool(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false; got {text!r}")


def _text(value: Any) -> str:
    return "none" if value is None else str(value)


def _option_help(option: registry.Option) -> str:
    users = [m for m in registry.methods() if m.option(option.name) is not None]
    defaults = ", ".join(f"{m.name} {_text(m.option(option.name).default)}" for m in users)  # type: ignore[union-attr]
    units = f" ({option.units})" if option.units else ""
    return f"{option.help}{units}; default: {defaults}".replace("%", "%%")


def add_method_arguments(parser: argparse.ArgumentParser) -> None:
    """``--method`` (choices and help from the registry) and one flag per method option."""
    described = "; ".join(f"{m.name}: {m.description}" for m in registry.methods())
    parser.add_argument(
        "--method",
        choices=registry.names(),
        default=registry.default_method(),
        help=f"reconstruction method (default {registry.default_method()}). {described}".replace("%", "%%"),
    )
    group = parser.add_argument_group("method options (each applies to the methods that take it)")
    for option in registry.all_options().values():
        if option.name == _BACKGROUND:
            continue
        kind = _parse_bool if option.kind is bool else option.kind
        try:
            group.add_argument(
                flag(option),
                dest=f"option_{option.name}",
                type=kind,
                default=None,
                metavar=option.name.upper(),
                help=_option_help(option),
            )
        except argparse.ArgumentError as error:
            raise ValueError(
                f"the reconstruction option {option.name!r} would be the flag {flag(option)}, which "
                f"'lfm-studio reconstruct' has already. Fix: rename the option of the registered method."
            ) from error


def method_options(args: argparse.Namespace) -> tuple[registry.Method, dict[str, Any]]:
    """The chosen method and its checked options (``background`` from ``--background``).

    A given flag out of bounds is a ``ValueError`` naming the flag; a flag the method does not
    take is reported on stderr and ignored.
    """
    method = registry.get(args.method)
    given: dict[str, Any] = {_BACKGROUND: registry.BACKGROUND.check(args.background, label="--background")}
    ignored = []
    for name, option in registry.all_options().items():
        value = getattr(args, f"option_{name}", None)
        if name == _BACKGROUND or value is None:
            continue
        own = method.option(name)
        if own is None:
            ignored.append(flag(option))
        else:
            given[name] = own.check(value, label=flag(option))
    if ignored:
        takes = ", ".join(flag(o) for o in method.options if o.name != _BACKGROUND) or "none"
        print(
            f"lfm-studio reconstruct: warning: {', '.join(ignored)} not used by --method {method.name} "
            f"(its options: {takes}); ignored.",
            file=sys.stderr,
        )
    return method, method.resolve(given)
