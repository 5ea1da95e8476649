"""Plan results and the metrics computed from them (docs/model.md section 11)."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

import solvers
from pmht_opt import validation
from pmht_opt.constraints.base import Constraint, ConstraintReport
from pmht_opt.constraints.params import positive_number
from pmht_opt.estep import EStepSummary
from pmht_opt.exceptions import ConfigError
from pmht_opt.geometry import count_crossings, miss_distances, missed
from pmht_opt.model import ACC, POS, VEL
from pmht_opt.scenario import Scenario

#: A platform has arrived once it stays within this much (relative to the coordinates) of its end.
ARRIVED = 1e-9


def excursion(points: np.ndarray, bounds: tuple[float, float, float, float]) -> float:
    """Largest distance of any point ``(..., 2)`` outside the box ``(xmin, xmax, ymin, ymax)``."""
    xmin, xmax, ymin, ymax = bounds
    p = np.asarray(points, dtype=float)
    dx = np.maximum(np.maximum(xmin - p[..., 0], p[..., 0] - xmax), 0.0)
    dy = np.maximum(np.maximum(ymin - p[..., 1], p[..., 1] - ymax), 0.0)
    return float(np.max(np.hypot(dx, dy)))


@dataclass
class IterationHistory:
    """Per-iteration record of an EM run.

    ``objective[0]`` is the EM objective of the initial (standing) paths and ``objective[i]`` the one
    after iteration ``i``; the time and iteration arrays have one entry per iteration (``estep_time``
    has one more: the final E-step that scores the last paths).

    ``r[i]`` is the fitting penalty ``objective[i]`` is computed with: iteration ``i``'s ``r`` under an
    annealing schedule (``r[0] = r[1]``), otherwise the scenario's ``r`` throughout. EM guarantees
    ``objective[i] >= objective[i-1]`` (without constraints) whenever ``r[i] == r[i-1]``, that is from
    index :attr:`settled` on.

    ``fallbacks[i]`` counts the platforms whose M-step in iteration ``i + 1`` failed with the backend's
    fast settings and was solved by one of its retry settings (:mod:`pmht_opt.mstep.tuning`);
    ``mstep_status[i]`` is that M-step's status; ``estep_gated[i]`` says whether the E-step after
    iteration ``i`` (``0``: the initial one) was gated. ``stop_reason`` names the stopping criterion
    that ended the run; ``anneal`` describes the schedule of ``r`` the run used, and says whether it
    was compressed to fit the run's iterations.
    """

    objective: np.ndarray
    estep_time: np.ndarray
    mstep_time: np.ndarray
    solver_iterations: np.ndarray
    r: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fallbacks: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    mstep_status: tuple[solvers.Status, ...] = ()
    estep_gated: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    stop_reason: str = ""
    anneal: str = "none"

    @property
    def fitted_r(self) -> float:
        """The penalty ``r`` the returned paths were fitted at (the last iteration's): the scenario's
        ``r`` unless a criterion other than the iteration limit stopped the run during annealing."""
        return float(self.r[-1]) if self.r.size else float("nan")

    @property
    def settled(self) -> int:
        """First index from which ``r`` no longer changes: annealing is over and, without
        constraints, the objective never decreases from there on (0 for plain EM)."""
        if self.r.size == 0:
            return 0
        changed = np.nonzero(self.r[1:] != self.r[:-1])[0]
        return int(changed[-1]) + 1 if changed.size else 0

    @property
    def n_iterations(self) -> int:
        """Number of EM iterations run."""
        return int(self.mstep_time.shape[0])


@dataclass
class PlanResult:
    """Planned paths and what they achieve.

    Attributes
    ----------
    states
        ``(M, T+1, 6)`` states ``[px, vx, ax, py, vy, ay]``, ``t = 0..T``.
    assignment
        ``(N,)`` platform of each locale: the MAP of the final weights.
    visit_time
        ``(N,)`` time step (``1..T``) of each locale's MAP visit.
    platform_prior
        ``(N, M)`` final ``pi^k``.
    history
        Per-iteration objective, timings and solver iterations.
    constraints
        The constraints the plan was made under.
    reports
        How each constraint holds on the returned paths (:meth:`constraint_reports`), measured on the
        exact geometry against the rows of the last M-step.
    estep
        The final E-step, compactly (:class:`~pmht_opt.estep.EStepSummary`): sparse weights and each
        locale's platform probabilities.
    anneal
        Description of the annealing schedule of ``r`` the plan was made with (``"none"``).
    planner
        The planner that made it (:data:`pmht_opt.PLANNERS`: ``"pmht"``, ``"smoothed"``,
        ``"coverage"``).

    Figures and exports are functions that take a result: :func:`pmht_opt.plotting.plot_result`,
    :func:`pmht_opt.io.export_csv`, :func:`pmht_opt.io.export_geojson` and
    :func:`pmht_opt.io.export_qgc_plan`.
    """

    scenario: Scenario
    states: np.ndarray
    assignment: np.ndarray
    visit_time: np.ndarray
    platform_prior: np.ndarray
    history: IterationHistory
    converged: bool = False
    wall_time: float = 0.0
    solver: str = ""
    snapshots: dict[int, np.ndarray] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)
    constraints: tuple[Constraint, ...] = ()
    reports: tuple[ConstraintReport, ...] = ()
    estep: EStepSummary | None = None
    anneal: str = "none"
    planner: str = ""

    def __repr__(self) -> str:
        sc = self.scenario
        label = f"{sc.name!r}, " if sc.name else ""
        return (
            f"PlanResult({label}{self.planner or 'plan'}: {sc.n_platforms} platforms, {sc.n_locales} "
            f"locales, T={sc.horizon}, solver={self.solver!r}, iterations={self.n_iterations}, "
            f"distance={self.total_distance:.4g}, "
            f"coverage@{sc.radius_text}={self.coverage():.0%}, max violation={self.max_violation:.1e})"
        )

    @property
    def positions(self) -> np.ndarray:
        """``(M, T+1, 2)`` positions, ``t = 0..T``."""
        return self.states[:, :, POS]

    @property
    def n_iterations(self) -> int:
        """EM iterations run."""
        return self.history.n_iterations

    # ----------------------------------------------------------------- metrics

    @cached_property
    def distance_per_platform(self) -> np.ndarray:
        """``(M,)`` length of each path: sum of the segments between consecutive positions."""
        seg = np.diff(self.positions, axis=1)
        return np.hypot(seg[..., 0], seg[..., 1]).sum(axis=1)

    @property
    def total_distance(self) -> float:
        """Total distance travelled by all platforms (the paper's metric)."""
        return float(self.distance_per_platform.sum())

    @cached_property
    def arrival_time(self) -> np.ndarray:
        """``(M,)`` when each platform reaches the place it ends at and stays there (s): the end of
        its route, home for a closed one. A platform still moving at the horizon arrives at
        ``T dt``."""
        pos = self.positions
        scale = max(1.0, float(np.max(np.abs(pos))))
        away = np.hypot(*(pos - pos[:, -1:, :]).transpose(2, 0, 1)) > ARRIVED * scale  # (M, T+1)
        last = np.where(away.any(axis=1), pos.shape[1] - 1 - np.argmax(away[:, ::-1], axis=1), -1)
        return (last + 1) * self.scenario.dt

    @property
    def mission_time(self) -> float:
        """When the last platform arrives (:attr:`arrival_time`): how long the mission takes."""
        return float(np.max(self.arrival_time))

    @cached_property
    def miss_distance(self) -> np.ndarray:
        """``(N,)`` distance from each locale to the nearest path, measured on the segments between
        consecutive positions (docs/model.md section 11)."""
        return miss_distances(self.scenario.locales, self.positions)

    def _radius(self, radius: object) -> float | np.ndarray:
        """``radius`` checked, or the scenario's coverage radius (one number, or one per locale)."""
        if radius is None:
            return self.scenario.coverage_radius
        if isinstance(radius, np.ndarray):
            return self.scenario.replace(coverage_radius=radius).coverage_radius
        return positive_number("radius", radius, allow_zero=True)

    def coverage(self, radius: float | np.ndarray | None = None) -> float:
        """Fraction of locales within ``radius`` of some platform's path (docs/model.md section 11).

        ``radius`` defaults to the scenario's :attr:`~pmht_opt.Scenario.coverage_radius`. A locale
        counts up to :data:`COVERAGE_RTOL` of the radius beyond it: a plan made to pass at exactly the
        radius meets it to its solver's tolerance.
        """
        return 1.0 - self.missed_locales(radius).size / self.scenario.n_locales

    def missed_locales(self, radius: float | np.ndarray | None = None) -> np.ndarray:
        """Indices of the locales further than ``radius`` (default: the scenario's) from every path."""
        return missed(self.miss_distance, self._radius(radius))

    @cached_property
    def locales_per_platform(self) -> np.ndarray:
        """``(M,)`` number of locales assigned to each platform."""
        return np.bincount(self.assignment, minlength=self.scenario.n_platforms)

    @cached_property
    def crossings(self) -> int:
        """Number of intersections between segments of different platforms' paths."""
        return count_crossings(self.positions)

    @property
    def max_speed(self) -> float:
        """Largest speed measured on the positions, ``max ||p_t - p_{t-1}|| / dt``: what a user who flies
        the plan sees. The motion model moves positions by process noise as well as by the velocity
        state, so this can exceed :attr:`max_speed_state`."""
        d = np.diff(self.positions, axis=1)
        return float(np.max(np.hypot(d[..., 0], d[..., 1]), initial=0.0)) / self.scenario.dt

    @property
    def max_speed_state(self) -> float:
        """Largest speed of the velocity states ``||(vx, vy)||`` over all platforms and times."""
        v = self.states[:, :, VEL]
        return float(np.max(np.hypot(v[..., 0], v[..., 1])))

    @property
    def max_acceleration(self) -> float:
        """Largest acceleration measured on the positions, ``max ||p_{t+1} - 2 p_t + p_{t-1}|| / dt^2``,
        the first step's measured from the start's velocity (``p_{-1} = p_0 - v_0 dt``), as
        :class:`~pmht_opt.constraints.AccelLimit` bounds it."""
        dt = self.scenario.dt
        p = self.positions
        before = p[:, :1] - self.states[:, :1, VEL] * dt
        dd = np.diff(np.concatenate([before, p], axis=1), n=2, axis=1)
        return float(np.max(np.hypot(dd[..., 0], dd[..., 1]), initial=0.0)) / dt**2

    @property
    def max_acceleration_state(self) -> float:
        """Largest acceleration of the states ``||(ax, ay)||`` over all platforms and times."""
        a = self.states[:, :, ACC]
        return float(np.max(np.hypot(a[..., 0], a[..., 1])))

    def max_excursion(self, bounds: tuple[float, float, float, float] | None = None) -> float:
        """Largest distance of any position outside ``bounds`` (default: the scenario's area)."""
        box = validation.box("bounds", bounds, ConfigError) if bounds is not None else self.scenario.bounds
        assert box is not None
        return excursion(self.positions, box)

    def constraint_reports(self) -> list[ConstraintReport]:
        """How each constraint holds on the returned paths, measured on the exact geometry."""
        return list(self.reports)

    @property
    def max_violation(self) -> float:
        """Largest violation of any constraint (0 without constraints or when all hold)."""
        return max((r.max_violation for r in self.constraint_reports()), default=0.0)

    def metrics(self, radius: float | np.ndarray | None = None) -> dict[str, Any]:
        """The headline metrics as plain Python values (for tables and JSON)."""
        rho = self._radius(radius)
        return {
            "total_distance": self.total_distance,
            "mission_time": self.mission_time,
            "coverage": self.coverage(rho),
            "coverage_radius": rho.tolist() if isinstance(rho, np.ndarray) else rho,
            "missed_locales": self.missed_locales(rho).tolist(),
            "mean_miss_distance": float(np.mean(self.miss_distance)),
            "max_miss_distance": float(np.max(self.miss_distance)),
            "crossings": int(self.crossings),
            "max_speed": self.max_speed,
            "max_speed_state": self.max_speed_state,
            "max_acceleration": self.max_acceleration,
            "max_acceleration_state": self.max_acceleration_state,
            "max_excursion": self.max_excursion(),
            "locales_per_platform": self.locales_per_platform.tolist(),
            "distance_per_platform": self.distance_per_platform.tolist(),
            "iterations": self.n_iterations,
            "converged": bool(self.converged),
            "final_objective": float(self.history.objective[-1]),
            "wall_time": float(self.wall_time),
            "solver": self.solver,
            "solver_fallbacks": int(np.sum(self.history.fallbacks)),
            "anneal": self.anneal,
            "constraints": {
                r.name: {
                    "soft": r.soft,
                    "max_violation": r.max_violation,
                    "violations": r.n_violations,
                    **{k: v for k, v in r.details.items() if not isinstance(v, tuple)},
                }
                for r in self.constraint_reports()
            },
        }


def check_plan(result: Any) -> PlanResult:
    """``result`` if it is a :class:`PlanResult`, else :class:`ConfigError` naming it (the exporters'
    first check)."""
    if not isinstance(result, PlanResult):
        raise ConfigError(f"result: expected a PlanResult, got {type(result).__name__}.")
    return result
