"""Blocks of independent work on threads, their results taken in order.

The E-steps work a block of locales at a time, and each block's arithmetic depends on that block
only; the sums over blocks (``W``, ``WZ``, the sparse weights) are then formed in block order by the
caller. Computing the blocks on threads and handing them to the caller in order therefore gives the
single-threaded answer to the last bit, for any number of threads. NumPy releases the interpreter
lock inside its array loops, so blocks of a few hundred thousand elements run concurrently, and the
caller's sums overlap with the next blocks' arithmetic.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np

from pmht_opt.exceptions import ConfigError
from solvers.band_lu import usable_cores

__all__ = ["concurrent", "ordered_map", "scratch", "thread_count", "usable_cores"]

R = TypeVar("R")

_PREFIX = "pmht-blocks"
_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()
_LOCAL = threading.local()


def thread_count(threads: Any) -> int:
    """``threads`` as a positive ``int``; :class:`~pmht_opt.exceptions.ConfigError` naming it otherwise."""
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ConfigError(f"threads: expected a positive integer, got {threads!r}.")
    return int(threads)


def _forget_pool() -> None:
    """In a child made by ``fork`` the parent's pool threads do not exist: make a new pool there."""
    global _POOL
    _POOL = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _pool() -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max(2, usable_cores()), thread_name_prefix=_PREFIX)
        return _POOL


def ordered_map(fn: Callable[[int, int], R], spans: Sequence[tuple[int, int]], threads: int) -> Iterator[R]:
    """``fn(lo, hi)`` for every span, in order; with ``threads > 1`` up to ``threads`` spans are worked
    on ahead of the caller, on a shared pool of threads (inline when called from that pool).

    The generator waits for the work in flight when it is closed early or interrupted (a caller that
    stops at a ``None``, or Ctrl-C), so nothing runs on after it; exceptions of ``fn`` are raised in
    order, as a loop would raise them.
    """
    # One span, or work of the pool's own threads, runs inline (waiting on the pool from inside it
    # could deadlock).
    if threads <= 1 or len(spans) <= 1 or threading.current_thread().name.startswith(_PREFIX):
        for lo, hi in spans:
            yield fn(lo, hi)
        return
    items = iter(spans)
    pool = _pool()
    pending: deque[Future[R]] = deque()
    try:
        for lo, hi in items:
            pending.append(pool.submit(fn, lo, hi))
            if len(pending) >= threads:
                break
        while pending:
            result = pending.popleft().result()
            following = next(items, None)
            if following is not None:
                pending.append(pool.submit(fn, *following))
            yield result
    finally:
        for future in pending:
            future.cancel()
        wait(pending)


@contextmanager
def concurrent(workers: int, fn: Callable[..., R], /, *args: Any, **kwargs: Any) -> Iterator[Callable[[], R]]:
    """Run ``fn(*args, **kwargs)`` on the pool while the ``with`` body runs (inline, when the body asks
    for it, with ``workers <= 1`` or inside the pool); the body gets a function that returns its
    result. On leaving the block the work is waited for, so nothing runs on after it."""
    if workers <= 1 or threading.current_thread().name.startswith(_PREFIX):
        yield lambda: fn(*args, **kwargs)
        return
    future = _pool().submit(fn, *args, **kwargs)
    try:
        yield future.result
    finally:
        future.cancel()
        wait([future])


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
