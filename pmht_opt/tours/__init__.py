"""Straight-line tours through discs: the close-enough TSP and its multi-vehicle generalisation.

``plan_tours(DiscProblem(starts, centres, radii, closed), TourSettings(...))`` returns one polyline per
vehicle, from its start (and back when closed), that together meet every target's disc, shortest in
total (or in the longest route). See :mod:`pmht_opt.tours.engine` for the method.

This package is self-contained: it uses numpy, scipy, pyvrp, the ``solvers`` layer and
:mod:`pmht_opt.exceptions` only.
"""

from pmht_opt.tours.engine import plan_tours
from pmht_opt.tours.mennell import read_mennell
from pmht_opt.tours.problem import DiscProblem, DiscTours, Progress, TourSettings
from pmht_opt.tours.verify import check_tours, coverage_gaps

__all__ = [
    "DiscProblem",
    "DiscTours",
    "Progress",
    "TourSettings",
    "check_tours",
    "coverage_gaps",
    "plan_tours",
    "read_mennell",
]
