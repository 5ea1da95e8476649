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
every valid row is kept. Nothing ever needs starting afresh to recover.
"""

from __future__ import annotations

import json
import os
import re
import time
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
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


class DamagedRowWarning(UserWarning):
    """A line of a results file that is not a complete, valid row; its trial is run again."""


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
    """What :func:`load` found in a results file."""

    rows: dict[str, Row]
    runs: list[dict[str, Any]]
    damaged: list[str]
    clean: bool


def load(path: Path, schema: Schema, study: str) -> Loaded:
    """The valid rows of a results file (the last row of each trial wins), its runs and its damage.

    Every damaged line is reported as a :class:`DamagedRowWarning` and left out. ``clean`` is false when
    the file should be rewritten before appending (damage, superseded rows, or no final newline).
    """
    rows: dict[str, Row] = {}
    runs: list[dict[str, Any]] = []
    damaged: list[str] = []
    raw = path.read_bytes()
    lines = raw.split(b"\n")
    ends_cleanly = raw.endswith(b"\n") or not raw
    if lines and lines[-1] == b"":
        lines.pop()
    superseded = False
    stale_header = True

    def report(number: int, trial: str | None, where: str, problem: str) -> None:
        who = f"trial {trial}" if trial else "trial unknown"
        message = f"{path}:{number}: {who}: {where}: {problem}; the row is dropped and its trial runs again."
        damaged.append(message)
        warnings.warn(message, DamagedRowWarning, stacklevel=3)

    for number, line in enumerate(lines, start=1):
        text = line.decode("utf-8", errors="replace")
        if "\x00" in text:
            report(number, _trial_of(text), "line", "NUL bytes")
            continue
        if not text.strip():
            report(number, None, "line", "empty line")
            continue
        try:
            record = json.loads(text)
        except ValueError:
            report(number, _trial_of(text), "line", "truncated or not JSON")
            continue
        if not isinstance(record, dict):
            report(number, None, "line", "not a JSON object")
            continue
        kind = record.get("record")
        if number == 1:
            _check_header(path, record, study)
            stale_header = record.get("schema") != schema.to_json()
            continue
        if kind == "run":
            runs.append(record)
            continue
        if kind != "row":
            report(number, _trial_of(text), "record", f"unknown record {kind!r}")
            continue
        problem = schema.row_problem(record)
        if problem is not None:
            trial = record.get("trial") if isinstance(record.get("trial"), str) else None
            report(number, trial, *problem)
            continue
        superseded |= record["trial"] in rows
        rows[record["trial"]] = record
    return Loaded(rows, runs, damaged, clean=not (damaged or superseded or stale_header) and ends_cleanly)


def _check_header(path: Path, record: Mapping[str, Any], study: str) -> None:
    if record.get("record") != "header" or record.get("format") != FORMAT:
        raise ConfigError(f"{path}: not a results file of this project (no header on line 1).")
    if record.get("study") != study:
        raise ConfigError(f"{path}: holds study {record.get('study')!r}, not {study!r}.")


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
        self.run = 1 + max((int(r.get("run", 0)) for r in runs), default=0)
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
