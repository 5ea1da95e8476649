"""Smooth paths that follow straight-line tours closely and meet every locale's disc.

Each platform's route is flown along its polyline (:mod:`~pmht_opt.planners.coverage.flight`): the
positions it reaches at every step are synthetic measurements of the model's smoother, one per step,
weighted by the smoothing rule; every locale's disc, at its full radius, is a hard constraint at the
step the motion reaches its visit point (:class:`~pmht_opt.planners.coverage.discs.VisitDiscs`), with
the user's constraints beside it. That is the M-step of docs/model.md section 4.4 with fixed weights:
it is solved a few times, each moving every disc's step to where the last path passes closest (and
re-linearising the constraints that depend on the path, such as obstacles). The M-step's backend
checks each answer against the exact smoother; the returned plan is verified on its positions
(:func:`pmht_opt.verify.verify_plan`) and every locale's coverage is measured on its segments.
"""

from __future__ import annotations

import copy
import time

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.exceptions import InfeasibleError, SolverError
from pmht_opt.geometry import missed_locales
from pmht_opt.model import POS, VEL
from pmht_opt.mstep import MStep, MStepData, MStepOutput, make_mstep, mstep_objective
from pmht_opt.parallel import usable_cores
from pmht_opt.planners.coverage.discs import VisitDiscs
from pmht_opt.planners.coverage.flight import (
    SmoothingModel,
    SpeedProfile,
    retime,
    smoothing_model,
    visit_steps,
    visit_times,
)
from pmht_opt.planners.routes import CRUISE_SHARE, ramp_steps, speed_limits, terminal_ends
from pmht_opt.result import IterationHistory, PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import Settings
from pmht_opt.tours import DiscTours
from pmht_opt.verify import verify_plan

#: How close (relative to the tour's size) a visit point lies to the segment it is placed on.
ON_POLYLINE = 1e-9
#: How far inside their radii (relative) the discs are imposed again when a backend's answer misses
#: one by its own tolerance.
TIGHTEN = 1e-4
#: A locale's disc may be met up to ``T // WINDOW_FRACTION`` steps from where the tour meets it.
WINDOW_FRACTION = 25


class Track:
    """The motion along each route (synthetic measurements) and the steps at which discs are met."""

    def __init__(
        self, scenario: Scenario, tours: DiscTours, ends: np.ndarray, at_rest: bool, vmax: np.ndarray
    ) -> None:
        T, N, M = scenario.horizon, scenario.n_locales, scenario.n_platforms
        self.reserve = max(1, T // 10) if at_rest else 0
        available = max(T - self.reserve, 1)
        self.positions = np.repeat(scenario.start_positions[:, None, :], T + 1, axis=1)
        self.visit_time = np.ones(N, dtype=int)
        self.platform = np.zeros(N, dtype=int)
        self.lengths = np.zeros(M)
        #: Steps each platform takes to fly its route (it holds its last point after them).
        self.steps = np.full(M, available)
        self.polylines: list[np.ndarray] = []
        t_grid = np.arange(1, T + 1, dtype=float)
        for m in range(M):
            poly = tours.vertices(m)
            if not np.any(np.isnan(ends[m])) and not np.allclose(poly[-1], ends[m]):
                poly = np.vstack([poly, ends[m]])  # an end other than the start: flown to last
            self.polylines.append(poly)
            arcs = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poly, axis=0).T))])
            self.lengths[m] = arcs[-1]
            route = np.asarray(tours.routes[m], dtype=int)
            self.platform[route] = m
            if arcs[-1] <= 0.0:
                continue  # idle: holds its start
            steps, ramp_out = available, at_rest
            if np.isfinite(vmax[m]):  # at its cruise speed under the limit, then at rest
                ramp = ramp_steps(T, available)
                need = arcs[-1] / (CRUISE_SHARE * vmax[m] * scenario.dt) + ramp
                steps, ramp_out = int(min(available, np.ceil(need))), True
            self.steps[m] = steps
            ramp = ramp_steps(T, steps)
            profile = SpeedProfile(float(arcs[-1]), steps, ramp, ramp if ramp_out else 0)
            clock = np.minimum(t_grid, steps)
            if route.size:
                s = _arc_of(poly, arcs, tours.points[route])
                # The turns (the polyline's inner vertices) each take a step of their own, so the
                # samples pass through every corner; the visits between them lie on straight legs,
                # which a segment of the path covers at any fraction (VisitDiscs).
                turns = arcs[1:-1]
                apart = np.ones(turns.size, dtype=bool)
                apart[1:] = np.diff(turns) > 1e-9 * max(arcs[-1], 1e-300)
                reached = profile.time(turns)
                kept = visit_steps(visit_times(reached, steps, apart), steps).astype(float)
                clock = retime(clock, reached, kept, steps)
                self.visit_time[route] = visit_steps(
                    retime(profile.time(s), reached, kept, steps, inverse=True), steps
                )
            along = profile.arc(clock)
            self.positions[m, 1:] = np.column_stack(
                [np.interp(along, arcs, poly[:, 0]), np.interp(along, arcs, poly[:, 1])]
            )

    def initial_states(self, scenario: Scenario) -> np.ndarray:
        """``(M, T+1, 6)`` the motion as states (positions, and velocities by differences)."""
        states = np.repeat(scenario.initial_states[:, None, :], scenario.horizon + 1, axis=1)
        states[:, 1:, :] = 0.0
        states[:, 1:, POS] = self.positions[:, 1:]
        states[:, 1:, VEL] = np.gradient(self.positions, scenario.dt, axis=1)[:, 1:]
        return states


def _arc_of(poly: np.ndarray, arcs: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Arc length along ``poly`` (cumulative ``arcs``) of the points on it, in route order: each is
    placed on the first segment, at or after the previous point's, that it lies on (to rounding; a
    closed route passes its start twice), or else the nearest."""
    out = np.zeros(points.shape[0])
    on = ON_POLYLINE * max(float(arcs[-1]), float(np.max(np.abs(poly))), 1e-300)
    lo = 0
    for k, p in enumerate(points):
        a, b = poly[lo:-1], poly[lo + 1 :]
        d = b - a
        len2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
        u = np.clip(np.einsum("ij,ij->i", p - a, d) / len2, 0.0, 1.0)
        gap = np.hypot(*(a + u[:, None] * d - p).T)
        hits = np.flatnonzero(gap <= on)
        j = int(hits[0]) if hits.size else int(np.argmin(gap))
        out[k] = arcs[lo + j] + u[j] * np.sqrt(len2[j])
        lo += j
    return np.maximum.accumulate(out)


def fly(
    scenario: Scenario,
    tours: DiscTours,
    settings: Settings,
    smoothing: float,
    iterations: int,
) -> PlanResult:
    """Smooth paths along ``tours``, every locale within its radius of its route's platform.

    Raises :class:`~pmht_opt.exceptions.InfeasibleError` (from the M-step's diagnosis) when the discs
    cannot be met together with the user's constraints along these routes, and
    :class:`~pmht_opt.exceptions.SolverError` when a backend fails or the plan does not pass its checks.
    """
    t0 = time.perf_counter()
    ends, at_rest = terminal_ends(scenario, settings.constraints)
    track = Track(scenario, tours, ends, at_rest, speed_limits(scenario, settings.constraints))
    T, M, N = scenario.horizon, scenario.n_platforms, scenario.n_locales
    speeds = track.lengths / (track.steps * scenario.dt)
    model = smoothing_model(speeds, scenario.dt, scenario.radii, smoothing)
    flown = scenario.replace(q=model.q, r=model.r)
    window = max(1, T // WINDOW_FRACTION)
    discs = VisitDiscs(track.platform, track.visit_time, scenario.locales, scenario.radii, window)
    constraints = (*settings.constraints, discs)
    W, WZ = _measurements(track, model, T)
    states = track.initial_states(scenario)
    objectives, times, statuses, fallbacks, counts = [], [], [], [], []
    threads = settings.threads if settings.threads is not None else min(M, usable_cores())
    mstep = _mstep(flown, settings, threads, constraints)
    active = tuple(range(len(constraints)))
    solver = str(getattr(mstep, "solver", mstep.name))
    tightened = False
    reports: tuple[ConstraintReport, ...] | None = None

    def step(it: int, mstep: MStep) -> None:
        nonlocal states
        ctx = ConstraintContext(scenario=flown, states=states, iteration=it)
        start = time.perf_counter()
        data = MStepData(W=W, WZ=WZ, r=model.r, ctx=ctx, active=active)
        try:
            out = mstep.solve(data)
        except SolverError:
            if it > 1 or iterations < 2:
                raise  # later iterations start from a path that meets their points
            out = _soft_start(flown, settings, constraints, threads, data)
        times.append(time.perf_counter() - start)
        states = out.states
        objectives.append(_objective(flown, states, W, WZ, model))
        statuses.append(out.status)
        fallbacks.append(out.fallbacks)
        counts.append(out.iterations)

    try:
        for it in range(1, iterations + 1):
            step(it, mstep)
        reports = _verified(solver, scenario, flown, constraints, states, iterations, raise_=False)
        if reports is None:
            # A backend's answer can miss a disc by its own feasibility tolerance, beyond the 1e-5
            # back-off of hard rows (an interior point that reports success with a cone met to 1e-6 of
            # its radius); one more M-step with every disc imposed TIGHTEN further inside its radius
            # keeps such an error inside. Not the default: a tangent disc must be met at its full radius.
            tightened = True
            mstep.close()
            mstep = _mstep(flown, settings, threads, (*settings.constraints, discs.tightened(TIGHTEN)))
            step(iterations + 1, mstep)
    except InfeasibleError as err:
        # The discs at these routes' points and times are one way to cover the locales, not the only
        # one: not a proof that the user's constraints cannot be met.
        raise SolverError(
            f"the routes found could not be flown within the constraints ({err}); the constraints "
            "themselves were not shown to be infeasible.",
            backend=err.backend,
            status="schedule infeasible",
        ) from err
    finally:
        mstep.close()
    done = len(objectives)
    if reports is None:  # the tightened fit, verified against the discs at their full radii
        reports = _verified(solver, scenario, flown, constraints, states, done, raise_=True)
    assert reports is not None
    missed = missed_locales(scenario.locales, states[:, :, POS], scenario.radii)
    if missed.size:
        raise SolverError(
            f"{solver}: locales {missed.tolist()} are further than their radius from every path.",
            backend=solver,
        )
    history = IterationHistory(
        objective=np.array([np.nan, *objectives]),
        estep_time=np.zeros(done + 1),
        mstep_time=np.array(times),
        solver_iterations=np.array(counts, dtype=int),
        r=np.full(done + 1, model.r),
        fallbacks=np.array(fallbacks, dtype=int),
        mstep_status=tuple(statuses),
        estep_gated=np.zeros(done + 1, dtype=bool),
        stop_reason="MaxIterations",
    )
    prior = np.zeros((N, M))
    prior[np.arange(N), track.platform] = 1.0
    return PlanResult(
        scenario=scenario,
        states=states,
        assignment=track.platform,
        visit_time=discs.visit_points(states[:, :, POS], T)[0],
        platform_prior=prior,
        history=history,
        converged=False,
        wall_time=time.perf_counter() - t0,
        solver=solver,
        constraints=constraints,
        reports=reports,
        planner="coverage",
        extras={
            "routes": [np.asarray(r) for r in tours.routes],
            "visit_points": tours.points,
            "tour": [p.copy() for p in track.polylines],
            "tour_length": float(track.lengths.sum()),
            "tour_lengths": track.lengths.copy(),
            "flight_steps": track.steps.copy(),
            "tightened": tightened,
            "smoothing": {"factor": smoothing, "q": model.q, "r": model.r, "weights": model.weights.tolist()},
        },
    )


def _verified(
    solver: str,
    scenario: Scenario,
    flown: Scenario,
    constraints: tuple[Constraint, ...],
    states: np.ndarray,
    iteration: int,
    raise_: bool,
) -> tuple[ConstraintReport, ...] | None:
    """Every constraint's report on ``states``, verified (:func:`pmht_opt.verify.verify_plan`): its
    ``SolverError`` raised, or ``None`` returned when ``raise_`` is false. States that are not finite
    are a ``SolverError`` either way."""
    if not np.all(np.isfinite(states)):
        raise SolverError(f"{solver}: the coverage plan is not finite.", backend=solver)
    ctx = ConstraintContext(scenario=flown, states=states, iteration=iteration)
    reports = tuple(c.violation(states, ctx) for c in constraints)
    try:
        verify_plan(solver, scenario, constraints, reports)
    except SolverError:
        if raise_:
            raise
        return None
    return reports


def _mstep(flown: Scenario, settings: Settings, threads: int, constraints: tuple[Constraint, ...]) -> MStep:
    """The M-step of the flight with ``constraints`` (the user's and the discs, as imposed)."""
    return make_mstep(
        flown, settings.solver, settings.solver_settings, settings.accept_inaccurate, threads, constraints
    )


def _soft_start(
    flown: Scenario, settings: Settings, constraints: tuple[Constraint, ...], threads: int, data: MStepData
) -> MStepOutput:
    """The first M-step again with the discs soft (an exact L1 penalty on how far each misses).

    The first iteration's points come from the motion along the tour, whose chords can lie nearest to
    many discs at once where the tour winds through densely overlapping ones: points at fixed
    fractions of one segment then cannot always lie in all of them, and the hard M-step fails. Its
    soft version always has an answer, a path that meets the discs where it can; the next iteration
    imposes them hard again at that path's nearest points, and only hard answers are returned.
    """
    *user, discs = constraints
    soft = copy.copy(discs)
    soft.soft = True
    mstep = _mstep(flown, settings, threads, (*user, soft))
    try:
        return mstep.solve(data)
    finally:
        mstep.close()


def _measurements(track: Track, model: SmoothingModel, T: int) -> tuple[np.ndarray, np.ndarray]:
    """``W (T, M)`` and ``WZ (T, M, 2)`` of the motion along every route, weighted by the rule."""
    M = track.positions.shape[0]
    W = np.repeat(model.weights[None, :], T, axis=0)
    WZ = W[..., None] * track.positions[:, 1:].transpose(1, 0, 2)
    assert W.shape == (T, M)
    return W, WZ


def _objective(
    scenario: Scenario, states: np.ndarray, W: np.ndarray, WZ: np.ndarray, model: SmoothingModel
) -> float:
    """The M-step's cost of ``states`` (smaller is better)."""
    return float(mstep_objective(scenario.model, states, W, WZ, model.r))


__all__ = ["fly"]
