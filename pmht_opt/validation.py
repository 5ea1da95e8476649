"""The one validation boundary: what the public entry points accept, and what leaves a plan.

Every entry point (scenarios and their files, configs, constraints, planners, orderers, metrics, the
command line) takes only what it can plan with, and refuses everything else with the project's own
exception naming the field (docs/conventions.md section 7):

* **exact types**: a number is an ``int``, a ``float`` or numpy's; a string that looks like a number
  (``"1e-8"``), a boolean, a ``None`` or an array of them is a mistake in the caller's data, not a
  value, and is refused rather than converted;
* **finite values in the ranges the numerics handle** (:data:`DT_RANGE`, :data:`Q_RANGE`,
  :data:`R_RANGE`, :data:`HORIZON_RANGE`, :data:`COORDINATE_MAX`, :data:`RADIUS_MAX`;
  docs/model.md section 14): outside them the exact smoother itself overflows, underflows or loses
  every digit, so a plan there would be noise reported as a plan.

Inside a plan, :func:`plan_boundary` translates whatever a solver or numpy raises into
:class:`~pmht_opt.exceptions.SolverError` with the original exception attached as its cause, and
:func:`check_finite_plan` refuses a plan with a non-finite value. ``KeyboardInterrupt`` is never
translated: an interrupt is an interrupt, not a failed solve. Exceptions raised by the caller's own
code (progress callbacks, stopping criteria) pass through unchanged (:func:`call_user`).
"""

from __future__ import annotations

import contextlib
import functools
import math
import numbers
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

import numpy as np

import solvers
from pmht_opt.exceptions import ConfigError, PmhtOptError, ScenarioError, SolverError

#: Time step ``dt`` (s) the numerics handle: the process-noise covariance holds ``dt^5``, whose Cholesky
#: factor underflows or overflows the exact smoother outside this range.
DT_RANGE = (1e-4, 1e4)
#: Process-noise intensity ``q``.
Q_RANGE = (1e-14, 1e3)
#: Variance ``r`` of the fitting penalty (and every value of an annealing schedule): below the floor the
#: penalty's weights ``W / r`` swamp the process noise beyond double precision; above it nothing
#: limits the numerics, and ``1e12`` (``sigma = 1e6``) covers missions in metres at the coordinates'
#: full range.
R_RANGE = (1e-10, 1e12)
#: Horizon ``T`` in steps: at least one planned step after the start and one more; at most what
#: fits the E-step's ``N x T x M`` arrays of a realistic problem in memory.
HORIZON_RANGE = (2, 100_000)
#: Largest absolute coordinate (locales, start positions, bounds) and start-state component
#: (velocity, acceleration): beyond it positions of order ``1e8`` keep only about 1e-7 of absolute
#: precision in the smoother, and squared distances approach the range where the E-step's log weights
#: stop telling locales apart.
COORDINATE_MAX = 1e7
#: Largest coverage or visit radius: a radius wider than any coordinate is not a sensor footprint.
RADIUS_MAX = 1e7
#: Most EM iterations a run may ask for (the schedule of ``r`` holds one value per iteration).
MAX_ITERATIONS = 1_000_000

P = ParamSpec("P")
R = TypeVar("R")

#: Attribute set on an exception raised by the caller's own code, so the boundary lets it through.
_USER_CODE = "_pmht_opt_user_code"


def describe(value: Any) -> str:
    """A value as a message shows it: the type for containers, the repr otherwise (shortened)."""
    if isinstance(value, (dict, list, tuple, set, np.ndarray)):
        return f"a {type(value).__name__}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def is_real(value: Any) -> bool:
    """Whether ``value`` is a real number: ``int``, ``float`` or numpy's (never a bool or a string)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def flag(name: str, value: Any) -> bool:
    """``value`` as a ``bool``; :class:`ConfigError` naming ``name`` unless it is ``True`` or ``False``
    (numpy's included)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"{name}: expected True or False, got {value!r}.")
    return bool(value)


def is_integer(value: Any) -> bool:
    """Whether ``value`` is an integer: ``int`` or numpy's (never a bool, nor a float like ``3.0``)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _span(lo: float | None, hi: float | None, lo_open: bool) -> str:
    if lo is None and hi is None:
        return "a finite number"
    if hi is None:
        return f"a finite number {'>' if lo_open else '>='} {lo:g}"
    if lo is None:
        return f"a finite number <= {hi:g}"
    return f"a number in {'(' if lo_open else '['}{lo:g}, {hi:g}]"


def real(
    field: str,
    value: Any,
    error: type[PmhtOptError],
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
) -> float:
    """``value`` as a finite float within ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``).

    Raises
    ------
    error
        Naming ``field``: not a real number (a string, a boolean), beyond the float range, not finite
        or out of range.
    """
    want = _span(lo, hi, lo_open)
    if not is_real(value):
        raise error(f"{field}: expected {want}, got {describe(value)}.")
    try:
        out = float(value)
    except OverflowError:
        raise error(f"{field}: expected {want}, got an integer beyond the float range.") from None
    if not math.isfinite(out):
        raise error(f"{field}: expected {want}, got {value!r}.")
    if (lo is not None and (out < lo or (lo_open and out == lo))) or (hi is not None and out > hi):
        raise error(f"{field}: expected {want}, got {out:g}.")
    return out


def integer(field: str, value: Any, error: type[PmhtOptError], lo: int, hi: int | None = None) -> int:
    """``value`` as an ``int`` within ``[lo, hi]``; a float (even ``3.0``), string or bool is refused."""
    want = f"an integer >= {lo}" if hi is None else f"an integer from {lo} to {hi}"
    if not is_integer(value):
        raise error(f"{field}: expected {want}, got {describe(value)}.")
    out = int(value)
    if out < lo or (hi is not None and out > hi):
        shown = f"{out}" if abs(out) < 10**15 else f"an integer of {len(str(abs(out)))} digits"
        raise error(f"{field}: expected {want}, got {shown}.")
    return out


def real_array(field: str, value: Any, error: type[PmhtOptError]) -> np.ndarray:
    """``value`` (a number or nested sequences of numbers, or a numeric array) as a float array.

    Every element must be a real number: strings, booleans, ``None``, ragged nesting and integers
    beyond the float range are refused naming ``field``; finiteness and ranges are the caller's.
    """
    if isinstance(value, (str, bytes)):
        raise error(f"{field}: expected numbers, got the string {describe(value)}.")
    if isinstance(value, (dict, set, frozenset)):
        raise error(f"{field}: expected numbers, got {describe(value)}.")
    try:
        # Sequences element by element: numpy would quietly turn [True, 0.5] into [1.0, 0.5].
        arr = value if isinstance(value, np.ndarray) else np.asarray(value, dtype=object)
    except (TypeError, ValueError):
        raise error(f"{field}: expected a rectangular array of numbers (rows of equal length).") from None
    except RecursionError:
        raise error(f"{field}: expected a rectangular array of numbers, got nesting too deep.") from None
    if arr.dtype == object:
        flat = list(arr.ravel())
        bad = [v for v in flat if not is_real(v)]
        if bad:
            first = bad[0]
            if isinstance(first, (list, tuple, np.ndarray)):
                what = "rows of unequal length or depth"
            elif isinstance(first, (str, bytes)):
                what = "strings"
            elif isinstance(first, (bool, np.bool_)):
                what = "booleans"
            else:
                what = describe(first)
            raise error(f"{field}: expected numbers, got {what}.")
        try:
            arr = np.array([float(v) for v in flat], dtype=float).reshape(arr.shape)
        except OverflowError:
            raise error(f"{field}: expected numbers, got an integer beyond the float range.") from None
    if arr.dtype.kind == "b":
        raise error(f"{field}: expected numbers, got booleans.")
    if arr.dtype.kind in "US":
        raise error(f"{field}: expected numbers, got strings.")
    if arr.dtype.kind not in "iuf":
        raise error(f"{field}: expected numbers, got an array of {arr.dtype.name}.")
    return arr.astype(float)


def bounded(field: str, arr: np.ndarray, limit: float, error: type[PmhtOptError]) -> np.ndarray:
    """``arr`` if every value is finite and at most ``limit`` in magnitude; else ``error`` naming
    ``field`` and the first offending row and column."""
    ok = np.isfinite(arr) & (np.abs(arr) <= limit)
    if not np.all(ok):
        where = tuple(int(i) for i in np.argwhere(~ok)[0])
        at = f" at {where[0]}" if len(where) == 1 else f" at row {where[0]}, column {where[1]}"
        value = arr[where]
        what = "a non-finite value" if not np.isfinite(value) else f"{value:g}"
        raise error(f"{field}: expected finite values of magnitude <= {limit:g}, got {what}{at}.")
    return arr


def box(field: str, value: Any, error: type[PmhtOptError]) -> tuple[float, float, float, float]:
    """``(xmin, xmax, ymin, ymax)``: four coordinates with ``xmin <= xmax`` and ``ymin <= ymax`` (a
    string or a scalar is not a box)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, (tuple, list, np.ndarray)):
        raise error(f"{field}: expected (xmin, xmax, ymin, ymax), got {describe(value)}.")
    if len(value) != 4:
        raise error(f"{field} must be (xmin, xmax, ymin, ymax), got {len(value)} values.")
    lim = COORDINATE_MAX
    b = tuple(real(f"{field}[{i}]", v, error, -lim, lim) for i, v in enumerate(value))
    if b[0] > b[1] or b[2] > b[3]:
        raise error(f"{field} must have xmin <= xmax and ymin <= ymax, got {b}.")
    return (b[0], b[1], b[2], b[3])


def text(field: str, value: Any, error: type[PmhtOptError]) -> str:
    """A string that files can hold: UTF-8 encodable (no lone surrogates)."""
    if not isinstance(value, str):
        raise error(f"{field}: expected a string, got {describe(value)}.")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as err:
        raise error(
            f"{field}: expected text, got an unpaired surrogate {value[err.start]!r} at {err.start} "
            "(not a character; no file can hold it)."
        ) from None
    return value


def seed(field: str, value: Any, error: type[PmhtOptError]) -> np.random.Generator:
    """A ``numpy.random.Generator`` from a seed: a non-negative integer, a ``Generator`` (used as
    is) or ``None`` (fresh entropy, not reproducible)."""
    if isinstance(value, np.random.Generator):
        return value
    if value is None:
        return np.random.default_rng()
    if not is_integer(value) or int(value) < 0:
        raise error(
            f"{field}: expected a non-negative integer, a numpy.random.Generator or None, got "
            f"{describe(value)}."
        )
    return np.random.default_rng(int(value))


def integers(field: str, values: Any, error: type[PmhtOptError], lo: int) -> tuple[int, ...]:
    """A sequence of integers, each at least ``lo``."""
    if isinstance(values, (str, bytes)) or not isinstance(values, Iterable):
        raise error(f"{field}: expected a sequence of integers, got {describe(values)}.")
    return tuple(integer(f"{field}[{i}]", v, error, lo) for i, v in enumerate(values))


def file_path(field: str, path: Any) -> Path:
    """``path`` (a string or path-like) as a :class:`~pathlib.Path`, else :class:`ConfigError` naming
    ``field``."""
    if isinstance(path, bool) or not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ConfigError(f"{field}: expected a file path, got {describe(path)}.")
    return Path(path)


@contextlib.contextmanager
def writing(path: Any) -> Iterator[Path]:
    """A file for the block to write ``path`` into, in place of ``path`` once the block has finished.

    Every writer of the project goes through it: missing folders are created; the block writes a
    temporary file beside ``path`` (same suffix, so a format read from the suffix is the same), which
    replaces ``path`` only when the block ends without an exception, so an interrupt or an error never
    leaves a half-written file; an ``OSError`` on the way (a directory in its place, no permission, a
    full disk) becomes :class:`ScenarioError` naming the path, as for every other file the project
    cannot use.
    """
    out = file_path("path", path)
    part = out.with_name(f".{out.stem}.part-{os.getpid()}{out.suffix}")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        yield part
        os.replace(part, out)
    except OSError as err:
        raise ScenarioError(f"path: cannot write {str(out)!r}: {err.strerror or err}.") from None
    finally:
        with contextlib.suppress(OSError):  # nothing to remove where nothing could be written
            part.unlink(missing_ok=True)


# ------------------------------------------------------------------ inside a plan


def log_prior_rows(
    field: str, value: Any, shape: tuple[int, int], error: type[PmhtOptError]
) -> np.ndarray | None:
    """A prior given per locale (rows of non-negative weights, each row normalised here) as its log,
    ``None`` for ``None`` (uniform); ``error`` naming ``field`` for a wrong shape, a negative or
    non-finite entry or a row without mass. Rows whose sum overflows are scaled by their largest
    entry first."""
    if value is None:
        return None
    arr = real_array(field, value, error)
    if arr.shape != shape:
        raise error(f"{field} must have shape {shape}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise error(f"{field} must be finite and non-negative.")
    with np.errstate(over="ignore"):  # an overflowing row is handled below
        sums = arr.sum(axis=1)
    if np.any(sums <= 0):
        raise error(f"{field} has a locale (row {int(np.argmin(sums))}) with no mass.")
    if not np.all(np.isfinite(sums)):
        arr = arr / arr.max(axis=1)[:, None]
        sums = arr.sum(axis=1)
    with np.errstate(divide="ignore"):  # a zero prior is log 0 = -inf
        return np.log(arr / sums[:, None])


def initial_paths(x0: np.ndarray, horizon: int, value: Any, error: type[PmhtOptError]) -> np.ndarray:
    """Paths ``(M, horizon + 1, n)`` to start an EM from, starting at the states ``x0 (M, n)``
    (a copy); for ``None``, every platform standing still at its start. ``error`` naming
    ``initial_paths`` for a wrong shape, a non-finite value or another start."""
    shape = (x0.shape[0], horizon + 1, x0.shape[1])
    if value is None:
        return np.repeat(x0[:, None, :], horizon + 1, axis=1)
    arr = real_array("initial_paths", value, error)
    if arr.shape != shape:
        raise error(f"initial_paths must have shape {shape}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise error("initial_paths contains NaN or infinite values.")
    if not np.allclose(arr[:, 0], x0):
        raise error("initial_paths must start (t = 0) at the scenario's start states.")
    return arr.copy()


def check_finite_plan(states: np.ndarray, backend: str) -> None:
    """:class:`SolverError` unless every state of the plan is finite: no plan with a NaN or an
    infinity is ever returned."""
    if not np.all(np.isfinite(states)):
        raise SolverError(
            f"{backend}: the plan has non-finite states; the problem is beyond the ranges the "
            "numerics handle (docs/model.md section 14).",
            backend=backend,
            status="non-finite",
        )


def call_user(fn: Callable[..., R], *args: Any) -> R:
    """Call the caller's own ``fn``; an exception it raises is marked to pass the boundary unchanged."""
    try:
        return fn(*args)
    except Exception as err:
        try:
            setattr(err, _USER_CODE, True)
        except AttributeError:  # an exception type without a __dict__: the boundary will wrap it
            pass
        raise


def foreign(err: BaseException, what: str, backend: str = "") -> BaseException:
    """The exception to raise for ``err`` at a boundary: ``err`` itself when it is the project's own,
    the caller's, or not an ``Exception`` (``KeyboardInterrupt``, ``SystemExit``); a backend's
    refusal of its settings as :class:`~pmht_opt.exceptions.ConfigError` naming ``solver_settings``;
    else a :class:`SolverError` saying what failed. The new exception has ``err`` as its cause."""
    if not isinstance(err, Exception) or isinstance(err, PmhtOptError) or getattr(err, _USER_CODE, False):
        return err
    if isinstance(err, solvers.SettingsError):  # a backend that checks its options only when it solves
        out: PmhtOptError = ConfigError(f"solver_settings: {err}")
        out.__cause__ = err
        return out
    if isinstance(err, MemoryError):
        reason = "out of memory"
    else:
        reason = f"{type(err).__name__}: {err}".rstrip(": ")
    out = SolverError(f"{what} failed: {reason}.", backend=backend, status=type(err).__name__)
    out.__cause__ = err
    return out


def plan_boundary(what: str) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """Decorate a method of a planning object: any foreign exception it raises becomes
    :class:`SolverError` (:func:`foreign`), naming ``what`` and the object's ``solver`` if it has one."""

    def wrap(fn: Callable[P, R]) -> Callable[P, R]:
        @functools.wraps(fn)
        def inner(*args: P.args, **kwargs: P.kwargs) -> R:
            try:
                return fn(*args, **kwargs)
            except BaseException as err:
                backend = str(getattr(args[0], "solver", "")) if args else ""
                out = foreign(err, what, backend)
                if out is err:
                    raise
                raise out from err

        return inner

    return wrap


def solver_settings(name: str, settings: Any) -> None:
    """Raise :class:`ConfigError` naming ``name`` unless ``settings`` is a dict of named settings none of
    which is NaN (each backend checks the values it knows; NaN is what none of them can use)."""
    if not isinstance(settings, dict):
        raise ConfigError(f"{name}: expected a dict, got {type(settings).__name__}.")
    bad = [k for k in settings if not isinstance(k, str)]
    if bad:
        raise ConfigError(f"{name}: expected setting names (strings), got {bad[0]!r}.")
    for key, value in settings.items():
        if isinstance(value, float) and math.isnan(value):
            raise ConfigError(f"{name}: {key} is NaN, which no backend can use.")
