"""Study 'table1' (placeholder until implemented)."""

from __future__ import annotations

from typing import Any


def add_arguments(p: Any) -> None:
    """Options of ``pmht-opt study table1``."""


def main(args: Any) -> int:
    """``pmht-opt study table1``."""
    raise NotImplementedError("table1")
