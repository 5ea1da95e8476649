"""The exact unconstrained M-step: a structured direct solve of the smoothing problem.

Without constraints the M-step is the smoothing problem of a linear-Gaussian model measured by the
synthetic measurements ``WZ / W`` with covariance ``R / W`` (docs/model.md section 4.4). Per platform
and axis it is banded: :class:`solvers.banded.BandedSmoother` solves its optimality conditions (the
dynamics kept as constraints, no ``Q^-1`` formed) by a banded LU with one step of iterative
refinement, to the rounding level, for the whole batch of platforms at once (x and y share the
factorisation). It also returns the process noise from the multipliers, so the prior term of the EM
objective keeps its precision when ``q dt^5`` is tiny against the positions.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

import solvers
from pmht_opt.exceptions import SolverError
from pmht_opt.mstep.base import MStep, MStepData, MStepOutput
from solvers.banded import BandedSmoother, BandedSmootherResult


class BandedMStep(MStep):
    """Exact unconstrained M-steps of every platform by one banded solve; takes no constraints."""

    name: ClassVar[str] = "banded"

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        E1 = np.array([1.0, 0.0, 0.0])
        self.smoother = BandedSmoother(self.model.F3, self.model.Q3, E1, self.T, self.M)

    def smooth(self, data: MStepData) -> BandedSmootherResult:
        """The exact smoother's answer for these weights (every platform, both axes)."""
        zt, W = data.synthetic()
        x0 = np.stack([self.x0[:, 0:3], self.x0[:, 3:6]], axis=-1)  # (M, 3, 2)
        try:
            return self.smoother.solve(data.r, x0, zt.transpose(1, 0, 2), W.T, refine=1, threads=self.threads)
        except solvers.ProblemError as err:
            raise SolverError(f"banded: the M-step cannot be solved: {err}", "banded", "error") from err

    def _solve(self, data: MStepData) -> MStepOutput:
        states, noise = self.smooth(data).side_by_side()  # x then y: [px, vx, ax, py, vy, ay]
        return MStepOutput(states=states, status=solvers.Status.OPTIMAL, raw_status="exact", noise=noise)
