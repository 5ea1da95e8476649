"""The motion model and the fitting penalty (paper eqs. 17-18; docs/model.md sections 2-3).

State of a platform: ``x = [px, vx, ax, py, vy, ay]``; each axis is an independent constant-acceleration
(white-noise jerk) model. The process noise is written through a Cholesky factor ``L`` of ``Q``
(``x_t = F x_{t-1} + L u_t`` with ``u_t ~ N(0, I)``); this is what keeps the M-step QP well scaled,
where ``Q^-1`` in a Hessian would not be (docs/model.md section 5).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from pmht_opt import validation
from pmht_opt.exceptions import ScenarioError

#: Indices of the state components.
PX, VX, AX, PY, VY, AY = range(6)
#: Indices of the positions within the state.
POS = np.array([PX, PY])
#: Indices of the velocities within the state.
VEL = np.array([VX, VY])
#: Indices of the accelerations within the state.
ACC = np.array([AX, AY])
STATE_DIM = 6


@dataclass(frozen=True)
class MotionModel:
    """Constant-acceleration dynamics with time step ``dt`` and noise intensity ``q``."""

    dt: float = 1.0
    q: float = 1e-8

    def __post_init__(self) -> None:
        # The ranges a Scenario accepts: the ones the numerics handle (pmht_opt.validation).
        object.__setattr__(self, "dt", validation.real("dt", self.dt, ScenarioError, *validation.DT_RANGE))
        object.__setattr__(self, "q", validation.real("q", self.q, ScenarioError, *validation.Q_RANGE))

    @cached_property
    def F3(self) -> np.ndarray:
        """Per-axis transition matrix ``(3, 3)``."""
        dt = self.dt
        return np.array([[1.0, dt, dt * dt / 2.0], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])

    @cached_property
    def Q3(self) -> np.ndarray:
        """Per-axis process noise covariance ``(3, 3)``, already multiplied by ``q``."""
        dt = self.dt
        return self.q * np.array(
            [
                [dt**5 / 20.0, dt**4 / 8.0, dt**3 / 6.0],
                [dt**4 / 8.0, dt**3 / 3.0, dt**2 / 2.0],
                [dt**3 / 6.0, dt**2 / 2.0, dt],
            ]
        )

    @cached_property
    def L3(self) -> np.ndarray:
        """Lower Cholesky factor of :attr:`Q3`."""
        return np.linalg.cholesky(self.Q3)

    @cached_property
    def L3_inv(self) -> np.ndarray:
        """Inverse of :attr:`L3` (computed once; used by every evaluation of the EM objective)."""
        return np.linalg.inv(self.L3)

    @cached_property
    def F(self) -> np.ndarray:
        """Full transition matrix ``(6, 6)``, ``blockdiag(F3, F3)``."""
        return np.kron(np.eye(2), self.F3)

    @cached_property
    def Q(self) -> np.ndarray:
        """Full process noise covariance ``(6, 6)``."""
        return np.kron(np.eye(2), self.Q3)

    @cached_property
    def L(self) -> np.ndarray:
        """Lower Cholesky factor of :attr:`Q`, ``(6, 6)``."""
        return np.kron(np.eye(2), self.L3)

    @cached_property
    def H(self) -> np.ndarray:
        """Position selector ``(2, 6)``."""
        H = np.zeros((2, STATE_DIM))
        H[0, PX] = 1.0
        H[1, PY] = 1.0
        return H

    def propagate(self, x0: np.ndarray, steps: int) -> np.ndarray:
        """Noise-free propagation of states ``x0 (..., 6)``: returns ``(..., steps + 1, 6)``."""
        out = np.empty((*x0.shape[:-1], steps + 1, STATE_DIM))
        out[..., 0, :] = x0
        for t in range(1, steps + 1):
            out[..., t, :] = out[..., t - 1, :] @ self.F.T
        return out

    def process_noise(self, states: np.ndarray) -> np.ndarray:
        """Standardised process noise ``u_t = L^-1 (x_t - F x_{t-1})`` of paths ``(..., T+1, 6)``.

        Returns ``(..., T, 6)``; ``0.5 * sum(u**2)`` is ``-log P(X)`` up to a constant.
        """
        resid = states[..., 1:, :] - states[..., :-1, :] @ self.F.T
        # L is block diagonal with two lower-triangular 3x3 blocks: solve per axis.
        out = np.empty_like(resid)
        out[..., :3] = resid[..., :3] @ self.L3_inv.T
        out[..., 3:] = resid[..., 3:] @ self.L3_inv.T
        return out

    def log_prior(self, states: np.ndarray) -> float:
        """``log P(X)`` of paths ``(M, T+1, 6)`` with known starts, without its constant normaliser."""
        u = self.process_noise(states)
        return float(-0.5 * np.sum(u * u))
