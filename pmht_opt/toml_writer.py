"""A small TOML writer for scenario and mission files (the standard library reads TOML but does not
write it)."""

from __future__ import annotations

import math
import re
from typing import Any

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
#: TOML's short escapes; every other control character is written as a ``\uXXXX`` escape.
_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def string(text: str) -> str:
    """``text`` as a TOML basic string.

    TOML forbids control characters (U+0000 to U+001F and U+007F) in a basic string and has no
    surrogate escapes, so JSON's escaping is not TOML's: a character outside the Basic Multilingual
    Plane is written as itself (the file is UTF-8), quotes, backslashes and control characters are
    escaped.
    """
    out = []
    for ch in text:
        code = ord(ch)
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif code < 0x20 or code == 0x7F:
            out.append(f"\\u{code:04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _key(key: str) -> str:
    return key if _BARE_KEY.match(key) else string(key)


def _is_table(value: Any) -> bool:
    return isinstance(value, dict)


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def value(v: Any) -> str:
    """One TOML value: strings, booleans, integers, floats, arrays and inline tables."""
    if isinstance(v, str):
        return string(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(float(v))  # numpy's floats are floats, but their repr is not TOML
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {value(x)}" for k, x in v.items() if x is not None) + " }"
    if isinstance(v, (list, tuple)):
        if v and isinstance(v[0], (list, tuple)):
            return "[\n" + "".join(f"  {value(x)},\n" for x in v) + "]"
        return "[" + ", ".join(value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps(data: dict[str, Any], header: str = "") -> str:
    """TOML text of ``data``: plain keys first, then ``[tables]``, then ``[[arrays of tables]]``;
    ``None`` values are left out."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    _table(lines, [], data)
    return "\n".join(lines).strip("\n") + "\n"


def _table(lines: list[str], path: list[str], data: dict[str, Any]) -> None:
    for k, v in data.items():
        if v is not None and not _is_table(v) and not _is_table_array(v):
            lines.append(f"{_key(k)} = {value(v)}")
    for k, v in data.items():
        if _is_table(v):
            lines += ["", "[" + ".".join(_key(p) for p in [*path, k]) + "]"]
            _table(lines, [*path, k], v)
    for k, v in data.items():
        if _is_table_array(v):
            for item in v:
                lines += ["", "[[" + ".".join(_key(p) for p in [*path, k]) + "]]"]
                _table(lines, [*path, k], item)
