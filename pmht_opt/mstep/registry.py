"""The M-step backends by name, derived from :mod:`solvers`' registry, and the one place that checks a
backend name and a constraint's needs against a backend's capabilities."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import solvers
from pmht_opt.constraints.base import Constraint
from pmht_opt.exceptions import ConfigError, UnknownSolverError
from pmht_opt.mstep.banded import BandedMStep
from pmht_opt.mstep.base import MStep
from pmht_opt.mstep.check import check_answer
from pmht_opt.mstep.cvxpy_ import JointCvxpyMStep
from pmht_opt.mstep.kalman import KalmanMStep
from pmht_opt.mstep.qp import QPMStep
from pmht_opt.scenario import Scenario


@dataclass(frozen=True)
class Backend:
    """An M-step backend: what it needs installed and what constraints it can impose.

    ``supports`` holds capabilities of :data:`pmht_opt.constraints.CAPABILITIES`. A backend with
    ``"linear"`` rows but no ``"soc"`` still takes constraints that need cones: the M-step hands it
    their inner polygons.
    """

    name: str
    spec: solvers.BackendSpec | None
    supports: frozenset[str]

    @property
    def installed(self) -> bool:
        """Whether the backend's package can be imported."""
        return self.spec is None or self.spec.installed

    def can_impose(self, needs: frozenset[str]) -> bool:
        """Whether every capability in ``needs`` is supported (cones through polygons)."""
        return all(n in self.supports or (n == "soc" and "linear" in self.supports) for n in needs)


def _derive() -> dict[str, Backend]:
    out = {}
    for name, spec in solvers.BACKENDS.items():
        caps = {"linear"}
        if "soc" in spec.cones:
            caps.add("soc")
        if name == "cvxpy":
            caps.add("cvxpy")  # the problem is a cvxpy problem: native cvxpy constraints join it
        out[name] = Backend(name, spec, frozenset(caps))
    out["banded"] = Backend("banded", None, frozenset())
    out["kalman"] = Backend("kalman", None, frozenset())
    return out


#: ``solver="auto"``: the exact banded smoother without constraints, else the first of these that can
#: impose them all.
AUTO_ORDER = ("clarabel", "cvxpy", "osqp")


#: Every M-step backend: the QP backends of :mod:`solvers` and the Kalman smoother.
BACKENDS: dict[str, Backend] = _derive()


def available_backends() -> list[str]:
    """Names of the M-step backends usable on this machine (their packages are installed)."""
    return [name for name, b in BACKENDS.items() if b.installed]


def check_backend(solver: object) -> str:
    """The backend name ``solver`` in canonical form, or :class:`UnknownSolverError` naming the field.

    ``"auto"`` is accepted (see :func:`resolve`). Raises for names that are not backends and for
    backends whose package is not installed; the message lists the available ones.
    """
    key = str(solver).lower()
    if key == "auto":
        return key
    backend = BACKENDS.get(key)
    if backend is None:
        raise UnknownSolverError("solver: " + solvers.unknown_solver_message(solver, available_backends()))
    if backend.spec is not None and not backend.installed:
        raise UnknownSolverError(
            "solver: " + solvers.missing_package_message(backend.spec, available_backends())
        )
    return key


def resolve(solver: str, constraints: Sequence[Constraint]) -> str:
    """The backend ``solver`` names: ``"auto"`` is ``"banded"`` (exact, fastest) without constraints,
    else the first of :data:`AUTO_ORDER` that is installed and can impose every constraint."""
    if solver != "auto":
        return solver
    if not constraints:
        return "banded"
    for name in AUTO_ORDER:
        backend = BACKENDS[name]
        if backend.installed and all(backend.can_impose(c.needs) for c in constraints):
            return name
    names = ", ".join(c.name for c in constraints)
    raise ConfigError(f"constraints: no installed backend can impose {names}.")


def check_constraints(solver: str, constraints: Sequence[Constraint]) -> None:
    """:class:`ConfigError` for a constraint that backend ``solver`` cannot impose."""
    backend = BACKENDS[resolve(solver, constraints)]
    for con in constraints:
        if not backend.can_impose(con.needs):
            able = [b.name for b in BACKENDS.values() if b.can_impose(con.needs)]
            raise ConfigError(
                f"constraints: {con.name} cannot be imposed by the {solver} backend; use one of "
                f"{', '.join(sorted(able))}."
            )


def make_mstep(
    scenario: Scenario,
    solver: str,
    settings: dict[str, Any] | None = None,
    accept_inaccurate: bool = False,
    threads: int = 1,
    constraints: tuple[Constraint, ...] = (),
) -> MStep:
    """Build the M-step backend ``solver`` for ``scenario``, checked against its constraints."""
    asked = check_backend(solver)
    key = resolve(asked, constraints)
    check_constraints(key, constraints)
    if key in ("banded", "kalman") and settings:
        raise ConfigError(f"solver_settings: the {key} backend takes none, got {sorted(settings)}.")
    if key == "banded":  # exact by construction: its answers are checked for being finite
        return BandedMStep(scenario, accept_inaccurate=accept_inaccurate, threads=threads, check=check_answer)
    reference = BandedMStep(scenario, threads=threads)
    if key == "kalman":
        return KalmanMStep(
            scenario,
            accept_inaccurate=accept_inaccurate,
            threads=threads,
            reference=reference,
            check=check_answer,
        )
    if any("cvxpy" in con.needs for con in constraints):
        return JointCvxpyMStep(
            scenario, settings, accept_inaccurate, tuple(constraints), reference=reference, check=check_answer
        )
    return QPMStep(
        scenario,
        settings,
        accept_inaccurate,
        solver=key,
        threads=threads,
        constraints=tuple(constraints),
        exact_unconstrained=asked == "auto",
        reference=reference,
        check=check_answer,
    )
