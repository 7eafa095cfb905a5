"""Processes for dataset runs (``mer retarget --input DIR --workers N``).

A dataset run is cut into tasks that do not depend on each other (:mod:`.dataset`: chunks of
(target, clip) pairs); :func:`run_tasks` runs them in this process or in ``N`` spawned processes,
each with one torch thread (``torch.set_num_threads(1)``: on a CPU, N single-threaded solves of
different clips scale better than one solve on N threads, whose small batched products do not).
Tasks are handed out one at a time in the order given (the largest first balances the load), and
each result comes back to the parent as it finishes. A task's result depends only on the task: the
same chunks give the same files whatever ``N`` is.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
from typing import Any, Callable, Iterable, Iterator, Sequence

log = logging.getLogger(__name__)

__all__ = ["available_cores", "one_thread", "run_tasks"]

_STATE: dict[str, Any] = {}  # a worker's shared setup (set once per process by _init)


def available_cores() -> int:
    """The cores this process may run on (``os.sched_getaffinity``; ``os.cpu_count`` where that is missing)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """torch on one thread inside the block (restored after): a one-worker run computes what each
    worker process does."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _init(setup: Any) -> None:
    import torch

    torch.set_num_threads(1)
    _STATE["setup"] = setup


def _call(args: tuple[Callable[[Any, Any], Any], Any]) -> Any:
    fn, task = args
    return fn(_STATE["setup"], task)


def run_tasks(fn: Callable[[Any, Any], Any], setup: Any, tasks: Sequence[Any], workers: int,
              on_result: Callable[[Any], None]) -> None:  # fmt: skip
    """``fn(setup, task)`` for every task, ``on_result`` called in this process with each result.

    Args:
        fn: a module-level function (it is pickled by name); setup: what every task shares, sent
            once to each process.
        workers: processes; <= 1 (or a single task): here, one torch thread.

    A task's exception stops the run (the other processes are terminated) and is raised here;
    results already handed to ``on_result`` stay delivered.
    """
    n = min(max(1, workers), len(tasks))
    if n <= 1:
        with one_thread():
            for task in tasks:
                on_result(fn(setup, task))
        return
    log.info("%d tasks in %d worker processes", len(tasks), n)
    ctx = multiprocessing.get_context("spawn")  # no fork of a process that already runs torch threads
    with ctx.Pool(n, initializer=_init, initargs=(setup,)) as pool:
        results: Iterable[Any] = pool.imap_unordered(_call, [(fn, t) for t in tasks], chunksize=1)
        for res in results:
            on_result(res)
