"""Planner settings of a mission: which planner runs, and its options (the ``[planner]`` table).

.. code-block:: toml

    [planner]
    kind = "pmht"                 # "pmht", "smoothed" or "coverage"
    solver = "auto"
    iterations = 100
    anneal = { start = 62500.0, iterations = 30 }   # or [start, iterations], or false
    return_to_base = true

    [planner.ordering]            # the smoothed planner's ordering: a method and its own options
    method = "ga"
    seed = 0

Every setting has the library's default; the command line's options override the file's.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from pmht_opt.anneal import Anneal
from pmht_opt.constraints.base import Constraint
from pmht_opt.constraints.params import positive_number
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.io import fields
from pmht_opt.ordering import ordering_method
from pmht_opt.planner import PMHTConfig

#: The planners a mission can name.
PLANNERS = ("pmht", "smoothed", "coverage")
#: The ordering methods a mission can name (whether each is installed is checked when it runs).
ORDERINGS = ("ga", "ortools", "pyvrp")
#: How the smoothed planner cuts a platform's horizon (:func:`~pmht_opt.plan_smoothed`'s ``split``).
SPLITS = ("equal", "distance")


def _library_default(name: str) -> Any:
    f = next(f for f in dataclasses.fields(PMHTConfig) if f.name == name)
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


@dataclass
class PlannerSettings:
    """Which planner a mission runs and how.

    Parameters
    ----------
    kind
        ``"pmht"`` (:func:`~pmht_opt.plan_pmht`), ``"smoothed"`` (an ordering, then
        :func:`~pmht_opt.plan_smoothed`) or ``"coverage"`` (``plan_coverage``, where installed).
    solver, tol, update_time_prior
        As in :class:`~pmht_opt.PMHTConfig`; ``update_time_prior=None`` keeps the preset's.
    iterations
        ``PMHTConfig.max_iter``.
    anneal
        The schedule of ``r``; ``None`` keeps the preset's (the library's default, or none with
        ``paper``), ``Anneal(iterations=0)`` is plain EM.
    paper
        Start from :meth:`PMHTConfig.paper` instead of the defaults.
    return_to_base
        Every platform ends at its start, at rest (:meth:`~pmht_opt.Terminal.return_to_base`), and
        orderings close their routes.
    ordering
        The smoothed planner's ordering: ``method`` (``"ga"``, ``"ortools"``, ``"pyvrp"``) and that
        method's own options (:func:`~pmht_opt.order_locales`).
    visit_radius, split
        The smoothed planner's (``None``: the scenario's coverage radius).
    radius
        The coverage planner's sensor radius (``None``: the scenario's coverage radius).
    """

    kind: str = "pmht"
    solver: str = "auto"
    iterations: int = 100
    tol: float = 0.0
    anneal: Anneal | None = None
    update_time_prior: bool | None = None
    paper: bool = False
    return_to_base: bool = False
    ordering: dict[str, Any] = field(default_factory=lambda: {"method": "ga"})
    visit_radius: float | None = None
    split: str = "equal"
    radius: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in PLANNERS:
            raise ConfigError(f"kind: expected one of {', '.join(PLANNERS)}, got {self.kind!r}.")
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or self.iterations < 1:
            raise ConfigError(f"iterations: expected a positive integer, got {self.iterations!r}.")
        if self.split not in SPLITS:
            raise ConfigError(f"split: expected one of {', '.join(SPLITS)}, got {self.split!r}.")
        for key in ("paper", "return_to_base"):
            if not isinstance(getattr(self, key), bool):
                raise ConfigError(f"{key}: expected true or false, got {getattr(self, key)!r}.")
        for key in ("visit_radius", "radius"):
            if getattr(self, key) is not None:
                positive_number(key, getattr(self, key))
        if not isinstance(self.ordering, dict):
            raise ConfigError(
                f"ordering: expected a table of a method and its options, got {self.ordering!r}."
            )
        method = self.ordering.get("method", "ga")
        if method not in ORDERINGS:
            raise ConfigError(f"ordering.method: expected one of {', '.join(ORDERINGS)}, got {method!r}.")
        self.ordering = {"method": method, **{k: v for k, v in self.ordering.items() if k != "method"}}
        try:  # the option names, whichever planner runs (their values when the ordering runs)
            ordering_method(method, self.ordering_options)
        except ConfigError as err:
            raise ConfigError(f"ordering.{err}") from None
        self.config(())  # the library's own checks (solver name, tolerances, schedule)

    @property
    def method(self) -> str:
        """The ordering method."""
        return str(self.ordering["method"])

    @property
    def ordering_options(self) -> dict[str, Any]:
        """The ordering method's options, without ``method``."""
        return {k: v for k, v in self.ordering.items() if k != "method"}

    def schedule(self) -> Anneal:
        """The annealing schedule the plan will use."""
        if self.anneal is not None:
            return self.anneal
        return Anneal(iterations=0) if self.paper else _library_default("anneal")

    def check_r(self, r: float) -> None:
        """Refuse a schedule that would start *below* the scenario's ``r``.

        Annealing starts wide and shrinks to ``r``; a start below ``r`` sharpens the penalty first,
        the opposite of its purpose. Schedules are absolute variances in the scenario's unit, so the
        library's default (``start = 1``, meant for areas of about 10 units) is wrong for a mission
        in metres, and the message says what to write instead.
        """
        sched = self.schedule()
        if sched.empty or sched.fn is not None or sched.start > r:
            return
        what = "the default schedule" if self.anneal is None else "the schedule"
        raise ConfigError(
            f"anneal: {what} starts at r = {sched.start:g}, not above this scenario's r = {r:g}; "
            f"schedules are variances in the scenario's unit: set anneal = {{ start = {100 * r:g}, "
            f"iterations = {sched.iterations} }} (100 r, as the default is for the paper's r = 0.01), "
            "or anneal = false."
        )

    def config(
        self, constraints: tuple[Constraint, ...] | list[Constraint], snapshots: tuple[int, ...] = ()
    ) -> PMHTConfig:
        """The :class:`~pmht_opt.PMHTConfig` of these settings with ``constraints``."""
        kwargs: dict[str, Any] = {
            "solver": self.solver,
            "max_iter": self.iterations,
            "tol": self.tol,
            "constraints": tuple(constraints),
            "snapshots": tuple(snapshots),
        }
        if self.anneal is not None:
            kwargs["anneal"] = self.anneal
        if self.update_time_prior is not None:
            kwargs["update_time_prior"] = self.update_time_prior
        return PMHTConfig.paper(**kwargs) if self.paper else PMHTConfig(**kwargs)

    def replace(self, **changes: Any) -> PlannerSettings:
        """A copy with some settings changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_table(self) -> dict[str, Any]:
        """The ``[planner]`` table of these settings (defaults left out)."""
        default = PlannerSettings()
        out: dict[str, Any] = {"kind": self.kind}
        for key in ("solver", "iterations", "tol", "update_time_prior", "paper", "return_to_base"):
            if getattr(self, key) != getattr(default, key):
                out[key] = getattr(self, key)
        if self.anneal is not None:
            a = self.anneal
            out["anneal"] = (
                False if a.empty else {"start": a.start, "iterations": a.iterations, "shape": a.shape}
            )
        for key in ("visit_radius", "radius"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.split != default.split:
            out["split"] = self.split
        if self.ordering != default.ordering:
            out["ordering"] = dict(self.ordering)
        return out


def read_anneal(where: str, value: Any) -> Anneal:
    """``false``, ``[start, iterations]`` or ``{ start = ..., iterations = ..., shape = ... }``."""
    if value is False:
        return Anneal(iterations=0)
    if isinstance(value, list):
        if len(value) != 2:
            raise ScenarioError(f"{where}: expected [start, iterations], got {len(value)} values.")
        return Anneal(
            start=fields.number(f"{where}[0]", value[0]), iterations=fields.integer(f"{where}[1]", value[1])
        )
    if isinstance(value, dict):
        readers: dict[str, Any] = {
            "start": fields.number,
            "iterations": fields.integer,
            "shape": fields.string,
        }
        return Anneal(**fields.keyed(where, value, readers))
    raise ScenarioError(
        f"{where}: expected false, [start, iterations] or a table, got {fields.describe(value)}."
    )


def read_settings(where: str, data: Any) -> PlannerSettings:
    """Planner settings from a ``[planner]`` table; messages name ``where`` and the key."""
    table = fields.table(where, data)
    readers: dict[str, Any] = {
        "kind": fields.string,
        "solver": fields.string,
        "iterations": fields.integer,
        "tol": fields.number,
        "anneal": read_anneal,
        "update_time_prior": fields.boolean,
        "paper": fields.boolean,
        "return_to_base": fields.boolean,
        "ordering": fields.table,
        "visit_radius": fields.number,
        "split": fields.string,
        "radius": fields.number,
    }
    kwargs = fields.keyed(where, table, readers, "setting")
    if "ordering" in kwargs:
        kwargs["ordering"] = dict(kwargs["ordering"])
        if "method" in kwargs["ordering"]:
            fields.string(f"{where}.ordering.method", kwargs["ordering"]["method"])
    try:
        return PlannerSettings(**kwargs)
    except ConfigError as err:
        raise ConfigError(f"{where}: {err}") from None
