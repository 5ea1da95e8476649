"""Naming the constraints that make an M-step infeasible.

When a platform's constrained M-step fails (a verdict of infeasibility, or a solver that stalls, as
interior-point and ADMM solvers do on infeasible problems without always certifying it), the same QP
is solved again with every block soft (:meth:`~pmht_opt.mstep.rows.Imposed.relaxed`, a large penalty
weight), by Clarabel where it is installed: the slacks that stay positive belong to the constraints
that cannot all be met, at the time steps where they clash. If none does, the problem was feasible and
the failure was the solver's own: a :class:`~pmht_opt.exceptions.SolverError` with its status.
"""

from __future__ import annotations

import numpy as np

import solvers
from pmht_opt.exceptions import ConfigError, InfeasibleError, PmhtOptError, SolverError
from pmht_opt.mstep.platform import HorizonQP
from pmht_opt.mstep.rows import PlatformRows

#: Penalty weight of the soft re-solve that locates infeasible constraints.
DIAGNOSIS_WEIGHT = 1e6
#: Slacks above this in the soft re-solve mark a constraint as a culprit.
CULPRIT_SLACK = 1e-6


def diagnose(
    probe: HorizonQP,
    platform: int,
    W: np.ndarray,
    WZ: np.ndarray,
    r: float,
    rows: PlatformRows,
    sol: solvers.QPSolution,
) -> PmhtOptError:
    """The error for platform ``platform``'s failed M-step: which constraints conflict, where it can tell.

    ``probe`` is a fresh full-horizon :class:`~pmht_opt.mstep.platform.HorizonQP` of the platform;
    ``sol`` is the infeasible answer.
    """
    names = sorted({i.name for i in rows.items if not i.soft})
    where = f"platform {platform}: the constraints {', '.join(names)} cannot all be met"
    plain: PmhtOptError
    if sol.status in solvers.INFEASIBLE:
        plain = InfeasibleError(
            f"{sol.backend}: {where} (status {sol.raw_status}).", sol.backend, sol.raw_status
        )
    else:
        plain = SolverError(
            f"{sol.backend}: the M-step solve failed (platform {platform}) with status {sol.raw_status!r}; "
            "its constraints can be met (a relaxed solve needs no slack), so the failure is the solver's.",
            sol.backend,
            sol.raw_status,
        )
    relaxed_rows = PlatformRows([i.relaxed(DIAGNOSIS_WEIGHT) for i in rows.items], ((-1,),))
    try:
        relaxed = probe.solve(W, WZ, r, relaxed_rows)
    except (SolverError, ConfigError):
        return plain
    if not relaxed.usable(True) or relaxed.x is None or probe.extra is None:
        return plain
    culprits: dict[str, list[tuple[int, str | None, float]]] = {}
    for value, owner in zip(probe.slacks(relaxed.x), probe.extra.slack_owner, strict=True):
        if value > CULPRIT_SLACK:
            culprits.setdefault(owner.constraint, []).append((owner.time, owner.label, float(value)))
    if not culprits:
        return plain
    parts = []
    for name, hits in sorted(culprits.items(), key=lambda kv: -max(h[2] for h in kv[1])):
        times = sorted({h[0] for h in hits})
        labels = sorted({h[1] for h in hits if h[1]}, key=lambda s: (len(s), s))
        span = f"t = {times[0]}" if len(times) == 1 else f"{len(times)} steps in t = {times[0]}..{times[-1]}"
        if labels:
            span += " (" + ", ".join(labels[:5]) + (", ..." if len(labels) > 5 else "") + ")"
        parts.append(f"{name} on platform {platform} at {span}, short by up to {max(h[2] for h in hits):.3g}")
    return InfeasibleError(
        f"{sol.backend}: infeasible constraints: " + "; ".join(parts) + ". Relax them or pass soft=True.",
        sol.backend,
        sol.raw_status,
    )
