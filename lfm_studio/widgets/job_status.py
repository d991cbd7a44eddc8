"""The state of one named background job (Qt-free record; :mod:`lfm_studio.widgets.jobs` emits it)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class JobStatus:
    """State of one named background job (what a status bar shows).

    ``state`` is "idle", "running", "cancelling", "done", "failed" or "cancelled";
    ``done``/``total`` count units of work (lenslets, depths, iterations).
    """

    name: str
    state: str = "idle"
    done: int = 0
    total: int = 0
    message: str = ""
    generation: int = 0

    @property
    def active(self) -> bool:
        """Running or being cancelled."""
        return self.state in ("running", "cancelling")

    @property
    def fraction(self) -> float | None:
        """Progress in [0, 1], None when the total is unknown."""
        return None if self.total <= 0 else min(1.0, max(0.0, self.done / self.total))
