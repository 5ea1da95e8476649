"""Exact smoothing of a batch of linear-Gaussian systems by a banded LU of their optimality conditions.

Each system ``b`` of the batch, with ``K`` measurement columns sharing one weight sequence, is::

    x_0 known,   x_t = F x_{t-1} + v_t,  v_t ~ N(0, Q)  (t = 1..T),
    y_t = h' x_t + e_t,  e_t ~ N(0, r / w_t)  (no measurement where w_t == 0).

The smoothed means are the minimisers of the weighted least-squares objective

    J(x) = 1/2 sum_t (x_t - F x_{t-1})' Q^-1 (x_t - F x_{t-1}) + sum_t w_t / (2 r) (h' x_t - y_t)^2.

Why not the normal equations
----------------------------
Eliminating the dynamics gives the banded "information form" ``(D' Q^-1 D + P) x = P y`` with ``D``
the block-bidiagonal difference operator (``(D x)_t = x_t - F x_{t-1}``) and ``P`` the penalty. Its
entries are formed with cancellation: ``D' Q^-1 D`` annihilates every noise-free path, i.e. its rows
sum to zero against those paths, and it is exactly this structure that fixes the path on a stretch
without measurements (``w_t = 0``, "coasting"), where the answer is an extrapolation. For the
constant-acceleration model with ``q = 1e-8`` the entries of ``Q^-1`` are near 1e10 while the
penalty is near 1e2, and the curvature along nearly noise-free paths over a coasting stretch of
length ``l`` falls like ``l^-5``: the condition number passes 1/eps, a rounding of the entries in
their last bit breaks the cancellation, and a banded Cholesky returns positions that can be wrong
in the first digit. Iterative refinement cannot repair a factorisation that poor.

The formulation used here
-------------------------
Keep the dynamics as constraints ``x_t - F x_{t-1} - Q lam_t = 0`` with multipliers ``lam_t``
(the process noise is ``v_t = Q lam_t``, its whitened value ``u_t = L' lam_t`` with ``L L' = Q``).
The optimality conditions are, for ``t = 1..T`` (``lam_{T+1} = 0``)::

    x_t - F x_{t-1} - Q lam_t                  = 0          (F x_0 on the right at t = 1)
    (w_t / r) h h' x_t + lam_t - F' lam_{t+1}   = (w_t / r) h y_t

a symmetric indefinite system in ``(lam_t, x_t)`` whose entries are the model's data themselves:
``F``, ``Q`` and the penalty, with no inverse and no product of them. A small componentwise
perturbation of this matrix is therefore a small relative perturbation of the model (of each
occurrence of ``F``, ``Q``, ``w_t``, ``y_t``), to which the smoothed path is insensitive even where
the information-form matrix is nearly singular: it is the problem's own conditioning that then
bounds the error, not that of a derived matrix.

The unknowns are scaled by ``d = sqrt(diag Q)`` (``x = d * xs``, ``lam = lam_s / d``), which makes
the blocks dimensionless: ``diag(1/d) F diag(d)`` and ``diag(1/d) Q diag(1/d)`` (a correlation
matrix) do not depend on ``q`` or on the time step for the constant-acceleration model, and the
penalty becomes ``sigma_t = w_t (h' diag(d))^2 / r``, a signal-to-noise ratio per step. Ordered as
``[lam_1, x_1, lam_2, x_2, ...]`` the matrix is banded with half-bandwidth ``n`` when ``F`` is
upper triangular and ``h`` picks one component (``2n - 1`` in general; no other order of a step's
unknowns gives a narrower band). The systems of the batch are stacked into one block-diagonal
band and the ``K`` columns share the factorisation: one LAPACK ``gbsv`` (LU with partial
pivoting) per group of systems, the groups fixed by the batch's size and run on concurrent threads
(:mod:`solvers.band_lu`); for a band this narrow their LU is the whole band's to the last bit.

Partial pivoting alone gives a small *normwise* backward error only: depending on the rows it picks,
parts of the elimination follow the information form above, and on long coasting stretches with a
small ``r`` the positions can be off by more than 1e-9 of their size. One step of iterative
refinement in working precision, with the residual evaluated from the block form above (the
innovation ``y_t - h' x_t`` is formed before it is multiplied by the weight, so a large weight does
not cancel), brings the *componentwise* backward error to the rounding level (Skeel, "Iterative
refinement implies numerical stability for Gaussian elimination", Math. Comp. 35, 1980), and with
it the property of the previous paragraph. ``tests/test_banded.py`` compares the result with exact
rational arithmetic, a dense least-squares solve in the noise variables and the RTS smoother in
extended precision.

The objective is evaluated without cancellation: the prior term from the multipliers
(``1/2 sum ||L' lam_t||^2``) rather than from differences of nearly equal states, which lose all
their digits when ``q dt^5`` is small against the positions, and the fit term from the innovations.

The parts: :mod:`~solvers.banded.smoother` (:class:`BandedSmoother`, :class:`BandedFactor`),
:mod:`~solvers.banded.result` (:class:`BandedSmootherResult`) and :mod:`~solvers.banded.cached`
(:func:`banded_smoother`, the one-call form).
"""

from solvers.banded.cached import banded_smoother
from solvers.banded.result import BandedSmootherResult
from solvers.banded.smoother import BandedFactor, BandedSmoother

__all__ = ["BandedFactor", "BandedSmoother", "BandedSmootherResult", "banded_smoother"]
