"""Options every study takes (output directory, workers, Dask, resume, verify), checked once.

Each study adds a frozen dataclass of its own options; both kinds validate themselves on construction
and raise :class:`~pmht_opt.exceptions.ConfigError` naming the command-line option, so a bad input stops
the run before any work starts.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from pmht_opt.exceptions import ConfigError
from studies.trials import check_dask_address, dask_executor, local_executor


def positive_int(option: str, value: object, *, minimum: int = 1) -> int:
    """``value`` if it is an integer of at least ``minimum``; else :class:`ConfigError` naming ``option``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        what = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        raise ConfigError(f"{option}: expected {what}, got {value!r}.")
    return value


def prepare_dir(option: str, path: Path) -> Path:
    """Create ``path`` (and missing parents) and make sure files can be written in it.

    Every study writes through this, so missing folders are treated the same way everywhere.

    Raises
    ------
    ConfigError
        ``path`` names a file, or cannot be created or written.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option}: {path} is a file; expected a directory.")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as err:
        raise ConfigError(f"{option}: cannot write in {path} ({err.strerror or err}).") from None
    return path


@dataclass(frozen=True)
class RunOptions:
    """How a study runs, whatever the study.

    Attributes
    ----------
    out
        Directory of the results (created if missing).
    workers
        Worker processes (1: inline, in this process).
    dask_scheduler
        Address of a Dask scheduler to run the trials on instead (``tcp://host:port``).
    fresh
        Start the results file afresh instead of resuming it.
    quiet
        No progress bar and no printed tables.
    verify
        Instead of running the study, run this many stored trials again and compare them with their rows.
    """

    out: Path
    workers: int = 1
    dask_scheduler: str | None = None
    fresh: bool = False
    quiet: bool = False
    verify: int = 0

    def __post_init__(self) -> None:
        positive_int("--workers", self.workers)
        positive_int("--verify", self.verify, minimum=0)
        if self.dask_scheduler is not None:
            object.__setattr__(self, "dask_scheduler", check_dask_address(self.dask_scheduler))
        if self.verify and self.fresh:
            raise ConfigError("--verify compares with the stored results; it cannot be used with --fresh.")

    def prepare(self) -> Path:
        """The output directory, created and checked to be writable."""
        return prepare_dir("--out", self.out)

    @contextlib.contextmanager
    def executor(self) -> Iterator[cf.Executor]:
        """A Dask executor when ``dask_scheduler`` is set, else a local one of ``workers``."""
        if self.dask_scheduler:
            with dask_executor(self.dask_scheduler) as ex:
                yield ex
            return
        ex = local_executor(self.workers)
        try:
            yield ex
        finally:
            ex.shutdown(wait=False, cancel_futures=True)
