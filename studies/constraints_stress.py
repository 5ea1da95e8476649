"""Study: do the constraints hold, whatever the user asks? Sweeps from generous to infeasible, every backend.

Each trial plans one scenario under one constraint case with one backend and sorts the outcome into

- ``solved``: a plan came back. The study then measures every hard constraint *again* on the returned
  positions, with its own geometry (below), independent of both the solver and the planner's own
  verification, and records the worst violation relative to the constraint's size;
- ``infeasible``: :class:`~pmht_opt.InfeasibleError`, which must name a constraint and is raised only
  on a proof (a pre-check, or a phase-one problem over constraints that are exactly convex);
- ``unproven``: :class:`~pmht_opt.ScheduleError`: the solver and the diagnosis found no plan on the
  steps and sides this iteration chose (a keep-out zone's side, a visit's step), which is not a proof
  that none exists;
- ``failed``: any other :class:`~pmht_opt.PmhtOptError` (a solver that gave up, a plan that failed its
  verification).

Cases (``CASES``) sweep speed limits (generous to very tight; starts at rest keep them feasible),
acceleration limits, a circular and a square keep-out zone of growing size placed where no platform
starts, guaranteed visits of shrinking radius, and combinations with a known answer: a speed limit that
leaves far too little travel for the visits, a visit disc inside an obstacle, an acceleration limit
too small to reach the visits, and an end behind a wall too long to go round at the speed limit (all
infeasible; the pre-checks prove the first three, only a solver and the diagnosis find the last, and as
the wall is not convex they can name it but not prove it).
Scenarios: the paper's A, B, C (seed 0) and an irregular one, ``L``: 40 locales along the two arms of an
L, two platforms starting at its inside corner, ``T = 300``.

The independent measurements on the positions are :func:`studies.constraint_measures.measure`.
A violation counts when it exceeds the planner's stated tolerance for the backend
(:data:`pmht_opt.verify.RTOL`) times the constraint's size (the limit, the radius).

    pmht-opt study constraints_stress --workers 2 --out studies/results/constraints_stress
    python studies/constraints_stress.py [--backends clarabel osqp cvxpy] [--kinds A B C L]
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import pmht_opt as po
from pmht_opt.em import EMCallbacks
from pmht_opt.verify import RTOL
from studies.constraint_measures import measure
from studies.options import Choices, StudyOptions, option
from studies.report import Columns, frame, markdown_table
from studies.trials import CONSTRAINED, ERROR_COLUMNS, OUTCOME_CHECKS, Check, TrialTable

KINDS = ("A", "B", "C", "L")
BACKENDS = ("clarabel", "osqp", "cvxpy")


def l_shaped() -> po.Scenario:
    """The irregular scenario: 40 locales on the arms of an L, two platforms at its inside corner."""
    arm1 = np.column_stack([np.linspace(0.0, 9.0, 20), np.zeros(20)])
    arm2 = np.column_stack([np.zeros(20), np.linspace(0.5, 9.5, 20)])
    locales = np.vstack([arm1, arm2]) + 0.5
    return po.Scenario(
        locales=locales,
        starts=np.array([[5.0, 5.0], [6.0, 6.0]]),
        horizon=300,
        bounds=(0.0, 10.0, 0.0, 10.0),
        name="L",
    )


def scenario(kind: str) -> po.Scenario:
    """Scenario ``kind``: the paper's A, B or C with seed 0, or the L-shaped one."""
    return l_shaped() if kind == "L" else po.paper_scenario(kind, seed=0)


def free_spot(sc: po.Scenario) -> tuple[np.ndarray, float]:
    """The point of a 9 x 9 grid over the area farthest from every start, and that distance."""
    b = sc.bounds or (0.0, 10.0, 0.0, 10.0)
    gx, gy = np.meshgrid(np.linspace(b[0], b[1], 9), np.linspace(b[2], b[3], 9))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    starts = sc.initial_states[:, [0, 3]]
    d = np.min(np.linalg.norm(grid[:, None, :] - starts[None, :, :], axis=2), axis=1)
    i = int(np.argmax(d))
    return grid[i], float(d[i])


def _square(center: np.ndarray, half: float) -> np.ndarray:
    c = np.asarray(center, dtype=float)
    return c + half * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])


def _locale_obstacle(sc: po.Scenario) -> list[po.Constraint]:
    """A disc of radius 0.5 around the locale farthest from every start, with every locale visited."""
    starts = sc.initial_states[:, [0, 3]]
    d = np.min(np.linalg.norm(sc.locales[:, None, :] - starts[None, :, :], axis=2), axis=1)
    n = int(np.argmax(d))
    return [po.CircleObstacle(sc.locales[n], min(0.5, 0.5 * float(d[n]))), po.VisitAll(0.05)]


def _walled_end(sc: po.Scenario) -> list[po.Constraint]:
    """Platform 0 must end 3 units to the right of its start, beyond a wall 400 units long that starts 1
    unit to its right, at speed at most 0.5: going round takes far more travel than the horizon allows,
    while every straight-line pre-check passes. Only a solver finds this one."""
    s0 = sc.start_positions[0]
    x = float(s0[0]) + 1.0
    wall = [(x, -200.0), (x + 0.5, -200.0), (x + 0.5, 200.0), (x, 200.0)]
    return [
        po.PolygonObstacle(wall, platforms=[0]),
        po.SpeedLimit(0.5, platforms=[0]),
        po.Terminal(position=(float(s0[0]) + 3.0, float(s0[1])), platforms=[0]),
    ]


def _obstacle(shape: str, fraction: float) -> Callable[[po.Scenario], list[po.Constraint]]:
    def build(sc: po.Scenario) -> list[po.Constraint]:
        center, room = free_spot(sc)
        size = fraction * room
        if shape == "circle":
            return [po.CircleObstacle(center, size)]
        return [po.PolygonObstacle(_square(center, size / np.sqrt(2.0)))]

    return build


def _area_and_starts(sc: po.Scenario) -> po.AreaBounds:
    """The scenario's area grown to hold every start (B starts a unit outside it): a start outside
    the bounds is a ``ScenarioError`` by design, not a case of this sweep."""
    x0, x1, y0, y1 = sc.bounds or (0.0, 10.0, 0.0, 10.0)
    p = sc.start_positions
    return po.AreaBounds(
        min(x0, float(p[:, 0].min())),
        max(x1, float(p[:, 0].max())),
        min(y0, float(p[:, 1].min())),
        max(y1, float(p[:, 1].max())),
    )


def _const(*cons: Callable[[], po.Constraint]) -> Callable[[po.Scenario], list[po.Constraint]]:
    return lambda sc: [c() for c in cons]


@dataclass(frozen=True)
class Case:
    """A constraint case: how to build it for a scenario, and whether it is feasible (``None``: unknown)."""

    build: Callable[[po.Scenario], list[po.Constraint]]
    feasible: bool | None


CASES: dict[str, Case] = {
    "speed-0.5": Case(_const(lambda: po.SpeedLimit(0.5)), True),
    "speed-0.1": Case(_const(lambda: po.SpeedLimit(0.1)), True),
    "speed-0.05": Case(_const(lambda: po.SpeedLimit(0.05)), True),
    "speed-0.02": Case(_const(lambda: po.SpeedLimit(0.02)), True),
    "speed-1e-3": Case(_const(lambda: po.SpeedLimit(1e-3)), True),
    "accel-1e-2": Case(_const(lambda: po.AccelLimit(1e-2)), True),
    "accel-1e-3": Case(_const(lambda: po.AccelLimit(1e-3)), True),
    "accel-1e-5": Case(_const(lambda: po.AccelLimit(1e-5)), True),
    "accel-1e-9": Case(_const(lambda: po.AccelLimit(1e-9)), True),
    "circle-0.25": Case(_obstacle("circle", 0.25), True),
    "circle-0.5": Case(_obstacle("circle", 0.5), True),
    "circle-0.9": Case(_obstacle("circle", 0.9), True),
    "square-0.5": Case(_obstacle("square", 0.5), True),
    "square-0.9": Case(_obstacle("square", 0.9), True),
    "visit-0.5": Case(_const(lambda: po.VisitAll(0.5)), True),
    "visit-0.3": Case(_const(lambda: po.VisitAll(0.3)), True),
    "visit-0.1": Case(_const(lambda: po.VisitAll(0.1)), True),
    "visit-0.05": Case(_const(lambda: po.VisitAll(0.05)), True),
    "speed-0.2+visit-0.1": Case(_const(lambda: po.SpeedLimit(0.2), lambda: po.VisitAll(0.1)), None),
    "speed-0.1+area": Case(lambda sc: [po.SpeedLimit(0.1), _area_and_starts(sc)], True),
    "speed-1e-4+visit-0.05": Case(_const(lambda: po.SpeedLimit(1e-4), lambda: po.VisitAll(0.05)), False),
    "obstacle-on-locale+visit": Case(_locale_obstacle, False),
    "accel-1e-7+visit-0.1": Case(_const(lambda: po.AccelLimit(1e-7), lambda: po.VisitAll(0.1)), False),
    "walled-end": Case(_walled_end, False),
}


class MStepClock:
    """Wall time of each M-step of a plan, read from the EM loop's callbacks.

    An M-step runs from the E-step before it to its own end; a plan that stops inside an M-step (the
    solve failed) has that M-step end when the error reaches the study.
    """

    def __init__(self) -> None:
        self.started: float | None = None
        self.durations: list[float] = []
        self.callbacks = EMCallbacks(after_estep=self._start, after_mstep=self._stop)

    def _start(self, run: object, estep: object) -> None:
        self.started = time.perf_counter()

    def _stop(self, run: object, output: object) -> None:
        if self.started is not None:
            self.durations.append(time.perf_counter() - self.started)
        self.started = None

    def slowest(self, failed: bool) -> float | None:
        """The longest M-step (``None`` if none ran), counting one cut short by a failure."""
        if failed and self.started is not None:
            self._stop(None, None)
        return max(self.durations) if self.durations else None


def trial(kind: str, case: str, backend: str) -> dict[str, Any]:
    """Plan ``kind`` under ``case`` with ``backend``; the outcome and the independent measurements."""
    sc = scenario(kind)
    constraints = CASES[case].build(sc)
    cfg = po.PMHTConfig(solver=backend, constraints=constraints, threads=1)
    clock = MStepClock()
    t0 = time.perf_counter()
    row: dict[str, Any] = {
        "raised": None,
        "message": None,
        "violation": None,
        "worst": None,
        "distance": None,
        "coverage": None,
        "excursion": None,
    }
    try:
        res = po.plan_pmht(sc, cfg, callbacks=clock.callbacks)
    except po.InfeasibleError as err:
        row.update(outcome="infeasible", raised=type(err).__name__, message=str(err)[:300])
    except po.ScheduleError as err:
        row.update(outcome="unproven", raised=type(err).__name__, message=str(err)[:300])
    except po.PmhtOptError as err:
        row.update(outcome="failed", raised=type(err).__name__, message=str(err)[:300])
    else:
        measured = measure(sc, res.positions, constraints)
        worst = max(measured, key=lambda k: measured[k])
        row.update(
            outcome="solved",
            violation=max(measured[worst], 0.0),
            worst=worst,
            distance=res.total_distance,
            coverage=res.coverage(),
            excursion=res.max_excursion(),
        )
    row["seconds"] = time.perf_counter() - t0
    row["slowest_mstep"] = clock.slowest(failed=row["outcome"] != "solved")
    row["tolerance"] = RTOL.get(backend, 1e-6)
    feasible = CASES[case].feasible
    row["expected"] = "unknown" if feasible is None else ("feasible" if feasible else "infeasible")
    return row


#: What a trial records: its outcome against the expected one, the independent measurements of a plan
#: (the worst constraint, its relative violation, the tolerance it is held to) and the time it took.
RESULTS = {
    "outcome": "str",
    "expected": "str",
    **ERROR_COLUMNS,
    "violation": "float?",
    "worst": "str?",
    "tolerance": "float",
    "distance": "float?",
    "coverage": "float?",
    "excursion": "float?",
    "seconds": "float",
    "slowest_mstep": "float?",
}
TABLE = TrialTable.of(
    "constraints_stress",
    trial,
    RESULTS,
    {
        **OUTCOME_CHECKS,
        "slowest_mstep": Check("skip", reason="wall time"),
        "violation": Check("close", rtol=1e-3, atol=1e-9, reason="last digits of the solvers' iterates"),
        "distance": CONSTRAINED,
        "excursion": CONSTRAINED,
    },
)


def summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per backend and expected answer: counts of each outcome, violations past tolerance, time."""
    df = frame(rows)
    df = df[df["error"] == ""]
    out = []
    for (backend, expected), g in df.groupby(["backend", "expected"]):
        solved = g[g["outcome"] == "solved"]
        out.append(
            {
                "backend": backend,
                "expected": expected,
                "plans": len(g),
                "solved": len(solved),
                "infeasible_named": int((g["outcome"] == "infeasible").sum()),
                "unproven": int((g["outcome"] == "unproven").sum()),
                "failed": int((g["outcome"] == "failed").sum()),
                "violations_past_tolerance": int((solved["violation"] > solved["tolerance"]).sum()),
                "max_violation": float(solved["violation"].max()) if len(solved) else 0.0,
                "median_seconds": float(g["seconds"].median()),
                "max_seconds": float(g["seconds"].max()),
                "max_mstep_seconds": float(g["slowest_mstep"].max()),
                "failures": "; ".join(
                    f"{r.kind}/{r.case}: {r.raised}" for r in g[g["outcome"] == "failed"].itertuples()
                ),
            }
        )
    return out


#: The summary's markdown table.
COLUMNS: Columns = (
    ("backend", lambda s: s["backend"]),
    ("expected", lambda s: s["expected"]),
    ("plans", lambda s: s["plans"]),
    ("solved", lambda s: s["solved"]),
    ("infeasible named", lambda s: s["infeasible_named"]),
    ("unproven", lambda s: s.get("unproven", 0)),
    ("failed", lambda s: s["failed"]),
    ("violations past tolerance", lambda s: s["violations_past_tolerance"]),
    ("max rel. violation", lambda s: f"{s['max_violation']:.2e}"),
    ("median s", lambda s: f"{s['median_seconds']:.1f}"),
    ("max s", lambda s: f"{s['max_seconds']:.1f}"),
    ("slowest M-step s", lambda s: f"{s['max_mstep_seconds']:.1f}"),
    ("failures", lambda s: s["failures"] or "-"),
)


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The summary as a markdown table."""
    return markdown_table(COLUMNS, table)


@dataclass(frozen=True)
class Options(StudyOptions):
    """Options of ``pmht-opt study constraints_stress``."""

    backends: tuple[str, ...] = option(BACKENDS, Choices("--backends", known=BACKENDS))
    kinds: tuple[str, ...] = option(KINDS, Choices("--kinds", "scenarios", known=KINDS))
    cases: tuple[str, ...] = option(tuple(CASES), Choices("--cases", "constraint cases", known=tuple(CASES)))


def params(options: Options) -> list[dict[str, Any]]:
    """The trials of a run."""
    return [
        {"kind": k, "case": c, "backend": b}
        for b in options.backends
        for k in options.kinds
        for c in options.cases
    ]


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("constraints_stress", __file__)
