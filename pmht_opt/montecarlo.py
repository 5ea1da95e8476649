"""Monte Carlo trials: run a function over many seeded trials in parallel into a resumable table.

A *trial* is a dict of plain parameters (scenario, seed, method, ...); the trial function takes them as
keyword arguments and returns a dict of results (numbers, strings, booleans, or lists, which are stored
as JSON). :func:`run_trials` runs every trial not already in the results table on any
:class:`concurrent.futures.Executor` (inline, a local process pool, or a Dask cluster through
:func:`dask_executor`), shows a progress bar, and rewrites the table atomically after each finished
trial, so an interrupted run loses at most the trials in flight and a re-run does only what is left.

The table is a CSV file with a sidecar ``<name>.schema.json`` holding the column types; read it back
typed with :func:`read_table`. Rows are in the order of the trial list, whatever order the workers
finish in, so the same trials give the same file with 1 worker, 2 workers or a Dask cluster.

Trial functions must be importable top-level functions (they are pickled to the workers) and must
draw randomness only from the seeds in their parameters.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import csv
import json
import math
import multiprocessing
import os
import tempfile
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

from pmht_opt.exceptions import ConfigError, MissingDependencyError, PmhtOptError
from pmht_opt.progress import ProgressBar

Row = dict[str, Any]
TrialFn = Callable[..., Mapping[str, Any]]

#: Column types a table can hold.
TYPES = ("int", "float", "bool", "str", "json")


def _file_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


_FILE_MODE = _file_mode()


def trial_id(params: Mapping[str, Any]) -> str:
    """A stable identifier of a trial: its parameters as canonical JSON."""
    try:
        return json.dumps(dict(params), sort_keys=True, separators=(",", ":"))
    except TypeError as err:
        raise ConfigError(f"trial parameters must be plain JSON values: {err}.") from None


def _type_of(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "str"
    if hasattr(value, "item") and getattr(value, "ndim", None) == 0:  # numpy scalars
        return _type_of(value.item())
    return "json"


def _encode(value: Any, kind: str) -> str:
    if value is None:
        return ""
    if kind == "json":
        return json.dumps(value.tolist() if hasattr(value, "tolist") else value, separators=(",", ":"))
    if hasattr(value, "item"):
        value = value.item()
    if kind == "float":
        return repr(float(value))
    return str(value)


def _decode(text: str, kind: str) -> Any:
    if kind == "str":
        return text
    if text == "":
        return None
    if kind == "int":
        return int(text)
    if kind == "float":
        return float(text)
    if kind == "bool":
        return text == "True"
    if kind == "json":
        return json.loads(text)
    return text


def _merge_kind(old: str | None, new: str) -> str:
    if old is None or old == new:
        return new
    if {old, new} == {"int", "float"}:
        return "float"
    return "json" if "json" in (old, new) else "str"


def schema_path(path: Path) -> Path:
    """The sidecar file that holds a table's column types."""
    return path.with_name(path.stem + ".schema.json")


def read_table(path: str | Path) -> list[Row]:
    """Rows of a results table written by :func:`run_trials`, with their types restored.

    Raises
    ------
    ConfigError
        The file or its schema is missing or malformed.
    """
    path = Path(path)
    try:
        schema = json.loads(schema_path(path).read_text())
        with path.open(newline="") as fh:
            reader = csv.DictReader(fh)
            rows = list(reader)
    except FileNotFoundError as err:
        raise ConfigError(f"results table: {err.filename} does not exist.") from None
    except (json.JSONDecodeError, csv.Error, UnicodeDecodeError) as err:
        raise ConfigError(f"results table {path}: malformed ({err}).") from None
    if not isinstance(schema, dict) or any(v not in TYPES for v in schema.values()):
        raise ConfigError(f"results table {path}: malformed schema {schema_path(path)}.")
    try:
        return [{k: _decode(v or "", schema.get(k, "str")) for k, v in row.items()} for row in rows]
    except (ValueError, json.JSONDecodeError) as err:
        raise ConfigError(f"results table {path}: a value does not match its column type ({err}).") from None


def write_table(path: str | Path, rows: Sequence[Mapping[str, Any]]) -> Path:
    """Write ``rows`` as a typed CSV table (atomically: a reader never sees half a file)."""
    path = Path(path)
    kinds: dict[str, str | None] = {}
    for row in rows:
        for key, value in row.items():
            old = kinds.get(key)
            kinds[key] = old if value is None else _merge_kind(old, _type_of(value))
    schema = {key: kind or "str" for key, kind in kinds.items()}  # all-empty columns hold strings
    columns = list(schema)
    path.parent.mkdir(parents=True, exist_ok=True)

    def dump(target: Path, write: Callable[[TextIO], object]) -> None:
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=target.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "w", newline="") as fh:
                write(fh)
            os.chmod(tmp, _FILE_MODE)  # mkstemp makes it private; a results table is not
            os.replace(tmp, target)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise

    def write_csv(fh: TextIO) -> None:
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_encode(row.get(c), schema[c]) for c in columns])

    dump(schema_path(path), lambda fh: fh.write(json.dumps(schema, indent=1) + "\n"))
    dump(path, write_csv)
    return path


def _call(fn: TrialFn, params: dict[str, Any]) -> Row:
    """Run one trial in a worker; failures of the project's own kind become an ``error`` column."""
    try:
        out = dict(fn(**params))
        out.setdefault("error", "")
    except PmhtOptError as err:
        out = {"error": f"{type(err).__name__}: {err}"}
    except Exception as err:  # keep the run alive; the row says what happened
        last = traceback.extract_tb(err.__traceback__)[-1]
        out = {"error": f"{type(err).__name__}: {err} ({Path(last.filename).name}:{last.lineno})"}
    return out


class InlineExecutor(cf.Executor):
    """Runs each task when it is submitted, in this process (one worker, no pickling)."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future[Any]:
        fut: cf.Future[Any] = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as err:
            fut.set_exception(err)
            if not isinstance(err, Exception):
                raise
        return fut


def local_executor(workers: int) -> cf.Executor:
    """An inline executor for 1 worker, else a pool of ``workers`` fresh processes (spawned)."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers: expected a positive integer, got {workers!r}.")
    if workers == 1:
        return InlineExecutor()
    # Spawned, not forked: the parent may hold solver threads, and OR-Tools and HiGHS cannot share
    # a process (see pmht_opt.ordering.ortools_).
    return cf.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))


@contextlib.contextmanager
def dask_executor(address: str | None = None, **cluster: Any) -> Iterator[cf.Executor]:
    """An executor on a Dask cluster: the scheduler at ``address``, or a new ``LocalCluster(**cluster)``.

    Needs the ``dask`` extra (``pip install "pmht-opt[dask]"``).
    """
    try:
        from distributed import Client, LocalCluster
    except ModuleNotFoundError:
        raise MissingDependencyError(
            "Dask execution needs dask.distributed; install the extra: pip install 'pmht-opt[dask]'."
        ) from None
    local = None
    try:
        if address is None:
            local = LocalCluster(**cluster)
            client = Client(local)
        else:
            client = Client(address, timeout="20s")
    except OSError as err:
        raise ConfigError(f"dask scheduler {address!r}: cannot connect ({err}).") from None
    try:
        yield client.get_executor()
    finally:
        client.close()
        if local is not None:
            local.close()


def run_trials(
    fn: TrialFn,
    trials: Sequence[Mapping[str, Any]],
    out: str | Path | None = None,
    *,
    executor: cf.Executor | None = None,
    workers: int = 1,
    progress: bool = True,
    label: str = "trials",
    resume: bool = True,
) -> list[Row]:
    """Run ``fn(**trial)`` for every trial; return one row per trial (parameters, then results).

    Parameters
    ----------
    fn
        Top-level function returning a mapping of results.
    trials
        Parameters of each trial; two trials with the same parameters are one trial.
    out
        Results table (CSV). With ``resume``, trials already in it are not run again; it is rewritten
        after every finished trial.
    executor
        Where to run the trials; default :func:`local_executor` with ``workers``. Not shut down here
        unless created here.
    progress
        Show a progress bar on stderr.
    resume
        Keep and reuse the rows already in ``out``; ``False`` starts the table afresh.

    Returns
    -------
    list of dict
        Rows in the order of ``trials``. A trial that raised has an ``error`` column saying why
        (empty when it succeeded).
    """
    params = [dict(t) for t in trials]
    ids = [trial_id(p) for p in params]
    unique = list(dict.fromkeys(ids))
    by_id = dict(zip(ids, params, strict=True))
    path = Path(out) if out is not None else None
    done: dict[str, Row] = {}
    if path is not None and resume and path.exists():
        for row in read_table(path):
            if "trial" in row:
                done[row["trial"]] = row
    todo = [i for i in unique if i not in done]
    rows: dict[str, Row] = {i: done[i] for i in unique if i in done}
    # Rows of trials not asked for this time stay in the table.
    extra = [row for key, row in done.items() if key not in by_id]

    def save() -> None:
        if path is not None:
            write_table(path, [rows[i] for i in unique if i in rows] + extra)

    bar = ProgressBar(len(unique), label=label) if progress else None
    if bar is not None and len(unique) - len(todo):
        bar.update(len(unique) - len(todo), suffix="(resumed)")
    own = executor is None
    ex = local_executor(workers) if executor is None else executor

    def finished() -> Iterator[tuple[str, Row]]:
        if isinstance(ex, InlineExecutor):  # one at a time, saved as each finishes
            for key in todo:
                yield key, _call(fn, by_id[key])
            return
        futures = {ex.submit(_call, fn, by_id[key]): key for key in todo}
        try:
            for fut in cf.as_completed(futures):
                yield futures[fut], fut.result()
        finally:
            for fut in futures:
                fut.cancel()

    try:
        for key, result in finished():
            rows[key] = {"trial": key, **by_id[key], **result}
            save()
            if bar is not None:
                failed = sum(1 for r in rows.values() if r.get("error"))
                bar.update(1, suffix=f"{failed} failed" if failed else "")
    finally:
        if bar is not None:
            bar.close()
        if own:
            ex.shutdown(wait=True, cancel_futures=True)
    save()
    return [rows[i] for i in ids]


def summarise(values: Sequence[float]) -> dict[str, float]:
    """Mean, median, max and count of the finite values (NaN when there are none)."""
    finite = sorted(v for v in values if v is not None and math.isfinite(v))
    if not finite:
        return {"mean": math.nan, "median": math.nan, "max": math.nan, "n": 0}
    n = len(finite)
    mid = n // 2
    median = finite[mid] if n % 2 else 0.5 * (finite[mid - 1] + finite[mid])
    return {"mean": sum(finite) / n, "median": median, "max": finite[-1], "n": n}
