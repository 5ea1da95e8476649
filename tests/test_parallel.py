"""Threads change no digit: the E-step's blocks and the exact smoother's batch on several threads."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.em import EMRun
from pmht_opt.estep import estep, log_likelihood, safe_log
from pmht_opt.parallel import ordered_map


def _case(seed: int, prior: str) -> tuple[np.ndarray, np.ndarray, Any, Any]:
    """Random locales and random-walk paths, with uniform priors or non-uniform ones with zeros."""
    rng = np.random.default_rng(seed)
    N, M, T = 150, 3, 200
    z = rng.uniform(0, 10, (N, 2))
    pos = np.cumsum(rng.normal(0, 0.08, (M, T, 2)), axis=1) + rng.uniform(2, 8, (M, 1, 2))
    lt = lk = None
    if prior == "dirichlet":
        lt = np.log(rng.dirichlet(np.full(T, 0.5), size=N))
        k = rng.dirichlet(np.ones(M), size=N)
        k[k < 0.15] = 0.0
        lk = safe_log(k / k.sum(axis=1, keepdims=True))
    return z, pos, lt, lk


def _fields(es: po.EStepResult) -> dict[str, np.ndarray]:
    weights = es.weights
    dense = weights.toarray() if hasattr(weights, "toarray") else np.asarray(weights)
    return {"weights": dense, "W": es.W, "WZ": es.WZ, "lse": es.log_normaliser}


@pytest.mark.parametrize("prior", ["uniform", "dirichlet"])
@pytest.mark.parametrize(("r", "gate"), [(1.0, None), (0.01, None), (0.01, "auto"), (0.05, "auto")])
def test_estep_is_the_same_on_any_number_of_threads(
    prior: str, r: float, gate: Any, monkeypatch: Any
) -> None:
    """Small blocks (many of them) on 1, 2 and 3 threads: every weight, sum and normaliser equal."""
    from pmht_opt.estep import candidates, likelihood

    monkeypatch.setattr(likelihood, "_BLOCK", 2000)  # a few locales per dense block
    monkeypatch.setattr(candidates, "_BLOCK", 3000)  # and per gated block
    z, pos, lt, lk = _case(3, prior)
    one = estep(z, pos, lt, lk, r, gate=gate, threads=1)
    if gate is not None and r == 0.01:
        assert not isinstance(one.weights, np.ndarray)  # the gated E-step ran
    for threads in (2, 3):
        got = estep(z, pos, lt, lk, r, gate=gate, threads=threads)
        for name, value in _fields(one).items():
            np.testing.assert_array_equal(_fields(got)[name], value, err_msg=name)
        assert log_likelihood(z, pos, lt, lk, r, gate=gate, threads=threads) == one.log_likelihood


def test_plans_are_the_same_on_any_number_of_threads(monkeypatch: Any) -> None:
    """Whole annealed plans, dense and gated E-steps, with 1 and 2 threads: identical to the last bit."""
    from pmht_opt import parallel
    from pmht_opt.estep import candidates, likelihood

    monkeypatch.setattr(likelihood, "_BLOCK", 5000)
    monkeypatch.setattr(candidates, "_BLOCK", 5000)
    monkeypatch.setattr(parallel, "MIN_THREADED_TRIPLES", 0)  # threads even for this small a plan
    sc = po.paper_scenario("C", seed=2, horizon=150)
    cfgs = [po.PMHTConfig(max_iter=25, anneal=po.Anneal(1.0, 12), threads=t) for t in (1, 2)]
    assert [EMRun(sc, cfg).estep_threads for cfg in cfgs] == [1, 2]
    plans = [po.plan_pmht(sc, cfg) for cfg in cfgs]
    np.testing.assert_array_equal(plans[0].positions, plans[1].positions)
    np.testing.assert_array_equal(plans[0].history.objective, plans[1].history.objective)
    np.testing.assert_array_equal(plans[0].assignment, plans[1].assignment)


def test_small_esteps_stay_on_one_thread() -> None:
    """Below the threshold an E-step's blocks (and the objective beside them) run on the calling
    thread, whatever the threads asked for; above it they get them."""
    from pmht_opt.parallel import MIN_THREADED_TRIPLES, block_threads

    assert block_threads(2, MIN_THREADED_TRIPLES - 1) == 1
    assert block_threads(2, MIN_THREADED_TRIPLES) == 2
    assert block_threads(1, 10 * MIN_THREADED_TRIPLES) == 1
    assert EMRun(po.paper_scenario("A", seed=0), po.PMHTConfig(threads=2)).estep_threads == 1


def test_ordered_map_keeps_order_and_raises_in_order() -> None:
    def work(lo: int, hi: int) -> int:
        time.sleep(0.002 * ((7 - lo) % 4))  # later spans often finish first
        if lo == 5:
            raise ValueError("span 5")
        return lo * 10 + hi

    spans = [(i, i + 1) for i in range(8)]
    got = []
    with pytest.raises(ValueError, match="span 5"):
        for value in ordered_map(work, spans, threads=3):
            got.append(value)
    assert got == [i * 10 + i + 1 for i in range(5)]


def test_ordered_map_closed_early_leaves_nothing_running() -> None:
    running = threading.Event()
    done: list[int] = []

    def work(lo: int, hi: int) -> int:
        running.set()
        time.sleep(0.02)
        done.append(lo)
        return lo

    gen = ordered_map(work, [(i, i + 1) for i in range(10)], threads=2)
    assert next(gen) == 0
    gen.close()
    finished = len(done)
    time.sleep(0.1)
    assert len(done) == finished  # nothing ran on after the generator closed
    assert finished < 10


def test_concurrent_gives_the_result_and_waits_on_leaving() -> None:
    from pmht_opt.parallel import concurrent

    done: list[int] = []

    def slow(x: int, *, y: int) -> int:
        time.sleep(0.05)
        done.append(x)
        return x + y

    with concurrent(2, slow, 1, y=2) as result:
        assert result() == 3
    with pytest.raises(RuntimeError, match="body"), concurrent(2, slow, 5, y=0):
        raise RuntimeError("body")
    settled = list(done)  # the work of the failed body was cancelled or had finished
    time.sleep(0.1)
    assert done == settled and done[0] == 1
    with concurrent(1, slow, 7, y=1) as result:  # inline: runs when asked
        assert done == settled
        assert result() == 8


def test_concurrent_raises_the_work_s_error() -> None:
    from pmht_opt.parallel import concurrent

    def fail() -> int:
        raise ValueError("work")

    with pytest.raises(ValueError, match="work"), concurrent(2, fail) as result:
        result()


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs fork")
def test_a_forked_child_gets_pools_of_its_own() -> None:
    """A child made by fork after the pools were used plans with threads instead of waiting forever
    on the parent's pool threads, which do not exist in it."""
    import multiprocessing as mp

    from solvers import band_lu

    sc = po.paper_scenario("A", seed=0, horizon=500)
    cfg = po.PMHTConfig(max_iter=3, threads=2)
    parent = po.plan_pmht(sc, cfg).positions  # the pools now exist in this process
    assert band_lu._POOL._pool is not None  # the exact smoother's pool too
    ctx = mp.get_context("fork")
    with ctx.Pool(1) as pool:
        child = pool.apply_async(_plan_positions, (sc, cfg)).get(timeout=60)
    np.testing.assert_array_equal(child, parent)


def _plan_positions(sc: po.Scenario, cfg: po.PMHTConfig) -> np.ndarray:
    return po.plan_pmht(sc, cfg).positions


@pytest.mark.parametrize("threads", [0, -2, 1.5, True, "2", None])
def test_bad_thread_counts_are_config_errors(threads: Any) -> None:
    z, pos, _, _ = _case(0, "uniform")
    with pytest.raises(po.ConfigError, match="threads"):
        estep(z, pos, None, None, 0.1, threads=threads)
    with pytest.raises(po.ConfigError, match="threads"):
        log_likelihood(z, pos, None, None, 0.1, threads=threads)


def test_ordered_map_interrupted_while_waiting_leaves_nothing_running() -> None:
    """Ctrl-C while the caller waits for a block: the interrupt reaches the caller only once no block
    runs any more (the one waited for included)."""
    import signal

    running: set[int] = set()
    lock = threading.Lock()

    def work(lo: int, hi: int) -> int:
        with lock:
            running.add(lo)
        time.sleep(0.4 if lo == 0 else 0.1)
        with lock:
            running.discard(lo)
        return lo

    main = threading.main_thread().ident
    assert main is not None and threading.current_thread() is threading.main_thread()
    # Python's own handler, whatever an earlier test in this process left installed.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.1, lambda: signal.pthread_kill(main, signal.SIGINT))
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            for _ in ordered_map(work, [(i, i + 1) for i in range(6)], threads=2):
                pass
    finally:
        timer.join()
        signal.signal(signal.SIGINT, previous)
    with lock:
        assert running == set()


def test_concurrent_stops_its_work_at_the_next_block() -> None:
    from pmht_opt.parallel import concurrent

    blocks: list[int] = []

    def block(lo: int, hi: int) -> int:
        time.sleep(0.01)
        blocks.append(lo)
        return lo

    def many_blocks() -> int:
        for _ in ordered_map(block, [(i, i + 1) for i in range(500)], 1):
            pass
        return len(blocks)

    with pytest.raises(RuntimeError, match="body"), concurrent(2, many_blocks):
        time.sleep(0.05)
        raise RuntimeError("body")
    done = len(blocks)
    assert done < 100  # stopped long before its 500 blocks (5 s) were done
    time.sleep(0.05)
    assert len(blocks) == done
