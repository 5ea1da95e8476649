"""Blocks: the conic rows a constraint adds to one platform's M-step, written on its stacked states.

A block is ``h - G z in K^units`` where ``z = (x_1, ..., x_T)`` are one platform's states stacked
(``6 T`` entries, state ``t`` at offset ``6 (t - 1)``, components ``[px, vx, ax, py, vy, ay]``) and
``K`` is one of the cones of :mod:`solvers`: ``zero`` (equalities), ``nonneg`` (inequalities) or
``soc`` (second-order cones of ``dim`` rows each). Blocks say *what* must hold; the M-step decides how
a backend represents them (a backend without cones gets inner polygons) and where ``z`` sits in its
variable vector.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from pmht_opt.model import STATE_DIM
from solvers import cone_violation

#: Kinds of block rows: ``h - G z = 0``, ``h - G z >= 0``, and stacked second-order cones
#: ``(h - G z)[0] >= ||(h - G z)[1:]||`` of ``dim`` rows each.
BLOCK_KINDS = ("zero", "nonneg", "soc")

#: Default number of sides of the inner polygons that stand in for circles on backends without cones.
DEFAULT_SIDES = 16


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
    sides
        Sides of the inner regular polygon that replaces each cone on a backend without cones.
    span
        Optional ``(units, 2)`` first and last time step (inclusive) that each unit's rows may address
        over a whole run, for rows that move from one iteration to the next within a known window. The
        M-step then keeps one sparsity pattern covering the window, so a backend updates numbers
        instead of setting its problem up again.
    group
        Consecutive units that stand for one constraint and share one slack in soft mode (the ``S``
        rows of an inner polygon stand for one cone); 1 otherwise.
    radius
        For the rows of an inner polygon (:func:`inner_polygon`): per row, the radius ``h_0`` of the
        cone it stands for, so that the M-step can scale and tighten the rows as it would the cone;
        ``None`` for any other block.
    """

    platform: int
    kind: str
    G: sp.csr_matrix
    h: np.ndarray
    dim: int = 1
    times: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    labels: list[str] | None = None
    sides: int = DEFAULT_SIDES
    span: np.ndarray | None = None
    group: int = 1
    radius: np.ndarray | None = None

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
        if self.units % self.group:
            raise ValueError(f"Block has {self.units} units, not a multiple of its group {self.group}.")
        if self.radius is not None:
            self.radius = np.asarray(self.radius, dtype=float).reshape(-1)
            if self.kind != "nonneg" or self.radius.shape[0] != self.units:
                raise ValueError("Only the rows of an inner polygon have a radius, one per row.")

    @property
    def units(self) -> int:
        """Number of cones (``soc``) or rows (linear kinds)."""
        return self.h.shape[0] // self.dim

    def residual(self, z: np.ndarray) -> np.ndarray:
        """``(units,)`` violation of each unit at stacked states ``z`` (0 where met)."""
        return cone_violation(self.h - self.G @ z, self.kind, self.dim)


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
    sides: int = DEFAULT_SIDES,
    labels: list[str] | None = None,
) -> Block:
    """``||x_t[comps] - centre|| <= radius`` at each of ``times``: one second-order cone per time.

    ``centres`` is ``(len(times), 2)`` and ``radii`` ``(len(times),)``. Per unit the rows are
    ``(radius, centre - x_t[comps])``: ``h = (r, c)`` and ``G = [0; e_a; e_b]``.
    """
    times = np.asarray(times, dtype=int)
    k = times.shape[0]
    centres = np.broadcast_to(np.asarray(centres, dtype=float), (k, 2))
    radii = np.broadcast_to(np.asarray(radii, dtype=float), (k,))
    tt = np.repeat(times, 3)
    coeff = np.zeros((3 * k, 2))
    coeff[1::3, 0] = 1.0
    coeff[2::3, 1] = 1.0
    G = state_rows(T, tt, np.array(comps), coeff)
    h = np.zeros(3 * k)
    h[0::3] = radii
    h[1::3] = centres[:, 0]
    h[2::3] = centres[:, 1]
    return Block(platform, "soc", G, h, dim=3, times=times, labels=labels, sides=sides)


def inner_polygon(block: Block) -> Block:
    """A cone block's inner polygonal approximation: linear rows that imply every cone.

    For a unit ``s = h - G z`` of a second-order cone, ``||s_1..|| <= s_0`` is replaced by the
    ``S = block.sides`` rows ``cos(pi / S) s_0 + n_k . s_1.. >= 0`` with the unit normals
    ``n_k = (cos(2 pi k / S), sin(2 pi k / S))``: the regular ``S``-gon inscribed in the circle of
    radius ``s_0`` (around ``-s_1..``), so meeting the rows means meeting the cone with a margin of at
    most ``s_0 (1 - cos(pi / S))``. Only three-row cones (discs in the plane) are converted.
    """
    if block.kind != "soc":
        return block
    if block.dim != 3:
        raise ValueError(f"Only three-row cones have a polygonal form, got dimension {block.dim}.")
    sides = block.sides
    angles = 2.0 * np.pi * np.arange(sides) / sides
    normals = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (S, 2)
    inner = np.cos(np.pi / sides)
    k = block.units
    h = block.h.reshape(k, 3)
    # Row (i, s): inner * (h0 - g0 z) + n_s . (h12 - g12 z) >= 0, i.e. h' - G' z >= 0.
    h_new = (h[:, 0, None] * inner + np.ascontiguousarray(h[:, 1:]) @ normals.T).ravel()
    G = block.G.tocsr()
    coef = (np.full(sides, inner), normals[:, 0], normals[:, 1])
    rows, cols, vals = [], [], []
    for c in range(3):
        gc = G[c::3].tocoo()
        rows.append((gc.row[:, None] * sides + np.arange(sides)[None, :]).ravel())
        cols.append(np.repeat(gc.col, sides))
        vals.append((gc.data[:, None] * coef[c][None, :]).ravel())
    # Built from triplets, so zero coefficients stay stored: the pattern does not depend on the angles.
    G_new = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(k * sides, G.shape[1])
    )
    labels = None if block.labels is None else [lab for lab in block.labels for _ in range(sides)]
    span = None if block.span is None else np.repeat(block.span, sides, axis=0)
    return Block(
        block.platform,
        "nonneg",
        G_new,
        h_new,
        times=np.repeat(block.times, sides),
        labels=labels,
        sides=sides,
        span=span,
        group=sides,
        radius=np.repeat(h[:, 0], sides),
    )


def with_span_pattern(block: Block) -> sp.csr_matrix:
    """``block.G`` with explicit zeros wherever a unit's rows may reach within its span.

    Every row of a unit gets a stored entry for each state component any row of that unit touches, at
    every step of the unit's span. Rows that move within their window from one iteration to the next
    then keep one sparsity pattern.
    """
    G = block.G.tocoo()
    if block.span is None:
        return block.G
    dim = block.dim
    # The (unit, state component) pairs the unit's rows touch, and for each its span of steps.
    touched = np.zeros((block.units, STATE_DIM), dtype=bool)
    touched[G.row // dim, G.col % STATE_DIM] = True
    unit, comp = np.nonzero(touched)
    span = np.asarray(block.span, dtype=int)
    lo = span[unit, 0]
    lengths = span[unit, 1] - lo + 1
    pair = np.repeat(np.arange(unit.size), lengths)
    steps = lo[pair] + np.arange(pair.size) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    cols_one = STATE_DIM * (steps - 1) + comp[pair]
    # Every row of the unit, at each of those columns.
    r = (dim * unit[pair][None, :] + np.arange(dim)[:, None]).ravel()
    c = np.tile(cols_one, dim)
    both = sp.csr_matrix(
        (
            np.concatenate([G.data, np.zeros(r.size)]),
            (np.concatenate([G.row, r]), np.concatenate([G.col, c])),
        ),
        shape=G.shape,
    )
    both.sum_duplicates()
    return both


def difference_block(
    platform: int,
    T: int,
    times: np.ndarray,
    stencil: dict[int, float],
    start: np.ndarray,
    radii: np.ndarray,
    comps: tuple[int, int],
    sides: int = DEFAULT_SIDES,
) -> Block:
    """``||sum_k c_k p_{t+k}|| <= radius`` at each of ``times``: a cone on a finite difference of positions.

    ``stencil`` maps offsets ``k`` to coefficients ``c_k`` (``{0: 1, -1: -1}`` is the displacement
    ``p_t - p_{t-1}``; ``{1: 1, 0: -2, -1: 1}`` the second difference); ``start`` is the known position
    ``p_0``, whose terms move to the right-hand side. Per unit the rows are ``(radius, -sum_k c_k
    p_{t+k})``.
    """
    times = np.asarray(times, dtype=int)
    k = times.shape[0]
    radii = np.broadcast_to(np.asarray(radii, dtype=float), (k,))
    rows, cols, vals = [], [], []
    h = np.zeros((k, 3))
    h[:, 0] = radii
    for offset, coef in stencil.items():
        steps = times + offset
        free = steps >= 1
        for axis, comp in enumerate(comps):
            rows.append(3 * np.flatnonzero(free) + 1 + axis)
            cols.append(STATE_DIM * (steps[free] - 1) + comp)
            vals.append(np.full(int(free.sum()), coef))
            h[~free, 1 + axis] -= coef * start[axis]
    G = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * k, STATE_DIM * T)
    )
    return Block(platform, "soc", G, h.ravel(), dim=3, times=times, sides=sides)
