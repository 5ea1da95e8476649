"""A process pool that survives its workers and never outlives its parent.

:class:`concurrent.futures.ProcessPoolExecutor` breaks as a whole when one worker dies (the OOM killer,
a segfault in a native solver, SIGKILL): every pending future fails with ``BrokenProcessPool`` and no one
can tell which task killed it. Here each worker runs one task at a time over its own pipe, so a death is
pinned on exactly the task that worker held: that future fails with :class:`WorkerCrashed` and a fresh
worker takes the dead one's place; every other task goes on.

Workers never outlive the parent: on Linux they ask the kernel for SIGKILL when the parent dies
(``prctl(PR_SET_PDEATHSIG)``), and everywhere a watchdog thread waits on the parent's sentinel and exits
the process when it fires. Workers ignore SIGINT: Ctrl-C reaches the whole process group, and it is
the parent's to decide what an interrupt means (it stops the run and terminates the workers).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import ctypes.util
import itertools
import multiprocessing
import multiprocessing.connection
import os
import pickle
import signal
import sys
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

from pmht_opt.exceptions import ConfigError

_PR_SET_PDEATHSIG = 1


class WorkerCrashed(BrokenProcessPool):
    """The worker process running this task died (signal, segfault, OOM killer); the task did not finish."""


def _die_with_parent(parent_pid: int) -> None:
    """Make this process exit as soon as its parent does (called first thing in a worker)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError, TypeError):
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    parent = multiprocessing.parent_process()
    if os.getppid() != parent_pid or parent is None:  # the parent died before prctl took effect
        os._exit(1)
    sentinel = parent.sentinel

    def watch() -> None:
        multiprocessing.connection.wait([sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def _worker(conn: multiprocessing.connection.Connection, parent_pid: int, max_tasks: int | None) -> None:
    """A worker's loop: receive a pickled task, run it, send back ``(ok, result or exception)``."""
    _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for _ in itertools.count() if max_tasks is None else range(max_tasks):
        try:
            payload = conn.recv_bytes()
        except (EOFError, OSError):
            return
        try:
            fn, args, kwargs = pickle.loads(payload)
            reply: tuple[bool, Any] = (True, fn(*args, **kwargs))
        except BaseException as err:  # sent back to the parent, which decides what it means
            reply = (False, err)
        try:
            conn.send(reply)
        except Exception as err:  # an unpicklable result or exception
            conn.send((False, RuntimeError(f"{type(err).__name__} while returning the result: {err}")))


@dataclass
class _Worker:
    process: multiprocessing.process.BaseProcess
    conn: multiprocessing.connection.Connection
    task: tuple[cf.Future[Any], bytes] | None = None
    done: int = 0


@dataclass
class _State:
    queue: deque[tuple[cf.Future[Any], bytes]] = field(default_factory=deque)
    workers: list[_Worker] = field(default_factory=list)
    retired: list[_Worker] = field(default_factory=list)
    closed: bool = False


class WorkerPool(cf.Executor):
    """``workers`` spawned processes; a worker that dies fails only its own task with :class:`WorkerCrashed`.

    Parameters
    ----------
    workers
        Number of worker processes (started when the first task is submitted).
    max_tasks_per_child
        Replace a worker after this many tasks (``1``: every task in a fresh process, for measurements
        that must not share caches or heap); ``None`` keeps workers for the pool's life.
    """

    def __init__(self, workers: int, *, max_tasks_per_child: int | None = None) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ConfigError(f"workers: expected a positive integer, got {workers!r}.")
        self._n = workers
        self._max_tasks = max_tasks_per_child
        self._ctx = multiprocessing.get_context("spawn")
        self._state = _State()
        self._lock = threading.Condition()
        self._wake_r, self._wake_w = self._ctx.Pipe(duplex=False)
        self._thread: threading.Thread | None = None

    @property
    def workers(self) -> int:
        """The number of worker processes."""
        return self._n

    def pids(self) -> list[int]:
        """Process ids of the live workers (for tests and diagnostics)."""
        with self._lock:
            return [w.process.pid for w in self._state.workers if w.process.pid is not None]

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future[Any]:
        """Queue ``fn(*args, **kwargs)``; ``fn`` and its arguments must pickle (top-level functions)."""
        payload = pickle.dumps((fn, args, kwargs))
        fut: cf.Future[Any] = cf.Future()
        with self._lock:
            if self._state.closed:
                raise RuntimeError("cannot submit to a pool that was shut down")
            self._state.queue.append((fut, payload))
            if self._thread is None:
                self._thread = threading.Thread(target=self._manage, name="worker-pool", daemon=True)
                self._thread.start()
        self._wake_w.send_bytes(b"")
        return fut

    def _spawn(self) -> _Worker:
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(target=_worker, args=(child, os.getpid(), self._max_tasks), daemon=True)
        proc.start()
        child.close()
        return _Worker(proc, parent)

    def _assign(self) -> None:
        state = self._state
        while state.queue and not state.closed:
            idle = [w for w in state.workers if w.task is None]
            if not idle and len(state.workers) < self._n:
                state.workers.append(self._spawn())
                continue
            if not idle:
                return
            fut, payload = state.queue.popleft()
            if not fut.set_running_or_notify_cancel():
                continue
            worker = idle[0]
            worker.task = (fut, payload)
            try:
                worker.conn.send_bytes(payload)
            except OSError:
                pass  # the worker is dead; its sentinel reports it on the next wait

    def _manage(self) -> None:
        """The pool's thread: hand out tasks, collect results, replace workers that died."""
        state = self._state
        while True:
            with self._lock:
                if state.closed:
                    return
                self._assign()
                waits: list[Any] = [self._wake_r]
                for w in state.workers:
                    waits += [w.conn, w.process.sentinel]
            ready = multiprocessing.connection.wait(waits)
            with self._lock:
                if self._wake_r in ready:
                    while self._wake_r.poll():
                        self._wake_r.recv_bytes()
                for w in list(state.workers):
                    if w.conn in ready and w.task is not None:
                        self._collect(w)
                    elif w.process.sentinel in ready and not self._collect_last(w):
                        self._bury(w)

    def _collect(self, w: _Worker) -> None:
        assert w.task is not None
        fut = w.task[0]
        try:
            ok, value = w.conn.recv()
        except (EOFError, OSError):
            self._bury(w)
            return
        w.task = None
        w.done += 1
        if ok:
            fut.set_result(value)
        else:
            fut.set_exception(value)
        if self._max_tasks is not None and w.done >= self._max_tasks:
            # The worker exits by itself; a replacement starts while it tears down (joined at shutdown).
            self._state.workers.remove(w)
            self._state.retired.append(w)

    def _collect_last(self, w: _Worker) -> bool:
        """A worker exited: take a result it sent just before, if any. True when that settled it."""
        if w.task is not None and w.conn.poll():
            self._collect(w)
            return w not in self._state.workers
        return False

    def _bury(self, w: _Worker) -> None:
        w.process.join(timeout=5)
        if w in self._state.workers:
            self._state.workers.remove(w)
        w.conn.close()
        if w.task is not None:
            code = w.process.exitcode
            how = f"signal {-code}" if code is not None and code < 0 else f"exit code {code}"
            w.task[0].set_exception(WorkerCrashed(f"worker process {w.process.pid} died ({how})"))
            w.task = None

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Stop the workers. Tasks still queued are cancelled; running ones are terminated."""
        with self._lock:
            self._state.closed = True
            queued = list(self._state.queue)
            self._state.queue.clear()
            workers = self._state.workers + self._state.retired
        for fut, _ in queued:
            fut.cancel()
        with contextlib.suppress(OSError):
            self._wake_w.send_bytes(b"")
        if self._thread is not None:
            self._thread.join(timeout=10)
        for w in workers:
            if w.process.is_alive():
                w.process.terminate()
        for w in workers:
            w.process.join(timeout=5 if wait else 0.5)
            if w.process.is_alive():
                w.process.kill()
                w.process.join(timeout=5)
            w.conn.close()
            if w.task is not None and not w.task[0].done():
                w.task[0].set_exception(WorkerCrashed("the pool was shut down while the task ran"))
