"""What the studies share: the executor from the command line, the area rule, writing summaries."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
from collections.abc import Iterator, Sequence
from pathlib import Path
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


#: A run "leaves the area" when a path goes more than this far outside the 10 x 10 box (scenario B's
#: starts are exactly 1 outside, which does not count).
EXCURSION_LIMIT = 1.0


def write_summary(out_dir: Path, name: str, table: Sequence[Any], text: str, header: str = "") -> None:
    """Write ``<name>_summary.json`` (the aggregates) and ``<name>.md`` (the table), and print it."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / f"{name}_summary.json").write_text(json.dumps(list(table), indent=1) + "\n")
    (out_dir / f"{name}.md").write_text(header + text + "\n")
    print(text)
