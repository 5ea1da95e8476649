"""Thread pools that survive interrupts and ``fork``: the pieces shared by the parallel parts.

Work handed to a pool must be finished before the call that handed it returns, also when that call
is interrupted (Ctrl-C): a thread still writing into arrays that the caller reuses afterwards would
corrupt a later answer. :func:`wait_all` therefore keeps waiting through further interrupts and
raises the first one afterwards. A child made by ``fork`` has none of its parent's pool threads, so
:class:`LazyPool` makes a new pool there.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any

__all__ = ["LazyPool", "usable_cores", "wait_all"]


def usable_cores() -> int:
    """The number of cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def wait_all(futures: Iterable[Future[Any]]) -> None:
    """Cancel what has not started and wait for the rest, through any number of interrupts (the
    first is raised once nothing runs any more)."""
    pending = list(futures)
    for future in pending:
        future.cancel()
    interrupted: BaseException | None = None
    while True:
        try:
            wait(pending)
            break
        except KeyboardInterrupt as err:
            interrupted = interrupted or err
    if interrupted is not None:
        raise interrupted


class LazyPool:
    """A thread pool made at its first use (and again in a child made by ``fork``)."""

    def __init__(self, workers: int, prefix: str) -> None:
        self.workers, self.prefix = workers, prefix
        self._pool: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()
        if hasattr(os, "register_at_fork"):
            os.register_at_fork(after_in_child=self._forget)

    def _forget(self) -> None:
        # The parent's threads do not exist here, and its lock may have been held by one of them.
        self._pool, self._lock = None, threading.Lock()

    def get(self) -> ThreadPoolExecutor:
        """The pool, made now if need be."""
        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix=self.prefix)
            return self._pool

    def in_pool(self) -> bool:
        """Whether the calling thread is one of this pool's (waiting on the pool there could deadlock)."""
        return threading.current_thread().name.startswith(self.prefix)
