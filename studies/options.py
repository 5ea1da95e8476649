"""Options every study takes (output directory, workers, Dask, resume, verify), checked once, and the
one way a study of trials runs into its directory.

Each study adds a frozen dataclass of its own options; both kinds validate themselves on construction
and raise :class:`~pmht_opt.exceptions.ConfigError` naming the command-line option, so a bad input stops
the run before any work starts. The helpers here (:func:`positive_int`, :func:`check_choices`,
:func:`add_choices`) are what those dataclasses share, so every study words its checks and its options
alike.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import dataclasses
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pmht_opt.exceptions import ConfigError
from studies.executors import check_dask_address, dask_executor, local_executor
from studies.trials import Row, TrialTable, run_trials


def positive_int(option: str, value: object, *, minimum: int = 1) -> int:
    """``value`` if it is an integer of at least ``minimum``; else :class:`ConfigError` naming ``option``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        what = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        raise ConfigError(f"{option}: expected {what}, got {value!r}.")
    return value


def check_choices(option: str, values: Sequence[str], known: Iterable[str]) -> None:
    """Raise :class:`ConfigError` naming ``option`` unless ``values`` is a non-empty selection of ``known``.

    argparse already restricts each value to its ``choices``; this check also holds for options built
    in code, where nothing else would stop a misspelt name before the first trial.
    """
    known = tuple(known)
    if not values or any(v not in known for v in values):
        raise ConfigError(f"{option}: expected some of {', '.join(known)}, got {list(values)}.")


def add_choices(
    p: argparse.ArgumentParser, option: str, known: Iterable[str], help: str | None = None
) -> None:
    """Add ``option`` taking one or more of ``known``, all of them by default."""
    names = list(known)
    p.add_argument(option, nargs="+", default=names, choices=names, help=help)


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

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        """The command-line options every study takes."""
        p.add_argument("--out", type=Path, default=Path("study-results"), help="directory for the results")
        p.add_argument("--workers", type=int, default=1, help="parallel worker processes (default 1: inline)")
        p.add_argument(
            "--dask-scheduler",
            default=None,
            metavar="ADDRESS",
            help="run the trials on the Dask cluster at ADDRESS (tcp://host:port); needs the dask extra",
        )
        p.add_argument("--fresh", action="store_true", help="start the results file afresh (default: resume)")
        p.add_argument("--quiet", action="store_true", help="no progress bar and no printed tables")
        p.add_argument(
            "--verify",
            type=int,
            default=0,
            metavar="K",
            help="run K stored trials again and compare them with their rows instead of running the study",
        )

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> RunOptions:
        """The options from parsed arguments (each field is the option of the same name)."""
        return cls(**{f.name: getattr(ns, f.name) for f in dataclasses.fields(cls)})

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

    def run_trials(self, table: TrialTable, trials: Sequence[Mapping[str, Any]]) -> tuple[Path, list[Row]]:
        """Run ``trials`` of ``table`` into the output directory as these options say (executor,
        progress bar, resume or afresh); the directory and the rows, in the order of ``trials``."""
        out = self.prepare()
        with self.executor() as ex:
            rows = run_trials(
                table,
                trials,
                out,
                executor=ex,
                progress=not self.quiet,
                label=table.name,
                resume=not self.fresh,
            )
        return out, rows

    def publish(
        self, table: TrialTable, out: Path, summary: Sequence[Any], text: str, header: str = ""
    ) -> list[Path]:
        """Print the markdown ``text`` (unless quiet) and write the summary files of ``table``
        (:func:`studies.report.write_summary`); the paths of the results file and of those written."""
        # pandas comes with the report: imported only once a study has run, so that a missing extra is
        # reported by the command, not by an import.
        from studies.report import write_summary

        if not self.quiet:
            print(text)
        return [table.path(out), *write_summary(out, table.name, summary, text, header)]
