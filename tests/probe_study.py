"""A study of the study command's own behaviour: trials that kill their worker or return NaN.

Registered under the name ``probe`` by the tests that need it (``studies.cli.STUDIES``), it runs
through the same command, parser, executors and results file as every study; its trials are cheap.
"""

from __future__ import annotations

import math
import os
import signal
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from studies.options import Choices, Count, StudyOptions, option
from studies.trials import TrialTable

MODES = ("crash", "nan", "plain")


def trial(seed: int, mode: str) -> dict[str, Any]:
    """``seed`` squared; seed 2 kills its worker (``crash``), seed 1 returns NaN (``nan``)."""
    if mode == "crash" and seed == 2:
        os.kill(os.getpid(), signal.SIGKILL)
    return {"square": math.nan if mode == "nan" and seed == 1 else float(seed * seed)}


TABLE = TrialTable.of("probe", trial, {"square": "float"})


@dataclass(frozen=True)
class Options(StudyOptions):
    """Options of the probe study."""

    trials: int = option(4, Count("--trials", "trials"))
    mode: tuple[str, ...] = option(("plain",), Choices("--mode", "what the trials do", known=MODES))


def params(options: Options) -> list[dict[str, Any]]:
    """Seeds 0..trials-1 in the (first) mode."""
    return [{"seed": s, "mode": options.mode[0]} for s in range(options.trials)]


def summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The trials that finished."""
    return [{"finished": sum(1 for r in rows if not r["error_class"])}]


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """One line."""
    return f"finished: {table[0]['finished']}"
