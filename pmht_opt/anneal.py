"""Deterministic annealing of the fitting penalty ``r``.

With the sharp penalty of the paper (``r = 0.01``) the first E-steps lock every locale onto its nearest
platform and time; platforms left without locales then fly off under constant acceleration
(docs/model.md section 6). Annealing runs the first iterations with a wide penalty, so every locale
pulls on every nearby path, and shrinks it to the scenario's ``r``.

Iteration ``i`` (``1..max_iter``) of the EM uses one value ``r_i`` for both of its steps: the E-step that
weighs the locales against the current paths and the M-step that fits the paths to those weights. A
schedule of length ``n`` gives ``r_1 .. r_n``; ``r_n`` is exactly the scenario's ``r`` and every later
iteration uses it too, so plain EM (and its guarantee that the objective never decreases) resumes at
iteration ``n``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pmht_opt import validation
from pmht_opt.exceptions import ConfigError

#: The schedule shapes :class:`Anneal` knows.
SHAPES = ("geometric", "linear")


@dataclass(frozen=True)
class Anneal:
    """A schedule for the penalty ``r`` over the first EM iterations.

    Parameters
    ----------
    start
        ``r`` of the first iteration, in squared distance units, above the scenario's ``r`` and within
        ``[1e-10, 1e12]``; ``None`` (the default) is :data:`START_FACTOR` times the scenario's ``r``
        (1.0 for the paper's ``r = 0.01``), so the schedule follows the scenario's units.
    iterations
        Length ``n`` of the schedule: iterations ``1..n`` anneal, iteration ``n`` already uses the
        scenario's ``r``. ``0`` is no annealing (plain EM).
    shape
        ``"geometric"``: ``r_i = start * (r / start) ** ((i - 1) / (n - 1))``, a constant factor per
        iteration (the textbook choice). ``"linear"``: ``r`` falls by a constant step.
    fn
        Optional callable ``iteration -> r`` (``iteration`` from 1) for the first ``iterations``
        iterations instead of ``start`` and ``shape``; its value at ``iterations`` must be the
        scenario's ``r`` or is replaced by it. See :meth:`custom`.
    """

    start: float | None = None
    iterations: int | None = 30
    shape: str = "geometric"
    fn: Callable[[int], float] | None = None

    def __post_init__(self) -> None:
        if self.iterations is None:
            if self.fn is None:
                raise ConfigError("anneal.iterations: None is only allowed with a callable schedule.")
        else:
            limit = validation.MAX_ITERATIONS
            iterations = validation.integer("anneal.iterations", self.iterations, ConfigError, 0, limit)
            object.__setattr__(self, "iterations", iterations)
        if self.start is not None:
            object.__setattr__(self, "start", _check_r("anneal.start", self.start))
        if self.shape not in SHAPES:
            raise ConfigError(f"anneal.shape: expected one of {', '.join(SHAPES)}, got {self.shape!r}.")
        if self.fn is not None and not callable(self.fn):
            raise ConfigError(f"anneal.fn: expected a callable iteration -> r, got {type(self.fn).__name__}.")

    @classmethod
    def custom(cls, fn: Callable[[int], float], iterations: int | None = None) -> Anneal:
        """A schedule given by ``fn(iteration) -> r`` (``iteration`` from 1).

        With ``iterations`` the callable covers iterations ``1..iterations`` and the last of them uses
        the scenario's ``r``. Without, it covers every iteration and must reach the scenario's ``r`` by
        the last one; the schedule ends where it reaches ``r`` for good.
        """
        return cls(iterations=iterations, fn=fn)

    @property
    def empty(self) -> bool:
        """True when the schedule anneals nothing."""
        return self.iterations == 0

    def values(self, r: float, max_iter: int) -> np.ndarray:
        """``r_i`` for ``i = 1..max_iter`` (index ``i - 1``); ends at exactly ``r``.

        Raises
        ------
        ConfigError
            A value that is not a finite positive number, or a callable schedule that never reaches
            ``r``.
        """
        r = _check_r("scenario r", r)
        out = np.full(max_iter, r)
        n = max_iter if self.iterations is None else min(self.iterations, max_iter)
        if n == 0:
            return out
        start = self.start_for(r)
        if self.fn is None and start <= r:
            raise ConfigError(
                f"anneal.start: the schedule starts at r = {start:g}, not above the scenario's "
                f"r = {r:g}; annealing starts wide and shrinks to r (docs/model.md section 6): give a "
                f"start above r (e.g. {START_FACTOR * r:g}, as the default does), leave it out, or "
                "use anneal=None."
            )
        if self.fn is not None:
            for i in range(1, n + 1):
                try:
                    value = self.fn(i)
                except Exception as err:  # a user's callable: report it as a bad schedule
                    raise ConfigError(f"anneal: the schedule raised at iteration {i}: {err!r}.") from err
                out[i - 1] = _check_r(f"anneal: r at iteration {i}", value)
            if self.iterations is None:
                if not math.isclose(out[-1], r, rel_tol=1e-9):
                    raise ConfigError(
                        f"anneal: the schedule must reach the scenario's r = {r:g} by the last iteration "
                        f"({max_iter}); it gives {out[-1]:g} there."
                    )
                out[np.isclose(out, r, rtol=1e-9, atol=0.0)] = r
            elif n == self.iterations:
                out[n - 1] = r
            return out
        assert self.iterations is not None
        steps = np.arange(self.iterations, dtype=float) / max(self.iterations - 1, 1)
        if self.shape == "geometric":
            full = start * (r / start) ** steps
        else:
            full = start + (r - start) * steps
        full[-1] = r
        out[:n] = full[:n]
        return out

    def start_for(self, r: float) -> float:
        """The first iteration's ``r`` for a scenario whose penalty is ``r``."""
        return START_FACTOR * r if self.start is None else self.start

    def fit(self, max_iter: int) -> tuple[Anneal, str]:
        """This schedule fitted into a run of at most ``max_iter`` iterations, and a note saying how.

        A schedule longer than the run would leave its plan fitted at a wider penalty than the
        scenario's ``r``. It is compressed to the same share of the run as the default schedule has of
        the default run (:data:`FIT_SHARE`: 30 of 100 iterations), at least one iteration; the note
        says so (and is empty when the schedule fits). A callable schedule cannot be compressed:
        :class:`ConfigError`, before the run starts.
        """
        n = self.iterations
        if n is None or n <= max_iter:
            return self, ""
        if self.fn is not None:
            raise ConfigError(
                f"anneal: the custom schedule takes {n} iterations but the run may take only {max_iter}, "
                f"so its plan would not be fitted at the scenario's r; give a schedule of at most "
                f"{max_iter} iterations or a longer run."
            )
        short = max(1, round(FIT_SHARE * max_iter))
        fitted = Anneal(start=self.start, iterations=short, shape=self.shape)
        return fitted, f"compressed from {n} to {short} iterations to fit a run of {max_iter}"

    def describe(self, r: float | None = None) -> str:
        """A short human-readable description (with the start in numbers if ``r`` is given)."""
        if self.empty:
            return "none"
        if self.fn is not None:
            return "custom" if self.iterations is None else f"custom over {self.iterations} iterations"
        if self.start is None and r is None:
            origin = f"{START_FACTOR:g} r"
        else:
            origin = f"r={self.start_for(r if r is not None else 0.0):g}"
        return f"{self.shape} from {origin} over {self.iterations} iterations"


#: The default schedule starts at this multiple of the scenario's ``r``.
START_FACTOR = 100.0
#: A schedule longer than its run is compressed to this share of the run (the default's 30 of 100).
FIT_SHARE = 0.3


def _check_r(name: str, value: object) -> float:
    """A penalty variance in the range the numerics handle (:data:`pmht_opt.validation.R_RANGE`)."""
    return validation.real(name, value, ConfigError, *validation.R_RANGE)


def as_anneal(value: object) -> Anneal:
    """Coerce the ``anneal`` setting of :class:`PMHTConfig`.

    Accepts ``None``/``False`` (none), an :class:`Anneal`, a tuple ``(start, iterations)``, a dict of
    :class:`Anneal`'s fields, or a callable ``iteration -> r`` (see :meth:`Anneal.custom`).
    """
    if value is None or value is False:
        return Anneal(iterations=0)
    if isinstance(value, Anneal):
        return value
    if isinstance(value, dict):
        try:
            return Anneal(**value)
        except TypeError as err:
            raise ConfigError(f"anneal: {err}.") from None
    if isinstance(value, tuple) and len(value) == 2:
        return Anneal(start=value[0], iterations=value[1])
    if callable(value):
        return Anneal.custom(value)
    raise ConfigError(
        f"anneal: expected None, an Anneal, (start, iterations) or a dict, got {type(value).__name__}."
    )
