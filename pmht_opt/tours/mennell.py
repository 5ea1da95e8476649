"""Reader of W. Mennell's CETSP instance files (the Close-Enough TSP benchmark).

Each data line is ``x y z r demand``; only ``x``, ``y`` and the radius ``r`` are used. Comment lines
begin with ``//``; the one that begins with ``//Depot`` gives the depot, as ``//Depot is 100, 100, 0``
or ``//Depot: 2.78, 1.65, 0`` (other comments, some of which also mention a depot, are ignored).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from pmht_opt.exceptions import ConfigError

_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def read_mennell(path: str | Path, radius_factor: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depot ``(2,)``, centres ``(N, 2)`` and radii ``(N,)`` (times ``radius_factor``) of a file.

    Raises
    ------
    ConfigError
        Naming the file (and line) when a data line is malformed, a radius is not positive, there is
        no target, no or several depot lines, or ``radius_factor`` is not a positive number.
    """
    path = Path(path)
    if not (isinstance(radius_factor, int | float) and np.isfinite(radius_factor) and radius_factor > 0):
        raise ConfigError(f"radius_factor: expected a positive number, got {radius_factor!r}.")
    try:
        text = path.read_text()
    except OSError as err:
        raise ConfigError(f"{path}: cannot be read ({err}).") from err
    depot: list[float] | None = None
    rows: list[tuple[float, float, float]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("//"):
            body = line[2:].lstrip()
            if body.lower().startswith("depot"):
                values = [float(v) for v in _NUMBER.findall(body[5:])]
                if len(values) < 2:
                    raise ConfigError(f"{path}, line {number}: depot line without two coordinates: {raw!r}.")
                if depot is not None:
                    raise ConfigError(f"{path}, line {number}: a second depot line.")
                depot = values[:2]
            continue
        fields = line.replace(",", " ").split()
        try:
            values = [float(v) for v in fields]
        except ValueError:
            raise ConfigError(
                f"{path}, line {number}: expected numbers 'x y z r demand', got {raw!r}."
            ) from None
        if len(values) < 4 or not np.all(np.isfinite(values[:4])):
            raise ConfigError(f"{path}, line {number}: expected 'x y z r demand', got {raw!r}.")
        if values[3] <= 0:
            raise ConfigError(f"{path}, line {number}: the radius must be positive, got {values[3]!r}.")
        rows.append((values[0], values[1], values[3]))
    if depot is None:
        raise ConfigError(f"{path}: no '//Depot' comment line.")
    if not rows:
        raise ConfigError(f"{path}: no target lines.")
    data = np.array(rows)
    return np.array(depot), data[:, :2].copy(), data[:, 2] * radius_factor
