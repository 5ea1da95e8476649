"""``plan(scenario, method="coverage")``: the coverage planner behind the one entry point."""

from __future__ import annotations

from dataclasses import dataclass

from pmht_opt.constraints.params import positive_number
from pmht_opt.planners.base import Planner
from pmht_opt.planners.coverage.planner import DEFAULT_SHRINK, CoverageProgress, plan_coverage
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import PMHTConfig, Settings
from pmht_opt.stopping import MaxIterations, Progress, ProgressObserver, StoppingCriterion

#: Orderings of the tour search when nothing else stops it: more than the default search takes.
SEARCH_ITERATIONS = 10_000


@dataclass(frozen=True)
class CoverageOptions:
    """The options of ``plan(..., method="coverage")`` (:func:`plan_coverage`'s, which see)."""

    radius: float | None = None
    orderer: str = "auto"
    starts: int = 3
    rounds: int = 4
    beam: int = 1
    keep: int = 2
    shrink: float = DEFAULT_SHRINK
    iterations: int | None = None

    def __post_init__(self) -> None:
        if self.radius is not None:
            positive_number("radius", self.radius)


class CoveragePlanner(Planner):
    """Every locale within its sensor radius, with the shortest smooth paths found."""

    name = "coverage"
    summary = "every locale within its sensor radius of a path, shortest smooth paths (recommended)"
    Options = CoverageOptions

    def default_stop(self) -> StoppingCriterion:
        return MaxIterations(SEARCH_ITERATIONS)

    def run(
        self,
        scenario: Scenario,
        settings: Settings,
        options: CoverageOptions,
        stop: StoppingCriterion,
        callback: ProgressObserver | None,
    ) -> PlanResult:
        config = PMHTConfig.of(settings, PMHTConfig().options)
        count = [0]

        def report(progress: CoverageProgress) -> None:
            count[0] += 1
            if callback is not None:
                callback(Progress(count[0], [progress.best], progress.elapsed, True, progress.stage))

        return plan_coverage(
            scenario,
            options.radius,
            config,
            seed=settings.seed,
            orderer=options.orderer,
            starts=options.starts,
            rounds=options.rounds,
            beam=options.beam,
            keep=options.keep,
            shrink=options.shrink,
            iterations=options.iterations,
            callback=report,
            stop=stop,
        )
