"""Write the single-M-step weight fixtures of the exactness tests (``mstep_weights.npz``).

Cases (each ``W (T, M)``, ``WZ (T, M, 2)``, ``r`` and the scenario that produced them):

* ``anneal-first-{A,B,C}``: the first iteration of the default annealed EM (``r = 1``, standing paths);
* ``paper30-{A,B,C}``: the weights of the 31st M-step of ``PMHTConfig.paper()`` (long coasting
  stretches after the last significant weight, a flat M-step objective);
* ``gated-{A,B,C}``: the weights of the 41st M-step of the default EM, from a gated E-step (exact-zero
  stretches).

    python tests/data/make_mstep_weights.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import pmht_opt as po


def _capture(kind: str, cfg: po.PMHTConfig, after: int) -> tuple[np.ndarray, np.ndarray, float, bool]:
    sc = po.paper_scenario(kind, seed=1)
    with po.EMRun(sc, cfg) as run:
        for _ in range(after):
            run.step()
        es = run.estep
        r = run.schedule.r_at(after + 1)
        return es.W.copy(), es.WZ.copy(), r, es.gated


def main() -> None:
    out: dict[str, np.ndarray] = {}
    for kind in "ABC":
        cases = {
            f"anneal-first-{kind}": (po.PMHTConfig(solver="kalman"), 0),
            f"paper30-{kind}": (po.PMHTConfig.paper(solver="kalman"), 30),
            f"gated-{kind}": (po.PMHTConfig(solver="kalman"), 40),
        }
        for name, (cfg, after) in cases.items():
            W, WZ, r, gated = _capture(kind, cfg, after)
            out[f"{name}/W"], out[f"{name}/WZ"], out[f"{name}/r"] = W, WZ, np.asarray(r)
            out[f"{name}/kind"] = np.asarray(kind)
            zero = float(np.mean(W == 0))
            print(f"{name}: r = {r:g}, gated = {gated}, exact zeros {zero:.0%}, max W {W.max():.3g}")
    path = Path(__file__).with_name("mstep_weights.npz")
    np.savez_compressed(path, **out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
