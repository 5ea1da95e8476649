"""Errors of the generic QP layer.

``solvers`` knows nothing of its callers; a domain package translates these into its own hierarchy.
"""

from __future__ import annotations


class QPError(Exception):
    """Base class of every error raised by :mod:`solvers`."""


class ProblemError(QPError, ValueError):
    """A malformed problem: wrong shapes, non-finite data, cones that do not add up."""


class UnknownSolverError(QPError, ValueError):
    """A solver name that is not known, or whose package is not installed."""


class UnsupportedProblemError(QPError, ValueError):
    """The chosen backend cannot represent this problem (e.g. a second-order cone for OSQP)."""


class UpdateError(QPError, ValueError):
    """An in-place update whose sizes do not match the problem the session was built with."""


class SettingsError(QPError, ValueError):
    """A backend option that the backend does not know, or a value it rejects."""
