"""Full coverage at a sensor radius: ``plan(scenario, "coverage")`` and :func:`plan_coverage`.

A locale is covered when some platform's path passes within its sensor radius (docs/model.md
section 11). The planner finds the shortest straight-line routes that meet every locale's disc
(:mod:`pmht_opt.tours`) and flies them as smooth paths that meet every disc at its full radius
(:mod:`.fly`, with the smoothing rule of :mod:`.flight` and the disc constraint of :mod:`.discs`).
"""

from pmht_opt.planners.coverage.method import CoverageOptions, CoveragePlanner
from pmht_opt.planners.coverage.planner import missed_locales, plan_coverage

__all__ = ["CoverageOptions", "CoveragePlanner", "missed_locales", "plan_coverage"]
