"""Behaviour regression: plans and tours equal those recorded at the reference commit, within the
accuracy each backend promises.

``tests/regression/plans.npz`` was written by ``tests/regression/record.py``, with the machine, the
packages and the BLAS it ran on in ``tests/regression/environment.json``. A deliberate change of
behaviour re-records both in their own commit, with the reason in ``docs/decisions.md``.

Integer results (assignments, visit steps, tour orders) must be equal. Positions are compared within
the tolerance of the backend that solved the case (:data:`cases.POSITION_TOL`), never to the last bit:
another CPU or BLAS rounds differently. Bit-for-bit claims (threads, processes, workers) are tested
elsewhere by two runs made in the same test.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent / "regression"))

from cases import CASES, run_case, tolerance

REFERENCE = np.load(Path(__file__).parent / "regression" / "plans.npz")
#: Relative tolerance of the GA's cost history: sums of Euclidean distances in the same order.
HISTORY_RTOL = 1e-12


@pytest.mark.parametrize("name", sorted(CASES))
def test_same_plan_as_the_reference(name: str) -> None:
    out = run_case(name)
    for key, value in out.items():
        ref = REFERENCE[f"{name}/{key}"]
        if key == "positions":
            np.testing.assert_allclose(value, ref, rtol=0, atol=tolerance(name), err_msg=f"{name}/{key}")
        elif key == "history":
            np.testing.assert_allclose(value, ref, rtol=HISTORY_RTOL, atol=0, err_msg=f"{name}/{key}")
        else:
            np.testing.assert_array_equal(value, ref, err_msg=f"{name}/{key}")


def test_the_tolerances_cover_every_case() -> None:
    """Every case has a tolerance, and the exact backends' is far below the iterative ones'."""
    tols = {name: tolerance(name) for name in CASES if not name.startswith("ga-")}
    assert tols["default-kalman-A0"] < 1e-7 < tols["default-osqp-A0"]
