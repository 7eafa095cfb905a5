"""Progress of a long solve, for whoever shows it (``mer retarget``'s bar on one file).

The solvers call :func:`report` once per Levenberg-Marquardt iteration; nothing happens unless a
caller has installed a callback with :func:`solver_progress`. Context variables, so concurrent
solves in other threads or tasks are not mixed up and the solvers take no extra arguments.
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from typing import Callable, Iterator

__all__ = ["solver_progress", "solver_stage", "report"]

Callback = Callable[[str, int, int], None]
_callback: ContextVar[Callback | None] = ContextVar("mer_solver_progress", default=None)
_stage: ContextVar[str] = ContextVar("mer_solver_stage", default="solve")


@contextmanager
def solver_progress(callback: Callback | None) -> Iterator[None]:
    """Call ``callback(stage, iteration, most_iterations)`` after every solver iteration inside."""
    token = _callback.set(callback)
    try:
        yield
    finally:
        _callback.reset(token)


@contextmanager
def solver_stage(name: str) -> Iterator[None]:
    """Name the stage the iterations inside belong to (``key frames``, ``all frames``, ...)."""
    token = _stage.set(name)
    try:
        yield
    finally:
        _stage.reset(token)


def report(done: int, total: int) -> None:
    """One iteration of ``total`` at most is done (a no-op without a callback)."""
    cb = _callback.get()
    if cb is not None:
        cb(_stage.get(), done, total)
