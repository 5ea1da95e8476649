"""The Kalman cross-check: a Rauch-Tung-Striebel smoother on the synthetic measurements.

Without constraints the M-step is a smoothing problem: the paths that maximise ``log P(X)`` plus the
weighted fit are the smoothed means of a linear-Gaussian model measured by ``ztilde = WZ / W`` with
covariance ``R / W`` (paper eqs 15-16; docs/model.md section 4.4). The x and y axes share ``F3``, ``Q3`` and
``R / W``, so one covariance recursion per platform serves both axes' means. The process noise of
the answer comes from the smoother's adjoint recursion, so the EM objective's prior term is the exact
smoother's at every time step a scenario accepts.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

import solvers
from pmht_opt.mstep.base import MStep, MStepData, MStepOutput
from solvers.kalman import rts_smoother


class KalmanMStep(MStep):
    """RTS smoother per platform and axis on the synthetic measurements; takes no constraints."""

    name: ClassVar[str] = "kalman"

    def _solve(self, data: MStepData) -> MStepOutput:
        zt, W = data.synthetic()
        model = self.model
        x0 = np.stack([self.x0[:, 0:3], self.x0[:, 3:6]], axis=-1)  # (M, 3, 2)
        res = rts_smoother(
            F=model.F3,
            Q=model.Q3,
            H=np.array([[1.0, 0.0, 0.0]]),
            R=np.array([[data.r]]),
            x0=x0,
            P0=np.zeros((self.M, 3, 3)),
            y=zt.transpose(1, 0, 2)[:, :, None, :],
            weight=W.T,
        )
        means = res.means  # (M, T+1, 3, 2)
        states = np.concatenate([means[..., 0], means[..., 1]], axis=2)
        # The process noise from the smoother's adjoint recursion, not from the states: the EM
        # objective's prior term then keeps its digits at small dt (solvers.kalman).
        noise = np.concatenate([res.noise[..., 0], res.noise[..., 1]], axis=2)  # (M, T, 6)
        return MStepOutput(states=states, status=solvers.Status.OPTIMAL, raw_status="exact", noise=noise)
