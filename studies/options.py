"""Options every study takes (output directory, workers, Dask, resume, verify, tables only), checked
once, and the one way a study of trials runs into its directory.

Each study adds a frozen dataclass of its own options; both kinds validate themselves on construction
and raise :class:`~pmht_opt.exceptions.ConfigError` naming the command-line option, so a bad input stops
the run before any work starts. A study's own options derive from :class:`StudyOptions` and declare each
field with its command-line form (:func:`option` with :class:`Count`, :class:`Integers`,
:class:`Choices`, :class:`Positives`, :class:`Texts`, :class:`Text`, :class:`Flag` or :class:`Without`),
so every study words its checks and its options alike.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import dataclasses
import math
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

from pmht_opt.exceptions import ConfigError
from studies.executors import check_dask_address, dask_executor, local_executor
from studies.stored import run_provenance, stored_rows
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


@dataclass(frozen=True)
class Option:
    """How one field of a study's options is given on the command line, checked and read back.

    Declared with the field (:func:`option`), so a study states each of its options once: the flag,
    its help, the check and the default all come from that one declaration.
    """

    flag: str
    help: str | None = None

    @property
    def dest(self) -> str:
        """The attribute argparse stores the value in."""
        return self.flag.lstrip("-").replace("-", "_")

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """Add the option to ``p``; ``default`` is the field's default."""
        raise NotImplementedError

    def check(self, value: Any) -> None:
        """Raise :class:`ConfigError` naming the flag when ``value`` is out of range."""

    def read(self, given: Any) -> Any:
        """The field's value from what argparse parsed."""
        return given


@dataclass(frozen=True)
class Count(Option):
    """An integer of at least ``minimum``."""

    minimum: int = 1

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """``FLAG N``."""
        p.add_argument(self.flag, type=int, default=default, help=self.help)

    def check(self, value: Any) -> None:
        """:func:`positive_int`."""
        positive_int(self.flag, value, minimum=self.minimum)


@dataclass(frozen=True)
class Choices(Option):
    """One or more of ``known`` (by default the field's default; ``installed`` computes it when the
    command runs instead, for choices that depend on what is installed)."""

    known: tuple[str, ...] = ()
    installed: Callable[[], tuple[str, ...]] | None = None

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """``FLAG NAME [NAME ...]``, restricted to ``known``."""
        given = None if self.installed is not None else list(default)
        p.add_argument(self.flag, nargs="+", default=given, choices=list(self.known), help=self.help)

    def check(self, value: Any) -> None:
        """:func:`check_choices`."""
        check_choices(self.flag, value, self.known)

    def read(self, given: Any) -> Any:
        """A tuple of the names given, or of those installed."""
        if self.installed is not None and not given:
            return self.installed()
        return tuple(given)


@dataclass(frozen=True)
class Positives(Option):
    """One or more positive finite numbers."""

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """``FLAG X [X ...]``."""
        given = None if default is None else list(default)
        p.add_argument(self.flag, nargs="+", type=float, default=given, help=self.help)

    def check(self, value: Any) -> None:
        """Every value finite and positive, and at least one."""
        if not value or any(not (math.isfinite(v) and v > 0) for v in value):
            raise ConfigError(f"{self.flag}: expected positive numbers, got {list(value)}.")

    def read(self, given: Any) -> Any:
        """A tuple of floats."""
        return tuple(float(v) for v in given)


@dataclass(frozen=True)
class Without(Option):
    """A ``--no-...`` flag that turns off a field that is on by default."""

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """``--no-...``, no value."""
        p.add_argument(self.flag, action="store_true", help=self.help)

    def read(self, given: Any) -> Any:
        """On unless the flag was given."""
        return not given


@dataclass(frozen=True)
class Integers(Option):
    """One or more integers of at least ``minimum`` (seeds, horizons)."""

    minimum: int = 0

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """``FLAG N [N ...]``."""
        given = None if default is None else list(default)
        p.add_argument(self.flag, nargs="+", type=int, default=given, help=self.help)

    def check(self, value: Any) -> None:
        """At least one value, each an integer of at least ``minimum``."""
        if not value:
            raise ConfigError(f"{self.flag}: expected at least one integer, got {list(value)}.")
        for v in value:
            positive_int(self.flag, v, minimum=self.minimum)

    def read(self, given: Any) -> Any:
        """A tuple of ints."""
        return tuple(int(v) for v in given)


@dataclass(frozen=True)
class Texts(Option):
    """Zero or more non-empty words (names, paths); ``empty`` whether none at all is allowed."""

    empty: bool = False

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """``FLAG WORD [WORD ...]``."""
        given = None if default is None else list(default)
        p.add_argument(self.flag, nargs="*" if self.empty else "+", default=given, help=self.help)

    def check(self, value: Any) -> None:
        """Every value a non-empty string (and at least one unless ``empty``)."""
        if not isinstance(value, tuple) or (not value and not self.empty):
            raise ConfigError(f"{self.flag}: expected at least one value, got {value!r}.")
        if any(not isinstance(v, str) or not v.strip() for v in value):
            raise ConfigError(f"{self.flag}: expected non-empty words, got {list(value)}.")

    def read(self, given: Any) -> Any:
        """A tuple of strings."""
        return tuple(str(v) for v in given)


@dataclass(frozen=True)
class Text(Option):
    """One word, or ``""`` for none (a path that may be left out)."""

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """``FLAG WORD``."""
        p.add_argument(self.flag, default=default, help=self.help)

    def check(self, value: Any) -> None:
        """A string."""
        if not isinstance(value, str):
            raise ConfigError(f"{self.flag}: expected a word, got {value!r}.")

    def read(self, given: Any) -> Any:
        """The string (``""`` when not given)."""
        return "" if given is None else str(given)


@dataclass(frozen=True)
class Flag(Option):
    """A flag that turns on a field that is off by default."""

    def add(self, p: argparse.ArgumentParser, default: Any) -> None:
        """``--...``, no value."""
        p.add_argument(self.flag, action="store_true", help=self.help)

    def read(self, given: Any) -> Any:
        """On when the flag was given."""
        return bool(given)


def option(default: Any, spec: Option) -> Any:
    """A field of a study's options (a :class:`StudyOptions`): its default and its command-line form."""
    return dataclasses.field(default=default, metadata={"option": spec})


@dataclass(frozen=True)
class StudyOptions:
    """Base of a study's own options, whose fields are declared with :func:`option`.

    Construction checks every field (so options built in code are held to what the command line is),
    :meth:`add_arguments` adds them to the study's parser in the order declared, and :meth:`from_args`
    reads them back.
    """

    def __post_init__(self) -> None:
        for name, spec in self._options():
            spec.check(getattr(self, name))

    @classmethod
    def _options(cls) -> list[tuple[str, Option]]:
        return [(f.name, f.metadata["option"]) for f in dataclasses.fields(cls) if "option" in f.metadata]

    @classmethod
    def add_arguments(cls, p: argparse.ArgumentParser) -> None:
        """The command-line options of this study."""
        defaults = {f.name: f.default for f in dataclasses.fields(cls)}
        for name, spec in cls._options():
            spec.add(p, defaults[name])

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> Self:
        """The options from parsed arguments."""
        return cls(**{name: spec.read(getattr(ns, spec.dest)) for name, spec in cls._options()})


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
        Instead of running the study, run this many stored trials again and compare them with their rows
        (``None``: run the study; a count must be positive, since ``--verify 0`` would otherwise read
        as "do not verify" and run the study, appending to the results it was asked to check).
    tables_only
        Run no trial: write the summaries, tables and figures from the rows already stored (the study's
        trials that have none are left out, and said so).
    """

    out: Path
    workers: int = 1
    dask_scheduler: str | None = None
    fresh: bool = False
    quiet: bool = False
    verify: int | None = None
    tables_only: bool = False

    def __post_init__(self) -> None:
        positive_int("--workers", self.workers)
        if self.verify is not None:
            positive_int("--verify", self.verify)
        if self.dask_scheduler is not None:
            object.__setattr__(self, "dask_scheduler", check_dask_address(self.dask_scheduler))
        if self.verify is not None and self.fresh:
            raise ConfigError("--verify compares with the stored results; it cannot be used with --fresh.")
        if self.tables_only and (self.fresh or self.verify is not None):
            raise ConfigError(
                "--tables-only reads the stored results; it cannot be used with --fresh or --verify."
            )

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
            default=None,
            metavar="K",
            help="run K (at least 1) stored trials again and compare them with their rows instead of "
            "running the study",
        )
        p.add_argument(
            "--tables-only",
            action="store_true",
            help="run no trial: rewrite the summaries, tables and figures from the results in --out",
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
        if self.tables_only:
            return out, stored_rows(table, trials, out)
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
        self,
        table: TrialTable,
        out: Path,
        summary: Sequence[Any],
        text: str,
        header: str = "",
        *,
        rows: Sequence[Mapping[str, Any]] = (),
    ) -> list[Path]:
        """Print the markdown ``text`` (unless quiet) and write the summary files of ``table``
        (:func:`studies.report.write_summary`); the paths of the results file and of those written.

        The NaN results among ``rows`` (the rows the summary was made from) that the schema does not
        expect are listed below the table and in the summary's ``nan_results``: the summary's means
        and medians leave them out, which the table must say.
        """
        # pandas comes with the report: imported only once a study has run, so that a missing extra is
        # reported by the command, not by an import.
        from studies.report import nan_note, write_summary

        extra: dict[str, Any] = {}
        flagged = [(r["trial"], c) for r in rows for c in table.schema.nan_columns(r)]
        if flagged:
            text += "\n\n" + nan_note(flagged)
            extra["nan_results"] = [{"trial": t, "column": c} for t, c in flagged]
        if self.tables_only:
            header = (
                f"Written with --tables-only from the stored rows of {table.path(out).name}; the runs "
                "that measured them are in its run records.\n\n" + header
            )
            extra["runs"] = run_provenance(table, out)
        if not self.quiet:
            print(text)
        return [table.path(out), *write_summary(out, table.name, summary, text, header, extra)]
