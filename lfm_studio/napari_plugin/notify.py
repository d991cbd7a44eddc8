"""What the plugin tells the user: napari notifications with the engine's own error text.

Every refusal or failure the user can fix goes through :func:`report_error` (a napari
error notification, shown in the viewer, not a traceback in the console), questionable
but accepted input through :func:`report_warning`, and news (started, cancelled, saved)
through :func:`report_info`. :func:`design_warnings_collected` turns the engine's
``DesignWarning`` s raised while building a design into warning notifications.
"""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Callable, Iterator
from typing import Any

from napari.utils.notifications import show_error, show_info, show_warning

from lfm_studio.engine.design import Design, DesignWarning
from lfm_studio.engine.errors import error_text

_log = logging.getLogger(__name__)


def report_error(message: str) -> None:
    """Show ``message`` as a napari error notification (and log it)."""
    _log.info("lfm-studio error: %s", message)
    show_error(message)


def report_warning(message: str) -> None:
    """Show ``message`` as a napari warning notification."""
    show_warning(message)


def report_info(message: str) -> None:
    """Show ``message`` as a napari info notification."""
    show_info(message)


@contextlib.contextmanager
def design_warnings_collected() -> Iterator[list[str]]:
    """Collect the ``DesignWarning`` s raised inside the block; on exit show each one once as a warning.

    Other warnings are re-issued unchanged. Use on the GUI thread only (``warnings`` state is global).
    """
    found: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DesignWarning)
        yield found
    for other in (w for w in caught if not issubclass(w.category, DesignWarning)):
        warnings.warn_explicit(other.message, other.category, other.filename, other.lineno)
    for message in dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, DesignWarning)):
        found.append(message)
        report_warning(message)


def design_or_report(loader: Callable[[Any], Design], argument: Any, refusal: str) -> Design | None:
    """``loader(argument)`` with its design warnings shown; ``None`` after the error notification
    ``"{refusal}: {error}"`` when the design cannot be read or is refused."""
    try:
        with design_warnings_collected():
            return loader(argument)
    except (ValueError, OSError) as error:
        report_error(f"{refusal}: {error_text(error)}")
        return None
