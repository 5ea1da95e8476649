"""The M-steps the solver study solves: two consecutive iterations of a real EM run, and constraints.

Single M-steps are only comparable when their weights are those a plan really meets, so they are
taken from a run of the planner itself (:class:`pmht_opt.EMRun`), never re-implemented here: the
default (annealed) plan with the kalman M-step is stepped to iteration ``K - 1``, and the E-steps
feeding the M-steps of iterations ``K`` and ``K + 1`` are kept with the paths they were computed
from. A backend solves iteration ``K`` first, so a warm-starting backend meets iteration ``K + 1`` as
it would inside a plan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmht_opt import EMRun, PMHTConfig, Scenario, paper_scenario
from pmht_opt.constraints import AreaBounds, CircleObstacle, Constraint, ConstraintContext, SpeedLimit
from pmht_opt.estep import EStepResult
from pmht_opt.model import VEL
from pmht_opt.mstep import MStepData

#: Unconstrained iterates: stage name -> EM iteration ``K`` whose successor is the measured M-step.
STAGES: dict[str, int] = {"early": 5, "late": 40}
QUICK_STAGES: dict[str, int] = {"early": 3, "late": 12}
#: Constrained cases, built on the late iterate.
CONSTRAINED_CASES = ("speed+area", "obstacle")
#: Speed limit of the constrained case, as a fraction of the unconstrained answer's top speed: low
#: enough that the limit binds on every scenario.
SPEED_FRACTION = 0.7
OBSTACLE_RADIUS = 1.5
#: Candidate obstacle centres; the first one no start is near is used (a start inside an obstacle is
#: a bad scenario).
OBSTACLE_CENTRES = ((5.0, 5.0), (5.0, 3.5), (3.5, 5.0), (6.5, 5.0), (5.0, 6.5))


def study_scenario(kind: str, seed: int, horizon: int | None = None) -> Scenario:
    """Paper scenario ``kind`` (seed ``seed``), optionally with a shorter horizon."""
    if horizon is None:
        return paper_scenario(kind, seed=seed)
    return paper_scenario(kind, seed=seed, horizon=int(horizon))


@dataclass(frozen=True)
class Step:
    """What one M-step of an EM run is solved from.

    Attributes
    ----------
    states
        ``(M, T+1, 6)`` paths before the M-step: the linearisation point of its constraints.
    estep
        The E-step of those paths, whose weights the M-step fits.
    r
        The iteration's penalty.
    iteration
        The EM iteration of the M-step (``1..``).
    """

    states: np.ndarray
    estep: EStepResult
    r: float
    iteration: int

    def data(self, scenario: Scenario, constraints: tuple[Constraint, ...] = ()) -> MStepData:
        """The M-step's input, with every one of ``constraints`` imposed."""
        es = self.estep
        if not constraints:
            return MStepData(W=es.W, WZ=es.WZ, r=self.r)
        ctx = ConstraintContext(scenario=scenario, states=self.states, estep=es, iteration=self.iteration)
        return MStepData(W=es.W, WZ=es.WZ, r=self.r, ctx=ctx, active=tuple(range(len(constraints))))


@dataclass(frozen=True)
class Iterate:
    """Two consecutive M-steps of a real EM run: iteration ``K`` (``prev``) and ``K + 1`` (``cur``)."""

    scenario: Scenario
    prev: Step
    cur: Step

    @property
    def iteration(self) -> int:
        """``K``."""
        return self.prev.iteration


def _step(run: EMRun) -> Step:
    """The M-step ``run`` is about to solve."""
    it = run.iteration + 1
    return Step(states=run.states, estep=run.estep, r=run.schedule.r_at(it), iteration=it)


def make_iterate(scenario: Scenario, iteration: int) -> Iterate:
    """The M-steps of iterations ``K = max(iteration, 2)`` and ``K + 1`` of the default plan.

    The plan uses the kalman M-step (exact) and the default configuration (its budget and annealing
    schedule), stepped ``K + 1`` times: the E-step after iteration ``K`` is at iteration ``K + 1``'s
    penalty, as inside the whole plan.
    """
    K = max(int(iteration), 2)
    with EMRun(scenario, PMHTConfig(solver="kalman")) as run:
        for _ in range(K - 1):
            run.step()
        prev = _step(run)
        run.step()
        cur = _step(run)
    return Iterate(scenario=scenario, prev=prev, cur=cur)


def max_speed(states: np.ndarray) -> float:
    """Largest speed over platforms and times of ``(M, T+1, 6)`` states."""
    v = states[:, :, VEL]
    return float(np.max(np.hypot(v[..., 0], v[..., 1])))


def case_constraints(case: str, scenario: Scenario, free_states: np.ndarray) -> tuple[Constraint, ...]:
    """The constraints of a constrained case, sized from the unconstrained answer ``free_states``.

    The area is the scenario's, grown to contain the starts (scenario B starts outside it).
    """
    starts = scenario.start_positions
    bounds = scenario.bounds if scenario.bounds is not None else (0.0, 10.0, 0.0, 10.0)
    box = (
        min(bounds[0], float(starts[:, 0].min())),
        max(bounds[1], float(starts[:, 0].max())),
        min(bounds[2], float(starts[:, 1].min())),
        max(bounds[3], float(starts[:, 1].max())),
    )
    if case == "speed+area":
        return (SpeedLimit(SPEED_FRACTION * max_speed(free_states)), AreaBounds(*box))
    if case == "obstacle":
        for centre in OBSTACLE_CENTRES:
            if np.min(np.hypot(*(starts - np.array(centre)).T)) > OBSTACLE_RADIUS + 0.25:
                return (CircleObstacle(centre, OBSTACLE_RADIUS),)
        return (CircleObstacle(OBSTACLE_CENTRES[0], 0.5),)
    raise ValueError(f"unknown constrained case {case!r}")
