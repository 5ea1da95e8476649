"""The smoothed planner's sub-batches: each locale's window of time steps, and the visit constraint in it.

The paper feeds a tour to the PMHT planner through its priors: ``pi^k[n, m] = 1`` for the tour's
platform, and ``pi^tau[n, .]`` uniform on the locale's *sub-batch* (the platform's horizon cut into one
window per locale, in tour order) and zero elsewhere. :class:`TourVisits` makes the order certain:
each locale within its radius of its platform at one step inside its own window.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pmht_opt.constraints.base import ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import DEFAULT_SIDES, Block
from pmht_opt.constraints.visits import VisitAll
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import POS, STATE_DIM, VEL
from pmht_opt.scenario import Scenario

#: How a platform's horizon is cut into sub-batches.
SPLITS = ("equal", "distance")
#: Weights held at once while the visit steps are chosen (entries of a block of locales' ``(T, M)`` rows).
VISIT_BLOCK = 1 << 19


def sub_batches(
    scenario: Scenario,
    routes: Sequence[np.ndarray],
    split: str = "equal",
    closed: Sequence[bool] | np.ndarray | None = None,
) -> np.ndarray:
    """``(N, 2)`` first and last time step (inclusive, ``1..T``) of each locale's sub-batch.

    ``"equal"`` (the paper) gives every locale of a route the same number of steps; ``"distance"``
    makes each window proportional to the leg that ends at the locale (start to first locale, then
    consecutive locales), so a long leg gets more time. A route that returns to its start
    (``closed[m]``) keeps time for the leg home after its last window: the share of the horizon that
    leg's length has of the whole route (under ``"equal"``, the share of one more leg), so the path
    has the time to get home.
    """
    if split not in SPLITS:
        raise ConfigError(f"split: expected one of {SPLITS}, got {split!r}.")
    T = scenario.horizon
    home = np.zeros(scenario.n_platforms, dtype=bool) if closed is None else np.asarray(closed, dtype=bool)
    out = np.zeros((scenario.n_locales, 2), dtype=int)
    for m, route in enumerate(routes):
        L = len(route)
        if L == 0:
            continue
        if L > T:
            raise ConfigError(f"platform {m} has {L} locales but the horizon has only {T} steps.")
        start = scenario.start_positions[m][None, :]
        if split == "equal":
            share = np.ones(L + 1)
        else:
            pts = np.vstack([start, scenario.locales[route], start])
            share = np.hypot(*np.diff(pts, axis=0).T) + 1e-9
        if not home[m]:
            share = share[:L]
        edges = np.concatenate([[0.0], np.cumsum(share)]) / share.sum() * T
        bounds = np.round(edges[: L + 1]).astype(int)
        last = T - 1 if home[m] and L < T else T  # a closed route keeps a step at least for home
        # Every window keeps at least one step.
        for k in range(1, L + 1):
            bounds[k] = min(max(bounds[k], bounds[k - 1] + 1), last - (L - k))
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
        radius: float | np.ndarray | None = None,
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


def polyline_start(
    scenario: Scenario,
    routes: list[np.ndarray],
    windows: np.ndarray,
    split: str = "equal",
    closed: Sequence[bool] | np.ndarray | None = None,
) -> np.ndarray:
    """Paths along the tour: straight legs reaching each locale in its sub-batch (at its middle for
    ``"equal"``, at its end for ``"distance"``, whose windows are the legs that end there), and home at
    the horizon for a closed route."""
    M, T = scenario.n_platforms, scenario.horizon
    x0 = scenario.initial_states
    paths = np.repeat(x0[:, None, :], T + 1, axis=1)
    t_grid = np.arange(T + 1, dtype=float)
    home = np.zeros(M, dtype=bool) if closed is None else np.asarray(closed, dtype=bool)
    for m, route in enumerate(routes):
        if len(route) == 0:
            continue
        at = windows[route, 1].astype(float) if split == "distance" else windows[route].mean(axis=1)
        last = scenario.start_positions[m] if home[m] else scenario.locales[route[-1]]
        knots_t = np.concatenate([[0.0], at, [float(T)]])
        pts = np.vstack([scenario.start_positions[m], scenario.locales[route], last])
        pos = np.stack([np.interp(t_grid, knots_t, pts[:, k]) for k in range(2)], axis=1)
        vel = np.gradient(pos, scenario.dt, axis=0)
        body = paths[m, 1:]  # a view
        body[:] = 0.0
        body[:, POS] = pos[1:]
        body[:, VEL] = vel[1:]
    paths[:, 0, :] = x0
    assert paths.shape == (M, T + 1, STATE_DIM)
    return paths


def witness_visits(
    scenario: Scenario, positions: np.ndarray, radius: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(platform (N,), windows (N, 2))``: where the paths ``positions (M, T+1, 2)`` visit each locale.

    A locale goes to the platform whose path is inside its disc (``radius``: one number or one per
    locale) at the most steps ``t = 1..T``, and its window is the longest run of consecutive such
    steps (the earliest among equally long ones); a locale no path is inside gets the single closest
    step. Visits imposed in these windows are met by the paths themselves, so a planner that restarts
    from them has a feasible point (:func:`~pmht_opt.planners.pmht.run_em`).
    """
    N, M, T = scenario.n_locales, scenario.n_platforms, scenario.horizon
    radii = np.broadcast_to(np.asarray(radius, dtype=float), (N,))
    pos = positions[:, 1:, :]
    gap = np.hypot(
        pos[:, :, None, 0] - scenario.locales[None, None, :, 0],
        pos[:, :, None, 1] - scenario.locales[None, None, :, 1],
    )  # (M, T, N)
    inside = gap <= radii
    platform = np.empty(N, dtype=int)
    windows = np.empty((N, 2), dtype=int)
    for n in range(N):
        counts = inside[:, :, n].sum(axis=1)
        if counts.max() == 0:
            m, t = (int(i) for i in np.unravel_index(int(np.argmin(gap[:, :, n])), (M, T)))
            platform[n], windows[n] = m, (t + 1, t + 1)
            continue
        m = int(np.argmax(counts))
        # Runs of consecutive steps inside: their starts and ends, from the edges of the indicator.
        edges = np.diff(np.concatenate([[0], inside[m, :, n].astype(int), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        k = int(np.argmax(ends - starts))
        platform[n], windows[n] = m, (starts[k] + 1, ends[k])
    return platform, windows


def window_priors(
    scenario: Scenario, platform: np.ndarray, windows: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(time_prior (N, T), platform_prior (N, M))`` that put every locale on its ``platform`` and
    inside its window (``(lo, hi)``, steps counted from 1), and nowhere else."""
    N, M, T = scenario.n_locales, scenario.n_platforms, scenario.horizon
    time_prior = np.zeros((N, T))
    for n, (lo, hi) in enumerate(windows):
        time_prior[n, lo - 1 : hi] = 1.0
    platform_prior = np.zeros((N, M))
    platform_prior[np.arange(N), platform] = 1.0
    return time_prior, platform_prior
