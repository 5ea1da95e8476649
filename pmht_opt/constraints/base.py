"""The constraint protocol: what a constraint adds to a platform's M-step, and how it is checked.

A constraint is a small object with three duties:

* :meth:`Constraint.check_scenario`: reject a scenario that violates it before anything is solved
  (a start inside an obstacle, outside the area);
* :meth:`Constraint.blocks`: the rows it adds to one EM iteration's M-step, as :class:`Block` s of
  conic rows ``h - G z in K`` on one platform's stacked states ``z = (x_1, ..., x_T)`` (``6 T``
  entries, state ``t`` at offset ``6 (t - 1)``, components ``[px, vx, ax, py, vy, ay]``);
* :meth:`Constraint.violation`: how far a returned plan is from meeting it, measured on the exact
  geometry (true circles, not the polygons OSQP gets), per platform and time step.

Blocks are backend-neutral. The QP backends map ``z`` into their variable vector; cvxpy builds the
same rows as expressions. A backend without second-order cones asks for a polygonal version
(``ctx.conic`` is ``False``): every kind here then gives an *inner* polygon, so meeting the polygon
means meeting the circle it approximates.

Soft mode (``soft=True``) is handled by the backends, not the kinds: each unit of a block (a row of a
linear block, a whole cone of a conic block) gets a non-negative slack ``s`` that relaxes it, and
``weight * s`` joins the cost. That is an exact L1 penalty: when the hard problem is feasible and
``weight`` exceeds the constraint's multipliers, the soft problem has the hard problem's solution.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import scipy.sparse as sp

from pmht_opt.exceptions import ConfigError
from pmht_opt.model import STATE_DIM

if TYPE_CHECKING:
    from pmht_opt.estep import EStepResult
    from pmht_opt.scenario import Scenario

#: Kinds of block rows: ``h - G z = 0``, ``h - G z >= 0``, and stacked second-order cones
#: ``(h - G z)[0] >= ||(h - G z)[1:]||`` of ``dim`` rows each.
BLOCK_KINDS = ("zero", "nonneg", "soc")

#: Default number of sides of the inner polygons that stand in for circles on OSQP.
DEFAULT_SIDES = 16

#: Violations at or below this are reported as met (the solvers' tolerance is far below it).
VIOLATION_TOL = 1e-6


@dataclass
class Block:
    """Rows one constraint adds to one platform's M-step: ``h - G z`` in ``units`` cones of ``kind``.

    Attributes
    ----------
    platform
        Platform index.
    kind
        ``"zero"``, ``"nonneg"`` or ``"soc"``.
    G
        ``(units * dim, 6 T)`` sparse rows on the platform's stacked states.
    h
        ``(units * dim,)`` right-hand side.
    dim
        Rows per unit: 1 for linear kinds, the cone dimension for ``"soc"``.
    times
        ``(units,)`` time step (``1..T``) each unit constrains, for reports.
    labels
        Optional ``(units,)`` description of each unit (e.g. ``"locale 7"``).
    """

    platform: int
    kind: str
    G: sp.csr_matrix
    h: np.ndarray
    dim: int = 1
    times: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    labels: list[str] | None = None

    def __post_init__(self) -> None:
        if self.kind not in BLOCK_KINDS:
            raise ValueError(f"Block kind must be one of {BLOCK_KINDS}, got {self.kind!r}.")
        self.G = sp.csr_matrix(self.G)
        self.h = np.asarray(self.h, dtype=float).reshape(-1)
        if self.kind != "soc":
            self.dim = 1
        if self.G.shape[0] != self.h.shape[0] or self.h.shape[0] % self.dim:
            raise ValueError(f"Block rows: G has {self.G.shape[0]}, h has {self.h.shape[0]}, dim {self.dim}.")
        self.times = np.asarray(self.times, dtype=int).reshape(-1)
        if self.times.shape[0] != self.units:
            raise ValueError(f"Block has {self.units} units but {self.times.shape[0]} times.")

    @property
    def units(self) -> int:
        """Number of cones (``soc``) or rows (linear kinds)."""
        return self.h.shape[0] // self.dim

    def residual(self, z: np.ndarray) -> np.ndarray:
        """``(units,)`` violation of each unit at stacked states ``z`` (0 where met)."""
        s = self.h - self.G @ z
        if self.kind == "zero":
            return np.abs(s)
        if self.kind == "nonneg":
            return np.maximum(-s, 0.0)
        s = s.reshape(self.units, self.dim)
        return np.maximum(np.linalg.norm(s[:, 1:], axis=1) - s[:, 0], 0.0)


@dataclass
class ConstraintContext:
    """What a constraint may look at when it writes one iteration's rows.

    Attributes
    ----------
    scenario
        The scenario being planned.
    states
        ``(M, T+1, 6)`` current iterate (the previous M-step's answer): the linearisation point of the
        non-convex kinds.
    estep
        The E-step that produced this iteration's weights (MAP assignments for visit constraints).
    iteration
        EM iteration about to be solved (``1..max_iter``).
    max_iter
        The run's iteration budget.
    conic
        Whether the backend takes second-order cones; if not, give inner polygons.
    settled
        First iteration that uses the scenario's ``r`` (after an annealing schedule; 1 without one).
    """

    scenario: Scenario
    states: np.ndarray
    estep: EStepResult | None = None
    iteration: int = 1
    max_iter: int = 1
    conic: bool = True
    settled: int = 1


@dataclass
class ConstraintReport:
    """How well one constraint holds on a plan (exact geometry).

    Attributes
    ----------
    name
        The constraint's description.
    soft
        Whether it was imposed softly.
    max_violation
        Largest violation over all platforms and times (0 when met).
    n_violations
        Number of (platform, time) units violated by more than the tolerance.
    worst
        ``(platform, time)`` of the largest violation, or ``None``.
    details
        Kind-specific extras (e.g. segments that cut an obstacle).
    """

    name: str
    soft: bool
    max_violation: float
    n_violations: int
    worst: tuple[int, int] | None
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def satisfied(self) -> bool:
        """Whether every unit holds within :data:`VIOLATION_TOL`."""
        return self.n_violations == 0


def positive_number(name: str, value: Any, allow_zero: bool = False) -> float:
    """``value`` as a finite positive float, or :class:`ConfigError` naming ``name``."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected a finite positive number, got {value!r}.") from None
    if not np.isfinite(out) or out < 0 or (out == 0 and not allow_zero):
        kind = "non-negative" if allow_zero else "positive"
        raise ConfigError(f"{name}: expected a finite {kind} number, got {value!r}.")
    return out


def point_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (``-1`` any length), or :class:`ConfigError`."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected numbers, got {value!r}.") from None
    ok = arr.ndim == len(shape) and all(s in (-1, d) for s, d in zip(shape, arr.shape, strict=True))
    if not ok:
        raise ConfigError(f"{name}: expected shape {shape}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name}: contains NaN or infinite values.")
    return arr


class Constraint(abc.ABC):
    """Base class of every constraint kind.

    Parameters
    ----------
    soft
        Impose the constraint through an exact L1 penalty on slacks instead of as a hard constraint;
        the plan then exists even when the constraint cannot be met, and its report gives the
        violations.
    weight
        Penalty per unit of violation in soft mode (in units of the M-step cost, whose fit term is
        ``W / (2 r)`` times a squared distance, so ``r = 0.01`` makes 1e3 a moderate weight).
    platforms
        Platforms the constraint applies to; ``None`` means all.
    """

    #: Backends that can impose this kind.
    backends: ClassVar[frozenset[str]] = frozenset({"clarabel", "osqp", "cvxpy"})
    #: Whether :meth:`blocks` depends on the iterate (linearisations, MAP visits).
    dynamic: ClassVar[bool] = False

    def __init__(self, soft: bool = False, weight: float = 1e4, platforms: Any = None) -> None:
        if not isinstance(soft, (bool, np.bool_)):
            raise ConfigError(f"{type(self).__name__}.soft: expected True or False, got {soft!r}.")
        self.soft = bool(soft)
        self.weight = positive_number(f"{type(self).__name__}.weight", weight)
        if platforms is None:
            self.platforms: tuple[int, ...] | None = None
        else:
            try:
                plats = tuple(int(p) for p in np.atleast_1d(platforms))
            except (TypeError, ValueError):
                raise ConfigError(
                    f"{type(self).__name__}.platforms: expected platform indices, got {platforms!r}."
                ) from None
            if any(p < 0 for p in plats):
                raise ConfigError(f"{type(self).__name__}.platforms: indices must be >= 0, got {plats}.")
            self.platforms = plats

    # ------------------------------------------------------------------ protocol

    @property
    def name(self) -> str:
        """Short description used in reports and error messages."""
        return type(self).__name__

    def applies_to(self, scenario: Scenario) -> list[int]:
        """Platforms of ``scenario`` this constraint binds."""
        if self.platforms is None:
            return list(range(scenario.n_platforms))
        return list(self.platforms)

    def check_scenario(self, scenario: Scenario) -> None:
        """Raise :class:`~pmht_opt.exceptions.ScenarioError` or :class:`ConfigError` before any solve
        if ``scenario`` makes this constraint meaningless (a start inside an obstacle, parameters per
        platform of the wrong length, platform indices out of range)."""
        bad = [p for p in self.applies_to(scenario) if p >= scenario.n_platforms]
        if bad:
            raise ConfigError(
                f"{self.name}: platforms {bad} do not exist (the scenario has {scenario.n_platforms})."
            )

    def active(self, iteration: int, max_iter: int, settled: int = 1) -> bool:
        """Whether the constraint is imposed at EM ``iteration``; always, unless a kind warms up.

        ``settled`` is the first iteration at the scenario's ``r`` (annealing over).
        """
        return True

    @abc.abstractmethod
    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        """Rows for this iteration's M-step, one or more blocks per bound platform."""

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        """Violations on the plan ``states (M, T+1, 6)``, measured exactly.

        ``ctx`` is the context of the M-step that produced ``states`` (its linearisation point and
        E-step), so kinds whose rows depend on the iterate are judged on the rows they imposed. The
        default measures this constraint's own blocks, written with cones, at ``states``; kinds that
        linearise a non-convex set override it with the exact geometry.
        """
        conic = replace(ctx, conic=True)
        return self._report(self._block_residuals(self.blocks(conic), states))

    def draw(self, ax: Any) -> None:  # noqa: B027 - most kinds have no shape to draw
        """Draw this constraint's geometry (keep-out zones, bounds) on matplotlib axes ``ax``.

        Called by :meth:`~pmht_opt.result.PlanResult.plot`; kinds without a shape in the plane draw
        nothing.
        """

    # ------------------------------------------------------------------ helpers for kinds

    def _block_residuals(
        self, blocks: list[Block], states: np.ndarray
    ) -> list[tuple[int, np.ndarray, np.ndarray]]:
        out = []
        for blk in blocks:
            z = states[blk.platform, 1:, :].reshape(-1)
            out.append((blk.platform, blk.times, blk.residual(z)))
        return out

    def _report(
        self, residuals: list[tuple[int, np.ndarray, np.ndarray]], details: dict[str, Any] | None = None
    ) -> ConstraintReport:
        worst_val, worst_at, count = 0.0, None, 0
        for platform, times, res in residuals:
            if res.size == 0:
                continue
            count += int(np.sum(res > VIOLATION_TOL))
            i = int(np.argmax(res))
            if res[i] > worst_val:
                worst_val, worst_at = float(res[i]), (int(platform), int(times[i]))
        return ConstraintReport(
            name=self.name,
            soft=self.soft,
            max_violation=worst_val,
            n_violations=count,
            worst=worst_at if worst_val > VIOLATION_TOL else None,
            details=details or {},
        )


def state_rows(T: int, times: np.ndarray, comps: np.ndarray, coeffs: np.ndarray) -> sp.csr_matrix:
    """Sparse rows on the stacked states: row ``i`` has ``coeffs[i, j]`` at component ``comps[j]`` of
    time ``times[i]`` (``1..T``). ``coeffs`` is ``(rows, len(comps))``."""
    times = np.asarray(times, dtype=int)
    comps = np.asarray(comps, dtype=int)
    coeffs = np.asarray(coeffs, dtype=float)
    n_rows = times.shape[0]
    cols = STATE_DIM * (times[:, None] - 1) + comps[None, :]
    rows = np.repeat(np.arange(n_rows), comps.shape[0])
    return sp.csr_matrix((coeffs.ravel(), (rows, cols.ravel())), shape=(n_rows, STATE_DIM * T))


def disc_block(
    platform: int,
    T: int,
    times: np.ndarray,
    comps: tuple[int, int],
    centres: np.ndarray,
    radii: np.ndarray,
    conic: bool,
    sides: int,
    labels: list[str] | None = None,
) -> Block:
    """``||(x_t[comps]) - centre|| <= radius`` at each of ``times``: a second-order cone, or the inner
    regular polygon with ``sides`` sides (vertices on the circle) when ``conic`` is ``False``.

    ``centres`` is ``(len(times), 2)`` and ``radii`` ``(len(times),)``.
    """
    times = np.asarray(times, dtype=int)
    k = times.shape[0]
    centres = np.broadcast_to(np.asarray(centres, dtype=float), (k, 2))
    radii = np.broadcast_to(np.asarray(radii, dtype=float), (k,))
    if conic:
        # Per unit, rows (r, c - p) where h - G z = (r, cx - px, cy - py): G = [0; e_px; e_py].
        tt = np.repeat(times, 3)
        coeff = np.zeros((3 * k, 2))
        coeff[1::3, 0] = 1.0
        coeff[2::3, 1] = 1.0
        G = state_rows(T, tt, np.array(comps), coeff)
        h = np.zeros(3 * k)
        h[0::3] = radii
        h[1::3] = centres[:, 0]
        h[2::3] = centres[:, 1]
        return Block(platform, "soc", G, h, dim=3, times=times, labels=labels)
    angles = 2.0 * np.pi * np.arange(sides) / sides
    normals = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (S, 2)
    tt = np.repeat(times, sides)
    G = state_rows(T, tt, np.array(comps), np.tile(normals, (k, 1)))
    inner = np.cos(np.pi / sides)
    h = (radii[:, None] * inner + centres @ normals.T).ravel()
    lab = None if labels is None else [lab for lab in labels for _ in range(sides)]
    return Block(platform, "nonneg", G, h, times=tt, labels=lab)


def check_sides(name: str, sides: Any) -> int:
    """Polygon side count: an integer >= 4 (a square is the coarsest useful inner approximation)."""
    if isinstance(sides, bool) or not isinstance(sides, (int, np.integer)) or sides < 4:
        raise ConfigError(f"{name}.sides: expected an integer >= 4, got {sides!r}.")
    return int(sides)
