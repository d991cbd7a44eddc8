"""Thread policy: defaults, overrides, named errors, restoring, the CLI option, the wait policy."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest
import torch

from lfm_studio.cli import build_parser, main
from lfm_studio.engine.threads import (
    THREADS_VARIABLE,
    available_cores,
    check_threads,
    configure_threads,
    default_threads,
    describe_threads,
    idle_cores,
    run_in_workers,
    torch_threads,
    wait_policy_in_effect,
    worker_count,
)


@pytest.fixture(autouse=True)
def _restore_threads():
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize(("load", "busy"), [(0.0, 0), (0.6, 1), (1.4, 1), (100.0, 10**6)])
def test_heavy_work_defaults_to_the_idle_cores(monkeypatch, load, busy):
    monkeypatch.delenv(THREADS_VARIABLE, raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))
    cores = len(os.sched_getaffinity(0))
    assert available_cores() == cores
    assert default_threads() == idle_cores() == max(1, cores - busy)  # at least one thread
    assert default_threads("small") == 1  # small convolutions: 2 threads ran 5-40x slower


def test_benchmarks_can_tell_whether_the_wait_policy_reached_torch(monkeypatch):
    import lfm_studio

    monkeypatch.setattr(lfm_studio, "WAIT_POLICY_AT_START", None)
    monkeypatch.setattr(lfm_studio, "TORCH_LOADED_FIRST", False)
    assert wait_policy_in_effect() == "PASSIVE"
    monkeypatch.setattr(lfm_studio, "TORCH_LOADED_FIRST", True)
    assert wait_policy_in_effect().startswith("unset (spinning)")
    monkeypatch.setattr(lfm_studio, "WAIT_POLICY_AT_START", "ACTIVE")
    assert wait_policy_in_effect() == "ACTIVE"


def test_environment_overrides_the_default_in_order(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.delenv(THREADS_VARIABLE, raising=False)
    assert default_threads() == 3
    monkeypatch.setenv(THREADS_VARIABLE, "5")
    assert default_threads() == 5
    monkeypatch.setenv(THREADS_VARIABLE, "many")
    with pytest.raises(ValueError, match=rf"{THREADS_VARIABLE} must be a positive integer; got 'many'"):
        default_threads()


@pytest.mark.parametrize("bad", [0, -2, 1.5, True, "2"])
def test_bad_thread_counts_are_named(bad):
    with pytest.raises(ValueError, match=r"threads must be a positive integer; got .*Fix"):
        check_threads(bad)
    with pytest.raises(ValueError, match="workload must be one of"):
        default_threads("huge")


def test_configure_sets_torch_and_the_context_manager_restores():
    assert configure_threads(1) == 1 and torch.get_num_threads() == 1
    with torch_threads(2) as count:
        assert count == 2 and torch.get_num_threads() == 2
        assert "torch 2 intra-op" in describe_threads()
    assert torch.get_num_threads() == 1
    assert configure_threads(workload="small") == 1


def test_cli_threads_option_sets_torch_threads_before_the_command(capsys):
    assert build_parser().parse_args(["--threads", "2", "info", "xlfm_cong2017"]).torch_threads == 2
    torch.set_num_threads(2)
    assert main(["--threads", "1", "info", "xlfm_cong2017", "--json"]) == 0
    assert torch.get_num_threads() == 1
    capsys.readouterr()
    assert main(["--threads", "0", "info", "xlfm_cong2017"]) == 2
    assert "threads must be a positive integer; got 0" in capsys.readouterr().err


def _wait_policy_in_fresh_interpreter(env: dict[str, str]) -> str:
    code = "import lfm_studio, torch, os; print(os.environ.get('OMP_WAIT_POLICY'))"
    result = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True, timeout=120
    )
    return result.stdout.strip()


def test_importing_the_package_sets_a_passive_wait_policy_unless_the_user_chose_one():
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    assert _wait_policy_in_fresh_interpreter(env) == "PASSIVE"
    assert _wait_policy_in_fresh_interpreter({**env, "OMP_WAIT_POLICY": "ACTIVE"}) == "ACTIVE"


def test_workers_return_every_result_in_order_each_on_one_torch_thread_and_restore_the_count():
    torch.set_num_threads(2)
    seen: list[tuple[int, str, int]] = []

    def task(item: int) -> int:
        seen.append((item, threading.current_thread().name, torch.get_num_threads()))
        return item * item

    assert run_in_workers(task, list(range(9)), 2) == [i * i for i in range(9)]
    assert sorted(i for i, _, _ in seen) == list(range(9))
    assert {threads for _, _, threads in seen} == {1}
    assert all(name.startswith("lfm-worker") for _, name, _ in seen)
    assert torch.get_num_threads() == 2
    inline: list[str] = []
    assert run_in_workers(lambda i: inline.append(threading.current_thread().name) or i, [5], 2) == [5]
    assert inline == [threading.current_thread().name]  # one item: no pool, the caller's threads
    with pytest.raises(ValueError, match="workers must be a positive integer; got 0"):
        run_in_workers(task, [1], 0)


def test_a_failing_item_is_raised_and_the_items_not_started_are_dropped():
    """Item 0 fails at once; every other item holds its worker (3 s at most), so at most the two items
    the workers hold have started when the failure is seen, whatever the load."""
    torch.set_num_threads(2)
    started: list[int] = []
    never = threading.Event()

    def task(item: int) -> int:
        started.append(item)
        if item == 0:
            raise RuntimeError("item 0 failed")
        never.wait(3.0)
        return item

    with pytest.raises(RuntimeError, match="item 0 failed"):
        run_in_workers(task, list(range(50)), 2)
    assert 0 in started and set(started) <= {0, 1, 2}
    assert torch.get_num_threads() == 2


def test_workers_called_from_two_threads_at_once_leave_each_callers_count_as_it_was():
    counts, results = {}, {}

    def caller(name: str, threads: int) -> None:
        torch.set_num_threads(threads)
        results[name] = run_in_workers(lambda i: float(torch.ones(64, 64).sum()) + i, list(range(20)), 2)
        counts[name] = torch.get_num_threads()

    callers = [threading.Thread(target=caller, args=(name, t)) for name, t in (("a", 2), ("b", 1))]
    for thread in callers:
        thread.start()
    for thread in callers:
        thread.join(30.0)
    assert results == {"a": [4096.0 + i for i in range(20)], "b": [4096.0 + i for i in range(20)]}
    assert counts == {"a": 2, "b": 1}


@pytest.mark.parametrize("workers", [1, 2])
def test_each_result_is_reported_on_the_callers_thread_as_it_finishes(workers):
    caller = threading.current_thread().name
    reported: list[tuple[int, int, str]] = []

    def report(index: int, result: int) -> None:
        reported.append((index, result, threading.current_thread().name))

    assert run_in_workers(lambda i: i + 10, list(range(7)), workers, on_result=report) == list(range(10, 17))
    assert sorted((i, r) for i, r, _ in reported) == [(i, i + 10) for i in range(7)]
    assert {name for _, _, name in reported} == {caller}


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_report_stops_the_items_not_started(workers):
    """Item 0 ends at once; every other item holds its worker (3 s at most), so when the report of
    item 0 raises, at most the two items the workers hold have started, whatever the load."""
    started: list[int] = []
    never = threading.Event()

    def task(item: int) -> int:
        started.append(item)
        if item:
            never.wait(3.0)
        return item

    def stop(index: int, result: int) -> None:
        raise KeyboardInterrupt("stop") if index == 0 else RuntimeError(f"reported {index}")

    with pytest.raises(KeyboardInterrupt, match="stop"):
        run_in_workers(task, list(range(200)), workers, on_result=stop)
    assert set(started) <= {0, 1, 2} if workers == 2 else started == [0]


def test_workers_run_in_the_callers_autograd_mode():
    modes: list[bool] = []

    def task(item: int) -> int:
        modes.append(torch.is_grad_enabled())
        return item

    with torch.no_grad():
        run_in_workers(task, list(range(4)), 2)
    run_in_workers(task, list(range(4)), 2)
    assert modes == [False] * 4 + [True] * 4


def test_in_order_results_are_reported_in_item_order_whatever_finishes_first_and_can_be_let_go():
    torch.set_num_threads(2)
    second_done = threading.Event()
    finished: list[int] = []

    def task(item: int) -> int:
        if item == 0:
            assert second_done.wait(10.0)  # item 1, on the other worker, ends first
        finished.append(item)
        if item == 1:
            second_done.set()
        return item

    reported: list[int] = []
    results = run_in_workers(task, [0, 1, 2, 3], 2, on_result=lambda i, r: reported.append(i), in_order=True)
    assert finished[0] == 1 and results == [0, 1, 2, 3]
    assert reported == [0, 1, 2, 3]  # item order, though item 1 ended first
    second_done.clear()
    finished.clear()
    unordered: list[int] = []
    assert run_in_workers(task, [0, 1], 2, on_result=lambda i, r: unordered.append(i), collect=False) == []
    assert sorted(unordered) == [0, 1]


def test_worker_count_is_the_callers_threads_on_the_cpu_and_one_on_a_gpu_or_with_a_graph():
    with torch_threads(2):
        assert worker_count(None, "cpu", records_graph=False) == 2
        assert worker_count(3, "cpu", records_graph=False) == 3
        assert worker_count(None, "cpu", records_graph=True) == 1
        assert worker_count(4, "meta", records_graph=False) == 1
    with pytest.raises(ValueError, match="workers must be a positive integer; got 0"):
        worker_count(0, "cpu", records_graph=False)
