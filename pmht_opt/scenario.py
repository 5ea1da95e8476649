"""Scenarios: locales to visit, platforms' starts, horizon and model parameters (docs/model.md 1, 12)."""

from __future__ import annotations

import json
import logging
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pmht_opt import validation
from pmht_opt.exceptions import ScenarioError
from pmht_opt.model import STATE_DIM, MotionModel
from pmht_opt.toml_writer import dumps

_log = logging.getLogger("pmht_opt")

Bounds = tuple[float, float, float, float]

#: The paper's area: a 10 x 10 box.
PAPER_BOUNDS: Bounds = (0.0, 10.0, 0.0, 10.0)
#: Fixed starts of scenario B: outside the map on the left.
SCENARIO_B_STARTS = np.array([[-1.0, 2.5], [-1.0, 5.0], [-1.0, 7.5]])
#: The fields of a scenario, as files and :meth:`Scenario.to_dict` hold them.
SCENARIO_FIELDS = ("name", "horizon", "dt", "q", "r", "bounds", "coverage_radius", "locales", "starts")


def _array(name: str, value: Any, widths: tuple[int, ...]) -> np.ndarray:
    """A finite ``(K, w)`` array, ``K >= 1`` and ``w`` in ``widths``, of values the numerics handle."""
    arr = validation.real_array(name, value, ScenarioError)
    if arr.ndim != 2 or arr.shape[1] not in widths:
        want = " or ".join(f"(K, {w})" for w in widths)
        raise ScenarioError(f"{name} must have shape {want}, got {arr.shape}.")
    if arr.shape[0] < 1:
        raise ScenarioError(f"{name} must have at least one row, got {arr.shape[0]}.")
    return validation.bounded(name, arr, validation.COORDINATE_MAX, ScenarioError)


@dataclass
class Scenario:
    """A planning problem.

    Every field is checked on construction (:mod:`pmht_opt.validation`): numbers must be numbers
    (not strings or booleans), finite, and within the ranges the numerics handle (docs/model.md
    section 14); anything else raises :class:`~pmht_opt.exceptions.ScenarioError` naming the field.

    Parameters
    ----------
    locales
        Positions ``(N, 2)`` to visit, known exactly; ``|coordinate| <= 1e7``.
    starts
        Platforms' starts: positions ``(M, 2)`` (zero initial speed and acceleration) or full states
        ``(M, 6)`` in the order ``[px, vx, ax, py, vy, ay]``; every component ``<= 1e7`` in magnitude.
    horizon
        Number of time steps ``T`` (the plan covers ``t = 0..T``), an integer from 2 to 100000.
    dt
        Time step in seconds, in ``[1e-4, 1e4]``.
    q
        Process noise intensity of the constant-acceleration model (paper: 1e-8), in ``[1e-14, 1e3]``.
    r
        Variance of the Gaussian fitting penalty (paper: 1e-2, i.e. sigma = 0.1), in ``[1e-10, 1e12]``.
    bounds
        ``(xmin, xmax, ymin, ymax)`` of the area of interest, used by metrics and plots. Defaults to the
        bounding box of the locales (logged at level INFO on the ``pmht_opt`` logger, as the command
        line prints it).
    name
        A label for reports: any text (files write it as UTF-8).
    coverage_radius
        The sensor footprint ``rho``: a locale counts as covered when some platform's path passes
        within ``rho`` of it (docs/model.md section 11). One number for every locale, or one per
        locale (an ``(N,)`` array: a target's own radius, as in the Close-Enough TSP's instances with
        random radii). Used by the coverage metrics, guaranteed visits, the coverage planner and the
        exports unless they are given their own radius. Default 0.3, three standard deviations of the
        paper's penalty (``r = 0.01``); each in ``(0, 1e7]``.
    """

    locales: np.ndarray
    starts: np.ndarray
    horizon: int = 500
    dt: float = 1.0
    q: float = 1e-8
    r: float = 1e-2
    bounds: Bounds | None = None
    name: str = ""
    coverage_radius: float | np.ndarray = 0.3
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
        self.horizon = validation.integer("horizon", self.horizon, ScenarioError, *validation.HORIZON_RANGE)
        for key, (lo, hi) in (
            ("dt", validation.DT_RANGE),
            ("q", validation.Q_RANGE),
            ("r", validation.R_RANGE),
        ):
            setattr(self, key, validation.real(key, getattr(self, key), ScenarioError, lo, hi))
        self.coverage_radius = _radius(self.coverage_radius, self.locales.shape[0])
        if self.bounds is None:
            lo = self.locales.min(axis=0)
            hi = self.locales.max(axis=0)
            self.bounds = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
            _log.info(
                "bounds: none given; assumed the locales' bounding box [%.6g, %.6g, %.6g, %.6g]", *self.bounds
            )
        else:
            self.bounds = validation.box("bounds", self.bounds, ScenarioError)
        self.name = validation.text("name", self.name, ScenarioError)

    @property
    def radii(self) -> np.ndarray:
        """``(N,)`` every locale's coverage radius (the one number repeated, or the locales' own)."""
        return np.broadcast_to(np.asarray(self.coverage_radius, dtype=float), (self.n_locales,))

    @property
    def radius_text(self) -> str:
        """The coverage radius in words: ``"0.3"``, or ``"0.5-2"`` for radii of their own."""
        return describe_radius(self.coverage_radius)

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
            "coverage_radius": (
                self.coverage_radius.tolist()
                if isinstance(self.coverage_radius, np.ndarray)
                else self.coverage_radius
            ),
            "locales": self.locales.tolist(),
            "starts": self.starts.tolist(),
        }

    @classmethod
    def from_dict(cls, data: Any) -> Scenario:
        """Build a scenario from :meth:`to_dict`'s form; unknown or missing keys raise ScenarioError."""
        if not isinstance(data, dict):
            raise ScenarioError(f"A scenario must be a table/object, got {type(data).__name__}.")
        keys = [k for k in data if not isinstance(k, str)]
        if keys:
            raise ScenarioError(f"Scenario field names must be text, got {keys[0]!r}.")
        unknown = sorted(set(data) - set(SCENARIO_FIELDS))
        if unknown:
            raise ScenarioError(f"Unknown scenario field(s): {', '.join(unknown)}.")
        for key in ("locales", "starts"):
            if key not in data:
                raise ScenarioError(f"The scenario has no {key!r} field.")
        # A null means "the default" only where the default is "none given" (assumed bounds, no name);
        # a null number or array is a mistake, not a request for the default.
        null = sorted(k for k, v in data.items() if v is None and k not in ("name", "bounds"))
        if null:
            raise ScenarioError(f"{null[0]}: expected a value, got null (None).")
        kwargs = {k: v for k, v in data.items() if v is not None}
        return cls(**kwargs)

    def save(self, path: str | Path) -> Path:
        """Write to ``path``; ``.toml`` or ``.json`` by the suffix, UTF-8, missing folders created.

        :meth:`load` reads the file back to the same scenario, whatever its name holds (any
        character, control characters and quotes included).

        Raises
        ------
        ScenarioError
            Another suffix, or a path that cannot be written.
        """
        path = validation.file_path("path", path)
        suffix = path.suffix.lower()
        if suffix == ".json":
            text = json.dumps(self.to_dict(), indent=1, ensure_ascii=False) + "\n"
        elif suffix == ".toml":
            text = dumps(self.to_dict(), header="pmht-opt scenario")
        else:
            raise ScenarioError(f"Scenario files end in .toml or .json, got {path.name!r}.")
        with validation.writing(path) as part:
            part.write_text(text, encoding="utf-8")
        return path

    @classmethod
    def load(cls, path: str | Path) -> Scenario:
        """Read a ``.toml`` or ``.json`` scenario file (UTF-8), raising ScenarioError naming what is
        wrong: the file, its encoding or syntax, or the field."""
        path = validation.file_path("path", path)
        suffix = path.suffix.lower()
        if suffix not in (".json", ".toml"):
            raise ScenarioError(f"Scenario files end in .toml or .json, got {path.name!r}.")
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as err:
            raise ScenarioError(f"Cannot read scenario file {str(path)!r}: {err.strerror}.") from err
        except UnicodeDecodeError as err:
            raise ScenarioError(
                f"{path.name}: not UTF-8 text (byte {err.start}: {err.reason}); scenario files are UTF-8."
            ) from err
        try:
            data = json.loads(text) if suffix == ".json" else tomllib.loads(text)
        except RecursionError as err:
            raise ScenarioError(f"Scenario file {str(path)!r} is nested too deeply to read.") from err
        except ValueError as err:  # the decoders' errors, and integers longer than Python reads
            raise ScenarioError(f"Scenario file {str(path)!r} is not valid {suffix[1:]}: {err}") from err
        try:
            return cls.from_dict(data)
        except ScenarioError as err:
            raise ScenarioError(f"{path.name}: {err}") from err
        except TypeError as err:
            raise ScenarioError(f"{path.name}: malformed scenario ({err}).") from err


def _radius(value: Any, n_locales: int) -> float | np.ndarray:
    """A coverage radius: one number, or one per locale (all equal ones collapse to the number)."""
    if validation.is_real(value) or isinstance(value, str) or isinstance(value, bool):
        return validation.real(
            "coverage_radius", value, ScenarioError, 0.0, validation.RADIUS_MAX, lo_open=True
        )
    arr = validation.real_array("coverage_radius", value, ScenarioError)
    if arr.ndim == 0:
        return _radius(float(arr), n_locales)
    if arr.shape != (n_locales,):
        raise ScenarioError(
            f"coverage_radius: expected one number or one per locale ({n_locales},), got shape {arr.shape}."
        )
    bad = ~np.isfinite(arr) | (arr <= 0) | (arr > validation.RADIUS_MAX)
    if np.any(bad):
        n = int(np.flatnonzero(bad)[0])
        raise ScenarioError(
            f"coverage_radius[{n}]: expected a number in (0, {validation.RADIUS_MAX:g}], "
            f"got {float(arr[n]):g}."
        )
    if np.all(arr == arr[0]):
        return float(arr[0])
    arr = arr.astype(float).copy()
    arr.setflags(write=False)
    return arr


def describe_radius(radius: float | np.ndarray) -> str:
    """A coverage radius in words: ``"0.3"``, or the range ``"0.5-2"`` of radii of their own."""
    arr = np.asarray(radius, dtype=float)
    if arr.ndim == 0 or arr.min() == arr.max():
        return f"{float(arr.flat[0]):g}"
    return f"{float(arr.min()):g}-{float(arr.max()):g}"


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
        A non-negative integer or a ``numpy.random.Generator``; the same seed gives the same scenario.
        ``None`` draws fresh entropy (not reproducible).
    overrides
        Scenario fields to change (e.g. ``horizon=200``); another keyword raises ScenarioError.
    """
    key = kind.upper() if isinstance(kind, str) else None
    if key not in ("A", "B", "C"):
        raise ScenarioError(f"kind: paper scenarios are 'A', 'B' and 'C', got {kind!r}.")
    unknown = sorted(set(overrides) - set(SCENARIO_FIELDS))
    if unknown:
        raise ScenarioError(
            f"{unknown[0]}: not a scenario field; paper_scenario takes {', '.join(SCENARIO_FIELDS)}."
        )
    rng = validation.seed("seed", seed, ScenarioError)
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
