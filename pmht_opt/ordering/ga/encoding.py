r"""How the GA encodes a tour, draws random ones and costs a whole population at once.

Encoding
--------
A solution is a permutation ``p`` of the ``N`` locales and ``M - 1`` sorted break points
``0 < b_1 < ... < b_{M-1} < N``. With ``b_0 = 0`` and ``b_M = N``, platform ``m`` (0-based) flies
``p[b_m : b_{m+1}]`` from its own start; a minimum route length ``min_tour`` means
``b_{m+1} - b_m >= min_tour``. The population keeps the *heads* ``[b_0, ..., b_{M-1}]``, the position in
``p`` of each route's first locale.

Random breaks are uniform over the compositions of ``N`` into ``M`` routes of at least ``min_tour``
locales (stars and bars: ``M - 1`` distinct sorted slots ``c_m`` in ``0 .. N - M min_tour + M - 2`` give
``b_m = c_m + m (min_tour - 1) + 1``); with ``min_tour = 1`` this is Kirk's choice of ``M - 1`` distinct
breaks in ``1 .. N - 1``. (Kirk's code draws constrained breaks from a different, non-uniform law.)

Cost
----
Stack the locales ``z_0 .. z_{N-1}`` and the starts ``s_0 .. s_{M-1}`` as rows ``0 .. N+M-1`` of a table
``L[r, n] = ||row_r - z_n||``. Each locale is entered exactly once, from the previous locale of its route
or, if it heads route ``m``, from start ``s_m``. With ``prev_k = p_{k-1}`` and ``prev_{b_m} = N + m``,

.. math::

    C(p, b) = \sum_{k=0}^{N-1} L[\mathrm{prev}_k, p_k],

so the whole population is costed by one gather ``L.ravel()[prev * N + p]`` and one row sum. Closed
routes (each platform flies back to its start) add the return legs
``\sum_m \lVert z_{p[b_{m+1} - 1]} - s_m \rVert``, a second gather of ``M`` entries per member.
"""

from __future__ import annotations

import numpy as np

from pmht_opt.scenario import Scenario


def random_heads(rng: np.random.Generator, rows: int, N: int, M: int, min_tour: int) -> np.ndarray:
    """``(rows, M)`` route heads ``[0, b_1, ..., b_{M-1}]``, uniform over the valid compositions.

    Floyd's algorithm for a uniform ``(M - 1)``-subset of the slots, run for all rows at once:
    ``M - 1`` vectorised steps, each one call of the generator.
    """
    heads = np.zeros((rows, M), dtype=np.intp)
    k = M - 1
    if k == 0:
        return heads
    slots = N - M * min_tour + k  # values 0 .. slots-1
    chosen = np.empty((rows, k), dtype=np.intp)
    for s in range(k):
        j = slots - k + s
        t = rng.integers(0, j + 1, size=rows)
        taken = (chosen[:, :s] == t[:, None]).any(axis=1)
        chosen[:, s] = np.where(taken, j, t)
    chosen.sort(axis=1)
    heads[:, 1:] = chosen + np.arange(1, M) * (min_tour - 1) + 1
    return heads


def random_population(
    rng: np.random.Generator, size: int, N: int, M: int, min_tour: int
) -> tuple[np.ndarray, np.ndarray]:
    """``size`` random permutations ``(size, N)`` and their random heads ``(size, M)``."""
    perms = rng.permuted(np.tile(np.arange(N, dtype=np.intp), (size, 1)), axis=1)
    return perms, random_heads(rng, size, N, M, min_tour)


def heads_to_routes(perm: np.ndarray, heads: np.ndarray) -> list[np.ndarray]:
    """Cut one permutation at its heads into one route per platform."""
    bounds = [*heads.tolist(), perm.size]
    return [perm[bounds[m] : bounds[m + 1]].copy() for m in range(heads.size)]


class PopulationCost:
    """The cost ``C(p, b)`` of every member of a population, by one gather and one row sum.

    Parameters
    ----------
    scenario
        Locales ``(N, 2)`` and starts ``(M, 2)``.
    population
        Number of members costed per call (the buffers are allocated once).
    closed
        Add each route's leg from its last locale back to its platform's start.
    """

    def __init__(self, scenario: Scenario, population: int, closed: bool = False) -> None:
        z, s = scenario.locales, scenario.start_positions
        N, M = z.shape[0], s.shape[0]
        self.N, self.M = N, M
        pts = np.vstack([z, s])
        self._table = np.sqrt(((pts[:, None, :] - z[None, :, :]) ** 2).sum(-1)).ravel()
        self._start_rows = (N + np.arange(M, dtype=np.intp)) * N
        self._rows = np.arange(population)[:, None]
        self._legs_at = np.empty((population, N), dtype=np.intp)
        # Return legs: back[m * N + n] = ||z_n - s_m||, read at each route's last locale.
        self._back = self._table.reshape(N + M, N)[N:].ravel() if closed else None
        self._route_rows = np.arange(M, dtype=np.intp) * N

    def __call__(self, perms: np.ndarray, heads: np.ndarray) -> np.ndarray:
        """``(P,)`` costs of permutations ``(P, N)`` cut at heads ``(P, M)``."""
        legs_at = self._legs_at
        np.multiply(perms[:, :-1], self.N, out=legs_at[:, 1:])
        legs_at[self._rows, heads] = self._start_rows
        legs_at += perms
        cost = self._table[legs_at].sum(axis=1)
        if self._back is not None:
            ends = np.empty_like(heads)
            ends[:, :-1] = heads[:, 1:] - 1
            ends[:, -1] = self.N - 1
            last = perms[self._rows, ends]
            cost = cost + self._back[self._route_rows + last].sum(axis=1)
        return cost
