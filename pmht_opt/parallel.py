"""Blocks of independent work on threads, their results taken in order.

The E-steps work a block of locales at a time, and each block's arithmetic depends on that block
only; the sums over blocks (``W``, ``WZ``, the sparse weights) are then formed in block order by the
caller. Computing the blocks on threads and handing them to the caller in order therefore gives the
single-threaded answer to the last bit, for any number of threads. NumPy releases the interpreter
lock inside its array loops, so blocks of a few hundred thousand elements run concurrently, and the
caller's sums overlap with the next blocks' arithmetic.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np

from pmht_opt.exceptions import ConfigError
from solvers.threads import LazyPool, usable_cores, wait_all

__all__ = [
    "MIN_THREADED_TRIPLES",
    "block_threads",
    "concurrent",
    "ordered_map",
    "scratch",
    "thread_count",
    "usable_cores",
]

R = TypeVar("R")

#: E-steps of fewer (locale, time, platform) triples keep their blocks, and the objective computed
#: beside them, on the calling thread (:func:`block_threads`).
MIN_THREADED_TRIPLES = 1 << 20

_POOL = LazyPool(max(2, usable_cores()), "pmht-blocks")
_LOCAL = threading.local()


class _StoppedError(Exception):
    """Raised inside work that :func:`concurrent` no longer wants (its ``with`` body was left)."""


def thread_count(threads: Any, *, or_none: bool = False) -> int:
    """``threads`` as a positive ``int``; :class:`~pmht_opt.exceptions.ConfigError` naming it otherwise
    (``or_none``: the caller also takes ``None``, and the message says so)."""
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        also = " or None" if or_none else ""
        raise ConfigError(f"threads: expected a positive integer{also}, got {threads!r}.")
    return int(threads)


def block_threads(threads: int, triples: int) -> int:
    """The threads worth giving an E-step of ``triples`` triples: ``threads``, or one below
    :data:`MIN_THREADED_TRIPLES`.

    A small E-step is a few blocks and a few dozen array passes of well under a millisecond each.
    Every pass a thread finishes then waits for the interpreter lock, which the other thread holds
    between its own passes, and those hand-overs cost more than the overlap gains; large blocks
    overlap well (docs/decisions.md section 6.11). The answer does not depend on it.
    """
    return threads if triples >= MIN_THREADED_TRIPLES else 1


def ordered_map(fn: Callable[[int, int], R], spans: Sequence[tuple[int, int]], threads: int) -> Iterator[R]:
    """``fn(lo, hi)`` for every span, in order; with ``threads > 1`` up to ``threads`` spans are worked
    on ahead of the caller, on a shared pool of threads (inline when called from that pool).

    The generator waits for the work in flight when it is closed early or interrupted (a caller that
    stops at a ``None``, or Ctrl-C, even twice), so nothing runs on after it; exceptions of ``fn`` are
    raised in order, as a loop would raise them.
    """
    if threads <= 1 or len(spans) <= 1 or _POOL.in_pool():
        stop: threading.Event | None = getattr(_LOCAL, "stop", None)
        for lo, hi in spans:
            if stop is not None and stop.is_set():
                raise _StoppedError
            yield fn(lo, hi)
        return
    items = iter(spans)
    pending: deque[Future[R]] = deque()
    try:
        for lo, hi in items:
            pending.append(_POOL.get().submit(fn, lo, hi))
            if len(pending) >= threads:
                break
        while pending:
            result = pending[0].result()  # taken off only once done: an interrupt leaves it waited for
            pending.popleft()
            following = next(items, None)
            if following is not None:
                pending.append(_POOL.get().submit(fn, *following))
            yield result
    finally:
        wait_all(pending)


@contextmanager
def concurrent(workers: int, fn: Callable[..., R], /, *args: Any, **kwargs: Any) -> Iterator[Callable[[], R]]:
    """Run ``fn(*args, **kwargs)`` on the pool while the ``with`` body runs (inline, when the body asks
    for it, with ``workers <= 1`` or inside the pool); the body gets a function that returns its
    result. On leaving the block the work is stopped at its next block of locales
    (:func:`ordered_map` inside it checks) and waited for, so nothing runs on after it."""
    if workers <= 1 or _POOL.in_pool():
        yield lambda: fn(*args, **kwargs)
        return
    stop = threading.Event()

    def run() -> R:
        _LOCAL.stop = stop
        try:
            return fn(*args, **kwargs)
        finally:
            _LOCAL.stop = None

    future = _POOL.get().submit(run)
    try:
        yield future.result
    finally:
        stop.set()
        wait_all([future])


def scratch(name: str, rows: int, cols: int) -> np.ndarray:
    """A ``(rows, cols)`` work array of this thread, reused across calls (its contents are undefined).

    Fresh memory costs far more on its first touch than memory used before, so the pool's threads
    keep their work arrays instead of allocating one per block.
    """
    size = rows * cols
    buf: np.ndarray | None = getattr(_LOCAL, name, None)
    if buf is None or buf.size < size:
        buf = np.empty(size)
        setattr(_LOCAL, name, buf)
    return buf[:size].reshape(rows, cols)
