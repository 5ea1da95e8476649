"""Typed reading of values from mission files: a string where a number belongs is an error.

TOML and JSON carry their own types, so a file that says ``horizon = "300"`` or ``vmax = "0.1"`` has
written a string, and the library's constructors (which accept anything ``float()`` accepts) would
quietly take it. These checks come first, naming the field and the type found; ranges and shapes are
then checked by the library's own constructors, with their messages.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from pmht_opt.exceptions import ScenarioError


def describe(value: Any) -> str:
    """How a value reads in a message: its type in the file's words, and the value."""
    kinds = {str: "a string", bool: "a boolean", dict: "a table", list: "an array", type(None): "nothing"}
    kind = next((v for k, v in kinds.items() if isinstance(value, k)), type(value).__name__)
    if isinstance(value, (dict, list)):
        return kind
    return f"{kind} ({value!r})"


def is_number(value: Any) -> bool:
    """True for an int or float (never a bool or a string)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def number(field: str, value: Any) -> float:
    """A finite number, or :class:`ScenarioError` naming ``field``."""
    if not is_number(value):
        raise ScenarioError(f"{field}: expected a number, got {describe(value)}.")
    try:
        out = float(value)
    except OverflowError:
        message = f"{field}: expected a finite number, got an integer beyond the float range."
        raise ScenarioError(message) from None
    if not math.isfinite(out):
        raise ScenarioError(f"{field}: expected a finite number, got {value!r}.")
    return out


def integer(field: str, value: Any) -> int:
    """An integer (``3``; not ``3.0`` nor ``"3"``), or :class:`ScenarioError` naming ``field``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ScenarioError(f"{field}: expected an integer, got {describe(value)}.")
    return int(value)


def boolean(field: str, value: Any) -> bool:
    """``true`` or ``false``, or :class:`ScenarioError` naming ``field``."""
    if not isinstance(value, bool):
        raise ScenarioError(f"{field}: expected true or false, got {describe(value)}.")
    return value


def string(field: str, value: Any) -> str:
    """A string, or :class:`ScenarioError` naming ``field``."""
    if not isinstance(value, str):
        raise ScenarioError(f"{field}: expected a string, got {describe(value)}.")
    return value


def text(path: Path, encoding: str = "utf-8") -> str:
    """The text of the file ``path``; :class:`ScenarioError` naming it when it cannot be read or is not
    UTF-8 (``encoding`` may be ``"utf-8-sig"`` for files that spreadsheets write with a byte-order mark)."""
    try:
        return path.read_text(encoding=encoding)
    except OSError as err:
        raise ScenarioError(f"cannot read {str(path)!r}: {err.strerror or err}.") from None
    except UnicodeDecodeError as err:
        raise ScenarioError(f"{path.name}: not UTF-8 text (byte {err.start}: {err.reason}).") from None


def keyed(where: str, table: dict[str, Any], readers: dict[str, Any], what: str = "key") -> dict[str, Any]:
    """``table`` with each value read by the reader of its key (called with ``where.key`` and the value);
    :class:`ScenarioError` naming the first unknown key and listing the known ones."""
    unknown = sorted(set(table) - set(readers))
    if unknown:
        raise ScenarioError(f"{where}: unknown {what} {unknown[0]!r}; it takes {', '.join(readers)}.")
    return {key: readers[key](f"{where}.{key}", value) for key, value in table.items()}


def table(field: str, value: Any) -> dict[str, Any]:
    """A table (a JSON object), or :class:`ScenarioError` naming ``field``."""
    if not isinstance(value, dict):
        raise ScenarioError(f"{field}: expected a table, got {describe(value)}.")
    return value


def numbers(field: str, value: Any, depth: int) -> list[Any]:
    """Nested arrays of numbers, ``depth`` deep (1: ``[1, 2]``; 2: ``[[1, 2], [3, 4]]``).

    Shapes are left to the library's constructors; this checks only that every leaf is a number, so
    ``["0", 1]`` is reported here with the element's index.
    """
    if not isinstance(value, list):
        want = "an array of numbers" if depth == 1 else "an array of arrays of numbers"
        raise ScenarioError(f"{field}: expected {want}, got {describe(value)}.")
    for i, item in enumerate(value):
        if depth > 1:
            numbers(f"{field}[{i}]", item, depth - 1)
        elif not is_number(item):
            raise ScenarioError(f"{field}[{i}]: expected a number, got {describe(item)}.")
    return value


def number_or_numbers(field: str, value: Any) -> Any:
    """A number, or an array of numbers (one per platform)."""
    if isinstance(value, list):
        return numbers(field, value, 1)
    return number(field, value)


def integer_or_integers(field: str, value: Any) -> Any:
    """An integer, or an array of integers (platform indices)."""
    if isinstance(value, list):
        return [integer(f"{field}[{i}]", v) for i, v in enumerate(value)]
    return integer(field, value)


def vector_or_vectors(field: str, value: Any) -> Any:
    """``[a, b]`` for every platform, or ``[[a, b], ...]`` one per platform."""
    if isinstance(value, list) and value and isinstance(value[0], list):
        return numbers(field, value, 2)
    return numbers(field, value, 1)
