"""The gated E-step equals the dense one to rounding; whole plans agree; bad gate values are refused."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import examples
from hypothesis import event, given, settings
from hypothesis import strategies as st

import pmht_opt as po
from pmht_opt.estep import EStepResult, estep, gate_margin, safe_log

TOL = 1e-12


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


def _case(seed: int, prior: str, r: float) -> tuple[np.ndarray, np.ndarray, Any, Any, float]:
    """Random locales and smooth random-walk paths in the 10 x 10 box, with priors of kind ``prior``."""
    rng = np.random.default_rng(seed)
    N, M, T = int(rng.integers(60, 160)), int(rng.integers(2, 5)), int(rng.integers(150, 300))
    z = rng.uniform(0, 10, (N, 2))
    steps = rng.normal(0, 0.08, (M, T, 2))
    pos = np.cumsum(steps, axis=1) + rng.uniform(2, 8, (M, 1, 2))
    lt = lk = None
    if prior == "dirichlet":  # non-uniform, with exact zeros in the platform prior
        lt = np.log(rng.dirichlet(np.full(T, 0.5), size=N))
        k = rng.dirichlet(np.ones(M), size=N)
        k[k < 0.15] = 0.0
        k /= k.sum(axis=1, keepdims=True)
        lk = safe_log(k)
    elif prior == "windows":  # each locale confined to a window of times and one platform (plan_smoothed)
        tau = np.zeros((N, T))
        for n in range(N):
            lo = int(rng.integers(0, T - 20))
            tau[n, lo : lo + int(rng.integers(1, 20))] = 1.0
        lt = safe_log(tau / tau.sum(axis=1, keepdims=True))
        k = np.zeros((N, M))
        k[np.arange(N), rng.integers(0, M, N)] = 1.0
        lk = safe_log(k)
    return z, pos, lt, lk, r


def _assert_same(g: EStepResult, d: EStepResult) -> None:
    tol = TOL
    assert _rel(g.W, d.W) < tol
    assert _rel(g.WZ, d.WZ) < tol
    np.testing.assert_allclose(g.log_normaliser, d.log_normaliser, rtol=tol, atol=tol)
    assert g.log_likelihood == pytest.approx(d.log_likelihood, rel=tol)
    for a, b in zip(g.map_assignment(), d.map_assignment(), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(g.max_weight(), d.max_weight(), atol=tol)
    np.testing.assert_allclose(g.time_prior(), d.time_prior(), atol=tol)
    # The platform prior is exact down to the underflow, tiny shares included (per-pair gate).
    kg, kd = g.platform_prior(), d.platform_prior()
    np.testing.assert_allclose(kg, kd, atol=tol)
    tiny = kd > 1e-250
    assert np.all(kg[tiny] > 0)
    np.testing.assert_allclose(np.log(kg[tiny]), np.log(kd[tiny]), atol=1e-9)
    # Rows recomputed exactly, and the stored sparse weights.
    np.testing.assert_allclose(g.weights_ntm(), d.weights_ntm(), atol=tol)
    dense_w = np.asarray(d.weights)
    if isinstance(g.weights, sp.csr_matrix):
        np.testing.assert_allclose(g.weights.toarray(), dense_w, atol=tol)
    # Rows recomputed with the dense arithmetic: bit for bit (ties among times broken alike).
    for n in range(0, dense_w.shape[0], 7):
        np.testing.assert_array_equal(g.locale_weights(n), d.locale_weights(n))
    # A range of rows at once gives each row exactly as one at a time.
    N = dense_w.shape[0]
    for es in (g, d):
        block = es.locales_weights(1, N)
        assert block.shape == (N - 1, es.n_times, es.n_platforms)
        for n in range(1, N, 5):
            np.testing.assert_array_equal(block[n - 1], es.locale_weights(n))


@pytest.mark.parametrize("prior", ["uniform", "dirichlet", "windows"])
@pytest.mark.parametrize("seed", [0, 1])
def test_gated_estep_equals_dense_small_r(seed: int, prior: str) -> None:
    z, pos, lt, lk, r = _case(seed, prior, 0.01 if seed == 0 else 0.002)
    d = estep(z, pos, lt, lk, r)
    g = estep(z, pos, lt, lk, r, gate="auto")
    assert g.gated and not d.gated
    assert isinstance(g.weights, sp.csr_matrix) and g.weights.shape == d.weights.shape
    assert g.weights.nnz < 0.1 * d.weights.size
    _assert_same(g, d)


@pytest.mark.parametrize("prior", ["uniform", "dirichlet"])
def test_gate_falls_back_to_dense_for_wide_r(prior: str) -> None:
    z, pos, lt, lk, _ = _case(3, prior, 1.0)
    d = estep(z, pos, lt, lk, 1.0)
    g = estep(z, pos, lt, lk, 1.0, gate="auto")
    assert not g.gated  # the gate would keep most triples: dense, bit for bit
    np.testing.assert_array_equal(np.asarray(g.weights), np.asarray(d.weights))


def test_numeric_gate_and_far_paths() -> None:
    z, pos, lt, lk, r = _case(4, "uniform", 0.01)
    d = estep(z, pos, lt, lk, r)
    g = estep(z, pos, lt, lk, r, gate=60.0)
    assert g.gated
    _assert_same(g, d)
    far = pos.copy()
    far[0, 5] = 1e200  # a diverged path: the dense code handles the overflow
    assert not estep(z, far, None, None, r, gate="auto").gated


def test_gate_margin_values() -> None:
    assert gate_margin(None, 10, 2) is None
    assert gate_margin("auto", 1000, 10) == pytest.approx(np.log(10000) + 37)
    assert gate_margin(25, 10, 2) == 25.0


@pytest.mark.parametrize("bad", ["fast", "", -1.0, 0, float("nan"), float("inf"), True, [40]])
def test_bad_gate_values_raise_config_error(bad: Any) -> None:
    with pytest.raises(po.ConfigError, match="estep_gate"):
        po.PMHTConfig(estep_gate=bad)
    with pytest.raises(po.ConfigError, match="estep_gate"):
        estep(np.zeros((1, 2)), np.zeros((1, 3, 2)), None, None, 0.01, gate=bad)


def test_good_gate_values_accepted() -> None:
    assert po.PMHTConfig().estep_gate == "auto"
    assert po.PMHTConfig(estep_gate="AUTO").estep_gate == "auto"
    assert po.PMHTConfig(estep_gate=None).estep_gate is None
    assert po.PMHTConfig(estep_gate=np.float64(30)).estep_gate == 30.0


@pytest.mark.parametrize("anneal", [None, po.Anneal(1.0, 8)])
def test_whole_plan_gated_equals_dense(anneal: Any) -> None:
    sc = po.paper_scenario("A", seed=1, horizon=250)
    base = {"solver": "kalman", "max_iter": 25, "anneal": anneal}
    dense = po.plan_pmht(sc, po.PMHTConfig(estep_gate=None, **base))
    assert not dense.history.estep_gated.any()
    gated = po.plan_pmht(sc, po.PMHTConfig(**base))
    assert gated.history.estep_gated.sum() >= 10  # most E-steps were gated
    np.testing.assert_allclose(gated.positions, dense.positions, atol=1e-9)
    np.testing.assert_array_equal(gated.assignment, dense.assignment)
    np.testing.assert_array_equal(gated.visit_time, dense.visit_time)
    np.testing.assert_allclose(gated.platform_prior, dense.platform_prior, atol=1e-12)
    np.testing.assert_allclose(gated.history.objective, dense.history.objective, rtol=1e-12)


def test_visit_all_plan_gated_equals_dense() -> None:
    sc = po.paper_scenario("A", seed=1, horizon=200)
    visits = [po.VisitAll(0.1, warmup=2)]
    base = {"solver": "clarabel", "max_iter": 8, "anneal": po.Anneal(1.0, 3), "constraints": visits}
    dense = po.plan_pmht(sc, po.PMHTConfig(estep_gate=None, **base))
    gated = po.plan_pmht(sc, po.PMHTConfig(**base))
    assert gated.history.estep_gated.any()
    np.testing.assert_allclose(gated.positions, dense.positions, atol=1e-5)
    np.testing.assert_array_equal(gated.visit_time, dense.visit_time)


def test_auto_gate_is_dense_with_time_prior_update() -> None:
    sc = po.paper_scenario("A", seed=1, horizon=150)
    res = po.plan_pmht(sc, po.PMHTConfig(solver="kalman", max_iter=6, anneal=None, update_time_prior=True))
    assert res.history.estep_gated.shape == (7,) and not res.history.estep_gated.any()


def test_smoothed_plan_gated_equals_dense() -> None:
    # Windowed time prior, one-hot platform prior: candidates from the priors' support; the polyline
    # start passes knots between steps, so equally distant steps must be tied alike in both E-steps.
    sc = po.paper_scenario("A", seed=1, horizon=300)
    tour = po.order_locales(sc, method="ga")
    cfg: dict[str, Any] = {"max_iter": 4}
    dense = po.plan_smoothed(sc, tour, po.PMHTConfig(estep_gate=None, **cfg))
    gated = po.plan_smoothed(sc, tour, po.PMHTConfig(**cfg))
    assert gated.history.estep_gated.all()
    np.testing.assert_allclose(gated.positions, dense.positions, atol=1e-5)
    np.testing.assert_array_equal(gated.visit_time, dense.visit_time)


def _brute_candidates(z: np.ndarray, pos: np.ndarray, query: np.ndarray, rho2: np.ndarray) -> np.ndarray:
    """``(n, m, t)`` of every triple within its queried pair's radius, by measuring all of them."""
    d2 = (z[:, None, None, 0] - pos[None, :, :, 0]) ** 2 + (z[:, None, None, 1] - pos[None, :, :, 1]) ** 2
    return np.argwhere(query[:, :, None] & (d2 <= rho2[:, :, None]))


@pytest.mark.parametrize("prior", ["uniform", "dirichlet", "windows"])
@pytest.mark.parametrize("r", [0.002, 0.05, 1.0])
def test_few_locales_choose_candidates_as_an_exact_count_would(prior: str, r: float) -> None:
    from pmht_opt.estep import candidates, gating
    from pmht_opt.estep.likelihood import EStepInputs

    z, pos, lt, lk, _ = _case(4, prior, r)
    z, lt, lk = z[:100], None if lt is None else lt[:100], None if lk is None else lk[:100]
    N, (M, T, _) = z.shape[0], pos.shape
    assert N <= 2 * candidates._GATE_SAMPLE  # the estimate counts every locale
    inputs = EStepInputs(z, pos, lt, lk, r)
    margin = gate_margin("auto", T, M)
    assert margin is not None
    got = gating._choose_source(inputs, margin)
    # The rule with the exact number of tree candidates: none past the budget, else the smaller set.
    budget = gating.GATE_MAX_FRACTION * N * T * M
    n_times = np.isfinite(lt).sum(axis=1) if lt is not None else np.full(N, T)
    n_plats = np.isfinite(lk).sum(axis=1) if lk is not None else np.full(N, M)
    support = float(np.sum(n_times * n_plats))
    tree = candidates.TreeCandidates(inputs, margin)
    exact = len(_brute_candidates(z, pos, tree.query, tree.rho2))
    lo = np.minimum(z.min(axis=0), pos.min(axis=(0, 1)))
    area = float(np.prod(np.maximum(z.max(axis=0), pos.max(axis=(0, 1))) - lo))
    if lt is None and np.pi * 2.0 * r * margin > gating.GATE_MAX_FRACTION * area:
        assert got is None
    elif min(support, exact) > budget:
        assert got is None
    elif support <= exact:
        assert isinstance(got, candidates.SupportCandidates)
    else:
        assert isinstance(got, candidates.TreeCandidates)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("block", [64, 1 << 18])
def test_chunked_search_finds_what_radius_queries_find(seed: int, block: int, monkeypatch: Any) -> None:
    """The chunk search returns exactly the triples within each pair's radius, in the order of the
    trees' radius queries (so every sum over them is formed as before), with the dense E-step's
    squared distances; also when blocks split the locales and the horizon is not a whole number of
    chunks."""
    from pmht_opt.estep import candidates
    from pmht_opt.estep.likelihood import EStepInputs

    monkeypatch.setattr(candidates, "_BLOCK", block)
    z, pos, _, _, _ = _case(seed, "uniform", 0.01)
    pos = pos[:, :135]  # 4 chunks and 7 points
    tree = candidates.TreeCandidates(EStepInputs(z, pos, None, None, 0.01), 60.0)
    blocks = [tree.block(lo, hi) for lo, hi in tree.spans()]
    assert blocks[0][0] == 0 and blocks[-1][1] == z.shape[0]
    assert all(a[1] == b[0] for a, b in itertools.pairwise(blocks))
    assert (len(blocks) > 1) == (block == 64)
    row = np.concatenate([b[2] for b in blocks])
    t = np.concatenate([b[3] for b in blocks])
    plat = np.concatenate([b[4] for b in blocks])
    want = []
    for n, m in zip(*np.nonzero(tree.query), strict=True):
        found = tree.trees[m].query_ball_point(z[n], tree.radius[n, m], return_sorted=False)
        want.extend((n, m, i) for i in found)
    assert len(want) > 0
    np.testing.assert_array_equal(np.column_stack([row, plat, t]), np.array(want))
    d2 = np.concatenate([b[5] for b in blocks])
    dx, dy = z[row, 0] - pos[plat, t, 0], z[row, 1] - pos[plat, t, 1]
    np.testing.assert_array_equal(d2, dx * dx + dy * dy)


@pytest.mark.parametrize("prior", ["uniform", "dirichlet", "windows"])
def test_statistics_of_the_gated_estep_equal_a_pass_over_its_weights(prior: str) -> None:
    """The platform prior, MAP assignment and largest weights the gated E-step computes block by block
    are bit for bit those of a pass over its sparse weights."""
    import dataclasses

    z, pos, lt, lk, r = _case(7, prior, 0.01)
    es = estep(z, pos, lt, lk, r, gate="auto")
    assert es.gated and es.platform_totals is not None
    bare = dataclasses.replace(es, platform_totals=None, best_column=None, largest=None)
    np.testing.assert_array_equal(es.platform_prior(), bare.platform_prior())
    np.testing.assert_array_equal(es.max_weight(), bare.max_weight())
    for a, b in zip(es.map_assignment(), bare.map_assignment(), strict=True):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=examples(25), deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    log_r=st.floats(np.log(1e-3), np.log(0.3)),
    prior=st.sampled_from(["uniform", "dirichlet", "windows"]),
)
def test_gated_estep_equals_dense_on_random_paths(seed: int, log_r: float, prior: str) -> None:
    """Property: wherever the gate runs it gives the dense E-step to rounding; where it does not, the
    dense E-step itself."""
    z, pos, lt, lk, r = _case(seed, prior, float(np.exp(log_r)))
    g = estep(z, pos, lt, lk, r, gate="auto")
    d = estep(z, pos, lt, lk, r, gate=None)
    event("gated" if g.gated else "dense")
    if g.gated:
        _assert_same(g, d)
    else:
        np.testing.assert_array_equal(np.asarray(g.weights), np.asarray(d.weights))


def _radii_on_points(tree: Any, seed: int) -> None:
    """Put every queried pair's radius exactly on the computed squared distance of one of its path
    points, or on a float neighbour of it: points exactly on (or one rounding inside or outside) the
    radii, where the trees' distances and the search's can disagree."""
    rng = np.random.default_rng(seed)
    z, pos = tree.z, tree.positions
    d2 = (z[:, None, None, 0] - pos[None, :, :, 0]) ** 2 + (z[:, None, None, 1] - pos[None, :, :, 1]) ** 2
    N, M, T = d2.shape
    rho2 = np.take_along_axis(d2, rng.integers(0, T, (N, M))[..., None], axis=2)[..., 0]
    side = rng.integers(-1, 2, (N, M))
    below, above = np.maximum(np.nextafter(rho2, -np.inf), 0.0), np.nextafter(rho2, np.inf)
    rho2 = np.where(side < 0, below, np.where(side > 0, above, rho2))
    tree.rho2 = np.where(tree.query, rho2, 0.0)
    tree.radius = np.sqrt(tree.rho2)


@settings(max_examples=examples(40), deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    log_r=st.floats(np.log(1e-3), np.log(0.1)),
    prior=st.sampled_from(["uniform", "dirichlet"]),
    grid=st.booleans(),
    on_radii=st.booleans(),
    fraction=st.floats(0.0, 1.5),
)
def test_the_count_inside_bounds_the_candidates_and_keeps_the_verdict(
    seed: int, log_r: float, prior: str, grid: bool, on_radii: bool, fraction: float
) -> None:
    """Property: the trees' count of points well inside the discs never exceeds the candidates the
    search finds, also with path points exactly on the radii (where the trees' rounding and the
    search's differ); and the estimate of a few locales, which uses that count to settle "too many"
    early, gives the exact count's verdict at every limit, those next to either count included. On
    a grid of coordinates many points are at equal distances from a locale."""
    from pmht_opt.estep import candidates
    from pmht_opt.estep.candidates import TreeCandidates
    from pmht_opt.estep.likelihood import EStepInputs

    z, pos, lt, lk, r = _case(seed, prior, float(np.exp(log_r)))
    if grid:
        z, pos = np.round(z * 4) / 4, np.round(pos * 4) / 4
    z, lt, lk = z[:100], None if lt is None else lt[:100], None if lk is None else lk[:100]
    inputs = EStepInputs(z, pos, lt, lk, r)
    margin = gate_margin("auto", pos.shape[1], pos.shape[0])
    assert margin is not None

    def tree() -> TreeCandidates:
        t = TreeCandidates(inputs, margin)
        if on_radii:
            _radii_on_points(t, seed)
        return t

    reference = tree()
    exact = len(_brute_candidates(z, pos, reference.query, reference.rho2))
    assert sum(reference.block(lo, hi)[2].size for lo, hi in reference.spans()) == exact  # the search
    inside = reference.inside_count()
    assert inside <= exact
    if not on_radii:  # a tight bound: only points within the rounding room of a radius are missed
        assert inside >= exact - max(3, exact // 1000)
    limits = {0.0, inside - 1.0, float(inside), inside + 1.0, exact - 1.0, float(exact), fraction * exact}
    old = candidates._TRY_INSIDE
    try:
        # As the gate runs, and with the count inside always tried first (so that every limit takes
        # the early path, also where the count inside and the exact one differ).
        for candidates._TRY_INSIDE in (old, 0.0):
            for limit in limits:
                assert (tree().estimate(limit) > limit) == (exact > limit), (limit, candidates._TRY_INSIDE)
    finally:
        candidates._TRY_INSIDE = old
    event("inside < exact" if inside < exact else "inside == exact")


@pytest.mark.parametrize("prior", ["uniform", "dirichlet", "windows"])
def test_blocks_of_locales_do_not_change_a_digit(prior: str, monkeypatch: Any) -> None:
    """The gated E-step in blocks of a few locales equals it in one block bit for bit, and its sums
    are those of one pass over its sparse weights in their order."""
    from pmht_opt.estep import candidates

    z, pos, lt, lk, r = _case(11, prior, 0.01)
    whole = estep(z, pos, lt, lk, r, gate="auto")
    monkeypatch.setattr(candidates, "_BLOCK", 64)
    parts = estep(z, pos, lt, lk, r, gate="auto")
    assert whole.gated and parts.gated
    for name in ("W", "WZ", "log_normaliser", "platform_totals", "best_column", "largest"):
        np.testing.assert_array_equal(getattr(parts, name), getattr(whole, name), err_msg=name)
    for name in ("data", "indices", "indptr"):
        np.testing.assert_array_equal(getattr(parts.weights, name), getattr(whole.weights, name))
    w = parts.weights
    T, M = parts.n_times, parts.n_platforms
    np.testing.assert_array_equal(parts.W.ravel(), np.bincount(w.indices, weights=w.data, minlength=T * M))
    rows = np.repeat(np.arange(w.shape[0]), np.diff(w.indptr))
    wz = np.bincount(w.indices, weights=w.data * z[rows, 0], minlength=T * M)
    np.testing.assert_array_equal(parts.WZ[:, :, 0].ravel(), wz)


@settings(max_examples=examples(25), deadline=None)
@given(
    N=st.integers(1, 40),
    M=st.integers(1, 3),
    T=st.integers(1, 70),
    seed=st.integers(0, 2**32 - 1),
    log_r=st.floats(np.log(1e-4), np.log(1e-2)),
)
def test_gated_estep_equals_dense_on_small_problems(N: int, M: int, T: int, seed: int, log_r: float) -> None:
    """Property: down to one locale, one platform and horizons shorter than a chunk, the gated E-step
    (where it runs) equals the dense one to rounding."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0, 20, (N, 2))
    pos = np.cumsum(rng.normal(0, 0.3, (M, T, 2)), axis=1) + rng.uniform(0, 20, (M, 1, 2))
    r = float(np.exp(log_r))
    g = estep(z, pos, None, None, r, gate="auto")
    d = estep(z, pos, None, None, r, gate=None)
    event("gated" if g.gated else "dense")
    if g.gated:
        _assert_same(g, d)


@settings(max_examples=examples(25), deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    log_r=st.floats(np.log(1e-3), np.log(1.0)),
    prior=st.sampled_from(["uniform", "dirichlet", "windows"]),
    gate=st.sampled_from([None, "auto", 5.0]),
)
def test_the_objective_alone_is_the_estep_s_bit_for_bit(
    seed: int, log_r: float, prior: str, gate: Any
) -> None:
    """Property: the log-likelihood computed without the weights (annealing's objective at the old
    ``r``) is the E-step's own, bit for bit, whether the E-step is gated, dense, or gives up the gate
    midway; also with a block size that splits the locales."""
    from pmht_opt.estep import candidates, log_likelihood

    z, pos, lt, lk, r = _case(seed, prior, float(np.exp(log_r)))
    es = estep(z, pos, lt, lk, r, gate=gate)
    event("gated" if es.gated else "dense")
    assert log_likelihood(z, pos, lt, lk, r, gate=gate) == es.log_likelihood
    old = candidates._BLOCK
    try:
        candidates._BLOCK = 64
        assert log_likelihood(z, pos, lt, lk, r, gate=gate) == es.log_likelihood
    finally:
        candidates._BLOCK = old


def test_the_objective_alone_follows_a_gate_given_up_midway(monkeypatch: Any) -> None:
    """The gate gives up after some blocks (its estimate said few candidates, the search finds too
    many) and the dense E-step runs, in several dense blocks with a shorter last one: the objective
    computed alone follows the same path and gives the same number, bit for bit."""
    import math

    from pmht_opt.estep import candidates, gating, likelihood, log_likelihood

    monkeypatch.setattr(candidates.TreeCandidates, "estimate", lambda self, limit=math.inf: 0.0)
    monkeypatch.setattr(candidates, "_BLOCK", 64)
    monkeypatch.setattr(likelihood, "_BLOCK", 4096)
    seen: list[str] = []
    real = gating._gated_blocks

    def recording(*args: Any) -> Any:
        for block in real(*args):
            seen.append("block" if block is not None else "gave up")
            yield block

    monkeypatch.setattr(gating, "_gated_blocks", recording)
    z, pos, lt, lk, r = _case(5, "uniform", 0.03)
    es = estep(z, pos, lt, lk, r, gate="auto")
    assert not es.gated and seen[-1] == "gave up" and seen.count("block") > 1
    T, M = pos.shape[1], pos.shape[0]
    assert z.shape[0] % (4096 // (T * M)) != 0  # the dense E-step's last block is a short one
    seen.clear()
    assert log_likelihood(z, pos, lt, lk, r, gate="auto") == es.log_likelihood
    assert seen[-1] == "gave up" and seen.count("block") > 1


def test_gated_weights_are_joined_on_first_read_only() -> None:
    """A gated E-step keeps its weights as the blocks' pieces until they are read: the EM loop's own
    reads (``gated``, ``n_times``, the sums) and the rows recomputed from the inputs join nothing; the
    first read of ``weights`` gives the CSR matrix, whose rows have the maxima and sums computed block
    by block on the way, the same matrix on every read, from two threads at once, through copies and
    pickles."""
    import dataclasses
    import pickle
    import threading

    from pmht_opt.estep import candidates
    from pmht_opt.estep.gated_sums import SparseParts

    z, pos, lt, lk, r = _case(11, "uniform", 0.01)
    old = candidates._BLOCK
    try:
        candidates._BLOCK = 64  # many blocks, so the join has pieces to put together
        es = estep(z, pos, lt, lk, r, gate="auto")
    finally:
        candidates._BLOCK = old
    parts = es.__dict__["_weights"]
    assert isinstance(parts, SparseParts) and len(parts.values) > 1
    assert es.gated and es.n_times == pos.shape[1] and es.log_likelihood == np.sum(es.log_normaliser)
    rows = es.locales_weights(3, 7)
    assert es.locale_weights(5).shape == (es.n_times, es.n_platforms) and es.weights_ntm().shape[0] == len(z)
    assert es.__dict__["_weights"] is parts  # nothing above joined the pieces
    read: list[Any] = []
    barrier = threading.Barrier(2)

    def reader() -> None:
        barrier.wait()
        read.append(es.weights)

    threads = [threading.Thread(target=reader) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    first = es.weights
    assert isinstance(first, sp.csr_matrix) and all(w is first for w in read)  # joined once
    assert first.shape == (len(z), es.n_times * es.n_platforms)
    np.testing.assert_array_equal(np.maximum.reduceat(first.data, first.indptr[:-1]), es.largest)
    spans = list(itertools.pairwise(first.indptr))
    best = [first.indices[a:b][first.data[a:b] == first.data[a:b].max()].min() for a, b in spans]
    np.testing.assert_array_equal(best, es.best_column)
    np.testing.assert_allclose(first.sum(axis=0).A1.reshape(es.W.shape), es.W, rtol=1e-12)
    np.testing.assert_allclose(first.sum(axis=1).A1, 1.0, rtol=1e-12)  # each locale's weights sum to one
    # The rows recomputed from the inputs (dropped triples included) are the joined rows to rounding.
    np.testing.assert_allclose(first[3:7].toarray().reshape(rows.shape), rows, rtol=1e-12, atol=1e-15)
    again = estep(z, pos, lt, lk, r, gate="auto")
    for copy in (pickle.loads(pickle.dumps(again)), dataclasses.replace(again, largest=None)):
        assert copy.gated
        np.testing.assert_array_equal(copy.weights.toarray(), first.toarray())
    with pytest.raises(TypeError):
        type(es)(es.weights, es.W, es.WZ, es.log_normaliser, es.n_platforms)  # keywords only
