"""The one parser of the studies: ``pmht-opt study NAME ...`` and ``python -m studies NAME ...``.

Each study module provides a frozen ``Options`` dataclass (with ``add_arguments`` and ``from_args``),
its results table ``TABLE`` and either ``main(run, options) -> list of paths written`` or, for a study that
is one table of trials and its summary, ``params(options)`` (the trials), ``summary(rows)`` and
``markdown(summary)`` (:func:`run_study` runs those). This module adds the options every study shares
(:class:`~studies.options.RunOptions`), turns the command line into the two typed option objects, and
either runs the study or, with ``--verify K``, runs K stored trials again and compares them with their
rows.

Exit status: 0 done (or verified), 1 a verification mismatch, 2 a bad input or a failed study (the
project's own error, one line), 3 done but some trials crashed their worker and have no result (they
are listed on stderr, also under ``--quiet``; the same command runs them again), 130 interrupted
(Ctrl-C; finished trials are kept).

Warnings about the results (damaged lines, NaN results) are printed as one line each on stderr,
``pmht-opt study: warning: ...``, not in Python's warning format.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import importlib
import sys
import tomllib
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple, NoReturn

from pmht_opt.exceptions import MissingDependencyError, PmhtOptError
from studies.executors import local_executor
from studies.options import RunOptions
from studies.store import StudyWarning
from studies.stored import verify
from studies.trials import TrialTable, crash_log


class Study(NamedTuple):
    """A study the command runs: its module, and what it studies in one line (its ``--help``)."""

    module: str
    text: str


#: Where the studies are listed (name, module, one line of help), as data: ``pmht-opt --help`` reads
#: it without importing them.
REGISTRY = Path(__file__).resolve().parent / "registry.toml"

#: The studies by their name on the command line.
STUDIES: dict[str, Study] = {
    name: Study(entry["module"], entry["text"]) for name, entry in tomllib.loads(REGISTRY.read_text()).items()
}


#: What the ``studies`` extra installs.
EXTRAS = ("pandas", "tqdm")


def require_extras() -> None:
    """Raise :class:`MissingDependencyError` naming the extra when pandas or tqdm is missing."""
    missing = []
    for name in EXTRAS:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError:
            missing.append(name)
    if missing:
        raise MissingDependencyError(
            f'the studies need {", ".join(missing)}; install the extra: pip install ".[studies]"'
        )


def _module(name: str) -> ModuleType:
    return importlib.import_module(STUDIES[name].module)


def build_parser(prog: str = "pmht-opt study") -> argparse.ArgumentParser:
    """The parser of every study's options."""
    parser = argparse.ArgumentParser(prog=prog, description="Run one of the studies into a directory.")
    names = parser.add_subparsers(dest="study", required=True, metavar="NAME")
    for name, study in STUDIES.items():
        sp = names.add_parser(name, help=study.text, description=study.text)
        RunOptions.add_arguments(sp)
        _module(name).Options.add_arguments(sp)
    return parser


def run_verify(table: TrialTable, run: RunOptions, executor: cf.Executor | None = None) -> int:
    """``--verify K``: print what was compared and every mismatch; 1 when there is one."""
    assert run.verify is not None
    rows, mismatches = verify(table, run.out, run.verify, executor=executor)
    skipped = {name: c.reason for name, c in table.checks.items() if c.kind == "skip"}
    close = {name: c for name, c in table.checks.items() if c.kind == "close"}
    print(f"verify: {len(rows)} stored trials of {table.path(run.out)} run again")
    for name, reason in skipped.items():
        print(f"  not compared: {name} ({reason})")
    for name, c in close.items():
        print(f"  {name}: within rtol {c.rtol:g}, atol {c.atol:g} ({c.reason})")
    print("  every other column: identical")
    for m in mismatches:
        print(f"MISMATCH {m}")
    if mismatches:
        print(f"verify: {len(mismatches)} mismatches", file=sys.stderr)
        return 1
    print("verify: every trial agrees with its row")
    return 0


#: Exit status of a study that finished with trials that crashed their worker.
EXIT_CRASHED = 3


@contextlib.contextmanager
def one_line_warnings(prog: str) -> Iterator[None]:
    """Show every :class:`~studies.store.StudyWarning` raised within as one line on stderr, ``PROG:
    warning: MESSAGE`` (every time: two runs in one process warn twice); other warnings as before."""
    with warnings.catch_warnings():
        warnings.simplefilter("always", StudyWarning)
        shown = warnings.showwarning

        def show(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
            if issubclass(category, StudyWarning):
                print(f"{prog}: warning: {message}", file=sys.stderr)
            else:
                shown(message, category, *args, **kwargs)

        warnings.showwarning = show
        yield


def run_study(module: ModuleType, run: RunOptions, options: Any) -> list[Path]:
    """Run the study of ``module`` with its ``options``; the paths written.

    A module with a ``main`` runs it. Any other is one table of trials: its trials run into ``run.out``
    (``TABLE.name`` + ``.jsonl``), then its summary goes to ``<name>_summary.json`` and, as markdown, to
    ``<name>.md``.
    """
    if hasattr(module, "main"):
        written: list[Path] = module.main(run, options)
        return written
    out, rows = run.run_trials(module.TABLE, module.params(options))
    summary = module.summary(rows)
    return run.publish(module.TABLE, out, summary, module.markdown(summary), rows=rows)


def main(argv: Sequence[str] | None = None, prog: str = "pmht-opt study") -> int:
    """Parse ``argv``, run the study (or verify it) and print the paths written; return the exit status."""
    try:
        require_extras()
    except MissingDependencyError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    ns = build_parser(prog).parse_args(argv)
    module = _module(ns.study)
    try:
        run = RunOptions.from_args(ns)
        options = module.Options.from_args(ns)
        with one_line_warnings(prog), crash_log() as crashed:
            if run.verify is not None:
                executor = getattr(module, "verify_executor", None)
                ex = executor() if executor is not None else local_executor(1)
                try:
                    return run_verify(module.TABLE, run, ex)
                finally:
                    ex.shutdown(wait=False, cancel_futures=True)
            written = run_study(module, run, options)
    except PmhtOptError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            f"{prog}: interrupted; finished trials are kept in {ns.out} (run the same command to resume).",
            file=sys.stderr,
        )
        return 130
    for path in written:
        print(f"wrote: {path}")
    if crashed:
        print(
            f"{prog}: {len(crashed)} of the trials crashed their worker and have no result (listed above); "
            "run the same command to retry them.",
            file=sys.stderr,
        )
        return EXIT_CRASHED
    return 0


def run_script(name: str, module_file: str) -> NoReturn:
    """``python studies/MODULE.py ...``: study ``name`` into ``studies/results/NAME`` next to the module,
    the rest of the command line as given; exits with the study's status."""
    out = Path(module_file).parent / "results" / name
    sys.exit(main([name, "--out", str(out), *sys.argv[1:]]))
