"""Event-loop helpers shared by the screenshot scripts (run as ``python scripts/NAME.py``)."""

from __future__ import annotations

import time


def wait_until(app, predicate, timeout_s: float, what: str) -> None:
    """Process events until ``predicate()`` holds (the GUI stays live meanwhile); exit on timeout."""
    end = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > end:
            raise SystemExit(f"screenshot: timed out after {timeout_s:.0f} s waiting for {what}")
        app.processEvents()
        time.sleep(0.02)


def settle(app, seconds: float) -> None:
    """Process events for ``seconds`` (lets deferred layouts and canvas draws finish)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        time.sleep(0.02)
