"""GA-TSP PMHT smoothed: a tour turned into hard ordering constraints (docs/model.md section 10).

The paper feeds a GA tour to the PMHT planner through its priors: ``pi^k[n, m] = 1`` for the tour's
platform, and ``pi^tau[n, .]`` uniform on the locale's *sub-batch* (the platform's horizon cut into one
window per locale, in tour order) and zero elsewhere. That makes the order likely, not certain: a
locale can still be passed at a distance. Here the tour is also a constraint: in every M-step, each
locale must be within ``visit_radius`` of its platform at one time step inside its own sub-batch,
the step the E-step finds most probable (re-chosen every iteration). Sub-batches are disjoint and
ordered, so the returned paths pass the locales in tour order, guaranteed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from pmht_opt.constraints.base import ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import DEFAULT_SIDES, Block
from pmht_opt.constraints.params import positive_number
from pmht_opt.constraints.visits import VisitAll
from pmht_opt.em import EMCallbacks, EMRun, with_progress
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import POS, STATE_DIM, VEL
from pmht_opt.ordering.tour import TourResult, check_routes
from pmht_opt.planner import PMHTConfig, ProgressCallback
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.stopping import Converged

#: When :func:`plan_smoothed` stops by default: the tour fixes the assignment, so once the visits are
#: at full strength the paths only polish; a position change below 3e-4 of the area for three
#: iterations marks the end of that.
SMOOTHED_CONVERGED = Converged(path_rtol=3e-4, stable=3)

#: How a platform's horizon is cut into sub-batches.
SPLITS = ("equal", "distance")
#: Weights held at once while the visit steps are chosen (entries of a block of locales' ``(T, M)`` rows).
VISIT_BLOCK = 1 << 19


def sub_batches(scenario: Scenario, routes: Sequence[np.ndarray], split: str = "equal") -> np.ndarray:
    """``(N, 2)`` first and last time step (inclusive, ``1..T``) of each locale's sub-batch.

    ``"equal"`` (the paper) gives every locale of a route the same number of steps; ``"distance"``
    makes each window proportional to the leg that ends at the locale (start to first locale, then
    consecutive locales), so a long leg gets more time.
    """
    if split not in SPLITS:
        raise ConfigError(f"split: expected one of {SPLITS}, got {split!r}.")
    T = scenario.horizon
    out = np.zeros((scenario.n_locales, 2), dtype=int)
    for m, route in enumerate(routes):
        L = len(route)
        if L == 0:
            continue
        if L > T:
            raise ConfigError(f"platform {m} has {L} locales but the horizon has only {T} steps.")
        if split == "equal":
            share = np.ones(L)
        else:
            pts = np.vstack([scenario.start_positions[m][None, :], scenario.locales[route]])
            share = np.hypot(*np.diff(pts, axis=0).T) + 1e-9
        edges = np.concatenate([[0.0], np.cumsum(share)]) / share.sum() * T
        bounds = np.round(edges).astype(int)
        # Every window keeps at least one step.
        for k in range(1, L + 1):
            bounds[k] = min(max(bounds[k], bounds[k - 1] + 1), T - (L - k))
        out[route, 0] = bounds[:-1] + 1
        out[route, 1] = bounds[1:]
    return out


class TourVisits(VisitAll):
    """Each locale within ``radius`` of its tour platform at one step of its sub-batch.

    :class:`~pmht_opt.constraints.VisitAll` with the visits fixed by the tour: the platform is the
    tour's, and the step is the E-step's most probable one inside the locale's window (re-chosen
    every iteration). Imposed from the first iteration. Used by :func:`plan_smoothed`. The paths are
    not kept near the area by default (``keep_within=None``): the windows follow the tour, whose
    polyline stays inside it, so the visits never ask for the loops that fixed MAP times can.
    """

    def __init__(
        self,
        platform: np.ndarray,
        windows: np.ndarray,
        radius: float | None = None,
        sides: int = DEFAULT_SIDES,
        **kwargs: Any,
    ) -> None:
        kwargs.setdefault("keep_within", None)
        super().__init__(radius, warmup=0, sides=sides, ramp=0, **kwargs)
        self.platform = np.asarray(platform, dtype=int)
        self.windows = np.asarray(windows, dtype=int)

    def visits(self, ctx: ConstraintContext) -> tuple[np.ndarray, np.ndarray]:
        if ctx.estep is None:
            raise ConfigError("TourVisits needs the E-step result; it can only be used inside the planner.")
        es = ctx.estep
        N = self.platform.shape[0]
        T = es.n_times
        steps = np.arange(1, T + 1)
        times = np.empty(N, dtype=int)
        # Locales a block at a time: rows of (T, M) weights each, a few MiB at most.
        chunk = max(1, VISIT_BLOCK // (T * es.n_platforms))
        for lo in range(0, N, chunk):
            hi = min(lo + chunk, N)
            own = es.locales_weights(lo, hi)[np.arange(hi - lo), :, self.platform[lo:hi]]  # (k, T)
            window = self.windows[lo:hi]
            inside = (steps >= window[:, :1]) & (steps <= window[:, 1:])
            # The first most probable step inside each window (weights are finite and >= 0).
            times[lo:hi] = 1 + np.argmax(np.where(inside, own, -np.inf), axis=1)
        return self.platform, times

    def visit_blocks(self, ctx: ConstraintContext) -> list[Block]:
        out = super().visit_blocks(ctx)
        for blk in out:
            # The visit step moves inside the locale's window from one iteration to the next.
            blk.span = self.windows[np.flatnonzero(self.platform == blk.platform)]
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        report = super().violation(states, ctx)
        _, times = self.visits(ctx)
        inside = (times >= self.windows[:, 0]) & (times <= self.windows[:, 1])
        report.details["times_in_sub_batch"] = int(np.sum(inside))
        return report


def _polyline_start(scenario: Scenario, routes: list[np.ndarray], windows: np.ndarray) -> np.ndarray:
    """Paths along the tour: straight legs reaching each locale at the middle of its sub-batch."""
    M, T = scenario.n_platforms, scenario.horizon
    x0 = scenario.initial_states
    paths = np.repeat(x0[:, None, :], T + 1, axis=1)
    t_grid = np.arange(T + 1, dtype=float)
    for m, route in enumerate(routes):
        if len(route) == 0:
            continue
        knots_t = np.concatenate([[0.0], windows[route].mean(axis=1), [float(T)]])
        pts = np.vstack([scenario.start_positions[m], scenario.locales[route], scenario.locales[route[-1]]])
        pos = np.stack([np.interp(t_grid, knots_t, pts[:, k]) for k in range(2)], axis=1)
        vel = np.gradient(pos, scenario.dt, axis=0)
        body = paths[m, 1:]  # a view
        body[:] = 0.0
        body[:, POS] = pos[1:]
        body[:, VEL] = vel[1:]
    paths[:, 0, :] = x0
    assert paths.shape == (M, T + 1, STATE_DIM)
    return paths


def _same_places(a: Scenario | None, b: Scenario) -> bool:
    """Whether a tour ordered on ``a`` (``None``: unknown) is one of ``b``'s locales and starts."""
    if a is None or a is b:
        return True
    return bool(np.array_equal(a.locales, b.locales) and np.array_equal(a.start_positions, b.start_positions))


def plan_smoothed(
    scenario: Scenario,
    tour: TourResult | Sequence[Any],
    config: PMHTConfig | None = None,
    visit_radius: float | None = None,
    *,
    split: str = "equal",
    sides: int = DEFAULT_SIDES,
    callback: ProgressCallback | None = None,
    callbacks: EMCallbacks | None = None,
    converge: Converged | None = SMOOTHED_CONVERGED,
) -> PlanResult:
    """Smooth paths that pass every locale in the order of ``tour`` (GA-TSP PMHT smoothed).

    Parameters
    ----------
    scenario
        The locales, starts and model.
    tour
        A :class:`~pmht_opt.ordering.TourResult` (e.g. from :func:`~pmht_opt.order_locales`) or one
        sequence of locale indices per platform, in visiting order.
    config
        Planner settings (solver, iterations, extra constraints such as a
        :class:`~pmht_opt.constraints.SpeedLimit`). Both prior updates and annealing are switched
        off: the tour fixes the assignment and the order, which is what they exist to find.
    visit_radius
        Each locale is passed within this distance, at a step inside its sub-batch; default: the
        scenario's :attr:`~pmht_opt.Scenario.coverage_radius`.
    split
        How each platform's horizon is cut into sub-batches: ``"equal"`` (the paper) or
        ``"distance"`` (proportional to the legs of the tour).
    sides
        Sides of the inner polygon standing in for the visit disc on a backend without cones.
    callback
        Called as ``callback(iteration, objective)`` after every iteration.
    callbacks
        Observers of the EM run (:class:`~pmht_opt.em.EMCallbacks`).
    converge
        Stop once the paths have settled (:class:`~pmht_opt.stopping.Converged`), within the
        configuration's iteration limit; ``None`` runs every iteration. The default
        (:data:`SMOOTHED_CONVERGED`) was chosen on recorded runs of A, B and C: it stops after about
        30 iterations instead of 100, with total distances within 0.15% of the 100-iteration plans and
        the same coverage (docs/decisions.md).

    Returns
    -------
    PlanResult
        The paths; ``assignment`` is the tour's platform and ``visit_time`` the enforced visit step of
        each locale; ``extras`` holds ``routes`` and ``sub_batches``.

    Raises
    ------
    InfeasibleError
        If the visits cannot be met together with the configuration's other constraints; the
        message names the platform and the locales.
    """
    routes = check_routes(scenario, tour.routes if isinstance(tour, TourResult) else tour)
    if isinstance(tour, TourResult) and not _same_places(tour.scenario, scenario):
        raise ConfigError(
            "tour: it was ordered for a scenario with other locales or starts than this one; order this "
            "scenario's locales (or pass the routes themselves)."
        )
    if converge is not None and not callable(converge):
        raise ConfigError(
            f"converge: expected a stopping criterion such as Converged(...) or None, got {converge!r}."
        )
    cfg = config if config is not None else PMHTConfig()
    if not isinstance(cfg, PMHTConfig):
        raise ConfigError(f"config must be a PMHTConfig, got {type(cfg).__name__}.")
    if visit_radius is None:
        visit_radius = scenario.coverage_radius
    visit_radius = positive_number("visit_radius", visit_radius)
    windows = sub_batches(scenario, routes, split)
    N, M, T = scenario.n_locales, scenario.n_platforms, scenario.horizon
    platform = np.empty(N, dtype=int)
    for m, route in enumerate(routes):
        platform[route] = m
    visits = TourVisits(platform, windows, visit_radius, sides=sides)
    run_cfg = dataclasses.replace(
        cfg,
        update_time_prior=False,
        update_platform_prior=False,
        anneal=None,
        constraints=(*cfg.constraints, visits),
        stop=cfg.stop if converge is None else (*cfg.stop, converge),
    )
    time_prior = np.zeros((N, T))
    for n, (lo, hi) in enumerate(windows):
        time_prior[n, lo - 1 : hi] = 1.0
    platform_prior = np.zeros((N, M))
    platform_prior[np.arange(N), platform] = 1.0
    with EMRun(
        scenario,
        run_cfg,
        time_prior=time_prior,
        platform_prior=platform_prior,
        initial_paths=_polyline_start(scenario, routes, windows),
        callbacks=with_progress(callbacks, callback),
    ) as run:
        result = run.run()
        ctx = run.last_context
    assert ctx is not None
    result.assignment = platform
    result.visit_time = visits.visits(ctx)[1]
    result.extras.update({"routes": routes, "sub_batches": windows, "visit_radius": visits.radius})
    return result
