r"""Local search on the key discs with the turn points held fixed: relocate, drop and 2-opt moves.

Each move is priced with the other turn points fixed, using the exact one-disc detour of
:mod:`pmht_opt.tours.detour`; that keeps a move's price local (a few distances) so whole
neighbourhoods are priced at once with numpy. The cone program re-optimises all turn points together
afterwards (:mod:`pmht_opt.tours.polish`).

- **Relocate** (Or-opt of one disc): take key disc :math:`k` out from between :math:`a` and :math:`b`
  (saving :math:`\lVert a-p\rVert + \lVert p-b\rVert - \lVert a-b\rVert`) and put it into another leg
  :math:`[c, d]`, of any route, at its best point (costing the detour). Putting it back into
  :math:`[a, b]` moves its turn point to the best one there.
- **Drop**: take :math:`k` out when the shortened polyline still meets its disc: covering in passing.
- **2-opt**: reverse a stretch of a route.

With route length caps (:mod:`pmht_opt.tours.caps`) a move is priced first by how much it changes the
routes' excess over their caps, then by its saving: a move that would take a route over its cap (or
further over it) is never made, and while a route is over its cap any of its discs may move to any
leg of another route that takes it with less excess, whatever the move costs in length.

A move must keep every disc met. The discs that only the removed legs met are checked against the new
polyline before a move is kept, so the search never leaves the feasible set. Moves of one pass are
priced on the pass's starting tour, sorted, and applied best first while they touch no vertex that an
earlier move of the pass changed (their prices are then still exact).

The ruin-and-recreate perturbation lives here too: :func:`ruin` removes a cluster of key discs and
:func:`repair` puts back, each at its cheapest place, every disc that the polyline no longer meets.
"""

from __future__ import annotations

import numpy as np

from pmht_opt.tours.caps import excess_change
from pmht_opt.tours.detour import best_points, reach_points
from pmht_opt.tours.geometry import segment_distances
from pmht_opt.tours.tour import Tour

#: Smallest saving (unit box) that a move must make. Smaller gains are left to the cone program, which
#: moves all turn points at once: chasing them move by move converges slowly (each turn point's best
#: place shifts with its neighbours') and costs passes for nothing.
EPS = 1e-7


def _norm(v: np.ndarray) -> np.ndarray:
    return np.hypot(v[..., 0], v[..., 1])


def _ids(tour: Tour) -> list[list[int]]:
    """Vertex identities per route: disc index, or ``-(m+1)`` for the start, ``-(M+m+1)`` for a tail."""
    M = len(tour.keys)
    out = []
    for m, k in enumerate(tour.keys):
        end = -(m + 1) if tour.layout.closed[m] else -(M + m + 1)
        out.append([-(m + 1), *k, end])
    return out


def relocate_pass(
    tour: Tour,
    neighbours: int = 12,
    objective: str = "distance",
    focus: np.ndarray | None = None,
    changed: list[np.ndarray] | None = None,
) -> int:
    """One pass of relocate and drop moves; returns how many were applied.

    Only key discs with ``focus`` set are moved (all when None); the vertices that applied moves
    changed are appended to ``changed``, so the next pass can focus on the discs around them.

    With ``objective="time"`` a move may also lengthen the total when it takes a disc off the longest
    route and shortens that route more than it lengthens the receiving one (the longest route first,
    then the total, must improve).
    """
    lay = tour.layout
    c, r = lay.centres, lay.radii
    M = len(tour.keys)
    A, B, R = tour.legs()
    if sum(len(k) for k in tour.keys) == 0:
        return 0
    D, _ = segment_distances(c, A, B)
    C = D <= r[:, None]
    cnt = C.sum(axis=1)
    ids = _ids(tour)
    leg_ids = [(ids[m][i], ids[m][i + 1]) for m in range(M) for i in range(len(ids[m]) - 1)]
    tail = np.array(
        [not lay.closed[m] and i == len(ids[m]) - 2 for m in range(M) for i in range(len(ids[m]) - 1)]
    )
    off = np.concatenate([[0], np.cumsum([len(i) - 1 for i in ids])])
    # Every key: its disc, in/out legs, neighbours a, p, b and the leg that replaces it.
    ks, kin, kout, ka, kp, kb2, klast = [], [], [], [], [], [], []
    for m in range(M):
        v = tour.verts(m)
        K = len(tour.keys[m])
        for j in range(K):
            if focus is not None and not focus[tour.keys[m][j]]:
                continue
            last = not lay.closed[m] and j == K - 1
            ks.append(tour.keys[m][j])
            kin.append(off[m] + j)
            kout.append(off[m] + j + 1)
            ka.append(v[j])
            kp.append(v[j + 1])
            kb2.append(v[j] if last else v[j + 2])
            klast.append(last)
    if not ks:
        return 0
    ks_a = np.array(ks)
    kin_a, kout_a = np.array(kin, dtype=np.intp), np.array(kout, dtype=np.intp)
    a, p, b2 = np.array(ka), np.array(kp), np.array(kb2)
    b = B[kout_a]
    gain = _norm(a - p) + _norm(p - b) - _norm(a - b2)
    Dnew, _ = segment_distances(c, a, b2)
    Cin, Cout = C[:, kin_a], C[:, kout_a]
    only = (Cin | Cout) & (cnt[:, None] - Cin - Cout == 0)
    col = np.arange(len(ks_a))
    orphan = only & (Dnew > r[:, None])
    orphan[ks_a, col] = False
    valid = ~orphan.any(axis=0)
    self_cov = (cnt[ks_a] - Cin[ks_a, col] - Cout[ks_a, col] > 0) | (Dnew[ks_a, col] <= r[ks_a])
    lengths = tour.lengths()
    kroute = R[kin_a]
    caps = lay.caps
    # (excess change, delta, key column, leg or -1, point)
    moves: list[tuple[float, float, int, int, np.ndarray | None]] = []
    drops = np.flatnonzero(valid & self_cov & (gain > EPS))
    dex = np.zeros(len(drops))
    if caps is not None:
        src = kroute[drops]
        dex = excess_change(caps, lengths, src, src, gain[drops], np.zeros(len(drops)))
    for d0, e in zip(drops, dex, strict=True):
        moves.append((float(e), -float(gain[d0]), int(d0), -1, None))
    # Insertion into other legs: the cheapest few by a lower bound, then exact detours.
    zk, rk = c[ks_a], r[ks_a]
    lb = _norm(A[None] - zk[:, None]) + _norm(zk[:, None] - B[None]) - 2 * rk[:, None] - _norm(A - B)[None]
    lb = np.maximum(lb, 0.0)
    lb[col, kin_a] = np.inf
    lb[col, kout_a] = np.inf
    lb[~valid] = np.inf
    timed = objective == "time" and M > 1
    crit = int(np.argmax(lengths))
    # Distance: only insertions that can pay for the removal. Time: from the longest route, any leg
    # of another route may receive the disc; so may any from a route over its cap.
    free = (kroute[:, None] == crit) & (R[None, :] != crit) if timed else np.zeros_like(lb, dtype=bool)
    if caps is not None and (lengths > caps).any():
        free |= (lengths > caps)[kroute][:, None] & (R[None, :] != kroute[:, None])
    lb[(lb >= gain[:, None] - EPS) & ~free] = np.inf
    nb = min(neighbours, lb.shape[1])
    near = (
        np.argpartition(lb, nb - 1, axis=1)[:, :nb]
        if nb < lb.shape[1]
        else np.tile(np.arange(lb.shape[1]), (len(ks_a), 1))
    )
    rows = np.repeat(col, near.shape[1])
    legs = near.ravel()
    ok = np.isfinite(lb[rows, legs])
    rows, legs = rows[ok], legs[ok]
    # Back into its own place too (leg code -2, between a and b2), priced in the same batch.
    vi = np.flatnonzero(valid)
    rows = np.concatenate([rows, vi])
    legs = np.concatenate([legs, np.full(len(vi), -2)])
    own = legs == -2
    la = np.where(own[:, None], a[rows], A[np.maximum(legs, 0)])
    lbb = np.where(own[:, None], b2[rows], B[np.maximum(legs, 0)])
    t = np.where(own, np.array(klast, dtype=bool)[rows], tail[np.maximum(legs, 0)])
    pts = np.zeros((len(rows), 2))
    cost = np.zeros(len(rows))
    if (~t).any():
        pts[~t], f = best_points(la[~t], lbb[~t], zk[rows[~t]], rk[rows[~t]])
        cost[~t] = f - _norm(la[~t] - lbb[~t])
    if t.any():
        pts[t], cost[t] = reach_points(la[t], zk[rows[t]], rk[rows[t]])
    delta = cost - gain[rows]
    dex = np.zeros(len(rows))
    if caps is not None:
        dst = np.where(own, kroute[rows], R[np.maximum(legs, 0)])
        dex = excess_change(caps, lengths, kroute[rows], dst, gain[rows], cost)
    for o in np.flatnonzero((dex < 0) | ((dex == 0) & (delta < -EPS))):
        moves.append((float(dex[o]), float(delta[o]), int(rows[o]), int(legs[o]), pts[o]))
    if timed:
        span = float(lengths.max())
        for o in np.flatnonzero((delta >= -EPS) & ~own & (dex == 0)):
            r0, l0 = int(rows[o]), int(legs[o])
            if kroute[r0] == crit and R[l0] != crit:
                after = lengths.copy()
                after[crit] -= gain[r0]
                after[R[l0]] += cost[o]
                if after.max() < span * (1 - 1e-12):  # ranked after every distance move
                    moves.append((0.0, float(after.max() - span) + 1e3, r0, l0, pts[o]))
    moves.sort(key=lambda mv: (mv[0], mv[1], mv[2], mv[3]))
    touched: set[int] = set()
    applied = 0
    before = tour.score(objective)
    for _, _, i, leg, q in moves:
        k = int(ks_a[i])
        if k in touched:
            continue
        m, j = tour.locate(k)
        K = len(tour.keys[m])
        prev_id = tour.keys[m][j - 1] if j > 0 else -(m + 1)
        next_id = tour.keys[m][j + 1] if j + 1 < K else (-(m + 1) if lay.closed[m] else -(M + m + 1))
        involved = {k, prev_id, next_id}
        if leg >= 0:
            involved |= set(leg_ids[leg])
        if involved & touched:
            continue
        m2 = int(R[leg]) if leg >= 0 else m
        saved = {r_: (list(tour.keys[r_]), tour.pts[r_]) for r_ in {m, m2}}
        tour.remove(m, j)
        risk = C[:, kin_a[i]] | C[:, kout_a[i]]
        if leg >= 0 or leg == -2:
            if leg >= 0:
                cid = leg_ids[leg][0]
                risk = risk | C[:, leg]
            else:
                cid = prev_id
            pos = 0 if cid < 0 else tour.keys[m2].index(cid) + 1
            assert q is not None
            tour.insert(m2, pos, k, q)
        risk[k] = True
        if not tour.covered(np.flatnonzero(risk)).all():
            for r_, (kk, pp) in saved.items():
                tour.keys[r_], tour.pts[r_] = kk, pp
            continue
        if timed or caps is not None:
            # Prices were made on the pass's first tour: the longest route may have changed, and
            # moves into one route may together take it over its cap.
            now = tour.score(objective)
            if not now < before:
                for r_, (kk, pp) in saved.items():
                    tour.keys[r_], tour.pts[r_] = kk, pp
                continue
            before = now
        touched |= involved
        applied += 1
        if changed is not None:
            changed.append(np.array([a[i], p[i], b2[i]]))
            if leg >= 0:
                changed.append(np.array([A[leg], B[leg], q]))
    return applied


def two_opt_pass(tour: Tour, tries: int = 8, changed: list[np.ndarray] | None = None) -> int:
    """2-opt on each route until no improving reversal keeps every disc met; returns how many."""
    lay = tour.layout
    applied = 0
    for m in range(len(tour.keys)):
        while True:
            K = len(tour.keys[m])
            if K < 2:
                break
            V = tour.verts(m)
            i, j = np.triu_indices(K, 1)
            # Reversing keys i..j replaces legs (V_i, V_i+1), (V_j+1, V_j+2) by (V_i, V_j+1), (V_i+1, V_j+2).
            delta = (
                _norm(V[i] - V[j + 1])
                + _norm(V[i + 1] - V[j + 2])
                - _norm(V[i] - V[i + 1])
                - _norm(V[j + 1] - V[j + 2])
            )
            if not lay.closed[m]:  # reversing the tail of an open route: its end moves
                end = j == K - 1
                delta[end] = _norm(V[i[end]] - V[K]) - _norm(V[i[end]] - V[i[end] + 1])
            order = np.argsort(delta, kind="stable")[:tries]
            done = False
            for o in order:
                if delta[o] >= -EPS:
                    break
                ii, jj = int(i[o]), int(j[o])
                saved_k, saved_p = list(tour.keys[m]), tour.pts[m].copy()
                tour.keys[m][ii : jj + 1] = tour.keys[m][ii : jj + 1][::-1]
                tour.pts[m][ii : jj + 1] = tour.pts[m][ii : jj + 1][::-1]
                a0, b0 = np.array([V[ii], V[jj + 1]]), np.array([V[ii + 1], V[jj + 2]])
                d, _ = segment_distances(lay.centres, a0, b0)
                risk = np.flatnonzero((d <= lay.radii[:, None]).any(axis=1))
                if tour.covered(risk).all():
                    applied += 1
                    done = True
                    if changed is not None:
                        changed.append(np.vstack([a0, b0]))
                    break
                tour.keys[m], tour.pts[m] = saved_k, saved_p
            if not done:
                break
    return applied


def insert_cheapest(tour: Tour, disc: int, objective: str = "distance") -> np.ndarray:
    """Make ``disc`` a key at its cheapest place over all legs of all routes (its best point there).

    With ``objective="time"`` the place that keeps the longest route shortest wins, then the cheapest.
    With caps, places that keep the route within its cap (or least over it) come first.
    Returns the replaced leg's ends and the new turn point, ``(3, 2)``: start, point, end.
    """
    lay = tour.layout
    z, rr = lay.centres[disc], lay.radii[disc]
    caps = lay.caps
    lengths = tour.lengths() if objective == "time" or caps is not None else np.zeros(len(tour.keys))
    best: tuple[tuple[float, float, float], int, int, np.ndarray, np.ndarray] | None = None
    # Every leg of every route priced at once; an open route's last leg is its tail (reach the disc).
    verts = [tour.verts(m) for m in range(len(tour.keys))]
    A = np.vstack([V[:-1] for V in verts])
    B = np.vstack([V[1:] for V in verts])
    bounds = np.cumsum([0] + [len(V) - 1 for V in verts])
    tail = np.zeros(len(A), dtype=bool)
    tail[bounds[1:][~lay.closed] - 1] = True
    Q = np.zeros_like(A)
    F = np.zeros(len(A))
    Q[~tail], F[~tail] = best_points(A[~tail], B[~tail], z[None], np.full(int((~tail).sum()), rr))
    F[~tail] -= _norm(A[~tail] - B[~tail])
    if tail.any():
        Q[tail], F[tail] = reach_points(A[tail], z[None], np.full(int(tail.sum()), rr))
    for m in range(len(tour.keys)):
        V = verts[m]
        q, cost = Q[bounds[m] : bounds[m + 1]], F[bounds[m] : bounds[m + 1]]
        i = int(np.argmin(cost))  # also the least excess on this route: it grows with the cost
        over = 0.0
        if caps is not None:
            over = float(max(lengths[m] + cost[i] - caps[m], 0.0) - max(lengths[m] - caps[m], 0.0))
        if objective == "time":
            after = lengths.copy()
            after[m] += cost[i]
            key = (over, float(after.max()), float(cost[i]))
        else:
            key = (over, float(cost[i]), 0.0)
        if best is None or key < best[0]:
            best = (key, m, i, q[i], V[i : i + 2])
    assert best is not None
    _, m, i, q, ends = best
    tour.insert(m, i, disc, q)
    return np.array([ends[0], q, ends[1]])


def repair(tour: Tour, rng: np.random.Generator, objective: str = "distance") -> np.ndarray:
    """Insert discs that no leg meets, cheapest first place each, in random order, until all are met.

    Coverage is checked in full once; after that only where an insertion changed the polyline: the
    replaced leg may have been all that met some disc, and the two new legs may meet missing ones.
    Returns the changed vertices ``(3 k, 2)`` (see :func:`insert_cheapest`).
    """
    lay = tour.layout
    c, r = lay.centres, lay.radii
    miss = np.flatnonzero(~tour.covered())
    changed: list[np.ndarray] = []
    while miss.size:
        disc = int(rng.choice(miss))
        if tour.key_mask()[disc]:
            raise AssertionError(f"key disc {disc} is not met by its own turn point")
        ends = insert_cheapest(tour, disc, objective)
        changed.append(ends)
        old, _ = segment_distances(c, ends[[0]], ends[[2]])
        risk = np.flatnonzero(old[:, 0] <= r)
        lost = risk[~tour.covered(risk)]
        new, _ = segment_distances(c[miss], ends[[0, 1]], ends[[1, 2]])
        still = miss[(new > r[miss, None]).all(axis=1) & (miss != disc)]
        miss = np.union1d(still, lost)
    return np.vstack(changed) if changed else np.zeros((0, 2))


def ruin(tour: Tour, rng: np.random.Generator, size: int) -> np.ndarray:
    """Remove a random key disc and the ``size - 1`` key discs whose centres are nearest to it;
    returns the removed turn points."""
    keys = np.array([k for ks in tour.keys for k in ks], dtype=np.intp)
    if keys.size == 0:
        return np.zeros((0, 2))
    seed = int(rng.choice(keys))
    c = tour.layout.centres
    order = np.argsort(_norm(c[keys] - c[seed]), kind="stable")
    removed = []
    for k in keys[order[:size]]:
        m, j = tour.locate(int(k))
        removed.append(tour.pts[m][j])
        tour.remove(m, j)
    return np.array(removed)
