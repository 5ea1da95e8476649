"""Results of trials as an append-only JSON Lines file: typed, keyed by trial, safe against half-writes.

One file holds one study table. Its lines are JSON objects of three kinds, told apart by ``record``:

``header`` (the first line)
    The format, the study's name and its :class:`Schema` (column -> type), so the file describes itself.
``run`` (one per run that appended to the file)
    The run's number and its provenance (:func:`studies.provenance.provenance`): commit, package
    versions, machine, load, date. A results file is never without it.
``row`` (one per finished trial)
    ``trial`` (the trial's id: its parameters as canonical JSON), ``run`` (the run that wrote it),
    ``error_class`` and ``error`` (empty for a trial that succeeded), then the study's columns, flat.

A row is appended, flushed and handed to the operating system as soon as its trial finishes, so the cost
of recording a trial does not grow with the number already recorded, and a crash of this process loses
nothing already written. ``fsync`` runs at the header and then at most about once a second and at close,
which bounds what a crash of the machine can lose without paying a disk flush per trial.

On load every line is checked: a truncated line, NUL bytes (what a file system leaves after a power cut),
a column missing, unknown, mistyped or empty where the schema requires a value, or a trial id that does
not match the row's own parameters. Each damaged line is reported as a :class:`DamagedRowWarning` naming
the line, the trial (where it can be told) and the field; it is dropped, so its trial runs again, and
every valid row is kept. A damaged or lost header is damage like any other (a correct one is written
again), provided the file is evidently this project's: a file with nothing of this project in it is
refused by name and never overwritten, not even to start afresh. Nothing ever needs starting afresh to
recover.

A NaN in a result column is kept but flagged as a :class:`NaNResultWarning` naming the trial and the
column, when it is written and whenever it is read, unless the schema declares that column's NaN to mean
"not measured" (:attr:`Schema.not_measured`): summaries leave NaN out of their means and medians, so it
must not pass unseen.
"""

from __future__ import annotations

import json
import os
import re
import time
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from pmht_opt.exceptions import ConfigError

# What a row must hold is the schema's business; it is named here too, with the files it describes.
from studies.schema import RESERVED as RESERVED
from studies.schema import Row as Row
from studies.schema import Schema as Schema
from studies.schema import trial_id as trial_id

#: Format name and version written in every header.
FORMAT = "pmht-opt-trials"
VERSION = 1
#: Seconds between two ``fsync`` calls while rows are being appended.
FSYNC_INTERVAL = 1.0


class StudyWarning(UserWarning):
    """A problem with stored or returned results that the run survives (the study command shows it as
    one line of its own on stderr)."""


class DamagedRowWarning(StudyWarning):
    """A line of a results file that is not a complete, valid row (its trial is run again), or a
    damaged header (a correct one is written)."""


class NaNResultWarning(StudyWarning):
    """A result column holding NaN where the schema does not say that NaN means "not measured"; the
    row is kept, and the study's table lists it."""


def _dumps(record: Mapping[str, Any]) -> bytes:
    # NaN is kept (as JSON's common extension): studies record NaN for "not measured".
    return (json.dumps(record, separators=(",", ":"), allow_nan=True) + "\n").encode()


_TRIAL_IN_TEXT = re.compile(r'"trial":\s*"((?:[^"\\]|\\.)*)"')


def _trial_of(text: str) -> str | None:
    """The trial id of a damaged line, when enough of it survived to tell."""
    match = _TRIAL_IN_TEXT.search(text.replace("\x00", ""))
    if match is None:
        return None
    try:
        found: str = json.loads(f'"{match.group(1)}"')
        return found
    except ValueError:
        return None


@dataclass
class Loaded:
    """What :func:`load` found in a results file; ``nan`` lists the ``(trial, column)`` of NaN results
    the schema does not expect (:meth:`Schema.nan_columns`)."""

    rows: dict[str, Row]
    runs: list[dict[str, Any]]
    damaged: list[str]
    clean: bool
    nan: list[tuple[str, str]] = field(default_factory=list)


@dataclass
class _Line:
    """One line of a results file: its number, its text, and the JSON object it holds (``None`` with
    ``problem`` saying why when it holds none)."""

    number: int
    text: str
    record: dict[str, Any] | None
    problem: str = ""


def _parse(raw: bytes) -> list[_Line]:
    lines = raw.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    out = []
    for number, line in enumerate(lines, start=1):
        text = line.decode("utf-8", errors="replace")
        if "\x00" in text:
            out.append(_Line(number, text, None, "NUL bytes"))
        elif not text.strip():
            out.append(_Line(number, text, None, "empty line"))
        else:
            try:
                record = json.loads(text)
            except ValueError:
                out.append(_Line(number, text, None, "truncated or not JSON"))
                continue
            if isinstance(record, dict):
                out.append(_Line(number, text, record))
            else:
                out.append(_Line(number, text, None, "not a JSON object"))
    return out


def load(path: Path, schema: Schema, study: str) -> Loaded:
    """The valid rows of a results file (the last row of each trial wins), its runs and its damage.

    Every damaged line is reported as a :class:`DamagedRowWarning` and left out; so is a damaged or
    missing header, as long as the file is evidently a results file of this project (:func:`_header`),
    and every NaN result the schema does not expect as a :class:`NaNResultWarning` (the row is kept).
    ``clean`` is false when the file should be rewritten before appending (damage, superseded rows, a
    header to write again, or no final newline).

    Raises
    ------
    ConfigError
        Naming the file: it holds another study's results, or it is not a results file of this project
        (nothing in it is: a foreign file is never taken for a damaged one, so it is never overwritten).
    """
    rows: dict[str, Row] = {}
    runs: list[dict[str, Any]] = []
    damaged: list[str] = []
    nan: list[tuple[str, str]] = []
    raw = path.read_bytes()
    lines = _parse(raw)
    ends_cleanly = raw.endswith(b"\n") or not raw
    superseded = False

    def report(number: int, trial: str | None, where: str, problem: str) -> None:
        who = f"trial {trial}" if trial else "trial unknown"
        message = f"{path}:{number}: {who}: {where}: {problem}; the row is dropped and its trial runs again."
        damaged.append(message)
        warnings.warn(message, DamagedRowWarning, stacklevel=3)

    header_problem, stale_header = _header(path, raw, lines, schema, study)
    if header_problem:
        message = f"{path}:1: header: {header_problem}; a correct header is written and every valid row kept."
        damaged.append(message)
        warnings.warn(message, DamagedRowWarning, stacklevel=2)
    for line in lines:
        record = line.record
        kind = record.get("record") if record is not None else None
        if line.number == 1 and kind not in ("run", "row"):
            continue  # the header, or what is left of it (reported above)
        if record is None:
            report(line.number, _trial_of(line.text), "line", line.problem)
            continue
        if kind == "run":
            runs.append(record)
            continue
        if kind != "row":
            report(line.number, _trial_of(line.text), "record", f"unknown record {kind!r}")
            continue
        problem = schema.row_problem(record)
        if problem is not None:
            trial = record.get("trial") if isinstance(record.get("trial"), str) else None
            report(line.number, trial, *problem)
            continue
        for column in schema.nan_columns(record):
            nan.append((record["trial"], column))
            warnings.warn(
                f"{path}:{line.number}: trial {record['trial']}: column {column}: NaN result "
                "(kept, and listed in the study's table).",
                NaNResultWarning,
                stacklevel=2,
            )
        superseded |= record["trial"] in rows
        rows[record["trial"]] = record
    clean = not (damaged or superseded or stale_header) and ends_cleanly
    return Loaded(rows, runs, damaged, clean=clean, nan=nan)


def _header(path: Path, raw: bytes, lines: list[_Line], schema: Schema, study: str) -> tuple[str, bool]:
    """What is wrong with the header on line 1 (``""`` when nothing is) and whether it declares another
    schema than ``schema`` (then the file is written again with the current one).

    A damaged or missing header is recoverable when the file is evidently this project's results file
    (:func:`_ours`): the rows and runs are read as usual and a correct header is written. A header of
    another study, or a file with nothing of this project in it, raises :class:`ConfigError`.
    """
    first = lines[0].record if lines else None
    if first is not None and first.get("record") == "header":
        if first.get("format") not in (FORMAT, None):
            raise ConfigError(
                f"{path}: not a results file of this project (format {first.get('format')!r}); "
                "it is left as it is: move it away or choose another --out."
            )
        found = first.get("study")
        if isinstance(found, str) and found != study:
            raise ConfigError(f"{path}: holds study {found!r}, not {study!r}.")
        if first.get("format") == FORMAT and found == study:
            return "", first.get("schema") != schema.to_json()
        problem = "incomplete (no format or study)"
    elif first is not None and first.get("record") in ("run", "row"):
        problem = "missing (line 1 is a record of the table)"
    elif not lines:
        problem = "missing (the file is empty)"
    else:
        problem = lines[0].problem or "not a header"
    if not _ours(raw, lines, schema):
        raise ConfigError(
            f"{path}: not a results file of this project (line 1: {problem}, and no line is a run or a "
            "row of this table); it is left as it is: move it away or choose another --out."
        )
    return problem, True


def _ours(raw: bytes, lines: list[_Line], schema: Schema) -> bool:
    """Whether a file whose header is damaged is this project's results file: it names the format,
    holds a run record or a valid row, or holds nothing but NUL bytes and blank space (what a power cut
    leaves; rewriting it loses nothing)."""
    if FORMAT.encode() in raw.replace(b"\x00", b"") or not raw.replace(b"\x00", b"").strip():
        return True
    for line in lines:
        record = line.record
        if record is None:
            continue
        if record.get("record") == "run" and isinstance(record.get("provenance"), dict):
            return True
        if record.get("record") == "row" and schema.row_problem(record) is None:
            return True
    return False


class ResultsFile:
    """An open results file that rows are appended to; use as a context manager.

    Opening reads what is there (see :func:`load`), rewrites it once if it was damaged (valid rows only,
    atomically), and appends a ``run`` record with this run's provenance.
    """

    def __init__(
        self,
        path: Path,
        schema: Schema,
        study: str,
        provenance: Mapping[str, Any],
        *,
        resume: bool = True,
    ) -> None:
        self.path = Path(path)
        self.schema = schema
        self.study = study
        self.rows: dict[str, Row] = {}
        self.damaged: list[str] = []
        runs: list[dict[str, Any]] = []
        clean = True
        if resume and self.path.exists():
            loaded = load(self.path, schema, study)
            self.rows, runs, self.damaged, clean = loaded.rows, loaded.runs, loaded.damaged, loaded.clean
        elif self.path.exists():
            # Starting afresh discards this table's rows, never a file that is not this table's.
            raw = self.path.read_bytes()
            _header(self.path, raw, _parse(raw), schema, study)
        numbers = [r["run"] for r in runs if isinstance(r.get("run"), int) and not isinstance(r["run"], bool)]
        self.run = 1 + max(numbers, default=0)
        if not resume or not self.path.exists() or not clean:
            self._rewrite(runs)
        self._fh: IO[bytes] = open(self.path, "ab")  # closed in close()
        self._write({"record": "run", "run": self.run, "provenance": dict(provenance)})
        self._sync()

    def _rewrite(self, runs: Iterable[Mapping[str, Any]]) -> None:
        """Write header, runs and the valid rows to a new file and put it in place atomically."""
        tmp = self.path.with_name(self.path.name + ".tmp")
        header = {"record": "header", "format": FORMAT, "version": VERSION, "study": self.study}
        header["schema"] = self.schema.to_json()
        with open(tmp, "wb") as fh:
            fh.write(_dumps(header))
            for run in runs:
                fh.write(_dumps(run))
            for row in self.rows.values():
                fh.write(_dumps(row))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.path)
        self._last_sync = time.monotonic()

    def _write(self, record: Mapping[str, Any]) -> None:
        self._fh.write(_dumps(record))
        self._fh.flush()

    def _sync(self) -> None:
        os.fsync(self._fh.fileno())
        self._last_sync = time.monotonic()

    def append(
        self,
        params: Mapping[str, Any],
        values: Mapping[str, Any] | None = None,
        *,
        error_class: str = "",
        error: str = "",
    ) -> Row:
        """Record one finished trial: its results, or the class and message of what it raised."""
        row: Row = {"record": "row", "run": self.run, "trial": trial_id(params)}
        if error_class:
            row.update(error_class=error_class, error=_message(error or error_class), **params)
        else:
            row.update(error_class="", error="", **params, **self.schema.normalise(values or {}))
            for column in self.schema.nan_columns(row):
                warnings.warn(
                    f"{self.path}: trial {row['trial']}: column {column}: the trial returned NaN "
                    "(kept, and listed in the study's table).",
                    NaNResultWarning,
                    stacklevel=2,
                )
        self._write(row)
        if time.monotonic() - self._last_sync >= FSYNC_INTERVAL:
            self._sync()
        self.rows[row["trial"]] = row
        return row

    def close(self) -> None:
        """Flush, ``fsync`` and close."""
        if not self._fh.closed:
            self._fh.flush()
            self._sync()
            self._fh.close()

    def __enter__(self) -> ResultsFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _message(text: str) -> str:
    return text if len(text) <= 2000 else text[:1997] + "..."


def read_rows(path: str | Path, schema: Schema, study: str) -> list[Row]:
    """The valid rows of a results file, in file order (damaged lines are warned about and skipped)."""
    return list(load(Path(path), schema, study).rows.values())
