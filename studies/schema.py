"""The columns of a study's table: their types, the checks of a row against them, and a trial's id.

A :class:`Schema` is what a results file (:mod:`studies.store`) declares in its header and what every row
is checked against, when it is written and when it is read back: a row that does not fit is damage,
never a result.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pmht_opt.exceptions import ConfigError

#: Columns every row has besides the study's own; a study may not use these names.
RESERVED = ("record", "run", "trial", "error_class", "error")
#: Column types: the JSON value each holds. ``float`` also takes integers (stored as floats) and NaN.
TYPES = ("int", "float", "bool", "str", "list", "dict", "json")

Row = dict[str, Any]


@dataclass(frozen=True)
class Column:
    """A column's type and whether it may be absent or null.

    A required ``str`` column must also be non-empty: an empty value is what a half-written row leaves.
    """

    type: str
    optional: bool = False

    def __post_init__(self) -> None:
        if self.type not in TYPES:
            raise ConfigError(f"column type: expected one of {', '.join(TYPES)}, got {self.type!r}.")

    @classmethod
    def parse(cls, spec: str) -> Column:
        """``"float"`` (required) or ``"float?"`` (optional) as a :class:`Column`."""
        return cls(spec.removesuffix("?"), spec.endswith("?"))

    def spec(self) -> str:
        """The inverse of :meth:`parse`."""
        return self.type + ("?" if self.optional else "")

    def problem(self, value: Any) -> str | None:
        """What is wrong with ``value`` for this column, or ``None`` when it fits."""
        if value is None:
            return None if self.optional else "missing value"
        if self.type == "json":
            return None
        expected: dict[str, type | tuple[type, ...]] = {
            "int": int,
            "float": (int, float),
            "bool": bool,
            "str": str,
            "list": list,
            "dict": dict,
        }
        if isinstance(value, bool) and self.type != "bool":
            return f"expected {self.type}, got a boolean"
        if not isinstance(value, expected[self.type]):
            return f"expected {self.type}, got {type(value).__name__}"
        if self.type == "str" and value == "" and not self.optional:
            return "empty value"
        return None


@dataclass(frozen=True)
class Schema:
    """The columns of a study's table: trial parameters and trial results, each name -> type spec.

    Parameters
    ----------
    params
        The parameters of a trial (all required): they make its id.
    values
        What the trial function returns, e.g. ``{"distance": "float", "paths": "list?"}``.
    not_measured
        Result columns in which NaN is a value the study writes on purpose, meaning "not measured",
        with the reason (a backend that failed has no time). A NaN anywhere else is flagged when it is
        written and read (:meth:`nan_columns`): a mean or median leaves it out, so it must not pass
        unseen. The reading policy of the study, not part of the file's header.
    """

    params: Mapping[str, str]
    values: Mapping[str, str]
    not_measured: Mapping[str, str] = field(default_factory=dict)
    columns: dict[str, Column] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        cols: dict[str, Column] = {}
        for group, specs in (("params", self.params), ("values", self.values)):
            for name, spec in specs.items():
                if name in RESERVED or name in cols:
                    raise ConfigError(f"schema {group}: column {name!r} is reserved or declared twice.")
                col = Column.parse(spec)
                if group == "params" and col.optional:
                    raise ConfigError(f"schema params: {name!r} must be required (it is part of the id).")
                cols[name] = col
        object.__setattr__(self, "columns", cols)
        for name, reason in self.not_measured.items():
            if name not in self.values or cols[name].type != "float" or not reason:
                raise ConfigError(f"schema not_measured: {name!r} must be a float result, with a reason.")

    def nan_columns(self, values: Mapping[str, Any]) -> list[str]:
        """The result columns of ``values`` that hold NaN where NaN does not mean "not measured"."""
        return [
            name
            for name, value in values.items()
            if name in self.values
            and name not in self.not_measured
            and isinstance(value, float)
            and math.isnan(value)
        ]

    def to_json(self) -> dict[str, dict[str, str]]:
        """The schema as stored in a file's header."""
        return {"params": dict(self.params), "values": dict(self.values)}

    def check_params(self, params: Mapping[str, Any]) -> None:
        """Raise :class:`ConfigError` naming the parameter when ``params`` does not fit the schema."""
        if set(params) != set(self.params):
            raise ConfigError(
                f"trial parameters {sorted(params)} do not match the schema's {sorted(self.params)}."
            )
        for name, value in params.items():
            problem = self.columns[name].problem(value)
            if problem is not None:
                raise ConfigError(f"trial parameter {name!r}: {problem} ({value!r}).")

    def row_problem(self, row: Mapping[str, Any]) -> tuple[str, str] | None:
        """``(field, problem)`` of the first thing wrong with a stored row, or ``None`` when valid."""
        for name in ("trial", "run"):
            if name not in row:
                return name, "missing column"
        if not isinstance(row["trial"], str) or not row["trial"]:
            return "trial", "expected a non-empty id"
        if isinstance(row["run"], bool) or not isinstance(row["run"], int):
            return "run", "expected int"
        for name in ("error_class", "error"):
            if not isinstance(row.get(name), str):
                return name, "missing column" if name not in row else "expected str"
        failed = row["error_class"]
        if failed and not row["error"]:
            return "error", "empty value"
        for name in row:
            if name not in RESERVED and name not in self.columns:
                return name, "column not in the schema"
        for name, col in self.columns.items():
            if name not in row:
                if col.optional or (failed and name not in self.params):
                    continue
                return name, "missing column"
            if failed and name not in self.params:
                return name, "an error row holds no results"
            problem = col.problem(row[name])
            if problem is not None:
                return name, problem
        params = {k: row[k] for k in self.params}
        if trial_id(params) != row["trial"]:
            return "trial", "id does not match the row's parameters"
        return None

    def normalise(self, values: Mapping[str, Any]) -> Row:
        """A trial function's results as stored: plain JSON types, checked against the schema.

        Raises
        ------
        ConfigError
            A result the schema does not declare, or of the wrong type (a bug in the study: it must
            stop the run, not fill a table with rows that every load would reject).
        """
        out: Row = {}
        for name, value in values.items():
            col = self.columns.get(name)
            if col is None or name in self.params:
                raise ConfigError(f"trial result {name!r} is not a result column of the schema.")
            plain = _plain(value)
            if col.type == "float" and isinstance(plain, int) and not isinstance(plain, bool):
                plain = float(plain)
            problem = col.problem(plain)
            if problem is not None:
                raise ConfigError(f"trial result {name!r}: {problem} ({plain!r}).")
            out[name] = plain
        for name, col in self.columns.items():
            if name not in self.params and not col.optional and name not in out:
                raise ConfigError(f"trial result {name!r} is missing (the schema requires it).")
        return out


def trial_id(params: Mapping[str, Any]) -> str:
    """A trial's stable identifier: its parameters as canonical JSON."""
    try:
        return json.dumps(dict(params), sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"trial parameters must be plain finite JSON values: {err}.") from None


def _plain(value: Any) -> Any:
    """numpy scalars and arrays as Python values (JSON has no numpy types)."""
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return value.tolist()
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    return value
