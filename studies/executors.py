"""Where trials run: inline in this process, a pool of spawned worker processes, or a Dask cluster.

Every study takes its executor from here (through :meth:`studies.options.RunOptions.executor`), so the
three behave alike for :func:`studies.trials.run_trials`: tasks are :func:`studies.trials.call_trial`
calls, an exception other than an interrupt lands in the future, and a malformed Dask address is
refused before anything connects.
"""

from __future__ import annotations

import asyncio
import concurrent.futures as cf
import contextlib
import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any
from urllib.parse import urlsplit

from pmht_opt.exceptions import ConfigError, MissingDependencyError
from studies.pool import WorkerPool


class InlineExecutor(cf.Executor):
    """Runs each task when it is submitted, in this process (one worker, no pickling)."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future[Any]:
        """Run ``fn`` now; its exception (never a ``KeyboardInterrupt``) goes into the future."""
        fut: cf.Future[Any] = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as err:
            fut.set_exception(err)
        return fut


def local_executor(workers: int, *, max_tasks_per_child: int | None = None) -> cf.Executor:
    """An inline executor for 1 worker, else a :class:`~studies.pool.WorkerPool` of spawned processes.

    Spawned, not forked: the parent may hold solver threads, and OR-Tools and HiGHS cannot share a
    process. ``max_tasks_per_child=1`` forces a fresh process per trial even for 1 worker.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"--workers: expected a positive integer, got {workers!r}.")
    if workers == 1 and max_tasks_per_child is None:
        return InlineExecutor()
    return WorkerPool(workers, max_tasks_per_child=max_tasks_per_child)


_DASK_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx", "inproc")


def check_dask_address(address: str) -> str:
    """``address`` as a Dask scheduler address (``tcp://host:port``; a bare ``host:port`` means tcp).

    Raises
    ------
    ConfigError
        Not of that form (checked before any connection is tried).
    """
    text = address.strip()
    full = text if "://" in text else f"tcp://{text}"
    parts = urlsplit(full)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in _DASK_SCHEMES or not parts.hostname or (parts.scheme != "inproc" and not port):
        raise ConfigError(f"--dask-scheduler: expected an address such as tcp://host:8786, got {address!r}.")
    return full


@contextlib.contextmanager
def dask_executor(
    address: str | None = None, *, connect_timeout: float = 5.0, **cluster: Any
) -> Iterator[cf.Executor]:
    """An executor on a Dask cluster: the scheduler at ``address``, or a new ``LocalCluster(**cluster)``.

    A malformed address fails at once. A well-formed one must accept a connection, complete Dask's
    handshake and answer an identity request as a scheduler, all within ``connect_timeout`` seconds
    (:func:`probe_scheduler`); otherwise :class:`ConfigError` naming the address. Needs the ``dask``
    extra.
    """
    try:
        from distributed import Client, LocalCluster
    except ModuleNotFoundError:
        raise MissingDependencyError(
            "Dask execution needs dask.distributed; install the extra: pip install '.[dask]'."
        ) from None
    local = None
    if address is not None:
        address = check_dask_address(address)
        parts = urlsplit(address)
        if parts.scheme == "tcp" and parts.hostname and parts.port:
            try:  # a refused or unreachable port fails here in milliseconds, not after Dask's retries
                socket.create_connection((parts.hostname, parts.port), timeout=connect_timeout).close()
            except OSError as err:
                raise ConfigError(f"--dask-scheduler {address}: cannot connect ({err}).") from None
        probe_scheduler(address, connect_timeout)
    try:
        if address is None:
            local = LocalCluster(**cluster)
            client = Client(local)
        else:
            client = Client(address, timeout=f"{connect_timeout}s")
    except (OSError, TimeoutError) as err:
        raise ConfigError(f"--dask-scheduler {address}: cannot connect ({err}).") from None
    try:
        yield client.get_executor()
    finally:
        client.close()
        if local is not None:
            local.close()


def probe_scheduler(address: str, timeout: float) -> dict[str, Any]:
    """The identity of the Dask scheduler at ``address``, asked for within ``timeout`` seconds.

    Dask's own connection waits for the peer's handshake without a time limit, so a port that accepts
    connections and never answers (a stuck process, a service that is not Dask) would hang a study
    forever. Here the connection, the handshake and the identity request run on an event loop of
    their own, in a daemon thread, under one deadline: a peer that is silent costs ``timeout``
    seconds and nothing is left waiting on it that could hold up the process's exit. The client's own
    connection follows at once, to a peer that has just answered.

    Raises
    ------
    ConfigError
        Naming the address: no answer in time, the connection failed, or the peer is not a scheduler.
    """
    outcome: dict[str, Any] = {}
    done = threading.Event()

    def ask() -> None:
        try:
            outcome["identity"] = asyncio.run(asyncio.wait_for(_identity(address, timeout), timeout))
        except BaseException as err:  # reported to the caller, who words it
            outcome["error"] = err
        finally:
            done.set()

    threading.Thread(target=ask, name="dask-probe", daemon=True).start()
    if not done.wait(timeout + 1.0) or isinstance(outcome.get("error"), (TimeoutError, asyncio.TimeoutError)):
        raise ConfigError(
            f"--dask-scheduler {address}: no answer from a Dask scheduler within {timeout:g} s "
            "(the port accepts connections but does not speak Dask's protocol)."
        )
    err = outcome.get("error")
    if err is not None:
        raise ConfigError(f"--dask-scheduler {address}: cannot connect ({type(err).__name__}: {err}).")
    identity: dict[str, Any] = outcome["identity"]
    if not isinstance(identity, dict) or identity.get("type") != "Scheduler":
        kind = identity.get("type") if isinstance(identity, dict) else type(identity).__name__
        raise ConfigError(f"--dask-scheduler {address}: answers as {kind!r}, not as a Dask scheduler.")
    return identity


async def _identity(address: str, timeout: float) -> Any:
    """Connect to ``address`` with Dask's comm, complete its handshake and ask for the identity (with
    the connection arguments a client takes from Dask's configuration, such as TLS certificates)."""
    from distributed.comm import connect
    from distributed.core import send_recv
    from distributed.security import Security

    comm = await connect(address, timeout=timeout, **Security().get_connection_args("client"))
    try:
        return await send_recv(comm, op="identity", reply=True)
    finally:
        comm.abort()
