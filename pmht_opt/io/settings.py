"""A mission's ``[planner]`` table: which planner runs, and its settings and options by name.

.. code-block:: toml

    [planner]
    method = "coverage"           # a planner of pmht_opt.PLANNERS ("kind" in older files)
    iterations = 60               # stop after this many iterations (MaxIterations)
    return_to_base = true         # every platform ends at its start, at rest; routes are closed
    solver = "auto"               # a shared setting (pmht_opt.Settings), by its name
    radius = 100.0                # an option of the chosen planner, by its name

Keys map onto the library's own dataclasses by name: :class:`~pmht_opt.Settings`' fields (but
``constraints``, which the mission's ``[[constraints]]`` give), and the chosen planner's options
(``PLANNERS[method].Options``). Four keys belong to the mission itself: ``method``, ``iterations``,
``return_to_base`` and, for the PMHT planner, ``tol`` (stop at that relative change of the EM
objective) and ``paper`` (the paper's options, :meth:`~pmht_opt.PMHTOptions.paper`). Every setting
has the library's default; the command line's options override the file's.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from pmht_opt.anneal import Anneal
from pmht_opt.constraints.base import Constraint
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.io import fields
from pmht_opt.planners import PLANNERS, planner
from pmht_opt.settings import SETTINGS_FIELDS, PMHTOptions, Settings
from pmht_opt.stopping import MaxIterations, ObjectiveTolerance, StoppingCriterion

#: The keys that belong to the mission, not to the planner's settings or options.
MISSION_KEYS = ("method", "iterations", "tol", "paper", "return_to_base")


def _mission_keys(method: str) -> tuple[str, ...]:
    """The mission's own keys that ``method`` takes (``tol`` and ``paper`` are the PMHT planner's)."""
    return MISSION_KEYS if method == "pmht" else tuple(k for k in MISSION_KEYS if k not in ("tol", "paper"))


#: The shared settings a file can give (the constraints come from its ``[[constraints]]``).
SHARED = tuple(f for f in SETTINGS_FIELDS if f != "constraints")
#: The default planner of a mission.
DEFAULT_METHOD = "coverage"


@dataclass
class PlannerSettings:
    """Which planner a mission runs, with which settings and options.

    Parameters
    ----------
    method
        The planner (:data:`pmht_opt.PLANNERS`).
    iterations
        Iterations of the planner's run at most (``None``: the planner's default stop).
    tol
        The PMHT planner's stop at a relative change of the EM objective (0: never).
    paper
        The PMHT planner starts from the paper's options (both prior updates, no annealing).
    return_to_base
        Every platform ends at its start, at rest (:meth:`~pmht_opt.Terminal.return_to_base`), and
        orderings close their routes.
    shared
        Shared settings by name (:class:`~pmht_opt.Settings`' fields but ``constraints``).
    options
        The planner's own options by name.
    """

    method: str = DEFAULT_METHOD
    iterations: int | None = None
    tol: float = 0.0
    paper: bool = False
    return_to_base: bool = False
    shared: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        chosen = planner(self.method)
        if self.iterations is not None and (
            isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or self.iterations < 1
        ):
            raise ConfigError(f"iterations: expected a positive integer, got {self.iterations!r}.")
        for key in ("paper", "return_to_base"):
            if not isinstance(getattr(self, key), bool):
                raise ConfigError(f"{key}: expected true or false, got {getattr(self, key)!r}.")
        if self.method != "pmht":
            for key, default in (("tol", 0.0), ("paper", False)):
                if getattr(self, key) != default:
                    raise ConfigError(f"{key}: a setting of the pmht planner, not of {self.method!r}.")
        unknown = sorted(set(self.shared) - set(SHARED))
        if unknown:
            raise ConfigError(f"{unknown[0]}: not a shared setting; they are {', '.join(SHARED)}.")
        self.settings(())  # the library's own checks, naming the field
        chosen.options(self.planner_options())
        self.stop()

    def planner_options(self) -> dict[str, Any]:
        """The planner's options: the paper's first (``paper``), then the file's."""
        if self.paper:
            base = PMHTOptions.paper()
            return {**{f: getattr(base, f) for f in ("update_time_prior", "anneal")}, **self.options}
        return dict(self.options)

    def settings(self, constraints: tuple[Constraint, ...] | list[Constraint]) -> Settings:
        """The shared settings with ``constraints``."""
        return Settings(**self.shared, constraints=tuple(constraints))

    def stop(self) -> StoppingCriterion | None:
        """When the run stops: ``None`` for the planner's own default."""
        criteria: list[StoppingCriterion] = []
        if self.tol:
            criteria.append(ObjectiveTolerance(self.tol))
        if self.iterations is not None:
            criteria.append(MaxIterations(self.iterations))
        elif criteria:
            criteria.append(PLANNERS[self.method].default_stop())
        if not criteria:
            return None
        return criteria[0] if len(criteria) == 1 else _any(criteria)

    def schedule(self) -> Anneal:
        """The annealing schedule a PMHT run of these settings uses."""
        options = PLANNERS["pmht"].options(self.planner_options() if self.method == "pmht" else {})
        anneal: Anneal = options.anneal
        return anneal

    def check_r(self, r: float) -> None:
        """Refuse a PMHT schedule that would start *below* the scenario's ``r`` (annealing starts
        wide and shrinks to ``r``); the default start follows the scenario's units (100 r)."""
        if self.method != "pmht":
            return
        sched = self.schedule()
        if sched.empty or sched.fn is not None or sched.start is None or sched.start > r:
            return
        raise ConfigError(
            f"anneal: the schedule starts at r = {sched.start:g}, not above this scenario's r = {r:g}; "
            "leave start out (it is then 100 r) or give one above r, or anneal = false."
        )

    def replace(self, **changes: Any) -> PlannerSettings:
        """A copy with some settings changed (checked again)."""
        return dataclasses.replace(self, **changes)

    def to_table(self) -> dict[str, Any]:
        """The ``[planner]`` table of these settings (defaults left out)."""
        out: dict[str, Any] = {"method": self.method}
        for key in ("iterations", "tol", "paper", "return_to_base"):
            default = next(f for f in dataclasses.fields(self) if f.name == key).default
            if getattr(self, key) != default:
                out[key] = getattr(self, key)
        out.update(self.shared)
        for key, value in self.options.items():
            out[key] = _anneal_table(value) if isinstance(value, Anneal) else value
        return out


def _any(criteria: list[StoppingCriterion]) -> StoppingCriterion:
    from pmht_opt.stopping import AnyOf

    return AnyOf(tuple(criteria))


def _anneal_table(a: Anneal) -> Any:
    if a.empty:
        return False
    table: dict[str, Any] = {"iterations": a.iterations, "shape": a.shape}
    if a.start is not None:
        table["start"] = a.start
    return table


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


#: How a value of a known key is read from a file (others are taken as the file gives them).
READERS: dict[str, Any] = {
    "method": fields.string,
    "iterations": fields.integer,
    "tol": fields.number,
    "paper": fields.boolean,
    "return_to_base": fields.boolean,
    "solver": fields.string,
    "threads": fields.integer,
    "seed": fields.integer,
    "accept_inaccurate": fields.boolean,
    "solver_settings": fields.table,
    "anneal": read_anneal,
    "update_time_prior": fields.boolean,
    "update_platform_prior": fields.boolean,
    "radius": fields.number_or_numbers,
    "visit_radius": fields.number,
    "split": fields.string,
    "orderer": fields.string,
    "order_options": fields.table,
}


def read_settings(where: str, data: Any) -> PlannerSettings:
    """Planner settings from a ``[planner]`` table; messages name ``where`` and the key."""
    table = dict(fields.table(where, data))
    if "kind" in table:  # the name older files use
        if "method" in table:
            raise ScenarioError(f"{where}: give method or kind, not both.")
        table["method"] = table.pop("kind")
    if "ordering" in table:  # older files: [planner.ordering] method = ..., options ...
        ordering = dict(fields.table(f"{where}.ordering", table.pop("ordering")))
        if "method" in ordering:
            table["orderer"] = ordering.pop("method")
        table["order_options"] = ordering
    values = {key: READERS.get(key, _as_given)(f"{where}.{key}", value) for key, value in table.items()}
    method = values.pop("method", DEFAULT_METHOD)
    mission = {k: values.pop(k) for k in MISSION_KEYS[1:] if k in values}
    shared = {k: values.pop(k) for k in SHARED if k in values}
    try:
        names = planner(method).option_names()
    except ConfigError as err:
        raise ConfigError(f"{where}.{err}") from None
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ConfigError(
            f"{where}.{unknown[0]}: not a setting of the {method!r} planner; it takes "
            f"{', '.join(dict.fromkeys((*_mission_keys(method), *SHARED, *names)))}."
        )
    try:
        return PlannerSettings(method=method, shared=shared, options=values, **mission)
    except ConfigError as err:
        raise ConfigError(f"{where}: {err}") from None


def _as_given(where: str, value: Any) -> Any:
    del where
    return value
