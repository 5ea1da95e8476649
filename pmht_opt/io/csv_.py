"""Plans as CSV: one row per platform and time step, with time, position, velocity and acceleration.

Columns: ``platform`` (0-based, as in the library and in mission files' ``platforms``), ``step``
(``t = 0..T``), ``time`` (s, ``t dt``), ``x``, ``y``, ``vx``, ``vy``, ``ax``, ``ay`` (the scenario's
units; metres east and north of the origin for a geo-referenced mission), and, with an origin,
``lat`` and ``lon`` (degrees). Floats are written in full (``repr``), so reading the file back gives
the plan's states exactly.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.exceptions import ScenarioError
from pmht_opt.geometry.earth import GeoOrigin, check_origin
from pmht_opt.model import AX, AY, PX, PY, STATE_DIM, VX, VY
from pmht_opt.result import check_plan
from pmht_opt.validation import file_path, writing

#: The columns of a plan's CSV (``lat`` and ``lon`` follow with an origin).
COLUMNS = ("platform", "step", "time", "x", "y", "vx", "vy", "ax", "ay")
_STATE = {"x": PX, "y": PY, "vx": VX, "vy": VY, "ax": AX, "ay": AY}


def export_csv(result: Any, path: str | Path, origin: GeoOrigin | None = None) -> Path:
    """Write the plan ``result`` (a :class:`~pmht_opt.PlanResult`) to ``path`` as CSV (module notes).

    Returns
    -------
    Path
        ``path``.
    """
    origin = check_origin(origin)
    states = np.asarray(check_plan(result).states)
    M, T1, _ = states.shape
    dt = float(result.scenario.dt)
    latlon = origin.plane.to_geodetic(states[:, :, [PX, PY]]) if origin is not None else None
    out = file_path("path", path)
    with writing(out) as part, part.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow([*COLUMNS, *(("lat", "lon") if latlon is not None else ())])
        for m in range(M):
            for t in range(T1):
                row: list[Any] = [m, t, repr(t * dt)]
                row += [repr(float(states[m, t, _STATE[c]])) for c in COLUMNS[3:]]
                if latlon is not None:
                    row += [repr(float(latlon[m, t, 0])), repr(float(latlon[m, t, 1]))]
                w.writerow(row)
    return out


def read_plan_csv(path: str | Path) -> np.ndarray:
    """The states ``(M, T+1, 6)`` ``[px, vx, ax, py, vy, ay]`` of a plan's CSV (:func:`export_csv`).

    Raises
    ------
    ScenarioError
        A missing column, a value that is not a number, or rows that do not make whole paths.
    """
    path = file_path("path", path)
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, ValueError, csv.Error) as err:  # unreadable, not UTF-8, not CSV
        raise ScenarioError(f"cannot read {path.name}: {err}.") from None
    if not rows:
        raise ScenarioError(f"{path.name}: no rows.")
    missing = [c for c in COLUMNS if c not in rows[0]]
    if missing:
        raise ScenarioError(f"{path.name}: missing column(s) {', '.join(missing)}.")
    try:
        plat = np.array([int(r["platform"]) for r in rows])
        step = np.array([int(r["step"]) for r in rows])
        vals = np.array([[float(r[c]) for c in COLUMNS[3:]] for r in rows])
    except ValueError as err:
        raise ScenarioError(f"{path.name}: {err}.") from None
    M, T1 = int(plat.max()) + 1, int(step.max()) + 1
    if len(rows) != M * T1:
        raise ScenarioError(f"{path.name}: {len(rows)} rows do not make {M} paths of {T1} steps.")
    states = np.full((M, T1, STATE_DIM), np.nan)
    for j, c in enumerate(COLUMNS[3:]):
        states[plat, step, _STATE[c]] = vals[:, j]
    if np.isnan(states).any():
        raise ScenarioError(f"{path.name}: some platform and step appear twice, others not at all.")
    return states
