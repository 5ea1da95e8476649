"""The sizes the scaling study measures, and its random scenarios.

A headline size (the target's problem), a centre, and sweeps of N, T and M one at a time through the
centre, so each sweep's slope isolates one size. Every size is a random scenario of the 10 x 10 box,
drawn from one seed, so the sizes differ only in N, T and M.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt import Scenario

#: The target at the headline size of the full study (gated E-step).
TARGET_SECONDS = 60.0
TARGET_GIB = 4.0
#: The target at the scale point of the full study (N = 5000, T = 5000, M = 20; gated, plain EM).
SCALE_SECONDS = 60.0
SCALE_GIB = 8.0
#: E-step modes compared: ``estep_gate`` "auto" (gated) and off (dense).
GATES = ("auto", "off")


@dataclass(frozen=True)
class Design:
    """Sizes of one run of the study: ``(N, T, M)`` triples, the EM iterations and the repeats."""

    headline: tuple[int, int, int]
    centre: tuple[int, int, int]
    n_values: tuple[int, ...]
    t_values: tuple[int, ...]
    m_values: tuple[int, ...]
    iterations: int
    reps: int
    #: The largest size, planned once with plain EM (``anneal=None``) and the gated E-step: the
    #: default annealed EM's first E-steps at a large ``r`` gate almost nothing, and at this size a
    #: dense E-step holds ``N x T x M`` weights at once.
    scale: tuple[int, int, int]

    def sweep_points(self) -> dict[str, list[tuple[int, int, int]]]:
        """``(N, T, M)`` of each sweep; all pass through the centre."""
        n0, t0, m0 = self.centre
        return {
            "N": [(n, t0, m0) for n in self.n_values],
            "T": [(n0, t, m0) for t in self.t_values],
            "M": [(n0, t0, m) for m in self.m_values],
        }


FULL = Design(
    headline=(1000, 2000, 10),
    centre=(500, 1000, 5),
    n_values=(100, 200, 500, 1000),
    t_values=(250, 500, 1000, 2000),
    m_values=(1, 2, 5, 10),
    iterations=100,
    reps=3,
    scale=(5000, 5000, 20),
)
QUICK = Design(
    headline=(60, 80, 3),
    centre=(40, 60, 2),
    n_values=(20, 40),
    t_values=(30, 60),
    m_values=(1, 2),
    iterations=8,
    reps=1,
    scale=(120, 100, 4),
)


def scaling_scenario(n_locales: int, horizon: int, n_platforms: int, seed: int) -> Scenario:
    """Random locales and starts in the 10 x 10 box."""
    rng = np.random.default_rng(seed)
    return Scenario(
        locales=rng.uniform(0.0, 10.0, (n_locales, 2)),
        starts=rng.uniform(0.0, 10.0, (n_platforms, 2)),
        horizon=horizon,
        bounds=(0.0, 10.0, 0.0, 10.0),
        name=f"random N={n_locales} T={horizon} M={n_platforms} seed={seed}",
    )


def params(
    task: str, size: tuple[int, int, int], solver: str, gate: str, iterations: int, seed: int, rep: int
) -> dict[str, Any]:
    """The parameters of one trial (:func:`studies.scaling_study.measure.trial`)."""
    n, t, m = size
    return {
        "task": task,
        "n_locales": n,
        "horizon": t,
        "n_platforms": m,
        "solver": solver,
        "gate": gate,
        "iterations": iterations,
        "seed": seed,
        "rep": rep,
    }
