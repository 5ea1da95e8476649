"""Progress reports of the EM-based planners: the iteration observers their callbacks become."""

from __future__ import annotations

from collections.abc import Callable

from pmht_opt.em import EMCallbacks, EMRun, IterationRecord
from pmht_opt.exceptions import ConfigError
from pmht_opt.settings import ProgressCallback
from pmht_opt.stopping import ProgressObserver


def observing(callbacks: EMCallbacks | None, callback: ProgressObserver | None) -> EMCallbacks | None:
    """``callbacks`` with ``callback(progress)`` also called after every iteration, with the
    :class:`~pmht_opt.stopping.EMProgress` the stopping criteria see."""
    if callback is None:
        return callbacks

    def report(run: EMRun, record: IterationRecord) -> None:
        assert run.progress is not None  # formed before the iteration's observers are called
        callback(run.progress)

    return _also_after(callbacks, report)


def with_progress(callbacks: EMCallbacks | None, callback: ProgressCallback | None) -> EMCallbacks | None:
    """``callbacks`` with ``callback(iteration, objective)`` also called after every iteration (the
    callback of :func:`plan_pmht` and :func:`~pmht_opt.plan_smoothed`)."""
    if callback is None:
        return callbacks
    if not callable(callback):
        raise ConfigError(f"callback: expected a callable(iteration, objective), got {callback!r}.")
    return _also_after(callbacks, lambda run, record: callback(record.iteration, record.objective))


def _also_after(callbacks: EMCallbacks | None, fn: Callable[[EMRun, IterationRecord], object]) -> EMCallbacks:
    """``callbacks`` with ``fn(run, record)`` called after every iteration, after their own."""
    base = callbacks if callbacks is not None else EMCallbacks()
    inner = base.after_iteration

    def after(run: EMRun, record: IterationRecord) -> None:
        if inner is not None:
            inner(run, record)
        fn(run, record)

    return EMCallbacks(base.after_estep, base.after_mstep, after)
