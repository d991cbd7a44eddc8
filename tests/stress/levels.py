"""How hard the stress suite pushes: the fast default, or everything with ``LFM_STRESS=full``.

Parametrised extreme cases: ``cases(fast, extra)`` runs ``fast`` always and ``extra`` only
with ``LFM_STRESS=full`` (so the default run stays under a minute on a 2-core CPU).
Hypothesis tests: ``examples(ci, full)`` is the ``max_examples`` of one test under the
``ci`` profile (default) or the ``full`` profile (``HYPOTHESIS_PROFILE=full``); the
profiles themselves are registered in ``conftest.py``.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

from hypothesis import settings

FULL = os.environ.get("LFM_STRESS", "").strip().lower() == "full"
PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "ci")


def cases(fast: Iterable[Any], extra: Iterable[Any] = ()) -> list[Any]:
    """Parameters of an extreme-case test: ``fast`` always, ``extra`` with ``LFM_STRESS=full``."""
    return [*fast, *(extra if FULL else ())]


def examples(ci: int, full: int) -> settings:
    """``@examples(ci, full)``: the number of hypothesis examples of one (expensive) test."""
    return settings(max_examples=full if PROFILE == "full" else ci)
