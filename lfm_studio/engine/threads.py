"""Thread policy: how many torch CPU threads the engine's heavy work runs on, set on purpose.

Measured on the 2-core development machine (PLATFORM.md, docs/benchmarks.md):

- FFT-bound work (PSF stacks, projectors, Richardson-Lucy) gains 1.2-1.9x from 2 threads
  on a quiet machine;
- small convolutions (training) ran 5-40x *slower* with 2 threads than with 1;
- when another job holds one core, 2-thread runs were up to 16x slower (1-thread runs
  stayed within 10 %), because OpenMP threads spin at barriers waiting for a descheduled
  partner. ``OMP_WAIT_POLICY=PASSIVE`` (threads sleep instead of spinning) removed that.

The policy:

- heavy engine work (the CLI, the studio's workers): all cores this process may use
  (:func:`default_threads`), with ``OMP_WAIT_POLICY=PASSIVE``;
- small-kernel work (training, tiny convolutions): 1 thread (``workload="small"``);
- tests and benchmarks: 1 thread unless they say otherwise (``scripts/test.sh`` exports
  ``OMP_NUM_THREADS=1``); every benchmark prints :func:`describe_threads`.

``LFM_STUDIO_THREADS`` (or ``OMP_NUM_THREADS``) in the environment overrides the default.
The OpenMP runtime reads ``OMP_WAIT_POLICY`` once, when torch is first imported, so the
CLI sets it before importing anything that imports torch (first lines of ``lfm_studio.cli``);
:func:`wait_policy_is_passive` reports whether the running process got it.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import torch

WAIT_POLICY = "PASSIVE"  # what the CLI puts in OMP_WAIT_POLICY before torch loads
THREADS_VARIABLE = "LFM_STUDIO_THREADS"
WORKLOADS = ("heavy", "small")


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask; ``os.cpu_count()`` where unknown)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


def _from_environment() -> int | None:
    for name in (THREADS_VARIABLE, "OMP_NUM_THREADS"):
        value = os.environ.get(name, "").strip()
        if value:
            try:
                threads = int(value)
            except ValueError:
                raise ValueError(
                    f"{name} must be a positive integer; got {value!r}. Fix: e.g. {name}=1."
                ) from None
            return check_threads(threads, name)
    return None


def check_threads(threads: int, name: str = "threads") -> int:
    """``threads`` as an int >= 1, or a ValueError naming ``name``."""
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(
            f"{name} must be a positive integer; got {threads!r}. "
            f"Fix: 1 for small kernels or a loaded machine, up to {available_cores()} (the cores here)."
        )
    return threads


def default_threads(workload: str = "heavy") -> int:
    """Threads the policy picks for ``workload`` (``"heavy"``: FFT-bound engine work; ``"small"``:
    small convolutions/training, always 1); the environment override wins for ``"heavy"``."""
    if workload not in WORKLOADS:
        raise ValueError(f"workload must be one of {WORKLOADS}; got {workload!r}.")
    if workload == "small":
        return 1
    override = _from_environment()
    return override if override is not None else available_cores()


def wait_policy_is_passive() -> bool:
    """Whether ``OMP_WAIT_POLICY`` is PASSIVE in this process's environment (set before torch loaded)."""
    return os.environ.get("OMP_WAIT_POLICY", "").strip().upper() == WAIT_POLICY


def configure_threads(threads: int | None = None, *, workload: str = "heavy") -> int:
    """Set torch's intra-op CPU threads by the policy (``threads=None``) or to ``threads``; return it.

    Process-wide (torch has one intra-op pool): call it once at start-up (the CLI's ``main``,
    the studio before starting workers), not per job.
    """
    count = default_threads(workload) if threads is None else check_threads(threads)
    if torch.get_num_threads() != count:
        torch.set_num_threads(count)
    return count


@contextlib.contextmanager
def torch_threads(threads: int) -> Iterator[int]:
    """Run a block with ``threads`` torch CPU threads, then restore the previous count (benchmarks)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(check_threads(threads))
    try:
        yield threads
    finally:
        torch.set_num_threads(previous)


def describe_threads() -> str:
    """One line for benchmark output: torch threads, cores, OpenMP wait policy."""
    policy = os.environ.get("OMP_WAIT_POLICY", "unset (spinning)")
    return (
        f"threads: torch {torch.get_num_threads()} intra-op, {available_cores()} core(s) available, "
        f"OMP_WAIT_POLICY={policy}"
    )
