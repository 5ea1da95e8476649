r"""The GA's operators as data: moves, break rules and the two tables that combine them.

Each generation the population is shuffled into groups, one per parent, and the best member of each
group is the parent of as many children as the table has *slots*. A slot pairs a **move** (how the
child's order is made from the parent's) with a **break rule** (where the child's routes begin):

``Breaks.PARENT``
    the parent's heads;
``Breaks.FRESH``
    new random heads (uniform over the valid compositions, see :mod:`.encoding`);
``Breaks.MOVED``
    heads carried by the move itself (only for moves that know where the routes go).

All moves share one signature. ``move.plan(rng, IJ, layout)`` draws the move's own random numbers for a
batch of ``n`` generations (``IJ (n, G, 2)`` are the sorted ``I <= J`` of each group, drawn once per
group and shared by every move) and precomputes what does not depend on the parents; the returned
:class:`MovePlan` then gives, for generation ``c`` and the parents' heads ``(G, M)``, the child's
*index* ``(G, N)`` (position ``k`` of the child reads position ``index[g, k]`` of parent ``g``) and,
for moves that carry breaks, its heads ``(G, M)``. A move that appears in several slots is planned
once per batch, so those slots get the same order (Kirk's flip with and without new breaks uses one
``I..J``).

The moves
---------
*Copy*: the identity. *Flip*: reverse ``p[I..J]``. *Swap*: exchange ``p[I]`` and ``p[J]``.
*Slide* (Kirk): rotate ``p[I..J]`` left by one.

*Segment move* (or-opt): the block ``p[I .. I+r-1]``, ``1 <= r <= J - I`` uniform, goes behind ``p[J]``,
reversed with probability ``reverse``; unreversed with ``r = 1`` it is Kirk's slide. The breaks follow:
heads between the block and ``p[J]`` move up by ``r``, heads inside the block (after ``I``) move with
it. So a block within one route leaves it for ``p[J]``'s route and every other locale keeps its route.
If a route ends up shorter than ``min_tour`` (or empty), the child keeps the parent's breaks.

*Route exchange*: two routes ``m1 < m2`` (uniform pair) trade their locales, order and number kept;
``A X B -> B X A`` on the positions from route ``m1``'s head to route ``m2``'s end, and the heads of
routes ``m1 + 1 .. m2`` shift by ``len(B) - len(A)``. With one platform there is no pair and the move
is Kirk's slide with the parent's breaks.

The tables
----------
====  =============================  ===========  ==========================  ==========
slot  :data:`KIRK` move              breaks       :data:`IMPROVED` move       breaks
====  =============================  ===========  ==========================  ==========
0     copy                           parent       copy                        parent
1     flip                           parent       flip                        parent
2     swap                           parent       swap                        parent
3     slide                          parent       segment move                moved
4     copy                           fresh        copy                        fresh
5     flip                           fresh        flip                        fresh
6     swap                           fresh        swap                        fresh
7     slide                          fresh        route exchange              moved
====  =============================  ===========  ==========================  ==========

:data:`KIRK` is the GA of the paper (after Kirk's MATLAB mTSP GAs): no crossover, four mutations of the
group's best with and without new random breaks. :data:`IMPROVED` replaces the two slides by moves that
get Kirk's GA out of its typical traps: two routes that should trade places (a swap moves one locale
and new breaks are a blind draw), or a segment that should move to another route, reversed, with its
break. Both are single moves here.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from pmht_opt.exceptions import ConfigError


@dataclass(frozen=True)
class Layout:
    """Sizes of a run: ``N`` locales, ``M`` routes, ``G`` groups, the minimum route length."""

    N: int
    M: int
    G: int
    min_tour: int

    @property
    def dtype(self) -> Any:
        """Integer type of the batch arrays: small, because these arrays are memory bound."""
        return np.int16 if self.N < 2**15 else np.intp


class MovePlan(Protocol):
    """A move's random numbers and precomputed arrays for one batch of generations."""

    def child(self, c: int, heads: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Index ``(G, N)`` (or broadcastable to it) and heads ``(G, M)`` or None, for generation ``c``."""
        ...


@runtime_checkable
class Move(Protocol):
    """``move.plan(rng, IJ, layout) -> MovePlan``; ``carries_breaks`` if the plan returns heads."""

    carries_breaks: bool

    def plan(self, rng: np.random.Generator, IJ: np.ndarray, layout: Layout) -> MovePlan:
        """Draw this move's random numbers for the batch and precompute its parent-free arrays."""
        ...


@dataclass(frozen=True)
class _Fixed:
    """A plan whose index does not depend on the parents' heads: one ``(n, G, N)`` array. With
    ``keeps_heads`` the children keep their parents' heads (the breaks between routes) as they are."""

    index: np.ndarray
    keeps_heads: bool = False

    def child(self, c: int, heads: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        return self.index[c], heads if self.keeps_heads else None


@dataclass(frozen=True)
class _Identity:
    index: np.ndarray  # (1, N)

    def child(self, c: int, heads: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        return self.index, None


def _positions(IJ: np.ndarray, layout: Layout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions ``k (N,)`` and the group's ``I``, ``J`` as ``(n, G, 1)``, in the batch dtype."""
    k = np.arange(layout.N, dtype=layout.dtype)
    return k, IJ[..., 0:1].astype(layout.dtype), IJ[..., 1:2].astype(layout.dtype)


@dataclass(frozen=True)
class Copy:
    """The parent's order unchanged."""

    carries_breaks = False

    def plan(self, rng: np.random.Generator, IJ: np.ndarray, layout: Layout) -> MovePlan:
        return _Identity(np.arange(layout.N, dtype=np.intp)[None, :])


@dataclass(frozen=True)
class Flip:
    """Reverse ``p[I..J]``."""

    carries_breaks = False

    def plan(self, rng: np.random.Generator, IJ: np.ndarray, layout: Layout) -> MovePlan:
        k, I, J = _positions(IJ, layout)  # noqa: E741 (the paper's I..J)
        return _Fixed(np.where((k >= I) & (k <= J), I + J - k, k))


@dataclass(frozen=True)
class Swap:
    """Exchange ``p[I]`` and ``p[J]``."""

    carries_breaks = False

    def plan(self, rng: np.random.Generator, IJ: np.ndarray, layout: Layout) -> MovePlan:
        k, I, J = _positions(IJ, layout)  # noqa: E741
        return _Fixed(np.where(k == I, J, np.where(k == J, I, k)))


def _slide(IJ: np.ndarray, layout: Layout) -> np.ndarray:
    k, I, J = _positions(IJ, layout)  # noqa: E741
    return np.where((k >= I) & (k <= J), np.where(k == J, I, k + 1), k)


@dataclass(frozen=True)
class Slide:
    """Kirk's slide: rotate ``p[I..J]`` left by one (``p[I]`` goes behind ``p[J]``)."""

    carries_breaks = False

    def plan(self, rng: np.random.Generator, IJ: np.ndarray, layout: Layout) -> MovePlan:
        return _Fixed(_slide(IJ, layout))


class _SegmentPlan:
    def __init__(self, index: np.ndarray, moves_to: np.ndarray, layout: Layout) -> None:
        self.index = index  # (n, G, N)
        self.moves_to = moves_to  # (n, G, N): new position of each old position
        self.min_tour = layout.min_tour
        self.bounds = np.full((layout.G, layout.M + 1), layout.N, dtype=np.intp)
        self.groups = np.arange(layout.G)[:, None]

    def child(self, c: int, heads: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        bounds = self.bounds
        bounds[:, :-1] = self.moves_to[c][self.groups, heads]
        fits = (bounds[:, 1:] - bounds[:, :-1]).min(axis=1) >= self.min_tour
        return self.index[c], np.where(fits[:, None], bounds[:, :-1], heads)


@dataclass(frozen=True)
class SegmentMove:
    """Or-opt: a block of ``p[I..J]``'s front goes behind ``p[J]``, reversed with probability ``reverse``.

    The breaks move with the locales (``Breaks.MOVED``); see the module notes.
    """

    reverse: float = 0.5
    carries_breaks = True

    def __post_init__(self) -> None:
        r = self.reverse
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0.0 <= r <= 1.0:
            raise ConfigError(f"SegmentMove.reverse: expected a probability in [0, 1], got {r!r}.")

    def plan(self, rng: np.random.Generator, IJ: np.ndarray, layout: Layout) -> MovePlan:
        n, G = IJ.shape[:2]
        block_u = rng.random((n, G, 1))
        reverse = rng.random((n, G, 1)) < self.reverse
        k, I, J = _positions(IJ, layout)  # noqa: E741
        inside = (k >= I) & (k <= J)
        span = J - I + 1
        r = 1 + (block_u * (span - 1)).astype(layout.dtype)  # 1 <= r <= J - I (r = 1 if I = J)
        tail = k > J - r  # where the block lands
        flip = np.where(inside, I + J - k, k)
        index = np.where(inside, np.where(tail, np.where(reverse, flip, k - (span - r)), k + r), k)
        # Heads inside the block (but not at I) move with it, those after it up to J move up by r. A
        # head at I stays: the block leaves the front of that route.
        moves_to = k + np.where(inside & (k > I), np.where(k < I + r, span - r, -r), 0)
        return _SegmentPlan(index, moves_to, layout)


class _ExchangePlan:
    """Route pairs of a batch, as flat indices into the ``(G, M + 1)`` bounds (heads, then ``N``)."""

    def __init__(self, pair: np.ndarray, layout: Layout) -> None:
        N, M, G = layout.N, layout.M, layout.G
        m1, m2 = pair[..., :1], pair[..., 1:]  # (n, G, 1) each
        # Route m1's head and end, route m2's head and end, for every group of every generation.
        self.ends = np.concatenate([m1, m1 + 1, m2, m2 + 1], axis=2) + (np.arange(G) * (M + 1))[:, None]
        self.between = (np.arange(M) > m1) & (np.arange(M) <= m2)  # (n, G, M): routes that shift
        self.N = N
        self.bounds = np.full((G, M + 1), N, dtype=np.intp)
        self.runs = np.empty((G, 5), dtype=np.intp)
        self.shifts = np.zeros((G, 5), dtype=np.intp)
        self.k = np.arange(N, dtype=np.intp)

    def child(self, c: int, heads: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        bounds, runs, shifts = self.bounds, self.runs, self.shifts
        bounds[:, :-1] = heads
        lo, e1, s2, hi = bounds.take(self.ends[c]).T
        # A X B -> B X A on positions lo .. hi - 1, A = p[lo:e1], X = p[e1:s2], B = p[s2:hi]. Each
        # output position reads position + shift, the shift constant on the five runs [0, lo), B's new
        # place, X's, A's and [hi, N).
        runs[:, 0] = lo
        runs[:, 1] = hi - s2
        runs[:, 2] = s2 - e1
        runs[:, 3] = e1 - lo
        runs[:, 4] = self.N - hi
        shifts[:, 1] = s2 - lo
        shifts[:, 2] = runs[:, 3] - runs[:, 1]
        shifts[:, 3] = e1 - hi
        index = self.k + np.repeat(shifts.ravel(), runs.ravel()).reshape(heads.shape[0], self.N)
        return index, heads - shifts[:, 2:3] * self.between[c]


@dataclass(frozen=True)
class RouteExchange:
    """Two routes (uniform pair) trade their locales and the breaks follow (``Breaks.MOVED``)."""

    carries_breaks = True

    def plan(self, rng: np.random.Generator, IJ: np.ndarray, layout: Layout) -> MovePlan:
        M = layout.M
        if M == 1:  # no pair to exchange: Kirk's slide, and the parent's (only) head
            return _Fixed(_slide(IJ, layout), keeps_heads=True)
        pairs = np.array([(a, b) for a in range(M) for b in range(a + 1, M)], dtype=np.intp)
        return _ExchangePlan(pairs[rng.integers(0, len(pairs), size=IJ.shape[:2])], layout)


class Breaks(enum.Enum):
    """Where a child's routes begin (its heads)."""

    PARENT = "parent"
    FRESH = "fresh"
    MOVED = "moved"


@dataclass(frozen=True)
class Slot:
    """One child of every parent: a move and a break rule."""

    move: Move
    breaks: Breaks


@dataclass(frozen=True)
class OperatorSet:
    """A table of slots: every parent has ``len(slots)`` children, one per slot.

    Attributes
    ----------
    name
        Recorded in the result's ``extras["operators"]``.
    slots
        The children, in order; the population is a multiple of their number.
    batch_entries
        Cap on the entries of each ``(n, G, N)`` batch array, which sets how many generations ``n``
        (at most :data:`BATCH`) draw their random numbers together; None: always :data:`BATCH`. The
        batch size fixes the order of the draws and so the tours a seed gives.
    """

    name: str
    slots: tuple[Slot, ...]
    batch_entries: int | None = None

    def __post_init__(self) -> None:
        slots = tuple(self.slots)
        if not slots:
            raise ConfigError("OperatorSet.slots: expected at least one slot, got none.")
        for i, slot in enumerate(slots):
            if not isinstance(slot, Slot) or not isinstance(slot.move, Move):
                raise ConfigError(f"OperatorSet.slots[{i}]: expected a Slot(move, breaks), got {slot!r}.")
            if not isinstance(slot.breaks, Breaks):
                raise ConfigError(f"OperatorSet.slots[{i}].breaks: expected a Breaks, got {slot.breaks!r}.")
            if slot.breaks is Breaks.MOVED and not slot.move.carries_breaks:
                raise ConfigError(
                    f"OperatorSet.slots[{i}].breaks: {type(slot.move).__name__} does not move breaks; "
                    "expected Breaks.PARENT or Breaks.FRESH."
                )
        object.__setattr__(self, "slots", slots)

    @property
    def group(self) -> int:
        """Children per parent, and so the size of a group."""
        return len(self.slots)

    @property
    def moves(self) -> tuple[Move, ...]:
        """The distinct moves, in order of first use: the order in which they draw."""
        out: list[Move] = []
        for slot in self.slots:
            if slot.move not in out:
                out.append(slot.move)
        return tuple(out)

    def batch_size(self, layout: Layout) -> int:
        """Generations whose random numbers are drawn together."""
        if self.batch_entries is None:
            return BATCH
        return max(1, min(BATCH, self.batch_entries // (layout.G * layout.N)))


#: Generations per batch of random draws at most (amortises the generator's call overhead).
BATCH = 128

#: The paper's GA: Kirk's copy, flip, swap and slide, with the parent's breaks and with new ones.
KIRK = OperatorSet(
    "kirk",
    (
        Slot(Copy(), Breaks.PARENT),
        Slot(Flip(), Breaks.PARENT),
        Slot(Swap(), Breaks.PARENT),
        Slot(Slide(), Breaks.PARENT),
        Slot(Copy(), Breaks.FRESH),
        Slot(Flip(), Breaks.FRESH),
        Slot(Swap(), Breaks.FRESH),
        Slot(Slide(), Breaks.FRESH),
    ),
)

#: Kirk's copy, flip and swap, with the segment move and the route exchange instead of the slides.
IMPROVED = OperatorSet(
    "improved",
    (
        Slot(Copy(), Breaks.PARENT),
        Slot(Flip(), Breaks.PARENT),
        Slot(Swap(), Breaks.PARENT),
        Slot(SegmentMove(reverse=0.5), Breaks.MOVED),
        Slot(Copy(), Breaks.FRESH),
        Slot(Flip(), Breaks.FRESH),
        Slot(Swap(), Breaks.FRESH),
        Slot(RouteExchange(), Breaks.MOVED),
    ),
    batch_entries=1 << 17,
)

#: The operator sets by name, the default first.
OPERATOR_SETS: dict[str, OperatorSet] = {"improved": IMPROVED, "kirk": KIRK}
