"""The compiled loops of the gated E-step give the numpy passes' numbers to the last bit."""

from __future__ import annotations

import os
import subprocess
import sys
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import examples
from hypothesis import event, given, settings
from hypothesis import strategies as st
from test_gating import _case

import pmht_opt as po
from pmht_opt import candidates, gated_sums, gating, kernels
from pmht_opt.estep import EStepResult, estep, gate_margin, log_likelihood
from pmht_opt.likelihood import EStepInputs
from solvers import band_kernels

needs_numba = pytest.mark.skipif(not kernels.available(), reason="numba is not installed")


def _outputs(es: EStepResult) -> dict[str, np.ndarray]:
    """Everything an E-step hands on, as arrays."""
    out = {
        "W": es.W,
        "WZ": es.WZ,
        "log_normaliser": es.log_normaliser,
        "platform_prior": es.platform_prior(),
        "time_prior": es.time_prior(),
        "max_weight": es.max_weight(),
        "assignment": es.map_assignment()[0],
        "visit_time": es.map_assignment()[1],
    }
    w = es.weights
    if isinstance(w, sp.csr_matrix):
        out |= {"data": w.data, "indices": w.indices, "indptr": w.indptr}
    else:
        out["dense"] = np.asarray(w)
    return out


def _both(monkeypatch: Any, *args: Any, **kwargs: Any) -> tuple[EStepResult, EStepResult]:
    """The E-step by the numpy passes and by the compiled loops; the objective alone
    (:func:`~pmht_opt.estep.log_likelihood`, which keeps no weights) equal too."""
    monkeypatch.setenv(kernels.ENV_SWITCH, "0")
    assert not kernels.available()
    plain = estep(*args, **kwargs)
    plain_objective = log_likelihood(*args, **kwargs)
    monkeypatch.setenv(kernels.ENV_SWITCH, "1")
    assert kernels.available()
    fast = estep(*args, **kwargs)
    assert log_likelihood(*args, **kwargs) == plain_objective == plain.log_likelihood
    return plain, fast


def _assert_identical(a: EStepResult, b: EStepResult) -> None:
    assert a.gated == b.gated
    oa, ob = _outputs(a), _outputs(b)
    assert oa.keys() == ob.keys()
    for key in oa:
        assert oa[key].dtype == ob[key].dtype, key
        np.testing.assert_array_equal(oa[key], ob[key], err_msg=key)


def _lattice(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Locales and paths on a coarse lattice: many equal distances, hence tied weights, including the
    largest of a row (its column is then the smallest among the ties)."""
    rng = np.random.default_rng(seed)
    z = rng.integers(0, 8, (40, 2)).astype(float)
    pos = rng.integers(0, 8, (3, 120, 2)).astype(float)
    return z, pos


@needs_numba
@pytest.mark.parametrize("prior", ["uniform", "dirichlet", "windows"])
@pytest.mark.parametrize("r", [0.002, 0.01])
@pytest.mark.parametrize("gate", ["auto", 3.0])
@pytest.mark.parametrize("threads", [1, 2])
def test_the_loops_give_the_numpy_bits(
    prior: str, r: float, gate: Any, threads: int, monkeypatch: Any
) -> None:
    """Weights, sums, normalisers and statistics equal bit for bit, with and without priors (zero
    entries included), with a wide and a narrow gate, on one and two threads."""
    z, pos, lt, lk, r = _case(4, prior, r)
    plain, fast = _both(monkeypatch, z, pos, lt, lk, r, gate=gate, threads=threads)
    assert plain.gated
    _assert_identical(plain, fast)


@needs_numba
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ties_are_broken_alike(seed: int, monkeypatch: Any) -> None:
    """On a lattice many weights tie; each row's largest and its column still agree."""
    z, pos = _lattice(seed)
    plain, fast = _both(monkeypatch, z, pos, None, None, 0.002, gate="auto")
    assert plain.gated
    best = plain.max_weight()
    assert np.sum(np.asarray(plain.weights.toarray()) == best[:, None]) > z.shape[0]  # ties exist
    _assert_identical(plain, fast)


@needs_numba
def test_a_gate_given_up_gives_the_dense_estep(monkeypatch: Any) -> None:
    """A locale whose priors leave no finite candidate makes both give way to the dense E-step."""
    z, pos, lt, lk, r = _case(5, "dirichlet", 0.01)
    lk = lk.copy()
    lk[3] = -np.inf  # no platform may visit locale 3
    lk[3, 0] = 0.0
    lt = lt.copy()
    lt[3] = -np.inf
    lt[3, 0] = 0.0
    pos = pos.copy()
    pos[0, 0] = (1e3, 1e3)  # ... at the only time it may be visited, from far away
    plain, fast = _both(monkeypatch, z, pos, lt, lk, r, gate=1e-3)
    _assert_identical(plain, fast)


@needs_numba
@settings(max_examples=examples(20), deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    log_r=st.floats(np.log(1e-3), np.log(0.3)),
    prior=st.sampled_from(["uniform", "dirichlet", "windows"]),
    margin=st.sampled_from(["auto", 0.5, 8.0]),
)
def test_the_loops_give_the_numpy_bits_on_random_paths(
    seed: int, log_r: float, prior: str, margin: Any
) -> None:
    """Property: whatever the paths, priors, penalty and gate, the two give the same bits."""
    z, pos, lt, lk, r = _case(seed, prior, float(np.exp(log_r)))
    with pytest.MonkeyPatch.context() as mp:
        plain, fast = _both(mp, z, pos, lt, lk, r, gate=margin)
    event("gated" if plain.gated else "dense")
    _assert_identical(plain, fast)


def test_the_loops_uncompiled_give_the_numpy_bits(monkeypatch: Any) -> None:
    """The loops' source, run as plain Python (as numba compiles it, without numba), gives the numpy
    passes' numbers: the algorithm, not only its compiled form, is the one the numpy passes compute."""
    z, pos, lt, lk, r = _case(11, "dirichlet", 0.002)
    z, pos, lt, lk = z[:25], pos[:, :60], lt[:25, :60], lk[:25]
    monkeypatch.setenv(kernels.ENV_SWITCH, "0")
    plain = estep(z, pos, lt, lk, r, gate="auto")
    python = SimpleNamespace(**kernels.LOOPS)
    monkeypatch.setattr(kernels, "compiled", lambda: python)
    slow = estep(z, pos, lt, lk, r, gate="auto")
    assert plain.gated
    _assert_identical(plain, slow)


def test_without_numba_the_numpy_passes_run(monkeypatch: Any) -> None:
    """Where numba cannot be imported the E-step runs its numpy passes, with the same numbers."""
    z, pos, lt, lk, r = _case(2, "uniform", 0.01)
    reference = estep(z, pos, lt, lk, r, gate="auto")
    monkeypatch.setenv(kernels.ENV_SWITCH, "1")
    monkeypatch.setitem(sys.modules, "numba", None)  # "import numba" raises ImportError
    monkeypatch.setattr(kernels, "_TRIED", False)
    monkeypatch.setattr(kernels, "_COMPILED", None)
    assert not kernels.available()
    _assert_identical(estep(z, pos, lt, lk, r, gate="auto"), reference)


def test_the_switch(monkeypatch: Any) -> None:
    """``0`` never; ``1``, ``auto`` and unset wherever numba is installed, at any size; anything else
    is refused, naming the variable."""
    monkeypatch.setenv(kernels.ENV_SWITCH, "0")
    assert kernels.compiled() is None and not kernels.available() and not kernels.lu_compiled()
    for value in ("auto", "", " AUTO ", "1"):
        monkeypatch.setenv(kernels.ENV_SWITCH, value)
        assert (kernels.compiled() is not None) == kernels.available() == kernels.lu_compiled()
    monkeypatch.delenv(kernels.ENV_SWITCH)
    assert (kernels.compiled() is not None) == kernels.lu_compiled()
    monkeypatch.setenv(kernels.ENV_SWITCH, "yes")
    for ask in (kernels.compiled, kernels.lu_compiled):
        with pytest.raises(po.ConfigError, match=kernels.ENV_SWITCH):
            ask()


@needs_numba
@pytest.mark.parametrize("r, gate", [(0.25, 1.0), (0.25, 2.0), (0.125, 4.0)])
def test_weights_exactly_on_the_gate_are_kept_alike(r: float, gate: float, monkeypatch: Any) -> None:
    """On a lattice with ``r = 2^-k`` and an integer margin, log weights fall exactly on a pair's
    threshold: both keep them (``>=``)."""
    for seed in range(4):
        z, pos = _lattice(seed)
        plain, fast = _both(monkeypatch, z, pos, None, None, r, gate=gate)
        assert plain.gated
        _assert_identical(plain, fast)


@needs_numba
@pytest.mark.parametrize("prior", ["uniform", "dirichlet", "windows"])
def test_many_blocks_on_threads_give_the_numpy_bits(prior: str, monkeypatch: Any) -> None:
    """Blocks of a few locales (so sums run across blocks, rows are offset by the block's first
    locale, and two threads work ahead of the ordered sums) give the same bits."""
    monkeypatch.setattr(candidates, "_BLOCK", 1 << 10)
    z, pos, lt, lk, r = _case(4, prior, 0.002)
    inputs = EStepInputs(z, pos, lt, lk, r)
    source = gating._choose_source(inputs, gate_margin("auto", pos.shape[1], pos.shape[0]))
    assert source is not None and len(source.spans()) > 5
    plain, fast = _both(monkeypatch, z, pos, lt, lk, r, gate="auto", threads=2)
    assert plain.gated
    _assert_identical(plain, fast)


@needs_numba
def test_inputs_of_other_float_types_give_the_float64_bits(monkeypatch: Any) -> None:
    """Big-endian, single-precision or long-double inputs are taken as native float64 by either path."""
    z, pos, lt, lk, r = _case(4, "dirichlet", 0.002)
    reference, _ = _both(monkeypatch, z, pos, lt, lk, r, gate="auto")
    for dtype in (">f8", np.longdouble):
        plain, fast = _both(
            monkeypatch,
            z.astype(dtype),
            pos.astype(dtype),
            lt.astype(dtype),
            lk.astype(dtype),
            r,
            gate="auto",
        )
        _assert_identical(plain, fast)
        _assert_identical(plain, reference)
    single, fast = _both(monkeypatch, z, pos, lt.astype(np.float32), lk.astype(np.float16), r, gate="auto")
    _assert_identical(single, fast)


@needs_numba
def test_the_switch_is_read_once_per_estep(monkeypatch: Any) -> None:
    """Flipping the switch while an E-step runs changes nothing of that E-step: every block of it is
    computed and summed one way."""
    monkeypatch.setattr(candidates, "_BLOCK", 1 << 10)
    z, pos, lt, lk, r = _case(4, "uniform", 0.002)
    reference, _ = _both(monkeypatch, z, pos, lt, lk, r, gate="auto")
    add = gated_sums.GatedAccumulator.add

    def flipping(self: Any, block: Any) -> None:
        add(self, block)
        os.environ[kernels.ENV_SWITCH] = "0" if os.environ[kernels.ENV_SWITCH] == "1" else "1"

    monkeypatch.setattr(gated_sums.GatedAccumulator, "add", flipping)
    for start in ("0", "1"):
        monkeypatch.setenv(kernels.ENV_SWITCH, start)
        _assert_identical(estep(z, pos, lt, lk, r, gate="auto"), reference)


def test_numba_is_imported_only_when_used() -> None:
    """``import pmht_opt`` leaves numba unimported; a plan imports it for the exact M-step's banded LU
    (where it is installed) unless the switch is ``0``."""
    plan = "; po.plan_pmht(po.paper_scenario('A', seed=0, horizon=100), po.PMHTConfig(max_iter=60))"
    for env, code, expected in (
        ("auto", "import pmht_opt as po", False),
        ("0", "import pmht_opt as po" + plan, False),
        ("auto", "import pmht_opt as po" + plan, band_kernels.available()),
    ):
        done = subprocess.run(
            [sys.executable, "-X", "importtime", "-c", code],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, kernels.ENV_SWITCH: env},
        )
        names = {line.rsplit("|", 1)[1].strip() for line in done.stderr.splitlines() if "|" in line}
        assert "pmht_opt" in names
        assert ("numba" in names) == expected, (env, code)
