"""The cheap check every M-step answer passes before it is used.

A backend's "solved" is not taken on trust: on badly scaled problems (a tiny ``r``, long coasting) an
interior-point or ADMM solver can stop far from the optimum and report success. The answer is compared
with the exact smoother of the unconstrained problem (:class:`solvers.banded.BandedSmoother`, a few
milliseconds for all platforms):

* a platform without constraint rows must agree with it in position within :data:`AGREEMENT` times
  the positions' scale (at least 1);
* a platform with constraint rows must not have a lower M-step cost than the unconstrained optimum
  (constraints only add cost) beyond :data:`COST_SLACK` of its size.

Every answer must also be finite. A failed check raises :class:`~pmht_opt.exceptions.WrongAnswerError`
(a :class:`~pmht_opt.exceptions.SolverError`)
naming the status the backend reported and, for a finite answer, the platform and how far it is off.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from pmht_opt.exceptions import WrongAnswerError
from pmht_opt.model import PX, PY

if TYPE_CHECKING:
    from pmht_opt.mstep.base import MStep, MStepData, MStepOutput

#: Largest position difference to the exact smoother, relative to the positions' scale (at least 1).
AGREEMENT = 1e-6
#: How far below the unconstrained optimum a constrained platform's cost may appear (relative).
COST_SLACK = 1e-6


def check_answer(mstep: MStep, data: MStepData, out: MStepOutput) -> None:
    """Raise :class:`WrongAnswerError` unless ``out`` is a finite, plausible optimum of ``data``."""
    backend = getattr(mstep, "solver", mstep.name)
    if not np.all(np.isfinite(out.states)):
        raise WrongAnswerError(
            f"{backend}: the M-step answer is not finite (status {out.raw_status}).", backend, out.raw_status
        )
    if mstep.name == "banded":
        return  # the reference itself: exact by construction (iterative refinement to rounding level)
    exact: Any = out.info.get("exact")
    if exact is None:
        exact = mstep.reference().smooth(data)
    p_exact = np.concatenate([exact.means[..., 0:1, 0], exact.means[..., 0:1, 1]], axis=2)  # (M, T+1, 2)
    p_out = out.states[:, :, [PX, PY]]
    for m in range(out.states.shape[0]):
        if m in out.constrained:
            _check_cost(mstep, data, out, m, float(np.sum(exact.objective[m])), backend)
            continue
        scale = max(1.0, float(np.max(np.abs(p_exact[m]))))
        gap = float(np.max(np.abs(p_out[m] - p_exact[m])))
        if gap > AGREEMENT * scale:
            raise WrongAnswerError(
                f"{backend}: the M-step answer of platform {m} is {gap:.3g} from the exact smoother's "
                f"although the backend reported {out.raw_status!r}: its tolerances, or the problem's "
                "scaling, are too loose for an exact M-step (try solver='auto' or 'banded').",
                backend,
                out.raw_status,
            )


def _check_cost(mstep: MStep, data: MStepData, out: MStepOutput, m: int, floor: float, backend: str) -> None:
    """A constrained platform's cost may not fall below the unconstrained optimum ``floor``."""
    states = out.states[m : m + 1]
    if out.noise is not None:
        prior = 0.5 * float(np.sum(out.noise[m] ** 2))
    else:
        u = mstep.model.process_noise(states)
        prior = 0.5 * float(np.sum(u * u))
    pos = states[0, 1:][:, [PX, PY]]
    W, WZ = data.W[:, m], data.WZ[:, m]
    zt = np.where(W[:, None] > 0, WZ / np.where(W > 0, W, 1.0)[:, None], 0.0)
    fit = float(np.sum(W[:, None] * (pos - zt) ** 2)) / (2.0 * data.r)
    cost = prior + fit
    if cost < floor - COST_SLACK * max(1.0, abs(floor)):
        raise WrongAnswerError(
            f"{backend}: the constrained M-step answer of platform {m} costs {cost:.6g}, below the "
            f"unconstrained optimum {floor:.6g}: it is not a solution (status {out.raw_status!r}).",
            backend,
            out.raw_status,
        )
