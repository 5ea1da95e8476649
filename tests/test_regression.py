"""Behaviour regression: plans and tours equal those recorded at the reference commit.

``tests/regression/plans.npz`` was written by ``tests/regression/record.py``; a deliberate change of
behaviour re-records it in its own commit, with the reason in ``docs/decisions.md``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent / "regression"))

from cases import CASES, run_case

REFERENCE = np.load(Path(__file__).parent / "regression" / "plans.npz")
#: Largest position difference accepted: the same arithmetic up to rounding.
POSITION_TOL = 1e-9


@pytest.mark.parametrize("name", sorted(CASES))
def test_same_plan_as_the_reference(name: str) -> None:
    out = run_case(name)
    for key, value in out.items():
        ref = REFERENCE[f"{name}/{key}"]
        if key in ("positions", "history"):
            np.testing.assert_allclose(value, ref, rtol=0, atol=POSITION_TOL, err_msg=f"{name}/{key}")
        else:
            np.testing.assert_array_equal(value, ref, err_msg=f"{name}/{key}")
