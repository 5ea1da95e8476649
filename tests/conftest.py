"""Shared fixtures and tolerances.

Tolerances are per backend and stated once here, as each backend promises them: every backend runs
the shared test problems, and each is held to its own stated accuracy.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import settings

import pmht_opt as po

#: Examples per property-based test under the "ci" profile (the default): a few seconds in all. The
#: "long" profile draws ten times as many, for deliberate runs: ``HYPOTHESIS_PROFILE=long pytest``.
#: Both are derandomised: every run draws the same examples.
CI_EXAMPLES = 30
settings.register_profile("ci", max_examples=CI_EXAMPLES, deadline=None, derandomize=True)
settings.register_profile("long", max_examples=10 * CI_EXAMPLES, deadline=None, derandomize=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def examples(n: int) -> int:
    """``n`` examples under the "ci" profile, scaled like the loaded profile (ten times under "long")."""
    return max(1, n * settings().max_examples // CI_EXAMPLES)


#: Backends of the M-step that every cross-check runs.
QP_BACKENDS = ["clarabel", "osqp", "cvxpy"]
ALL_BACKENDS = ["kalman", *QP_BACKENDS]
#: Largest position difference to the RTS answer accepted on one M-step.
POSITION_TOL = 1e-6
#: Largest violation accepted on a returned plan, per backend. OSQP stops ADMM at 1e-5 on
#: constrained M-steps (see mstep.tuning.CONSTRAINED_DEFAULTS); its polygons are inner approximations, so
#: the exact constraint is usually met with room to spare, but a step left unpolished may miss it
#: by about the ADMM tolerance.
VIOLATION_TOL = {"clarabel": 1e-6, "cvxpy": 1e-6, "osqp": 1e-4}


@pytest.fixture(scope="session")
def scenario_a() -> po.Scenario:
    return po.paper_scenario("A", seed=1)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


def small_scenario(n_locales: int = 6, n_platforms: int = 2, horizon: int = 40, seed: int = 0) -> po.Scenario:
    """A quick random scenario for tests that need many plans."""
    gen = np.random.default_rng(seed)
    return po.Scenario(
        locales=gen.uniform(0, 4, (n_locales, 2)),
        starts=gen.uniform(0, 4, (n_platforms, 2)),
        horizon=horizon,
    )
