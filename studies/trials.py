"""Trials: run a function over many seeded trials, in parallel, into a results file that nothing can spoil.

A *trial* is a dict of plain parameters (scenario, seed, method, ...); the study's trial function takes
them as keyword arguments and returns a dict of results. :func:`run_trials` runs every trial that its
results file (:mod:`studies.store`) does not already hold, on any :class:`concurrent.futures.Executor`
(inline, :class:`~studies.pool.WorkerPool`, or a Dask cluster through :func:`dask_executor`), appends one
row per finished trial, shows a tqdm progress bar, and returns the rows in the order of the trials,
whatever order the workers finish in: the same trials give the same rows on 1 worker, 2 workers or Dask.

What can go wrong, and what happens:

- A trial raises: its row records the exception's class and message. The project's own errors
  (:class:`~pmht_opt.exceptions.PmhtOptError`) and other exceptions are real results and stay; a resume
  runs again only the *retryable* ones (:data:`RETRYABLE`: interrupts and crashed workers).
- Ctrl-C: :class:`KeyboardInterrupt` stops the run; every finished row is already on disk, the trials in
  flight leave no row, and the workers are terminated. A solver that catches SIGINT and reports an
  interrupted solve is treated the same way.
- A worker process dies: only its trial is affected; it runs again up to ``retries`` times (in a fresh
  worker), then its row records the crash (retryable, so a later resume tries once more).
- The results file was damaged: see :mod:`studies.store`; damaged rows are recomputed, the rest kept.

Trial functions must be importable top-level functions (they are pickled to the workers) and must draw
randomness only from the seeds in their parameters.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import inspect
import math
import queue
import sys
import typing
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pmht_opt.exceptions import ConfigError, SolverError

# The executors live in their own module; they are named here too, where the trials that run on them are.
from studies.executors import InlineExecutor as InlineExecutor
from studies.executors import check_dask_address as check_dask_address
from studies.executors import dask_executor as dask_executor
from studies.executors import local_executor as local_executor
from studies.provenance import provenance
from studies.store import ResultsFile, Row, Schema, trial_id

TrialFn = Callable[..., Mapping[str, Any]]

#: Exception classes of error rows that a resume runs again: interrupts and crashed workers are
#: accidents of the run, not results of the trial.
RETRYABLE = frozenset(
    {"KeyboardInterrupt", "Interrupted", "WorkerCrashed", "BrokenProcessPool", "KilledWorker"}
)
#: How many times a trial whose worker died is run again within one run before it is recorded as a crash.
RETRIES = 2
#: The error class of a trial whose worker died on every run: it has no result, and a run that leaves
#: one says so on stderr (even under ``--quiet``) and in the study command's exit status.
CRASHED = "WorkerCrashed"

_CRASH_LOG: ContextVar[list[Row] | None] = ContextVar("crash_log", default=None)


@contextlib.contextmanager
def crash_log() -> Iterator[list[Row]]:
    """Collect the rows of the trials that crashed their worker in every :func:`run_trials` within.

    The study command runs a study inside one, whatever the study's own code looks like, and turns a
    non-empty log into its exit status: a crash must not pass for a finished study.
    """
    log: list[Row] = []
    token = _CRASH_LOG.set(log)
    try:
        yield log
    finally:
        _CRASH_LOG.reset(token)


@dataclass(frozen=True)
class Check:
    """How ``--verify`` compares a column of a recomputed trial with its stored row.

    ``exact`` (the default): identical values. ``close``: numbers within ``rtol``/``atol``. ``skip``:
    not compared. ``reason`` says why a column is not held to identity.
    """

    kind: str = "exact"
    rtol: float = 0.0
    atol: float = 0.0
    reason: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ("exact", "close", "skip"):
            raise ConfigError(f"check kind: expected exact, close or skip, got {self.kind!r}.")
        if self.kind != "exact" and not self.reason:
            raise ConfigError("a check that is not exact must state its reason.")

    def agrees(self, stored: Any, fresh: Any) -> bool:
        """Whether the two values agree under this check."""
        if self.kind == "skip":
            return True
        return _agree(stored, fresh, self.rtol if self.kind == "close" else 0.0, self.atol)


#: The CPU and wall seconds of a trial that times its method, and how ``--verify`` treats them: as
#: measurements of the machine at the time, never the same twice.
TIME_COLUMNS = {"cpu": "float", "wall": "float"}
TIME_CHECKS: Mapping[str, Check] = {
    "cpu": Check("skip", reason="CPU time differs from run to run"),
    "wall": Check("skip", reason="wall-clock time differs from run to run"),
}
#: A number computed from a solver's iterates: another run may differ in its last digits.
ITERATES = Check("close", rtol=1e-6, atol=1e-9, reason="last digits of the solvers' iterates")
#: A measure of a plan with constrained M-steps: their backends agree to their tolerances, which on the
#: flat optima of binding limits leaves positions up to about 1e-4 apart (rows recorded before the
#: constrained M-steps were condensed, docs/decisions.md 4.15, agree with today's code to this).
CONSTRAINED = Check(
    "close", rtol=1e-5, atol=1e-9, reason="constrained M-steps agree to the backends' tolerance"
)
#: Paths stored rounded to 1e-3 (for figures): a position moved within that tolerance may round the
#: other way.
ROUNDED_PATHS = Check(
    "close", rtol=0.0, atol=2e-3, reason="paths rounded to 1e-3; constrained M-steps' tolerance"
)
#: The project's error a trial may end in (its class and message; ``None`` for a trial that planned)...
ERROR_COLUMNS = {"raised": "str?", "message": "str?"}
#: ... and how ``--verify`` treats the error's message (whose figures come from the solvers' iterates)
#: and the ``seconds`` such a trial took.
OUTCOME_CHECKS: Mapping[str, Check] = {
    "seconds": Check("skip", reason="wall time"),
    "message": Check("skip", reason="figures in messages carry the solvers' last digits"),
}


def _agree(a: Any, b: Any, rtol: float, atol: float) -> bool:
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_agree(x, y, rtol, atol) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_agree(a[k], b[k], rtol, atol) for k in a)
    num = (int, float)
    if isinstance(a, num) and isinstance(b, num) and not isinstance(a, bool) and not isinstance(b, bool):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b or abs(a - b) <= atol + rtol * abs(a)
    return bool(a == b)


@dataclass(frozen=True)
class TrialTable:
    """A study's table: its name (the file is ``<name>.jsonl``), trial function, schema and checks.

    ``checks`` maps result columns to how ``--verify`` compares them (exact when absent).
    """

    name: str
    fn: TrialFn
    schema: Schema
    checks: Mapping[str, Check] = field(default_factory=dict)

    def path(self, out_dir: Path) -> Path:
        """The results file in ``out_dir``."""
        return Path(out_dir) / f"{self.name}.jsonl"

    @classmethod
    def of(
        cls, name: str, fn: TrialFn, values: Mapping[str, str], checks: Mapping[str, Check] | None = None
    ) -> TrialTable:
        """The table of trial function ``fn``, whose parameters are the schema's: their names and types
        are stated once, in its signature (``int``, ``float``, ``str`` or ``bool``)."""
        return cls(name, fn, Schema(params=signature_columns(fn), values=values), dict(checks or {}))


#: The column type of each type a trial's parameter may be annotated with.
_PARAM_TYPES: Mapping[object, str] = {int: "int", float: "float", str: "str", bool: "bool"}


def signature_columns(fn: TrialFn) -> dict[str, str]:
    """``fn``'s parameters as schema columns, in order; :class:`ConfigError` for one of another type."""
    hints = typing.get_type_hints(fn)
    out = {}
    for name in inspect.signature(fn).parameters:
        kind = _PARAM_TYPES.get(hints.get(name))
        if kind is None:
            raise ConfigError(f"trial parameter {name!r}: annotate it as int, float, str or bool.")
        out[name] = kind
    return out


@dataclass(frozen=True)
class TrialError:
    """What a trial raised, in a form that always pickles back from a worker."""

    error_class: str
    message: str


class Interrupted(Exception):  # noqa: N818 (the name is what an error row records)
    """A trial that a solver reported as interrupted (it caught SIGINT itself)."""


def call_trial(fn: TrialFn, params: Mapping[str, Any]) -> Mapping[str, Any] | TrialError:
    """Run one trial (in a worker): its results, or the exception it raised as a :class:`TrialError`.

    ``KeyboardInterrupt`` propagates: an interrupt is never a trial's result. A solver status that
    says the solve was interrupted becomes ``KeyboardInterrupt`` too.
    """
    try:
        return dict(fn(**params))
    except SolverError as err:
        if "interrupt" in str(getattr(err, "status", "")).lower():
            raise KeyboardInterrupt from err
        return TrialError(type(err).__name__, str(err) or type(err).__name__)
    except Exception as err:  # the row records it; the study goes on
        return TrialError(type(err).__name__, str(err) or type(err).__name__)


def _is_crash(err: BaseException) -> bool:
    return isinstance(err, cf.BrokenExecutor) or type(err).__name__ in RETRYABLE - {"KeyboardInterrupt"}


def _progress_bar(total: int, initial: int, label: str, show: bool) -> Any:
    from tqdm import tqdm

    tqdm.monitor_interval = 0  # no monitor thread (see pmht_opt.cli.commands._progress_bar)
    return tqdm(total=total, initial=initial, desc=label, disable=not show, file=sys.stderr, smoothing=0.1)


def run_trials(
    table: TrialTable,
    trials: Sequence[Mapping[str, Any]],
    out_dir: str | Path,
    *,
    executor: cf.Executor | None = None,
    workers: int = 1,
    progress: bool = True,
    label: str | None = None,
    resume: bool = True,
    retries: int = RETRIES,
) -> list[Row]:
    """Run ``table.fn(**trial)`` for every trial not yet in ``out_dir/<table.name>.jsonl``.

    Parameters
    ----------
    table
        The study's table: name, trial function and schema.
    trials
        Parameters of each trial; two trials with the same parameters are one trial.
    out_dir
        Directory of the results file (created if missing).
    executor
        Where to run the trials; default :func:`local_executor` with ``workers``. Not shut down here
        unless created here.
    progress
        Show a progress bar on stderr.
    resume
        Keep and reuse the valid rows already in the file (retryable error rows run again); ``False``
        starts the file afresh.
    retries
        Runs again, within this run, of a trial whose worker died, before its crash is recorded.

    Returns
    -------
    list of dict
        One row per trial, in the order of ``trials``: ``trial`` (its id), the parameters, the results,
        ``error_class`` and ``error`` (empty for a trial that succeeded).
    """
    params = [dict(t) for t in trials]
    for p in params:
        table.schema.check_params(p)
    ids = [trial_id(p) for p in params]
    by_id = dict(zip(ids, params, strict=True))
    unique = list(by_id)
    path = table.path(Path(out_dir))
    path.parent.mkdir(parents=True, exist_ok=True)
    own = executor is None
    with ResultsFile(path, table.schema, table.name, provenance(), resume=resume) as store:
        done = {k for k in unique if k in store.rows and store.rows[k]["error_class"] not in RETRYABLE}
        todo = [k for k in unique if k not in done]
        bar = _progress_bar(len(unique), len(unique) - len(todo), label or table.name, progress)
        ex = local_executor(workers) if executor is None else executor
        try:
            if isinstance(ex, InlineExecutor):
                _run_inline(table, todo, by_id, store, bar)
            else:
                _run_parallel(table, todo, by_id, store, bar, ex, retries)
        finally:
            bar.close()
            if own:
                ex.shutdown(wait=False, cancel_futures=True)
        rows = [public_row(store.rows[k]) for k in ids]
    crashed = [public_row(store.rows[k]) for k in unique if store.rows[k]["error_class"] == CRASHED]
    if crashed:
        _report_crashes(label or table.name, path, crashed)
    return rows


def _trials(n: int) -> str:
    return f"{n} trial" if n == 1 else f"{n} trials"


def _report_crashes(label: str, path: Path, crashed: Sequence[Row]) -> None:
    """Say on stderr which trials crashed their worker (not a progress message: shown under --quiet),
    and add them to the active :func:`crash_log`."""
    log = _CRASH_LOG.get()
    if log is not None:
        log.extend(crashed)
    print(
        f"{label}: {_trials(len(crashed))} crashed their worker and have no result in {path} "
        "(run the same command to retry them):",
        file=sys.stderr,
    )
    for row in crashed[:10]:
        print(f"  trial {row['trial']}: {row['error']}", file=sys.stderr)
    if len(crashed) > 10:
        print(f"  and {len(crashed) - 10} more (error_class {CRASHED} in the results file)", file=sys.stderr)


def public_row(row: Mapping[str, Any]) -> Row:
    """A stored row without its record marker: what a study's summary reads."""
    return {k: v for k, v in row.items() if k != "record"}


def _record(store: ResultsFile, params: Mapping[str, Any], out: Any, bar: Any) -> None:
    if isinstance(out, TrialError):
        store.append(params, error_class=out.error_class, error=out.message)
        bar.set_postfix_str(f"last error: {out.error_class}", refresh=False)
    else:
        store.append(params, out)
    bar.update(1)


def _run_inline(
    table: TrialTable, todo: Sequence[str], by_id: Mapping[str, dict[str, Any]], store: ResultsFile, bar: Any
) -> None:
    for key in todo:
        _record(store, by_id[key], call_trial(table.fn, by_id[key]), bar)


def _run_parallel(
    table: TrialTable,
    todo: Sequence[str],
    by_id: Mapping[str, dict[str, Any]],
    store: ResultsFile,
    bar: Any,
    ex: cf.Executor,
    retries: int,
) -> None:
    attempts: dict[str, int] = {}
    pending: dict[cf.Future[Any], str] = {}
    # Futures report here when done: waiting costs the same however many are pending.
    finished: queue.SimpleQueue[cf.Future[Any]] = queue.SimpleQueue()

    def submit(key: str) -> None:
        try:
            fut = ex.submit(call_trial, table.fn, by_id[key])
        except (cf.BrokenExecutor, RuntimeError) as err:  # an executor that can take no more work
            record_crash(key, err)
            return
        pending[fut] = key
        fut.add_done_callback(finished.put)

    def crash(key: str, err: BaseException) -> None:
        attempts[key] = attempts.get(key, 0) + 1
        if attempts[key] <= retries:
            submit(key)
        else:
            record_crash(key, err)

    def record_crash(key: str, err: BaseException) -> None:
        runs = attempts.get(key, 0)
        message = f"{type(err).__name__}: {err}" + (f" (on each of {runs} runs)" if runs > 1 else "")
        _record(store, by_id[key], TrialError(CRASHED, message), bar)

    try:
        for key in todo:
            submit(key)
        while pending:
            try:
                fut = finished.get(timeout=0.5)  # a timeout keeps Ctrl-C prompt on every platform
            except queue.Empty:
                continue
            key = pending.pop(fut)
            err = fut.exception()
            if err is None:
                _record(store, by_id[key], fut.result(), bar)
            elif isinstance(err, KeyboardInterrupt):
                raise KeyboardInterrupt from err
            elif _is_crash(err):
                crash(key, err)
            else:
                _record(store, by_id[key], TrialError(type(err).__name__, str(err)), bar)
    finally:
        for fut in pending:
            fut.cancel()
