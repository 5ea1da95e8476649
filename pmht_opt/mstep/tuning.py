"""Backend settings of the M-step, as data: the defaults, the constrained defaults and the retries.

Why each value (figures in docs/decisions.md sections 2 and 3):

* OSQP, unconstrained: the QP has equality rows only, so OSQP's polishing is the solve of its whole
  KKT system, refined against the unregularised matrix: exact to rounding, where ADMM alone must run
  to 1e-9 (residuals of the dynamics integrate into positions over hundreds of steps) and its
  duality-gap test then stalls small problems at "solved inaccurate" (one locale, 30 steps). So ADMM
  runs to 1e-4 only (its iterate is a warm start), polishing follows, and the answer counts as solved
  only if its residuals meet 1e-10 (``polish_tolerance``, :mod:`solvers.osqp_`), which a polish whose
  refinement has not converged misses by orders of magnitude. The refinement converges in a few steps
  with ``sigma = 1e-9``; with OSQP's 1e-6 it stalled at 1e-9 on coordinates of a few hundredths.
  ``rho = 1``; OSQP equilibrates the problem again at every update of ``P``, once per EM iteration,
  and four passes of its equilibration (its default is ten) cost half as much for the same answers.
  The retry refines the polish 50 times.
* OSQP, constrained: at 1e-9 ADMM needs tens of thousands of iterations with inequality rows; at 1e-5
  with polishing it solves limits, bounds, obstacles and terminal conditions. OSQP's duality-gap
  test keeps such solves at "solved inaccurate", so it is off. Polishing recovers the exact answer when
  ADMM found the active set; on speed limits positions can stay about 1e-3 from the optimum, so use
  clarabel for exact constrained plans. The iteration cap of a constrained attempt is 8000 (a
  feasible constrained M-step of scenario A takes a few hundred): an infeasible one, which ADMM
  rarely certifies, then fails within seconds, and the infeasibility diagnosis names it before any
  retry; a feasible but hard one continues from its iterate with room for 50000 more iterations
  (guaranteed visits take 5000-43000 on A, B, C). Each platform's solve in a constrained M-step has a
  work budget of its own (:data:`MSTEP_WORK`): one shared by the platforms' threads would make the
  answer depend on thread timing.
* OSQP's work budget per platform in a constrained M-step: 2e9 (iterations times the QP's size,
  :class:`solvers.WorkBudget`), about 6 s of ADMM on this project's 2-core reference machine, so
  that an M-step OSQP cannot solve fails within seconds whatever the number of platforms (one
  platform with visits alone, a size of about 36k on A, may take 55000 iterations; with a speed
  limit on every step, about 163k, 12000). Deterministic, unlike a time limit.
* Clarabel: iterative refinement of the KKT solves roughly doubles the time of a constrained M-step and
  is not needed on well-scaled ones, so it is off by default and the first retry. The last retries of
  a constrained M-step turn equilibration off (A seed 68 with ``VisitAll(0.1)``: "almost solved" under
  every other set, solved without it), then accept a primal feasibility of 1e-7, then 1e-6 (Clarabel's
  default 1e-8; hard rows are imposed 1e-5 inside their bounds, :data:`pmht_opt.mstep.rows.BACKOFF`):
  where a limit binds over long stretches (scenario B at T = 150 with a speed limit of 0.06) the
  interior point stalls between 2e-8 and 1e-7 and ends "almost solved" under every other setting, while the
  plan it returns meets the limit on the positions to 1e-9 of the limit. Not the default: at 1e-7 a
  visit disc of radius 0.1 was met only to 1.07e-6 of its radius, past the verification's 1e-6
  (:mod:`pmht_opt.verify` checks every returned plan on its positions either way). The very last
  refines every KKT solve to 1e-14 with up to 50 steps (Clarabel's refinement defaults: 1e-13 and
  1e-12, 10 steps): C seed 5 with ``VisitAll(0.2)`` ended "almost solved" under every set before it
  and solves in 22 interior-point iterations with it, same tolerances.
* Clarabel, constrained M-steps condensed onto their binding rows (:mod:`pmht_opt.mstep.condensed`):
  the small QP has tens of variables, so iterative refinement and tolerances of 1e-10 cost little;
  at Clarabel's defaults a guaranteed-visits M-step's cost ended 1.5e-7 (relative) above the full
  QP's, at 1e-10 within 1e-8 of it.
* OSQP, constrained M-steps condensed too: its whole QP with polygons fails or takes tens of seconds
  where a few rows bind (guaranteed visits: 9 of the stress sweep's visit cases failed). The small QP
  (an identity Hessian, dense rows of a few hundred entries) costs microseconds per ADMM iteration but
  may need 10000 of them where visits sit at neighbouring steps, so its cap is 100000; ``sigma =
  1e-9`` lets its polish converge, and the polished answer must meet 1e-9 (``polish_tolerance``),
  since the path must then meet every row of the working set to 1e-9; a failed polish is retried at
  1e-9 from its iterate (:data:`CONDENSED_RETRIES`). Where condensing does not settle, the whole QP is
  first solved on a working set of its rows (:data:`WORKING_SET`): a speed limit of 0.02 on B binds
  at a few hundred of its 8000 polygon rows.
* Retries (:class:`solvers.RetryChain`), tried in turn when a solve fails without an infeasibility
  verdict; a set that touches a setting the caller chose is skipped, and the set that solves is kept
  for that platform's later solves. Clarabel: iterative refinement (rescues "insufficient progress"
  on ill-scaled constrained M-steps). OSQP: a longer refinement of the polish.
* cvxpy with Clarabel, unconstrained: cvxpy's form keeps the raw penalty weights and its answers are
  less precise than the clarabel backend's; some M-steps end "almost solved" with Clarabel's defaults.
  The retries are a smaller static regularisation, then no equilibration (the smaller regularisation
  first was more precise per solve but let the EM objective fall once while reporting optimal).
"""

from __future__ import annotations

from typing import Any

from solvers import RetryChain

#: Backends whose constrained M-steps are condensed onto their binding rows first
#: (:mod:`pmht_opt.mstep.condensed`), with the options of the small condensed QP (over the constrained
#: ones; the caller's settings override both). ``solver_settings={"condense": False}`` turns it off.
CONDENSED: dict[str, dict[str, Any]] = {
    "osqp": {"max_iter": 100_000, "polish_tolerance": 1e-9, "sigma": 1e-9},
    "clarabel": {
        "iterative_refinement_enable": True,
        "tol_gap_abs": 1e-10,
        "tol_gap_rel": 1e-10,
        "tol_feas": 1e-10,
    },
}

#: Backends whose constrained M-steps are solved on a working set of their rows before the whole QP
#: (:mod:`pmht_opt.mstep.working`), with the options of those solves (over the constrained ones; the
#: caller's settings override both). ``solver_settings={"working_set": False}`` turns it off.
WORKING_SET: dict[str, dict[str, Any]] = {"osqp": {}}

#: Settings tried in turn after a condensed QP's solve failed without an infeasibility verdict (backends
#: not listed: none), continuing from the failed iterate where the backend can.
CONDENSED_RETRIES: dict[str, RetryChain] = {"osqp": RetryChain(({"eps_abs": 1e-9, "eps_rel": 1e-9},))}

#: Options of the unconstrained M-step QP per backend (the caller's settings override them).
DEFAULTS: dict[str, dict[str, Any]] = {
    "osqp": {
        "eps_abs": 1e-4,
        "eps_rel": 1e-4,
        "rho": 1.0,
        "polishing": True,
        "polish_refine_iter": 10,
        "polish_tolerance": 1e-10,
        "sigma": 1e-9,
        "check_dualgap": False,
        "check_termination": 10,
        "scaling": 4,
    },
    "clarabel": {
        "iterative_refinement_enable": True,
        "tol_gap_abs": 1e-12,
        "tol_gap_rel": 1e-12,
        "tol_feas": 1e-12,
    },
}

#: Options for platforms whose M-step has constraint rows.
CONSTRAINED_DEFAULTS: dict[str, dict[str, Any]] = {
    "osqp": {
        "eps_abs": 1e-5,
        "eps_rel": 1e-5,
        "rho": 1.0,
        "polishing": True,
        "polish_refine_iter": 10,
        "check_dualgap": False,
        "check_termination": 25,
        "max_iter": 8000,
    },
    "clarabel": {"iterative_refinement_enable": False},
}

#: Settings tried in turn after a failed QP solve.
RETRIES: dict[str, RetryChain] = {
    "clarabel": RetryChain(
        (
            {"iterative_refinement_enable": True},
            {"equilibrate_max_iter": 50},
            {"static_regularization_constant": 1e-7},
            {"max_step_fraction": 0.9},
        )
    ),
    "osqp": RetryChain(({"polish_refine_iter": 50},)),
}

#: Settings tried in turn after a failed solve with constraint rows (backends not listed: :data:`RETRIES`).
#: OSQP's first constrained attempt stops at 8000 iterations; then, once the infeasibility diagnosis
#: has found the rows feasible, it continues from its iterate with room for 50000 more, within the
#: M-step's work budget (:data:`MSTEP_WORK`).
CONSTRAINED_RETRIES: dict[str, RetryChain] = {
    "clarabel": RetryChain(
        (
            *RETRIES["clarabel"].sets,
            {"equilibrate_enable": False},
            {"iterative_refinement_enable": True, "tol_feas": 1e-7},
            {"tol_feas": 1e-6},
            {
                "iterative_refinement_enable": True,
                "iterative_refinement_reltol": 1e-14,
                "iterative_refinement_abstol": 1e-14,
                "iterative_refinement_max_iter": 50,
            },
        )
    ),
    "osqp": RetryChain(({"max_iter": 50_000},)),
}

#: Work budget (:class:`solvers.WorkBudget`) of each platform's solve (with its retries) in an
#: M-step with constraint rows, per backend (backends not listed: none).
#: ``solver_settings={"mstep_work_limit": ...}`` overrides it (``None``: no budget).
MSTEP_WORK: dict[str, float] = {"osqp": 2e9}

#: Options of Clarabel inside cvxpy on unconstrained M-steps: the clarabel backend's tolerances (cvxpy
#: passes them through). Constrained M-steps keep the cvxpy solver's own defaults.
CVXPY_INNER_DEFAULTS: dict[str, dict[str, Any]] = {
    "CLARABEL": {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "tol_feas": 1e-12},
}

#: Settings tried in turn after a failed cvxpy solve, per cvxpy solver.
CVXPY_INNER_RETRIES: dict[str, RetryChain] = {
    "CLARABEL": RetryChain(({"static_regularization_constant": 1e-10}, {"equilibrate_enable": False})),
}


def cvxpy_defaults(settings: dict[str, Any]) -> dict[str, Any]:
    """The default options of the cvxpy backend for the cvxpy solver ``settings`` asks for."""
    inner = str(settings.get("cvxpy_solver", "CLARABEL")).upper()
    return dict(CVXPY_INNER_DEFAULTS.get(inner, {}))


def cvxpy_retries(settings: dict[str, Any]) -> RetryChain:
    """The retries of the cvxpy backend for the cvxpy solver ``settings`` asks for."""
    inner = str(settings.get("cvxpy_solver", "CLARABEL")).upper()
    return CVXPY_INNER_RETRIES.get(inner, RetryChain())
