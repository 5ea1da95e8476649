"""Study 'solvers' (placeholder until implemented)."""

from __future__ import annotations

from typing import Any


def add_arguments(p: Any) -> None:
    """Options of ``pmht-opt study solvers``."""


def main(args: Any) -> int:
    """``pmht-opt study solvers``."""
    raise NotImplementedError("solvers")
