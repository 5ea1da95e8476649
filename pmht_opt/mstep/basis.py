"""The small QP of a condensed M-step on a basis of its rows (:mod:`pmht_opt.mstep.condensed`).

A working set's rows ``C_S`` may depend on each other: the rows of an inner polygon (a backend
without cones) are combinations of its cone's two rows on the path, and rows at neighbouring steps of
a path this smooth move together to within rounding through the dynamics. :func:`row_basis` writes
the rows on independent ones, ``C_S = T C_J``, and :func:`factor_sigma` factors the small QP's matrix
``Sigma = C_J H^-1 C_J'``, by Cholesky where it is definite and on its eigenvectors where it is
singular through the dynamics.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from scipy.linalg import qr, solve_triangular
from scipy.sparse.csgraph import connected_components

#: Rows of the working set whose direction is within this (relative) of the others' span depend on
#: them (:func:`_basis`).
RANK = 1e-9
#: Below this least pivot of the small QP's scaled ``Sigma`` (relative to its unit diagonal) the rows
#: are tested for dependence (:func:`_basis`): rows that depend on each other leave pivots of rounding
#: size where the factorisation does not fail outright.
PIVOT = 1e-13
#: Eigenvalues of a scaled ``Sigma`` that is not definite kept above this fraction of the largest
#: (:func:`_factor`).
EIGEN = 1e-12


Root = tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]


def factor_sigma(sigma: np.ndarray, exact: bool = True) -> tuple[Root | None, np.ndarray]:
    """``((F, back), d)``: the Jacobi scaling ``d`` of ``sigma``, ``F`` with ``F F' = d sigma d`` and
    ``back(v)`` a ``u`` with ``F' u = v``; ``None`` for the pair if there is none to trust.

    ``F`` is the lower Cholesky factor (``back`` its triangular solve). Where that fails and not
    ``exact``, ``F`` holds the eigenvectors of the eigenvalues above :data:`EIGEN` of the largest,
    scaled by their roots: rows whose dependence comes through the dynamics (positions at
    neighbouring steps of a path this smooth move together to within rounding) then share one
    variable, and the answer is checked on the path like any other.
    """
    diag = np.diag(sigma)
    d = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), 1.0)
    S = d[:, None] * sigma * d[None, :]
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        if exact:
            return None, d
    else:
        return (L, lambda v: solve_triangular(L.T, v)), d
    lam, V = np.linalg.eigh(S)
    keep = lam > EIGEN * float(lam.max(initial=0.0))
    if not np.any(keep):
        return None, d
    V, root = V[:, keep], np.sqrt(lam[keep])
    return (V * root, lambda v: V @ (v / root)), d


def row_basis(C: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray | None]:
    """Independent rows ``J`` of ``C`` (indices, in order) and ``T`` with ``C = T C_J`` (``None``
    when every row is independent: ``T`` the identity).

    Rows that share no column cannot depend on each other, so the rows are split into the groups
    that share columns (the rows of one step's constraints: a few rows on a few columns) and each
    group is tested alone, by a pivoted QR of its rows' directions (each row scaled to unit length): a
    row whose diagonal entry is below :data:`RANK` of the group's largest depends on the rows before
    it. The rows of a polygon standing for one cone lie in the plane of its two rows on the path,
    and rounding leaves their dependence near 1e-16, far below the rows of distinct constraints.
    (One QR of all the rows together stalled for up to half a second in the threaded BLAS of a
    loaded machine; the groups' are a few entries each.) Written on ``C_J`` the small QP has a
    definite ``Sigma``: the path moves by ``H^-1 C_S' w = H^-1 C_J' (T' w)``.
    """
    k = C.shape[0]
    if k <= 1:
        return np.arange(k), None
    C = sp.csr_matrix(C)
    shared = (abs(C) @ abs(C).T).tocsr()
    n_groups, group = connected_components(shared, directed=False)
    if n_groups == k:
        return np.arange(k), None
    dense = C[:, np.unique(C.indices)].toarray()  # the columns the rows touch: a few per row
    norms = np.linalg.norm(dense, axis=1)
    unit = dense / np.where(norms > 0, norms, 1.0)[:, None]
    order = np.argsort(group, kind="stable")
    bounds = np.flatnonzero(np.diff(np.concatenate(([-1], group[order], [n_groups]))))
    keep = np.ones(k, dtype=bool)
    pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (dependent rows, basis rows, coef)
    for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
        rows = order[a:b]
        if rows.size == 1:
            continue
        sub = unit[rows]
        sub = sub[:, np.any(sub != 0.0, axis=0)]
        Rq, piv = qr(sub.T, mode="r", pivoting=True)
        diag = np.abs(np.diag(Rq))
        rank = int(np.sum(diag > RANK * diag[0])) if diag[0] > 0 else 0
        if rank == rows.size:
            continue
        # sub[piv].T = Q Rq: the first rank pivots span the rest, with the coefficients R11^-1 R12.
        coef = back_substitution(Rq[:rank, :rank], Rq[:rank, rank:])
        keep[rows[piv[rank:]]] = False
        pairs.append((rows[piv[rank:]], rows[piv[:rank]], coef))
    if keep.all():
        return np.arange(k), None
    basis = np.flatnonzero(keep)
    column = np.full(k, -1)
    column[basis] = np.arange(basis.size)
    T = np.zeros((k, basis.size))
    T[basis, column[basis]] = 1.0
    for dep, base, coef in pairs:
        # C[dep[j]] = sum_i coef[i, j] norms[dep[j]] / norms[base[i]] C[base[i]].
        T[dep[:, None], column[base][None, :]] = (coef * (norms[dep][None, :] / norms[base][:, None])).T
    return basis, T


def back_substitution(R: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``R^-1 B`` for a small upper triangular ``R`` (a row of a group at a time): LAPACK's solve with
    several right-hand sides goes through the threaded BLAS, which stalled for milliseconds per call
    on a loaded machine, for a few rows."""
    X = np.zeros_like(B)
    for i in range(R.shape[0] - 1, -1, -1):
        X[i] = (B[i] - R[i, i + 1 :] @ X[i + 1 :]) / R[i, i]
    return X
