"""The GA-TSP baseline: a Kirk-style genetic algorithm for the open multiple TSP.

One concept per module: :mod:`.encoding` (permutation and breaks, random tours, the population's cost),
:mod:`.operators` (moves, break rules and the two tables of the paper's GA and the improved one),
:mod:`.restart` (restart policies) and :mod:`.solve` (the loop and :func:`solve_ga_tsp`). Stopping
criteria are shared with the EM planner (:mod:`pmht_opt.stopping`).
"""

from __future__ import annotations

from pmht_opt.ordering.ga.operators import (
    IMPROVED,
    KIRK,
    OPERATOR_SETS,
    Breaks,
    Copy,
    Flip,
    OperatorSet,
    RouteExchange,
    SegmentMove,
    Slide,
    Slot,
    Swap,
)
from pmht_opt.ordering.ga.restart import NoRestart, RestartPolicy, StallRestart
from pmht_opt.ordering.ga.solve import GAParams, solve_ga_tsp

__all__ = [
    "IMPROVED",
    "KIRK",
    "OPERATOR_SETS",
    "Breaks",
    "Copy",
    "Flip",
    "GAParams",
    "NoRestart",
    "OperatorSet",
    "RestartPolicy",
    "RouteExchange",
    "SegmentMove",
    "Slide",
    "Slot",
    "StallRestart",
    "Swap",
    "solve_ga_tsp",
]
