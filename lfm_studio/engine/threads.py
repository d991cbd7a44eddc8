"""Thread policy: how many torch CPU threads the engine's heavy work runs on, set on purpose.

Measured on the 2-core development machine (docs/platform.md, docs/benchmarks.md):

- FFT-bound work (PSF stacks, projectors, Richardson-Lucy) gains 1.2-1.9x from 2 threads
  on a quiet machine;
- small convolutions (training) ran 5-40x *slower* with 2 threads than with 1;
- when another job holds one core, 2-thread runs were up to 16x slower (1-thread runs
  stayed within 10 %), because OpenMP threads spin at barriers waiting for a descheduled
  partner. ``OMP_WAIT_POLICY=PASSIVE`` (threads sleep instead of spinning) removed that.

The policy:

- heavy engine work (every ``lfm-studio`` command, ``gui`` included): the cores that are idle
  when the command starts (:func:`idle_cores`: the process's cores minus the load average; both cores on a
  quiet 2-core machine, 1 when other jobs keep it busy), with ``OMP_WAIT_POLICY=PASSIVE``;
- the studio's workers: that count less one core, left for the GUI (``ui/app.py``);
- small-kernel work (training, tiny convolutions): 1 thread (``workload="small"``);
- work that splits into independent pieces (the conventional build's Debye chunks and
  depths, the Fourier per-lenslet path's lone lenslets): :func:`run_in_workers`, that many Python threads taking the
  next piece when free, each running torch ops on 1 intra-op thread, with progress and cancel
  checks on the caller's thread as each piece finishes (``on_result``). A core held by another
  job then just takes fewer pieces, where a 2-thread op waits at every barrier for its slower
  half (the conventional build of docs/benchmarks.md: 2 intra-op threads 2.95-3.76 s against
  2.30-2.89 s on 1; 2 workers 1.44-1.88 s, and 2.41-2.77 s against 2.46-3.41 s on 1 with a CPU hog);
- tests: a fixed count, whatever the load (``scripts/test.sh`` exports
  ``LFM_STUDIO_THREADS=2`` unless set), so that in-process CLI calls never change the thread
  count between two tests; benchmarks state theirs and print :func:`describe_threads`.

``LFM_STUDIO_THREADS`` (or ``OMP_NUM_THREADS``) in the environment overrides the default.
The OpenMP runtime reads ``OMP_WAIT_POLICY`` once, when torch is first imported, so importing
``lfm_studio`` sets it (unless the user did) before any torch import of ours; a program that
imports torch *before* ``lfm_studio`` keeps spinning threads, and :func:`wait_policy_in_effect`
says so (benchmarks print it).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import TypeVar

import torch

Item = TypeVar("Item")
Result = TypeVar("Result")

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


def idle_cores() -> int:
    """Cores not busy with other work now: available cores minus the 1-minute load average
    (rounded), at least 1 (all available cores where the load is unknown)."""
    cores = available_cores()
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # not Unix
        return cores
    return max(1, min(cores, cores - round(load)))


def default_threads(workload: str = "heavy") -> int:
    """Threads the policy picks for ``workload``: ``"heavy"`` (FFT-bound engine work) the idle
    cores (:func:`idle_cores`; 2-thread runs on a busy 2-core machine were 2.5x slower than
    1 thread), ``"small"`` (small convolutions, training) always 1. The environment override
    wins for ``"heavy"``."""
    if workload not in WORKLOADS:
        raise ValueError(f"workload must be one of {WORKLOADS}; got {workload!r}.")
    if workload == "small":
        return 1
    override = _from_environment()
    return override if override is not None else idle_cores()


def wait_policy_in_effect() -> str:
    """The OpenMP wait policy torch's runtime runs with: the user's ``OMP_WAIT_POLICY``, PASSIVE when
    ``lfm_studio`` was imported before torch, else ``"unset (spinning)"`` (torch loaded first)."""
    import lfm_studio

    if lfm_studio.WAIT_POLICY_AT_START:
        return lfm_studio.WAIT_POLICY_AT_START
    return (
        "unset (spinning): torch loaded before lfm_studio" if lfm_studio.TORCH_LOADED_FIRST else WAIT_POLICY
    )


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
    policy = wait_policy_in_effect()
    return (
        f"threads: torch {torch.get_num_threads()} intra-op, {available_cores()} core(s) available, "
        f"OMP_WAIT_POLICY={policy}"
    )


def worker_count(workers: int | None, device: torch.device | str, records_graph: bool) -> int:
    """Workers for :func:`run_in_workers`: ``workers`` (checked; default the caller's torch thread
    count, which the policy chose) on the CPU, 1 on other devices (a GPU runs one item's kernels at
    a time anyway) or when an autograd graph is recorded (it is built on the caller's thread)."""
    count = torch.get_num_threads() if workers is None else check_threads(workers, "workers")
    return 1 if torch.device(device).type != "cpu" or records_graph else count


def _one_intra_op_thread() -> None:
    """Pool initializer: this worker thread's torch ops run on 1 intra-op thread."""
    torch.set_num_threads(1)


def _with_grad_mode(task: Callable[[Item], Result], enabled: bool) -> Callable[[Item], Result]:
    """``task`` run under autograd mode ``enabled`` (the mode is per thread: a worker starts enabled)."""

    def run(item: Item) -> Result:
        with torch.set_grad_enabled(enabled):
            return task(item)

    return run


def run_in_workers(
    task: Callable[[Item], Result],
    items: Sequence[Item],
    workers: int,
    *,
    on_result: Callable[[int, Result], None] | None = None,
    collect: bool = True,
    in_order: bool = False,
) -> list[Result]:
    """``[task(item) for item in items]``, in order, on ``workers`` Python threads.

    Each thread takes the next item when it is free (a core shared with another job takes
    fewer), and runs torch ops on 1 intra-op thread (torch releases the GIL inside its ops) in the
    caller's autograd mode. ``workers`` 1, or a single item, runs inline on the caller's threads.
    ``task`` must not write where another item writes.

    ``on_result(index, result)``, when given, runs on the *caller's* thread as each item finishes
    (in finishing order; in item order inline): progress reports and cancel checks belong there.
    If it raises, or ``task`` does, the items not started are dropped and the exception is raised
    once the items already started have ended (the first one; the others are dropped).
    ``collect=False`` returns ``[]`` and lets each result go once ``on_result`` has taken it (large
    results that ``on_result`` stores elsewhere are then not all held at once). ``in_order=True``
    calls ``on_result`` in item order (a result that finishes early waits for the ones before it):
    for ``on_result`` whose effect depends on the order (sums in floating point, a cache that keeps
    the first entry), so the outcome does not depend on which thread was faster.

    Torch's thread count is per thread (OpenMP); a new thread starts with the process default,
    which the workers set to 1 and the caller's count is put back into at the end (threads
    started elsewhere meanwhile may start with 1).
    """
    workers = min(check_threads(workers, "workers"), len(items))
    report = on_result or (lambda index, result: None)
    if workers <= 1:
        kept = []
        for index, item in enumerate(items):
            result = _inline(task, item, index, report)
            if collect:
                kept.append(result)
        return kept
    caller = torch.get_num_threads()
    results: dict[int, Result] = {}
    try:
        with ThreadPoolExecutor(
            workers, thread_name_prefix="lfm-worker", initializer=_one_intra_op_thread
        ) as pool:
            run = _with_grad_mode(task, torch.is_grad_enabled())
            pending = {pool.submit(run, item): index for index, item in enumerate(items)}
            waiting: dict[int, Result] = {}  # finished, not yet reported
            following = 0  # the next index to report, with in_order
            try:
                for future in as_completed(list(pending)):
                    waiting[pending.pop(future)] = future.result()
                    del future  # with collect=False nothing else holds the result once it is reported
                    while (index := following if in_order else next(iter(waiting), -1)) in waiting:
                        result = waiting.pop(index)
                        report(index, result)
                        if collect:
                            results[index] = result
                        del result
                        following += 1
            except BaseException:
                for future in pending:
                    future.cancel()
                raise
            return [results[index] for index in range(len(items))] if collect else []
    finally:
        torch.set_num_threads(caller)


def _inline(
    task: Callable[[Item], Result], item: Item, index: int, report: Callable[[int, Result], None]
) -> Result:
    """One item on the caller's thread, reported as soon as it is done."""
    result = task(item)
    report(index, result)
    return result
