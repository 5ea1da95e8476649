"""Benchmark: one plan at the scale target, N = 5000 locales, M = 20 platforms, T = 5000 steps.

100 EM iterations with the fastest exact backend (``solver="auto"``: the banded smoother for the
unconstrained M-step), gated E-step. ``--config default`` is the default annealed EM (its first
iterations at large r gate almost nothing, so their E-steps are dense: N x T x M = 5e8 weights);
``--config plain`` starts at the scenario's r (``anneal=None``), so every E-step can be gated.
Prints and writes the wall time, the E-step / M-step split, the gated E-steps and the peak resident
memory of this process (``studies/results/bench_scale_<config>.json``, with provenance).

Target on this 2-core machine: at most 60 s and 8 GiB.

    python studies/bench_scale.py [--config plain|default] [--iterations 100]
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import pmht_opt as po
from studies.report import write_json
from studies.scaling_study.design import scaling_scenario

#: The target size (N, T, M) and its limits.
SIZE = (5000, 5000, 20)
TARGET_S = 60.0
TARGET_GIB = 8.0


def main() -> None:
    """Plan once at the target size and write the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", choices=["plain", "default"], default="plain")
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    n, t, m = SIZE
    sc = scaling_scenario(n, t, m, seed=0)
    cfg = po.PMHTConfig(max_iter=args.iterations)
    if args.config == "plain":
        cfg = po.PMHTConfig(max_iter=args.iterations, anneal=None)
    t0 = time.perf_counter()
    res = po.plan_pmht(sc, cfg)
    wall = time.perf_counter() - t0
    h = res.history
    peak_gib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    payload = {
        "benchmark": f"one plan, N={n} T={t} M={m}, {args.iterations} iterations, solver auto",
        "config": args.config,
        "wall_s": wall,
        "estep_s": float(h.estep_time.sum()),
        "mstep_s": float(h.mstep_time.sum()),
        "gated_esteps": int(h.estep_gated.sum()),
        "esteps": int(h.estep_gated.size),
        "iterations": res.n_iterations,
        "peak_rss_gib": peak_gib,
        "total_distance": res.total_distance,
        "targets": {"wall_s": TARGET_S, "peak_gib": TARGET_GIB},
    }
    print(
        f"N={n} T={t} M={m} ({args.config}): {wall:.1f} s (E-step {payload['estep_s']:.1f} s, M-step "
        f"{payload['mstep_s']:.1f} s), peak {peak_gib:.2f} GiB; "
        f"target {TARGET_S:.0f} s / {TARGET_GIB:.0f} GiB: "
        + (
            "no verdict (fewer iterations than the target's 100)"
            if args.iterations < 100
            else ("met" if wall <= TARGET_S and peak_gib <= TARGET_GIB else "MISSED")
        )
    )
    out = args.out or Path(__file__).parent / "results" / f"bench_scale_{args.config}.json"
    print(f"wrote: {write_json(out, payload)}")


if __name__ == "__main__":
    main()
