"""Full coverage at a sensor radius: :func:`plan_coverage`.

A locale is covered when some platform's path passes within the sensor radius of it (docs/model.md
section 11). The planner looks for the shortest smooth plan that covers every locale: tours of the
locales (:mod:`.search`), the shortest polylines through the locales' discs in tour order
(:mod:`.discs`), the tours ordered again on the points where those polylines touch the discs, and the
model's smoother flying the best polylines with each disc a hard constraint (:mod:`.tracking`).
"""

from pmht_opt.planners.coverage.planner import CoverageProgress, missed_locales, plan_coverage

__all__ = ["CoverageProgress", "missed_locales", "plan_coverage"]
