"""Stress-suite settings: hypothesis profiles and the count of stress cases run.

Profiles (``HYPOTHESIS_PROFILE``): ``ci`` (default) runs few examples, without deadlines
and derandomized, so a CI run is reproducible; ``full`` runs many random examples for a
local deep run. ``LFM_STRESS=full`` adds the slow parametrised extremes (``levels.py``).

Every stress test that runs counts: one per parametrised case, one per hypothesis example
(counted by wrapping ``test.hypothesis.inner_test``, which hypothesis lets callers replace).
The total is printed as ``stress cases run: N`` at the end of the terminal summary and
stored in the pytest cache under ``lfm_studio/stress_cases_run``
(``.pytest_cache/v/lfm_studio/stress_cases_run``).
"""

from __future__ import annotations

import functools
import os

import pytest
import torch
from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci",
    max_examples=10,
    deadline=None,
    derandomize=True,
    database=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "full", max_examples=200, deadline=None, print_blob=True, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

CASES_RUN = pytest.StashKey[int]()


@pytest.fixture(autouse=True)
def torch_threads(request: pytest.FixtureRequest):
    """One torch thread per stress test (restored after), unless it is parametrised with ``threads``.

    The cases are small transforms: on a shared 2-core machine two threads made them up to
    50x slower (spinning on a busy core), one thread keeps the suite's run time steady. Tests
    of thread-dependent bugs (the 2048^2 FFT) parametrise ``threads`` themselves.
    """
    old = torch.get_num_threads()
    callspec = getattr(request.node, "callspec", None)
    torch.set_num_threads(callspec.params.get("threads", 1) if callspec is not None else 1)
    yield
    torch.set_num_threads(old)


CACHE_KEY = "lfm_studio/stress_cases_run"


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item):
    """Count this item's cases: its hypothesis examples, or 1 for a plain (parametrised) test."""
    handle = getattr(getattr(item, "obj", None), "hypothesis", None)
    calls = [0]
    if handle is not None:
        inner = handle.inner_test

        @functools.wraps(inner)
        def counted(*args, **kwargs):
            calls[0] += 1
            return inner(*args, **kwargs)

        handle.inner_test = counted
    try:
        return (yield)
    finally:
        if handle is not None:
            handle.inner_test = inner
        config = item.config
        config.stash[CASES_RUN] = config.stash.get(CASES_RUN, 0) + (calls[0] if handle is not None else 1)


def pytest_terminal_summary(terminalreporter, exitstatus, config: pytest.Config) -> None:
    count = config.stash.get(CASES_RUN, 0)
    if not count:
        return
    terminalreporter.write_line(f"stress cases run: {count}")
    if getattr(config, "cache", None) is not None:
        config.cache.set(CACHE_KEY, count)
