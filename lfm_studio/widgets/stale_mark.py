"""A view's stale mark as a typed record: what it says, how it looks, its short canvas form.

Views (the PSF viewer's banner and canvas read-out, plots, tables) show the mark; the
application decides it (:mod:`lfm_studio.ui.stale_marks`). The colour and the short form
come from :attr:`StaleMark.activity` and :attr:`StaleMark.preview`, never from searching the
text, so an error message that happens to contain "failed" or "recomputing" changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Activity = Literal["", "recomputing", "failed", "cancelled"]
"""What the stage's job is doing about it."""

#: (background, text) colours of a mark's banner or label: out of date, or its recomputation failed.
STALE_COLOURS = ("#fff3cd", "#664d03")
FAILED_COLOURS = ("#f8d7da", "#842029")


@dataclass(frozen=True)
class StaleMark:
    """One view's mark.

    Attributes
    ----------
    text : the whole sentence shown in the banner or label, e.g.
        ``"stale: shows the previous design; PSF failed: disk full"``.
    activity : what the stage's job is doing (:data:`Activity`): colour and short form.
    preview : the view shows the current design's quick preview (coarse, not out of date).
    """

    text: str
    activity: Activity = ""
    preview: bool = False

    @property
    def colours(self) -> tuple[str, str]:
        """(background, text) colours: red when the recomputation failed or was cancelled."""
        return FAILED_COLOURS if self.activity in ("failed", "cancelled") else STALE_COLOURS

    @property
    def short(self) -> str:
        """The canvas read-out's short form (the banner has the whole text)."""
        if self.preview:
            if self.activity == "recomputing":
                return "PREVIEW (full PSF computing)"
            return f"PREVIEW (full PSF {self.activity})" if self.activity else "PREVIEW"
        return f"STALE ({self.activity})" if self.activity else "STALE"
