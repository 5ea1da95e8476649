"""Timing one backend on one M-step, as it would run inside a plan.

A backend is built once per measurement (its setup timed apart), solves iteration ``K`` (the first
solve, which includes cvxpy's compilation), then the M-step of iteration ``K + 1`` is timed
``repeats`` times, each after re-solving iteration ``K`` so a warm start starts from where it would
inside a plan. The backend is reached only through the M-step package's public surface
(:func:`pmht_opt.mstep.make_mstep`, :class:`~pmht_opt.mstep.MStepData`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt.constraints import Constraint
from pmht_opt.exceptions import ConfigError
from pmht_opt.mstep import MStep, MStepData, make_mstep
from pmht_opt.scenario import Scenario
from studies.solver_study.backends import STATUS_NA, backend_spec, classify, error_status


@dataclass(frozen=True)
class Job:
    """One backend to time on one M-step.

    Attributes
    ----------
    label
        The row's label.
    backend
        The backend label (:mod:`studies.solver_study.backends`) when the row's label is another name
        for it with other settings; default: ``label``.
    settings
        Settings over the label's own (tighter tolerances for a reference).
    polygons
        Impose second-order cones as their inner polygons on a backend that could take the cones, so
        it solves the same problem as a backend without cones. Only the QP backends offer this (their
        ``rows``, a :class:`~pmht_opt.mstep.rows.RowBuilder`, decides the form before the first solve).
    """

    label: str
    backend: str = ""
    settings: Mapping[str, Any] = field(default_factory=dict)
    polygons: bool = False

    @property
    def backend_label(self) -> str:
        """The backend label this job runs."""
        return self.backend or self.label


@dataclass
class Measured:
    """One backend's answer to one M-step: its class, the backend's words, the paths and the times."""

    status: str
    raw_status: str = ""
    message: str = ""
    states: np.ndarray | None = None
    iterations: int | None = None
    setup_s: float = math.nan
    first_s: float = math.nan
    times: list[float] | None = None


def not_applicable(message: str) -> Measured:
    """A measurement that was not made because the backend cannot take the problem."""
    return Measured(status=STATUS_NA, message=message)


def build(scenario: Scenario, job: Job, constraints: tuple[Constraint, ...]) -> MStep:
    """The backend of ``job`` for ``scenario``, as the study runs it.

    Single M-steps are solved with ``accept_inaccurate=True`` so an inaccurate answer can still be
    measured, and on one thread so the times compare the solvers, not the thread pool.
    """
    solver, settings = backend_spec(job.backend_label)
    merged = {**settings, **job.settings}
    ms = make_mstep(
        scenario, solver, merged or None, accept_inaccurate=True, threads=1, constraints=constraints
    )
    if job.polygons:
        rows: Any = getattr(ms, "rows", None)
        if rows is None:
            ms.close()
            raise ConfigError(f"{job.label}: this backend cannot be asked for polygons.")
        rows.conic = False
    return ms


def measure(
    scenario: Scenario,
    job: Job,
    prev: MStepData,
    cur: MStepData,
    repeats: int,
    constraints: tuple[Constraint, ...] = (),
) -> Measured:
    """Time ``job`` on the M-step ``cur`` after ``prev`` (module docstring).

    Never raises for a solver's failure: a failure is a measurement, classified by
    :func:`~studies.solver_study.backends.error_status`.
    """
    needs = frozenset().union(*(c.needs for c in constraints))
    made: list[MStep] = []
    try:
        with warnings.catch_warnings():
            # cvxpy warns "Solution may be inaccurate"; the status says so and is recorded.
            warnings.simplefilter("ignore")
            return _measure(scenario, job, prev, cur, repeats, constraints, made)
    except Exception as err:  # a study: every failure is a measurement, never a crash
        cls, raw, message = error_status(err, job.backend_label, needs)
        return Measured(status=cls, raw_status=raw, message=message[:400])
    finally:
        for ms in made:
            ms.close()


def _measure(
    scenario: Scenario,
    job: Job,
    prev: MStepData,
    cur: MStepData,
    repeats: int,
    constraints: tuple[Constraint, ...],
    made: list[MStep],
) -> Measured:
    """:func:`measure` without the failure handling; backends built are added to ``made`` so the caller
    closes them whatever happens."""
    t0 = time.perf_counter()
    ms = build(scenario, job, constraints)
    made.append(ms)
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    ms.solve(prev)
    first = time.perf_counter() - t0
    times = []
    out = None
    for rep in range(max(int(repeats), 1)):
        if rep:
            ms.solve(prev)
        t0 = time.perf_counter()
        out = ms.solve(cur)
        times.append(time.perf_counter() - t0)
    assert out is not None
    return Measured(
        status=classify(out.status),
        raw_status=out.raw_status,
        states=out.states,
        iterations=int(out.iterations),
        setup_s=setup,
        first_s=first,
        times=times,
    )
