"""What the studies share: choosing the executor from the command line."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
from collections.abc import Iterator
from typing import Any

from pmht_opt.montecarlo import dask_executor, local_executor


@contextlib.contextmanager
def executor_from_args(args: Any) -> Iterator[cf.Executor]:
    """A Dask executor if ``--dask-scheduler`` was given, else a local pool of ``--workers``."""
    address = getattr(args, "dask_scheduler", None)
    if address:
        with dask_executor(address) as ex:
            yield ex
        return
    ex = local_executor(int(getattr(args, "workers", 1)))
    try:
        yield ex
    finally:
        ex.shutdown(wait=True, cancel_futures=True)
