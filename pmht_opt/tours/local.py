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

A move must keep every disc met. The discs that only the removed legs met are checked against the new
polyline before a move is kept, so the search never leaves the feasible set. Moves of one pass are
priced on the pass's starting tour, sorted, and applied best first while they touch no vertex that an
earlier move of the pass changed (their prices are then still exact).
"""

from __future__ import annotations

import numpy as np

from pmht_opt.tours.detour import best_points, reach_points
from pmht_opt.tours.geometry import segment_distances
from pmht_opt.tours.tour import Tour

#: Smallest saving (unit box) that counts as an improvement.
EPS = 1e-10


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


def relocate_pass(tour: Tour, neighbours: int = 12, objective: str = "distance") -> int:
    """One pass of relocate and drop moves; returns how many were applied.

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
            last = not lay.closed[m] and j == K - 1
            ks.append(tour.keys[m][j])
            kin.append(off[m] + j)
            kout.append(off[m] + j + 1)
            ka.append(v[j])
            kp.append(v[j + 1])
            kb2.append(v[j] if last else v[j + 2])
            klast.append(last)
    ks_a = np.array(ks)
    kin_a, kout_a = np.array(kin), np.array(kout)
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
    moves: list[tuple[float, int, int, np.ndarray | None]] = []  # (delta, key column, leg or -1, point)
    for d0 in np.flatnonzero(valid & self_cov & (gain > EPS)):
        moves.append((-float(gain[d0]), int(d0), -1, None))
    # Insertion into other legs: the cheapest few by a lower bound, then exact detours.
    zk, rk = c[ks_a], r[ks_a]
    lb = _norm(A[None] - zk[:, None]) + _norm(zk[:, None] - B[None]) - 2 * rk[:, None] - _norm(A - B)[None]
    lb = np.maximum(lb, 0.0)
    lb[col, kin_a] = np.inf
    lb[col, kout_a] = np.inf
    lb[~valid] = np.inf
    lengths = tour.lengths()
    timed = objective == "time" and M > 1
    crit = int(np.argmax(lengths))
    kroute = R[kin_a]
    # Distance: only insertions that can pay for the removal. Time: from the longest route, any leg
    # of another route may receive the disc.
    free = (kroute[:, None] == crit) & (R[None, :] != crit) if timed else np.zeros_like(lb, dtype=bool)
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
    pts = np.zeros((len(rows), 2))
    cost = np.zeros(len(rows))
    t = tail[legs]
    if (~t).any():
        pts[~t], f = best_points(A[legs[~t]], B[legs[~t]], zk[rows[~t]], rk[rows[~t]])
        cost[~t] = f - _norm(A[legs[~t]] - B[legs[~t]])
    if t.any():
        pts[t], cost[t] = reach_points(A[legs[t]], zk[rows[t]], rk[rows[t]])
    span = float(lengths.max())
    for r0, l0, p0, c0 in zip(rows, legs, pts, cost, strict=True):
        if c0 - gain[r0] < -EPS:
            moves.append((float(c0 - gain[r0]), int(r0), int(l0), p0))
        elif timed and kroute[r0] == crit and R[l0] != crit:
            after = lengths.copy()
            after[crit] -= gain[r0]
            after[R[l0]] += c0
            if after.max() < span * (1 - 1e-12):  # ranked after every distance move
                moves.append((float(after.max() - span) + 1e3, int(r0), int(l0), p0))
    # Back into its own place at its best point.
    vi = np.flatnonzero(valid)
    if vi.size:
        ends = np.array(klast)[vi]
        q0, f0 = best_points(a[vi], b2[vi], zk[vi], rk[vi])
        qt, ft = reach_points(a[vi], zk[vi], rk[vi])
        q0[ends], f0[ends] = qt[ends], ft[ends] + _norm(a[vi] - b2[vi])[ends]
        cst0 = f0 - _norm(a[vi] - b2[vi])
        for i0, q1, c1 in zip(vi, q0, cst0, strict=True):
            if c1 - gain[i0] < -EPS:
                moves.append((float(c1 - gain[i0]), int(i0), -2, q1))
    moves.sort(key=lambda mv: (mv[0], mv[1], mv[2]))
    touched: set[int] = set()
    applied = 0
    before = tour.score(objective)
    for _, i, leg, q in moves:
        k = int(ks_a[i])
        if k in touched:
            continue
        m, j = tour.locate(k)
        prev_id, next_id = _ids(tour)[m][j], _ids(tour)[m][j + 2]
        involved = {k, prev_id, next_id}
        if leg >= 0:
            involved |= set(leg_ids[leg])
        if involved & touched:
            continue
        saved = tour.copy()
        tour.remove(m, j)
        risk = C[:, kin_a[i]] | C[:, kout_a[i]]
        if leg >= 0 or leg == -2:
            if leg >= 0:
                cid = leg_ids[leg][0]
                m2 = int(R[leg])
                risk = risk | C[:, leg]
            else:
                cid, m2 = prev_id, m
            pos = 0 if cid < 0 else tour.keys[m2].index(cid) + 1
            assert q is not None
            tour.insert(m2, pos, k, q)
        risk[k] = True
        if not tour.covered(np.flatnonzero(risk)).all():
            tour.keys, tour.pts = saved.keys, saved.pts
            continue
        if timed:  # prices were made on the pass's first tour: the longest route may have changed
            now = tour.score(objective)
            if not now < before:
                tour.keys, tour.pts = saved.keys, saved.pts
                continue
            before = now
        touched |= involved
        applied += 1
    return applied


def two_opt_pass(tour: Tour, tries: int = 8) -> int:
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
                    break
                tour.keys[m], tour.pts[m] = saved_k, saved_p
            if not done:
                break
    return applied


def insert_cheapest(tour: Tour, disc: int, objective: str = "distance") -> None:
    """Make ``disc`` a key at its cheapest place over all legs of all routes (its best point there).

    With ``objective="time"`` the place that keeps the longest route shortest wins, then the cheapest.
    """
    lay = tour.layout
    z, rr = lay.centres[disc], lay.radii[disc]
    lengths = tour.lengths() if objective == "time" else np.zeros(len(tour.keys))
    best = ((np.inf, np.inf), 0, 0, np.zeros(2))
    for m in range(len(tour.keys)):
        V = tour.verts(m)
        n = len(V) - 1
        q, f = best_points(V[:-1], V[1:], z[None], np.full(n, rr))
        cost = f - _norm(V[:-1] - V[1:])
        if not lay.closed[m]:
            q[-1], cost[-1] = reach_points(V[-1], z, np.array(rr))
        i = int(np.argmin(cost))
        if objective == "time":
            after = lengths.copy()
            after[m] += cost[i]
            key = (float(after.max()), float(cost[i]))
        else:
            key = (float(cost[i]), 0.0)
        if key < best[0]:
            best = (key, m, i, q[i])
    _, m, i, q = best
    tour.insert(m, i, disc, q)


def repair(tour: Tour, rng: np.random.Generator, objective: str = "distance") -> None:
    """Insert discs that no leg meets, cheapest first place each, in random order, until all are met."""
    while True:
        miss = np.flatnonzero(~tour.covered())
        if miss.size == 0:
            return
        disc = int(rng.choice(miss))
        if tour.key_mask()[disc]:
            raise AssertionError(f"key disc {disc} is not met by its own turn point")
        insert_cheapest(tour, disc, objective)


def ruin(tour: Tour, rng: np.random.Generator, size: int) -> None:
    """Remove a random key disc and the ``size - 1`` key discs whose centres are nearest to it."""
    keys = np.array([k for ks in tour.keys for k in ks], dtype=np.intp)
    if keys.size == 0:
        return
    seed = int(rng.choice(keys))
    c = tour.layout.centres
    order = np.argsort(_norm(c[keys] - c[seed]), kind="stable")
    for k in keys[order[:size]]:
        m, j = tour.locate(int(k))
        tour.remove(m, j)
