r"""Route length caps: what can be proven before the search, the caps in the unit box, a move's price.

A cap :math:`c_m` bounds the length :math:`L_m` of route :math:`m` (``DiscProblem.max_lengths``). The
searches treat the caps as the first criterion of a lexicographic score: the *excess*

.. math:: E = \sum_m \max(0,\ L_m - c_m)

comes before the objective (total length, or longest route), so a tour within its caps beats every
tour that is not, and a tour over them is pulled back by any move that lowers :math:`E`. Moves that
raise :math:`E` are never made. Without caps :math:`E = 0` for every tour and nothing changes.

**Proof of infeasibility.** A route from start :math:`s_m` that meets disc :math:`(z, \rho)` reaches
a point at distance at least :math:`g = \max(0, \lVert z - s_m\rVert - \rho)` from its start, so it
is at least :math:`g` long when open and :math:`2 g` when closed (out and back). A target that no
route can reach within its cap makes every tour break a cap: that is proven before any search.
Nothing else is proven (whether the targets *together* fit in the caps is a bin packing question);
a search that ends over the caps says so without claiming infeasibility.
"""

from __future__ import annotations

import numpy as np

from pmht_opt.exceptions import InfeasibleError
from pmht_opt.tours.geometry import GRID, Frame
from pmht_opt.tours.problem import DiscProblem

#: The search keeps each route this fraction (plus a few grid steps of the unit box) within its cap:
#: the answer is measured again in the user's units from the user's starts (not rounded to the grid),
#: and must then still be within the cap.
MARGIN = 1e-9
#: A target is proven out of reach only when its shortest route is longer than its cap by more than
#: this fraction (a rounding cannot make the proof wrong).
PROOF_SLACK = 1e-9


def prove_reach(problem: DiscProblem) -> None:
    """Raise InfeasibleError, naming the first such target, if some target's disc is out of every
    route's reach within its cap (module notes)."""
    caps = problem.caps
    if caps is None or problem.n_targets == 0:
        return
    off = problem.centres[:, None, :] - problem.starts[None, :, :]
    gap = np.maximum(np.hypot(off[..., 0], off[..., 1]) - problem.radii[:, None], 0.0)  # (N, M)
    need = np.where(np.asarray(problem.closed)[None, :], 2 * gap, gap)
    reachable = need <= caps[None, :] * (1 + PROOF_SLACK)
    lost = np.flatnonzero(~reachable.any(axis=1))
    if lost.size == 0:
        return
    n = int(lost[0])
    m = int(np.argmin(need[n] - caps))
    kind = "there and back" if bool(np.asarray(problem.closed)[m]) else "to reach it"
    raise InfeasibleError(
        f"max_lengths: target {n} (centre {problem.centres[n].tolist()}, radius {problem.radii[n]:.4g}) is "
        f"out of every route's reach: the nearest, route {m}, needs {need[n, m]:.4g} {kind} and its cap "
        f"is {caps[m]:.4g}" + (f" ({lost.size} such targets)." if lost.size > 1 else "."),
        backend="tours",
        status="infeasible",
    )


def unit_caps(problem: DiscProblem, frame: Frame) -> np.ndarray | None:
    """``(M,)`` the caps in the unit box, a hair within the user's (:data:`MARGIN`); None without."""
    caps = problem.caps
    if caps is None:
        return None
    out = np.maximum(caps / frame.side * (1 - MARGIN) - 8 * GRID, 0.0)
    out.setflags(write=False)
    return out


def excess_change(
    caps: np.ndarray,
    lengths: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    gain: np.ndarray,
    cost: np.ndarray,
) -> np.ndarray:
    r"""Change of the excess :math:`E` when a disc leaves route ``src`` (saving ``gain``) and joins
    route ``dst`` (costing ``cost``); ``src == dst`` for a move within a route, ``cost = 0`` for a
    drop. Vectorised over moves; exact for the prices given, since only those two routes change."""

    def over(m: np.ndarray, length: np.ndarray) -> np.ndarray:
        return np.maximum(length - caps[m], 0.0)

    same = src == dst
    before_src, before_dst = over(src, lengths[src]), over(dst, lengths[dst])
    within = over(src, lengths[src] - gain + cost) - before_src
    across = over(src, lengths[src] - gain) - before_src + over(dst, lengths[dst] + cost) - before_dst
    return np.where(same, within, across)
