"""What the studies share when they report: rows as a pandas frame, one median, one writer of files.

Every file a study writes goes through :func:`write_text`, which creates missing folders and returns the
path actually written, so the command can print exactly what it wrote.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from studies.provenance import provenance

#: A run "leaves the area" when a path goes more than this far outside the 10 x 10 box (scenario B's
#: starts are exactly 1 outside, which does not count).
EXCURSION_LIMIT = 1.0


def frame(rows: Iterable[Mapping[str, Any]]) -> pd.DataFrame:
    """Rows as a DataFrame; a missing ``error`` column (summaries built by hand) means no error."""
    df = pd.DataFrame([dict(r) for r in rows])
    if "error" not in df:
        df["error"] = ""
    df["error"] = df["error"].fillna("").astype(str)
    return df


def finite(values: Iterable[Any]) -> list[float]:
    """The finite numbers among ``values`` (``None``, NaN, infinities and non-numbers left out)."""
    return [
        float(v)
        for v in values
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    ]


def median(values: Iterable[Any]) -> float:
    """Median of the finite numbers among ``values``; NaN when there are none."""
    vals = sorted(finite(values))
    n = len(vals)
    if not n:
        return math.nan
    mid = n // 2
    return vals[mid] if n % 2 else 0.5 * (vals[mid - 1] + vals[mid])


def summarise(values: Iterable[Any]) -> dict[str, float]:
    """Mean, median, max and count of the finite values (NaN when there are none)."""
    vals = finite(values)
    if not vals:
        return {"mean": math.nan, "median": math.nan, "max": math.nan, "n": 0}
    return {"mean": sum(vals) / len(vals), "median": median(vals), "max": max(vals), "n": len(vals)}


#: A markdown table's columns: each column's heading, and how a row (a summary's dict) shows in it.
Columns = Sequence[tuple[str, Callable[[Mapping[str, Any]], object]]]


def markdown_table(columns: Columns, rows: Iterable[Mapping[str, Any]]) -> str:
    """``rows`` as a markdown table of ``columns``: the headings, their rule, then one line per row (each
    cell as ``str`` shows it)."""
    lines = ["| " + " | ".join(h for h, _ in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(cell(r)) for _, cell in columns) + " |" for r in rows]
    return "\n".join(lines)


def nan_note(flagged: Sequence[tuple[str, str]]) -> str:
    """The paragraph under a study's table that lists its NaN results, ``(trial, column)`` each."""
    lines = [
        f"**NaN results** ({len(flagged)}; left out of the means and medians above, kept in the "
        "results file):",
        "",
    ]
    lines += [f"- trial `{trial}`: column `{column}`" for trial, column in flagged]
    return "\n".join(lines)


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path``, creating missing folders; return the path written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def json_default(x: Any) -> Any:
    """JSON for numpy values (and the text of anything else)."""
    if hasattr(x, "tolist"):
        return x.tolist()
    return str(x)


def write_json(
    path: Path, payload: Mapping[str, Any] | Sequence[Any], *, with_provenance: bool = True
) -> Path:
    """Write ``payload`` as indented JSON; a mapping gets this run's ``provenance`` unless it has one."""
    body: Any = payload
    if with_provenance and isinstance(payload, Mapping) and "provenance" not in payload:
        body = {**payload, "provenance": provenance()}
    return write_text(path, json.dumps(body, indent=1, default=json_default) + "\n")


def write_summary(
    out_dir: Path,
    name: str,
    table: Sequence[Any],
    text: str,
    header: str = "",
    extra: Mapping[str, Any] | None = None,
) -> list[Path]:
    """Write ``<name>_summary.json`` (the aggregates, with provenance and ``extra``) and ``<name>.md``
    (the table)."""
    return [
        write_json(out_dir / f"{name}_summary.json", {"summary": list(table), **(extra or {})}),
        write_text(out_dir / f"{name}.md", header + text + "\n"),
    ]
