"""What every planner of :func:`pmht_opt.plan` is: a small object that declares its options.

A planner has a name, a frozen dataclass of its own options (checked in its ``__post_init__``), a
default stopping criterion, and one method, :meth:`Planner.run`, that takes the scenario, the shared
:class:`~pmht_opt.settings.Settings`, its options, the stopping criterion and the progress callback,
and returns a :class:`~pmht_opt.result.PlanResult`. :meth:`Planner.options` turns keyword options into
its dataclass, refusing a name it does not have (it would be ignored) with the names it has.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

from pmht_opt.exceptions import ConfigError
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario
from pmht_opt.settings import SETTINGS_FIELDS, PMHTConfig, Settings
from pmht_opt.stopping import ProgressObserver, StoppingCriterion


class Planner(abc.ABC):
    """One way of planning, as :func:`pmht_opt.plan` runs it.

    Subclasses set :attr:`name`, :attr:`summary` and :attr:`Options` (a frozen dataclass whose fields
    are the planner's own options, with their defaults) and implement :meth:`default_stop` and
    :meth:`run`.
    """

    #: The name ``plan(..., method=name)`` and the command line's ``--planner`` use.
    name: ClassVar[str] = ""
    #: One line on what it is for.
    summary: ClassVar[str] = ""
    #: The dataclass of the planner's own options.
    Options: ClassVar[type[Any]]

    def options(self, given: Mapping[str, Any]) -> Any:
        """The planner's options from keyword arguments, checked.

        Raises
        ------
        ConfigError
            An option the planner does not take, naming it and the ones it takes (a shared setting
            given as an option names :class:`~pmht_opt.settings.Settings` instead); a bad value,
            naming the option.
        """
        names = [f.name for f in dataclasses.fields(self.Options)]
        for key in given:
            if key in names:
                continue
            if key in SETTINGS_FIELDS:
                raise ConfigError(
                    f"{key}: a setting every planner shares; pass settings=pmht_opt.Settings({key}=...)."
                )
            takes = ", ".join(names) if names else "no options"
            raise ConfigError(f"{key}: not an option of the {self.name!r} planner; it takes {takes}.")
        return self.Options(**given)

    def option_names(self) -> tuple[str, ...]:
        """The names of the planner's own options."""
        return tuple(f.name for f in dataclasses.fields(self.Options))

    @abc.abstractmethod
    def default_stop(self) -> StoppingCriterion:
        """When the planner stops if the caller does not say."""

    @abc.abstractmethod
    def run(
        self,
        scenario: Scenario,
        settings: Settings,
        options: Any,
        stop: StoppingCriterion,
        callback: ProgressObserver | None,
    ) -> PlanResult:
        """Plan ``scenario``; ``callback`` gets a :class:`~pmht_opt.stopping.Progress` after every
        iteration and ``stop`` is asked after each whether to end."""


def refuse_ignored(config: PMHTConfig, names: Sequence[str], planner: str) -> None:
    """:class:`ConfigError` naming the first of ``names`` that ``config`` sets to other than its
    default: ``planner`` would ignore it (it decides that part of the run itself)."""
    default = PMHTConfig()
    for name in names:
        if getattr(config, name) != getattr(default, name):
            raise ConfigError(
                f"config.{name}: {planner} does not use it (it decides that part of the run itself); "
                "leave it at its default."
            )
