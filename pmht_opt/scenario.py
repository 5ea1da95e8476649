"""Scenarios: locales to visit, platforms' starts, horizon and model parameters (docs/model.md 1, 12)."""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pmht_opt.exceptions import ScenarioError
from pmht_opt.model import STATE_DIM, MotionModel

Bounds = tuple[float, float, float, float]

#: The paper's area: a 10 x 10 box.
PAPER_BOUNDS: Bounds = (0.0, 10.0, 0.0, 10.0)
#: Fixed starts of scenario B: outside the map on the left.
SCENARIO_B_STARTS = np.array([[-1.0, 2.5], [-1.0, 5.0], [-1.0, 7.5]])


def _number(name: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ScenarioError(f"{name} must be a number, got {value!r}.") from None
    if not math.isfinite(out):
        raise ScenarioError(f"{name} must be finite, got {value!r}.")
    return out


def _array(name: str, value: Any, widths: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ScenarioError(f"{name} must be a numeric array, got {type(value).__name__}.") from None
    if arr.ndim != 2 or arr.shape[1] not in widths:
        want = " or ".join(f"(K, {w})" for w in widths)
        raise ScenarioError(f"{name} must have shape {want}, got {arr.shape}.")
    if arr.shape[0] < 1:
        raise ScenarioError(f"{name} must have at least one row, got {arr.shape[0]}.")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ScenarioError(f"{name} has a non-finite value at row {bad[0]}, column {bad[1]}.")
    return arr


@dataclass
class Scenario:
    """A planning problem.

    Parameters
    ----------
    locales
        Positions ``(N, 2)`` to visit, known exactly.
    starts
        Platforms' starts: positions ``(M, 2)`` (zero initial speed and acceleration) or full states
        ``(M, 6)`` in the order ``[px, vx, ax, py, vy, ay]``.
    horizon
        Number of time steps ``T`` (the plan covers ``t = 0..T``).
    dt
        Time step in seconds.
    q
        Process noise intensity of the constant-acceleration model (paper: 1e-8).
    r
        Variance of the Gaussian fitting penalty (paper: 1e-2, i.e. sigma = 0.1).
    bounds
        ``(xmin, xmax, ymin, ymax)`` of the area of interest, used by metrics and plots. Defaults to the
        bounding box of the locales.
    name
        A label for reports.
    coverage_radius
        The sensor footprint ``rho``: a locale counts as covered when some platform's path passes
        within ``rho`` of it (docs/model.md section 11). Used by the coverage metrics, guaranteed visits
        and the coverage planner unless they are given their own radius. Default 0.3, three standard
        deviations of the paper's penalty (``r = 0.01``).
    """

    locales: np.ndarray
    starts: np.ndarray
    horizon: int = 500
    dt: float = 1.0
    q: float = 1e-8
    r: float = 1e-2
    bounds: Bounds | None = None
    name: str = ""
    coverage_radius: float = 0.3
    initial_states: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.locales = _array("locales", self.locales, (2,))
        starts = _array("starts", self.starts, (2, STATE_DIM))
        if starts.shape[1] == 2:
            full = np.zeros((starts.shape[0], STATE_DIM))
            full[:, 0] = starts[:, 0]
            full[:, 3] = starts[:, 1]
        else:
            full = starts
        self.starts = starts
        self.initial_states = full
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, (int, np.integer)):
            horizon = _number("horizon", self.horizon)
            if horizon != int(horizon):
                raise ScenarioError(f"horizon must be a whole number of steps, got {self.horizon!r}.")
            self.horizon = int(horizon)
        self.horizon = int(self.horizon)
        if self.horizon < 2:
            raise ScenarioError(f"horizon must be >= 2 time steps, got {self.horizon}.")
        for key in ("dt", "q", "r", "coverage_radius"):
            value = _number(key, getattr(self, key))
            if value <= 0:
                raise ScenarioError(f"{key} must be > 0, got {value}.")
            setattr(self, key, value)
        if self.bounds is None:
            lo = self.locales.min(axis=0)
            hi = self.locales.max(axis=0)
            self.bounds = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
        else:
            if len(tuple(self.bounds)) != 4:
                raise ScenarioError(f"bounds must be (xmin, xmax, ymin, ymax), got {self.bounds!r}.")
            b = tuple(_number("bounds", v) for v in self.bounds)
            if b[0] > b[1] or b[2] > b[3]:
                raise ScenarioError(f"bounds must have xmin <= xmax and ymin <= ymax, got {b}.")
            self.bounds = (b[0], b[1], b[2], b[3])
        self.name = str(self.name)

    @property
    def n_locales(self) -> int:
        """``N``."""
        return int(self.locales.shape[0])

    @property
    def n_platforms(self) -> int:
        """``M``."""
        return int(self.starts.shape[0])

    @property
    def start_positions(self) -> np.ndarray:
        """Start positions ``(M, 2)``."""
        return self.initial_states[:, [0, 3]]

    @property
    def model(self) -> MotionModel:
        """The motion model of this scenario."""
        return MotionModel(dt=self.dt, q=self.q)

    def replace(self, **changes: Any) -> Scenario:
        """A copy with some fields changed (validated again)."""
        fields = self.to_dict()
        fields.update(changes)
        return Scenario.from_dict(fields)

    # ------------------------------------------------------------------ files

    def to_dict(self) -> dict[str, Any]:
        """Plain-Python form (lists and floats) of this scenario."""
        return {
            "name": self.name,
            "horizon": self.horizon,
            "dt": self.dt,
            "q": self.q,
            "r": self.r,
            "bounds": list(self.bounds) if self.bounds is not None else None,
            "coverage_radius": self.coverage_radius,
            "locales": self.locales.tolist(),
            "starts": self.starts.tolist(),
        }

    @classmethod
    def from_dict(cls, data: Any) -> Scenario:
        """Build a scenario from :meth:`to_dict`'s form; unknown or missing keys raise ScenarioError."""
        if not isinstance(data, dict):
            raise ScenarioError(f"A scenario must be a table/object, got {type(data).__name__}.")
        allowed = {"name", "horizon", "dt", "q", "r", "bounds", "coverage_radius", "locales", "starts"}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise ScenarioError(f"Unknown scenario field(s): {', '.join(unknown)}.")
        for key in ("locales", "starts"):
            if key not in data:
                raise ScenarioError(f"The scenario has no {key!r} field.")
        kwargs = {k: v for k, v in data.items() if v is not None}
        return cls(**kwargs)

    def save(self, path: str | Path) -> Path:
        """Write to ``path``; ``.toml`` or ``.json`` by the suffix."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".json":
            path.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        elif suffix == ".toml":
            path.write_text(_to_toml(self.to_dict()))
        else:
            raise ScenarioError(f"Scenario files end in .toml or .json, got {path.name!r}.")
        return path

    @classmethod
    def load(cls, path: str | Path) -> Scenario:
        """Read a ``.toml`` or ``.json`` scenario file, raising ScenarioError naming what is wrong."""
        path = Path(path)
        suffix = path.suffix.lower()
        try:
            text = path.read_text()
        except OSError as err:
            raise ScenarioError(f"Cannot read scenario file {str(path)!r}: {err.strerror}.") from err
        try:
            if suffix == ".json":
                data = json.loads(text)
            elif suffix == ".toml":
                data = tomllib.loads(text)
            else:
                raise ScenarioError(f"Scenario files end in .toml or .json, got {path.name!r}.")
        except (json.JSONDecodeError, tomllib.TOMLDecodeError) as err:
            raise ScenarioError(f"Scenario file {str(path)!r} is not valid {suffix[1:]}: {err}") from err
        try:
            return cls.from_dict(data)
        except ScenarioError as err:
            raise ScenarioError(f"{path.name}: {err}") from err
        except TypeError as err:
            raise ScenarioError(f"{path.name}: malformed scenario ({err}).") from err


def _toml_value(value: Any) -> str:
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list):
        if value and isinstance(value[0], list):
            rows = ",\n".join("  " + _toml_value(v) for v in value)
            return "[\n" + rows + ",\n]"
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise ScenarioError(f"Cannot write {type(value).__name__} to TOML.")


def _to_toml(data: dict[str, Any]) -> str:
    lines = ["# pmht-opt scenario"]
    for key, value in data.items():
        if value is None:
            continue
        lines.append(f"{key} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


ScenarioKind = Literal["A", "B", "C"]


def paper_scenario(kind: str, seed: int | np.random.Generator | None = 0, **overrides: Any) -> Scenario:
    """One trial of the paper's scenarios (docs/model.md section 12).

    * ``A``: locales on the uniform 10 x 10 grid (centres 0.5 .. 9.5), 4 platforms uniformly random in
      the box.
    * ``B``: 100 locales uniformly random in the box, 3 platforms fixed at (-1, 2.5), (-1, 5), (-1, 7.5).
    * ``C``: 100 locales uniformly random in the box, 4 platforms uniformly random in the box.

    Parameters
    ----------
    kind
        ``"A"``, ``"B"`` or ``"C"`` (case-insensitive).
    seed
        Seed or ``numpy.random.Generator``; the same seed gives the same scenario.
    overrides
        Scenario fields to change (e.g. ``horizon=200``).
    """
    key = str(kind).upper()
    if key not in ("A", "B", "C"):
        raise ScenarioError(f"Paper scenarios are 'A', 'B' and 'C', got {kind!r}.")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    lo, hi = PAPER_BOUNDS[0], PAPER_BOUNDS[1]
    if key == "A":
        centres = np.arange(10) + 0.5
        gx, gy = np.meshgrid(centres, centres, indexing="ij")
        locales = np.column_stack([gx.ravel(), gy.ravel()])
        starts = rng.uniform(lo, hi, size=(4, 2))
    elif key == "B":
        locales = rng.uniform(lo, hi, size=(100, 2))
        starts = SCENARIO_B_STARTS.copy()
    else:
        locales = rng.uniform(lo, hi, size=(100, 2))
        starts = rng.uniform(lo, hi, size=(4, 2))
    label = f"{key}" if isinstance(seed, np.random.Generator) else f"{key} (seed {seed})"
    fields: dict[str, Any] = {
        "locales": locales,
        "starts": starts,
        "bounds": PAPER_BOUNDS,
        "name": label,
    }
    fields.update(overrides)
    return Scenario(**fields)
