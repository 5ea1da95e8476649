r"""Plan straight-line routes that meet every disc: an order from PyVRP, then ruin and recreate.

Stages, each measured by the benchmark study (``pmht-opt study cetsp``):

1. **Normalise** the problem into the unit box (:mod:`pmht_opt.tours.geometry`): the same tours
   whatever the units.
2. **Order** the disc centres with PyVRP (:mod:`pmht_opt.tours.ordering`): a multiple TSP from each
   vehicle's start, closed or open (for the makespan, a bisection on PyVRP's route length limit).
3. **Polish** that order with the cone program (:mod:`pmht_opt.tours.polish`): the exact turn points;
   discs the polyline crosses anyway stop being keys.
4. **Descend** (:mod:`pmht_opt.tours.local`): relocate, drop and 2-opt moves priced with the other turn
   points fixed, then the cone program again, until neither improves.
5. **Ruin and recreate**: remove a few neighbouring key discs, put back every disc that is no longer
   met at its cheapest place, descend. The best tour is kept apart; the next ruin starts from the
   last tour within a threshold of the best (record-to-record travel, the threshold falling to zero),
   which lets the search leave a local optimum that small ruins cannot. Every ``resequence``-th
   candidate is instead a re-sequencing (:func:`resequence`): PyVRP orders the current turn points
   anew, which can hand whole stretches from one vehicle to another. Stops after a number of
   iterations, or of iterations without a better tour: never on wall time, so the seed fixes the
   answer.
6. **Settle**: the cone program on every disc in the order the tour meets them, kept if shorter; the
   answer is then never longer than the polyline through the centres in that order.

**Route length caps** (``DiscProblem.max_lengths``, :mod:`pmht_opt.tours.caps`) hold in every stage:
a target that no route can reach within its cap is refused first (InfeasibleError, a proof); PyVRP
orders the centres with each vehicle's cap as its maximum route distance; every score puts the routes'
excess over their caps before the objective, so the cone program, the moves and the ruins never take
a route over its cap, and a tour over them is pulled back first; record-to-record travel walks only
through tours with no more excess than the best. A search that ends over a cap raises SolverError:
the caps were not met, which proves nothing. Without caps (or all ``inf``) the excess is 0 everywhere
and every choice, hence the answer, is the same to the bit as without the feature.

Two alternatives were measured on the nine closed fleet scenarios (A, B, C, seeds 0-2, radius 0.3,
caps at 0.8 of the uncapped longest route) and dropped. Letting the walk cross tours over a cap,
priced :math:`J + w E` with :math:`w = 1`, gave the same answers: after a repair that prefers places
within the caps and a descent that lowers the excess first, a candidate is almost never over a cap.
Counting each arc in PyVRP's caps shorter by half or all of its discs' radii (the routes through the
discs are shorter than through the centres) made the totals no better: 4.03% (worst 10.6%) and 4.79%
(16.8%) over the uncapped answer, against 3.96% (8.7%) with the centres' lengths.

The re-sequencing was measured on A, B and C at radius 0.3, plan seeds 0-2: every 10th candidate
(300 PyVRP iterations each) made the mean tour 1.5% shorter on scenario seeds 0-2 and the worst
plan-seed spread 1.05% against 2.8%; on seeds 3-5 it left spreads of 1.6% on average (3.2% at
worst), and every 5th candidate 1.25% (2.0%) for a tenth more time, hence every 5th. With the ruins
alone the search was still improving at its last iteration, each plan seed in a different pattern of
routes; four times the iterations left a spread of 1.6%.

A generalised TSP over discretised discs (PyVRP with one group of boundary points per disc, the
Carrabs et al. scheme) was tried first and dropped: PyVRP's search on such groups stalled about 10%
above the best known tour on kroD100 (radius factor 0.1) where the centres' TSP plus the cone program
is 3% above it, and the copies needed for overlapping discs made it large.

The answer is checked by :func:`pmht_opt.tours.verify.check_tours` before it is returned.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from pmht_opt.exceptions import SolverError
from pmht_opt.tours.caps import prove_reach, unit_caps
from pmht_opt.tours.geometry import Frame, unit_frame
from pmht_opt.tours.local import relocate_pass, repair, ruin, two_opt_pass
from pmht_opt.tours.ordering import order_points, order_points_minmax
from pmht_opt.tours.polish import place, refine, solve_keys, thin
from pmht_opt.tours.problem import SEED_MAX, DiscProblem, DiscTours, Progress, TourSettings
from pmht_opt.tours.tour import Layout, Tour
from pmht_opt.tours.verify import check_tours

#: Relative improvement that counts as better.
REL = 1e-12
#: After a change, moves are tried for the discs within this many median legs (plus a diameter) of it.
FOCUS = 3.0
#: A turn point that the cone program moved by more than this (unit box) counts as changed.
MOVED = 1e-7
Score = tuple[float, float, float]


def better(a: Score, b: Score) -> bool:
    """Whether score ``a`` (excess, objective, total) beats ``b``: less excess, or as much and an
    objective, then a total, lower by more than the relative tolerance."""
    if a[0] != b[0]:
        return a[0] < b[0]
    if a[1] < b[1] * (1 - REL) - 1e-15:
        return True
    return a[1] <= b[1] * (1 + REL) and a[2] < b[2] * (1 - REL) - 1e-15


def within(a: Score, best: Score, threshold: float) -> bool:
    """Whether a tour of score ``a`` is near enough to the best for record-to-record travel: no more
    excess over the caps, and an objective within ``threshold`` of the best's."""
    return a[0] <= best[0] and a[1] <= best[1] * (1 + threshold)


def _near(tour: Tour, points: np.ndarray) -> np.ndarray:
    """Discs whose centre lies within a few typical legs of any of ``points``: where moves may now pay."""
    lengths = [np.hypot(*np.diff(tour.verts(m), axis=0).T) for m in range(len(tour.keys))]
    legs = np.concatenate(lengths)
    legs = legs[legs > 0]
    reach = FOCUS * (float(np.median(legs)) if legs.size else 0.0) + 2 * float(tour.layout.radii.max())
    off = tour.layout.centres[:, None, :] - points[None, :, :]
    return np.asarray((np.hypot(off[..., 0], off[..., 1]) <= reach).any(axis=1))


def _moved(old: Tour, new: Tour) -> np.ndarray:
    """Turn points that differ between two tours (either tour's, ``(k, 2)``)."""
    before = {k: p for ks, ps in zip(old.keys, old.pts, strict=True) for k, p in zip(ks, ps, strict=True)}
    after = {k: p for ks, ps in zip(new.keys, new.pts, strict=True) for k, p in zip(ks, ps, strict=True)}
    out = [p for k, p in after.items() if k not in before or np.hypot(*(p - before[k])) > MOVED]
    out += [p for k, p in before.items() if k not in after]
    return np.array(out) if out else np.zeros((0, 2))


def descend(tour: Tour, settings: TourSettings, focus: np.ndarray | None = None, rounds: int = 8) -> Tour:
    """Local search to a local optimum, the cone program after each descent; never worse.

    ``focus`` marks the discs whose moves are tried first (all when None); after each pass only the
    discs near what the pass changed are tried again ("don't look bits"), and after the cone program
    those near the turn points it moved.
    """
    for _ in range(rounds):
        while True:
            changed: list[np.ndarray] = []
            n = relocate_pass(tour, settings.neighbours, settings.objective, focus, changed)
            n += two_opt_pass(tour, changed=changed)
            if n == 0:
                break
            focus = _near(tour, np.vstack(changed))
        polished = refine(tour, settings.objective)
        if polished is tour:
            return tour
        moved = _moved(tour, polished)
        tour = polished
        if moved.size == 0:
            return tour
        focus = _near(tour, moved)
    return tour


def start_seed(seed: int, k: int) -> int:
    """The seed of start ``k`` of a search seeded ``seed``: ``seed`` itself for the first (one start
    is the search of that seed), then seeds drawn from ``numpy.random.SeedSequence([seed, k])``."""
    if k == 0:
        return seed
    state = np.random.SeedSequence([seed, k]).generate_state(1, dtype=np.uint64)[0]
    return int(state % np.uint64(SEED_MAX + 1))


def _order(
    layout: Layout, points: np.ndarray, iterations: int, seed: int, settings: TourSettings
) -> list[list[int]]:
    """PyVRP's routes through ``points`` for the objective: for ``"time"`` with several vehicles the
    bisection on the longest route, else the shortest total; within the caps when there are some
    (PyVRP's best routes are taken even when it could not keep them)."""
    routes: list[list[int]] | None
    if settings.objective == "time" and len(layout.starts) > 1 and settings.bisection > 0:
        routes = order_points_minmax(
            layout.starts, layout.closed, points, iterations, seed, steps=settings.bisection, caps=layout.caps
        )
    else:
        routes = order_points(
            layout.starts, layout.closed, points, iterations, seed, caps=layout.caps, keep=True
        )
    assert routes is not None
    return routes


def initial_tour(layout: Layout, settings: TourSettings) -> Tour:
    """Every disc a key, in PyVRP's order of the centres, turn points at the centres.

    For ``objective="time"`` with several vehicles the order comes from a bisection on PyVRP's route
    length limit (:func:`~pmht_opt.tours.ordering.order_points_minmax`). With caps, PyVRP keeps each
    route within its cap (its best routes are taken even when it could not).
    """
    routes = _order(layout, layout.centres, settings.order_iterations, settings.seed, settings)
    return Tour(layout, [list(map(int, r)) for r in routes], [layout.centres[r].copy() for r in routes])


def resequence(tour: Tour, settings: TourSettings, rng: np.random.Generator) -> Tour:
    """The tour's key discs in a new order: PyVRP's multiple TSP through their turn points, then the
    cone program, a repair of any disc the new legs no longer meet, and the descent.

    The ruins move a few discs at a time; this move re-sequences every route at once, and may hand
    whole stretches from one vehicle to another: from a good set of turn points, PyVRP's search over
    orders finds routes that many ruins would not reach. The seed of PyVRP's search is drawn from
    ``rng``.
    """
    keys = [k for ks in tour.keys for k in ks]
    if not keys:
        return tour.copy()
    lay = tour.layout
    points = np.vstack([p for p in tour.pts if len(p)])
    seed = int(rng.integers(SEED_MAX + 1))
    routes = _order(lay, points, settings.resequence_iterations, seed, settings)
    out = Tour(lay, [[keys[i] for i in r] for r in routes], [points[r].copy() for r in routes])
    repair(out, rng, settings.objective)
    return descend(refine(out, settings.objective), settings)


def settle(tour: Tour, objective: str) -> Tour:
    """The better of the tour and the cone program on *all* its discs in the order it meets them.

    That program's optimum is at most the polyline through the centres in the same order, so the
    answer never exceeds it; usually the tour itself is better (its order constrains fewer discs).
    """
    placed = place(tour)
    full = Tour(
        tour.layout, [list(map(int, r)) for r in placed.routes], [placed.points[r] for r in placed.routes]
    )
    full = thin(solve_keys(full))
    return full if full.covered().all() and better(full.score(objective), tour.score(objective)) else tour


def _answer(problem: DiscProblem, frame: Frame, tour: Tour, info: dict[str, object]) -> DiscTours:
    placed = place(tour)
    M = problem.n_vehicles
    turns = [frame.from_unit(tour.pts[m]) for m in range(M)]
    out = DiscTours(
        routes=placed.routes,
        points=frame.from_unit(placed.points),
        lengths=np.zeros(M),
        turns=turns,
        problem=problem,
        info=info,
    )
    lengths = np.array([float(np.hypot(*np.diff(out.vertices(m), axis=0).T).sum()) for m in range(M)])
    out = DiscTours(out.routes, out.points, lengths, turns, problem, info)
    return out


def _caps_met(problem: DiscProblem, frame: Frame, tour: Tour, iterations: int) -> None:
    """Raise SolverError (``status="caps"``) if the search's best tour has a route over its cap."""
    caps = tour.layout.caps
    assert caps is not None and problem.caps is not None
    lengths = tour.lengths()
    over = np.flatnonzero(lengths > caps)
    if over.size == 0:
        return
    detail = ", ".join(f"route {m} {lengths[m] * frame.side:.4g} > {problem.caps[m]:.4g}" for m in over[:4])
    more = ", ..." if over.size > 4 else ""
    raise SolverError(
        f"max_lengths: the search did not find routes within their caps ({detail}{more} in the best "
        f"tour after {iterations} iterations). That does not prove that none exist: more search "
        "(order_iterations, iterations, patience), longer caps or more vehicles may find them.",
        backend="tours",
        status="caps",
    )


def plan_tours(
    problem: DiscProblem,
    settings: TourSettings | None = None,
    *,
    callback: Callable[[Progress], None] | None = None,
    stop: Callable[[Progress], bool] | None = None,
) -> DiscTours:
    """Routes from each vehicle's start that together meet every target's disc.

    Parameters
    ----------
    problem
        Starts, discs and which routes are closed.
    settings
        Seed, objective and effort (iteration counts); defaults when None.
    callback
        Called with a :class:`Progress` after the first tour and after each iteration.
    stop
        A criterion ``stop(progress) -> bool``; the search ends when it returns True.

    Raises
    ------
    InfeasibleError
        If a target's disc is out of every route's reach within its cap (``problem.max_lengths``).
    SolverError
        If the search ends with a route over its cap (``status="caps"``), a cone program fails, or
        the answer does not pass the independent check.
    """
    settings = settings or TourSettings()
    prove_reach(problem)
    t0 = time.perf_counter()
    M = problem.n_vehicles
    if problem.n_targets == 0:
        empty = [np.zeros(0, dtype=np.intp) for _ in range(M)]
        answer = DiscTours(
            empty, np.zeros((0, 2)), np.zeros(M), [np.zeros((0, 2)) for _ in range(M)], problem
        )
        check_tours(answer)
        return answer
    frame = unit_frame(problem.starts, problem.centres, problem.radii)
    layout = Layout(
        starts=frame.to_unit(problem.starts),
        closed=np.asarray(problem.closed, dtype=bool),
        centres=frame.to_unit(problem.centres),
        radii=frame.length_to_unit(problem.radii),
        caps=unit_caps(problem, frame),
    )
    objective = settings.objective
    scores: list[float] = []
    stages: dict[str, float] = {}
    done = 0  # iterations over every start
    best: Tour | None = None
    best_score: tuple[float, float, float] | None = None

    def report(settled: int) -> bool:
        progress = Progress(done, tuple(scores), time.perf_counter() - t0, settled)
        if callback is not None:
            callback(progress)
        return stop is not None and bool(stop(progress))

    halt = False
    n_keys_max = max(1, problem.n_targets)
    for k in range(settings.starts):
        if halt:
            break
        own = replace(settings, seed=start_seed(settings.seed, k))
        rng = np.random.default_rng(own.seed)
        first = initial_tour(layout, own)
        found = {"centres": first.score(objective)[1] * frame.side}
        polished = refine(first, objective)
        found["cone"] = polished.score(objective)[1] * frame.side
        current = descend(polished, settings)  # (works in place)
        current_score = current.score(objective)
        found["descent"] = current_score[1] * frame.side
        mine, mine_score = current, current_score  # this start's best
        if best is None or best_score is None or better(mine_score, best_score):
            best, best_score = mine, mine_score
        assert best_score is not None
        scores.append(best_score[1] * frame.side)
        settled = 0
        halt = report(settled)
        it = 0
        while not halt and it < settings.iterations and settled < settings.patience:
            it += 1
            done += 1
            if settings.resequence and it % settings.resequence == 0:
                cand = resequence(current, settings, rng)
            else:
                cand = current.copy()
                size = int(rng.integers(settings.ruin_min, settings.ruin_max + 1))
                removed = ruin(cand, rng, min(size, n_keys_max))
                inserted = repair(cand, rng, objective)
                cand = descend(cand, settings, _near(cand, np.vstack([removed, inserted])))
            cand_score = cand.score(objective)
            if better(cand_score, mine_score):
                mine, mine_score, settled = cand, cand_score, 0
                current, current_score = cand, cand_score
            else:
                settled += 1
                threshold = settings.accept * (1 - it / max(settings.iterations, 1))
                if within(cand_score, mine_score, threshold):  # record-to-record travel
                    current, current_score = cand, cand_score
                elif not within(current_score, mine_score, threshold):
                    current, current_score = mine, mine_score
            if better(mine_score, best_score):
                best, best_score = mine, mine_score
            scores.append(best_score[1] * frame.side)
            halt = report(settled)
        found["search"] = mine_score[1] * frame.side
        if mine is best:
            stages = found
    assert best is not None
    it = done
    best = settle(best, objective)
    if layout.caps is not None:
        _caps_met(problem, frame, best, it)
    info: dict[str, object] = {"iterations": it, "seed": settings.seed, "history": scores, "stages": stages}
    answer = _answer(problem, frame, best, info)
    check_tours(answer)
    return answer
