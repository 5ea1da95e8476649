"""What is done with a study's stored rows: run some again to verify them, or read them for tables.

:func:`verify` (``--verify K``) runs K stored trials again and compares every column with its row, under
the table's declared :class:`~studies.trials.Check` for each column. :func:`stored_rows`
(``--tables-only``) reads the rows of a study's trials without running any, so that its summaries and
figures can be written again from what the results file holds.
"""

from __future__ import annotations

import concurrent.futures as cf
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pmht_opt.exceptions import ConfigError
from studies.executors import InlineExecutor
from studies.store import Row, load, trial_id
from studies.trials import CRASHED, Check, TrialError, TrialTable, call_trial, public_row


def stored_rows(table: TrialTable, trials: Sequence[Mapping[str, Any]], out_dir: str | Path) -> list[Row]:
    """The stored rows of ``trials``, in their order, without running any trial or writing anything.

    For rewriting a study's summaries and figures from what its results file holds (``--tables-only``):
    trials with no valid row are left out, and their number is said on stderr (also under ``--quiet``:
    a summary of part of the trials must not pass for the whole). :class:`ConfigError` when there is
    no results file.
    """
    path = table.path(Path(out_dir))
    if not path.exists():
        raise ConfigError(f"--tables-only: no results file {path}; run the study first.")
    stored = load(path, table.schema, table.name).rows
    ids = list(dict.fromkeys(trial_id(dict(t)) for t in trials))
    rows = [public_row(stored[k]) for k in ids if k in stored]
    if len(rows) < len(ids):
        print(
            f"--tables-only: {len(ids) - len(rows)} of {len(ids)} trials have no row in {path}; "
            "they are left out.",
            file=sys.stderr,
        )
    return rows


def run_provenance(table: TrialTable, out_dir: str | Path) -> list[dict[str, Any]]:
    """The provenance of every run recorded in the results file of ``table``, oldest first: what a
    summary written with ``--tables-only`` was measured by."""
    path = table.path(Path(out_dir))
    return [run.get("provenance", {}) for run in load(path, table.schema, table.name).runs]


@dataclass(frozen=True)
class Mismatch:
    """A recomputed trial that disagrees with its stored row."""

    trial: str
    column: str
    stored: Any
    fresh: Any

    def __str__(self) -> str:
        return (
            f"trial {self.trial}: column {self.column!r}: stored {self.stored!r}, recomputed {self.fresh!r}"
        )


def pick_evenly(n: int, k: int) -> list[int]:
    """``k`` indices spread evenly over ``range(n)`` (first and last included when ``k >= 2``)."""
    k = min(k, n)
    if k <= 0:
        return []
    if k == 1:
        return [n // 2]
    return sorted({round(i * (n - 1) / (k - 1)) for i in range(k)})


def verify(
    table: TrialTable, out_dir: str | Path, k: int, *, executor: cf.Executor | None = None
) -> tuple[list[Row], list[Mismatch]]:
    """Run ``k`` stored trials again (evenly spaced in trial-id order) and compare them with their rows.

    Every result column is compared under its :class:`Check` (identity unless the table says otherwise,
    with its reason); so is the error class of a trial that failed.

    Returns
    -------
    (rows, mismatches)
        The rows that were checked and every disagreement found.
    """
    path = table.path(Path(out_dir))
    if not path.exists():
        raise ConfigError(f"--verify: no results file {path}.")
    rows = sorted(load(path, table.schema, table.name).rows.values(), key=lambda r: r["trial"])
    if not rows:
        raise ConfigError(f"--verify: {path} holds no valid row.")
    chosen = [rows[i] for i in pick_evenly(len(rows), k)]
    ex = executor or InlineExecutor()
    futures = [ex.submit(call_trial, table.fn, {n: r[n] for n in table.schema.params}) for r in chosen]
    mismatches: list[Mismatch] = []
    for row, fut in zip(chosen, futures, strict=True):
        try:
            out = fut.result()
        except Exception as err:  # the worker died: the trial has no result to compare
            out = TrialError(CRASHED, f"{type(err).__name__}: {err}")
        if isinstance(out, TrialError) or row["error_class"]:
            fresh_class = out.error_class if isinstance(out, TrialError) else ""
            if fresh_class != row["error_class"]:
                mismatches.append(Mismatch(row["trial"], "error_class", row["error_class"], fresh_class))
            continue
        fresh = table.schema.normalise(out)
        for name in table.schema.values:
            check = table.checks.get(name, Check())
            if not check.agrees(row.get(name), fresh.get(name)):
                mismatches.append(Mismatch(row["trial"], name, row.get(name), fresh.get(name)))
    return chosen, mismatches
