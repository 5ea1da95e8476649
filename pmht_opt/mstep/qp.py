"""The M-step QP through a :mod:`solvers` backend (``osqp`` or ``clarabel``), one QP per platform."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, ClassVar

import numpy as np

import solvers
from pmht_opt.constraints.base import Constraint
from pmht_opt.constraints.blocks import Block
from pmht_opt.exceptions import (
    ConfigError,
    InfeasibleError,
    PmhtOptError,
    ScheduleError,
    SolverError,
    UnknownSolverError,
)
from pmht_opt.mstep.base import (
    AnswerCheck,
    ExactReference,
    MStep,
    MStepData,
    MStepOutput,
    check_cvxpy_solver,
)
from pmht_opt.mstep.diagnosis import diagnose
from pmht_opt.mstep.platform import PlatformQP
from pmht_opt.mstep.rows import PlatformRows, RowBuilder
from pmht_opt.mstep.tuning import (
    CONDENSED,
    CONDENSED_RETRIES,
    CONSTRAINED_DEFAULTS,
    CONSTRAINED_RETRIES,
    DEFAULTS,
    MSTEP_WORK,
    RETRIES,
    WORKING_SET,
    cvxpy_defaults,
    cvxpy_retries,
)
from pmht_opt.scenario import Scenario
from pmht_opt.validation import flag
from pmht_opt.verify import resolution
from solvers.banded import BandedSmootherResult
from solvers.threads import LazyPool, wait_all

#: Largest violation of a platform's rows by the exact unconstrained optimum for it to be taken as the
#: constrained optimum without a solve (rounding of positions of order 10 is far below it); relative
#: to the radius of a cone below 1, so that a limit of 1e-9 is not taken as met 1e-10 beyond it.
SCREEN_TOL = 1e-10
#: The least back-off of hard cones, in units of the positions' resolution
#: (:func:`~pmht_opt.verify.resolution`).
MARGIN_RESOLUTIONS = 64.0
#: The thread that computes the exact smoother beside unconstrained solves (:meth:`QPMStep._solve`).
_EXACT = LazyPool(1, "pmht-exact")


def check_solution(sol: solvers.QPSolution, accept_inaccurate: bool, platform: int | None = None) -> None:
    """Raise the project's error unless the backend stands behind ``sol``."""
    if sol.usable(accept_inaccurate):
        return
    where = "" if platform is None else f" (platform {platform})"
    if sol.status in solvers.INFEASIBLE:  # a backend's word: the diagnosis gives proofs
        raise SolverError(
            f"{sol.backend}: the M-step's rows were reported infeasible{where} (status {sol.raw_status}).",
            backend=sol.backend,
            status=sol.raw_status,
        )
    hint = "" if accept_inaccurate else " (pass accept_inaccurate=True to use inaccurate solutions)"
    raise SolverError(
        f"{sol.backend}: the M-step solve failed{where} with status {sol.raw_status!r}{hint}.",
        backend=sol.backend,
        status=sol.raw_status,
    )


def _work_limit(value: object) -> float | None:
    """``solver_settings["mstep_work_limit"]`` checked: ``None`` or a positive finite number."""
    if value is None:
        return None
    try:
        return solvers.work_amount("mstep_work_limit", value)
    except solvers.SettingsError as err:
        raise ConfigError(f"solver_settings: {err} None lifts the budget.") from err


def _screen_tol(block: Block) -> np.ndarray | float:
    """The screening tolerance of each unit of ``block`` (:data:`SCREEN_TOL`)."""
    if block.kind != "soc":
        return SCREEN_TOL
    return SCREEN_TOL * np.clip(block.h[:: block.dim], 0.0, 1.0)


class QPMStep(MStep):
    """The M-step QP of :mod:`pmht_opt.mstep.formulation` through a :mod:`solvers` session
    (``clarabel``, ``osqp``, or ``cvxpy`` with any installed cvxpy solver).

    Without coupling constraints the QP separates by platform, so each platform is its own QP
    (:class:`~pmht_opt.mstep.platform.PlatformQP`), and the platforms are solved concurrently on
    ``threads`` threads (both backends release the GIL while they solve). Every constraint kind binds
    one platform at a time, so constraints keep this separation.
    """

    name: ClassVar[str] = "qp"

    def __init__(
        self,
        scenario: Scenario,
        settings: dict[str, Any] | None = None,
        accept_inaccurate: bool = False,
        solver: str = "clarabel",
        threads: int = 1,
        constraints: tuple[Constraint, ...] = (),
        exact_unconstrained: bool = False,
        *,
        reference: ExactReference | None = None,
        check: AnswerCheck | None = None,
    ) -> None:
        super().__init__(scenario, settings, accept_inaccurate, constraints, reference=reference, check=check)
        self.solver = solver
        #: Work budget of each platform's solve in an M-step with constraint rows (``None``: none),
        #: :data:`MSTEP_WORK`.
        self.mstep_work = _work_limit(self.settings.pop("mstep_work_limit", MSTEP_WORK.get(solver)))
        #: Whether constrained M-steps are condensed first (:mod:`pmht_opt.mstep.condensed`).
        self.condense = flag("solver_settings.condense", self.settings.pop("condense", solver in CONDENSED))
        #: Whether constrained QPs are solved on a working set of their rows first
        #: (:mod:`pmht_opt.mstep.working`).
        self.working_set = flag(
            "solver_settings.working_set", self.settings.pop("working_set", solver in WORKING_SET)
        )
        #: Whether platforms without constraint rows take the exact smoother's answer (solver "auto").
        self.exact_unconstrained = exact_unconstrained
        try:
            self.session_class = solvers.get_session_class(solver)
        except solvers.UnknownSolverError as err:
            raise UnknownSolverError(str(err)) from err
        self.rows = RowBuilder(self.constraints, conic=self.session_class.supports_soc)
        if solver == "cvxpy":  # tuned per cvxpy solver; cvxpy's compilation holds the GIL: one thread
            check_cvxpy_solver(self.settings, "solver_settings")
            self.options = {**cvxpy_defaults(self.settings), **self.settings}
            self.constrained_options = dict(self.settings)
            self.condensed_options = dict(self.settings)
            self.working_options = dict(self.settings)
            retries = cvxpy_retries(self.settings)
            constrained_retries = retries
            threads = 1
        else:
            self.options = {**DEFAULTS.get(solver, {}), **self.settings}
            self.constrained_options = {**CONSTRAINED_DEFAULTS.get(solver, {}), **self.settings}
            self.condensed_options = {
                **CONSTRAINED_DEFAULTS.get(solver, {}),
                **CONDENSED.get(solver, {}),
                **self.settings,
            }
            self.working_options = {
                **CONSTRAINED_DEFAULTS.get(solver, {}),
                **WORKING_SET.get(solver, {}),
                **self.settings,
            }
            retries = RETRIES.get(solver, solvers.NO_RETRY)
            constrained_retries = CONSTRAINED_RETRIES.get(solver, retries)
        # Sets touching a setting the caller chose are skipped: do not second-guess the caller.
        retries = retries.without(self.settings)
        self.constrained_retries = constrained_retries.without(self.settings)
        self.condensed_retries = CONDENSED_RETRIES.get(solver, solvers.NO_RETRY).without(self.settings)
        self.blocks = [self._platform(m, retries) for m in range(self.M)]
        self.threads = max(1, min(int(threads), self.M))
        self._pool: ThreadPoolExecutor | None = None

    def _platform(self, m: int, retries: solvers.RetryChain = solvers.NO_RETRY) -> PlatformQP:
        return PlatformQP(
            self.model,
            self.x0[m],
            self.T,
            self.session_class,
            self.options,
            self.constrained_options,
            retries,
            self.constrained_retries,
            margin=MARGIN_RESOLUTIONS * resolution(self.scenario),
            condensed_settings=self.condensed_options if self.condense else None,
            working_settings=self.working_options if self.working_set else None,
            condensed_retries=self.condensed_retries,
        )

    def _screen(
        self, data: MStepData, rows: dict[int, PlatformRows], exact_states: np.ndarray | None
    ) -> list[int]:
        """The platforms that need a solve.

        Where the exact unconstrained optimum already meets a platform's rows it is that platform's
        constrained optimum too: no solve. Without rows it is the answer outright when the exact
        smoother stands in for unconstrained platforms (solver "auto"); a platform with no weight and
        no row coasts, the unique answer, which first-order solvers struggle to return.
        """
        idle = ~np.any(data.W > 0, axis=0)
        exact_ok = np.zeros(self.M, dtype=bool)
        for m in range(self.M):
            items = rows[m].items if m in rows else []
            if items:
                assert exact_states is not None, "platforms with rows are screened on the exact answer"
                z = exact_states[m, 1:].reshape(-1)
                exact_ok[m] = all(np.all(i.block.residual(z) <= _screen_tol(i.block)) for i in items)
            else:
                exact_ok[m] = self.exact_unconstrained or bool(idle[m])
        return [int(m) for m in np.flatnonzero(~exact_ok)]

    def _probe(
        self, m: int, data: MStepData, rows: PlatformRows | None, verdicts: dict[int, PmhtOptError]
    ) -> Callable[[solvers.QPSolution], None] | None:
        """What platform ``m``'s QP asks after a failed solve, before any retry: an
        :class:`InfeasibleError` if its hard rows cannot all be met (``None`` without hard rows).
        The verdict is kept in ``verdicts[m]``, so that a platform whose retries fail too is not
        diagnosed twice."""
        if rows is None or not any(not i.soft for i in rows.items):
            return None

        def check(sol: solvers.QPSolution) -> None:
            err = self._diagnose(m, data, rows, sol)
            verdicts[m] = err
            if isinstance(err, (InfeasibleError, ScheduleError)):
                raise err  # settled by the phase-one problems: no retry can change it

        return check

    def _solve(self, data: MStepData) -> MStepOutput:
        rows = self.rows.rows(data.ctx, data.active, data.strengths)
        constrained = any(r.items for r in rows.values())
        exact: BandedSmootherResult | Future[BandedSmootherResult]
        laid_out: tuple[np.ndarray, np.ndarray] | None = None
        if constrained or self.exact_unconstrained:  # the screening reads the exact answer
            exact = self.reference().smooth(data)
            laid_out = exact.side_by_side()
            active = self._screen(data, rows, laid_out[0])
        else:
            # Nothing to screen but the idle platforms: the exact smoother, which checks the answers
            # and answers for idle platforms, runs on its own thread beside the solves (cvxpy's run on
            # one thread; OSQP's and Clarabel's leave a core idle while the last platform finishes).
            exact = _EXACT.get().submit(self.reference().smooth, data)
            active = self._screen(data, rows, None)
        try:
            return self._solve_active(data, rows, active, constrained, exact, laid_out)
        finally:
            if isinstance(exact, Future):
                wait_all([exact])  # no thread of this M-step runs on after it returns

    def _solve_active(
        self,
        data: MStepData,
        rows: dict[int, PlatformRows],
        active: list[int],
        constrained: bool,
        exact: BandedSmootherResult | Future[BandedSmootherResult],
        laid_out: tuple[np.ndarray, np.ndarray] | None,
    ) -> MStepOutput:
        """Solve the platforms ``active`` and join their answers with the exact smoother's for the
        others: ``exact`` with its states and noise ``laid_out`` (``side_by_side``), or still being
        computed (``laid_out`` then ``None``: the solves cannot start from it)."""
        exact_states, exact_noise = laid_out if laid_out is not None else (None, None)
        verdicts: dict[int, PmhtOptError] = {}

        def one(m: int) -> tuple[solvers.QPSolution, np.ndarray, np.ndarray]:
            # A failed platform fails the M-step at once: the platforms after it are not solved.
            platform_rows = rows.get(m)
            # Each platform its own budget: a budget shared by threads would make what one platform
            # may spend depend on how far the others had got, and so the answer on thread timing.
            budget = solvers.WorkBudget(self.mstep_work) if constrained and self.mstep_work else None
            sol, states, u = self.blocks[m].solve(
                data.W[:, m],
                data.WZ[:, m],
                data.r,
                platform_rows,
                probe=self._probe(m, data, platform_rows, verdicts),
                budget=budget,
                exact=None
                if exact_states is None or exact_noise is None
                else (exact_states[m, 1:], exact_noise[m]),
            )
            if not sol.usable(self.accept_inaccurate) and platform_rows is not None and platform_rows.items:
                raise verdicts.get(m) or self._diagnose(m, data, platform_rows, sol)
            check_solution(sol, self.accept_inaccurate, platform=m)
            assert states is not None and u is not None
            return sol, states, u

        if self.threads > 1 and len(active) > 1:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="pmht-mstep")
            answers = list(self._pool.map(one, active))
        else:
            answers = [one(m) for m in active]
        if isinstance(exact, Future):
            exact = exact.result()
            exact_states, exact_noise = exact.side_by_side()
        assert exact_states is not None and exact_noise is not None
        body = exact_states[:, 1:].copy()
        noise = exact_noise.copy()
        for m, (_, states, u) in zip(active, answers, strict=True):
            body[m], noise[m] = states, u
        sols = [sol for sol, _, _ in answers]
        out = MStepOutput(
            states=self._with_start(body),
            iterations=int(sum(s.iterations for s in sols)),
            fallbacks=sum("fallback" in s.info for s in sols),
            noise=noise,
            constrained=tuple(sorted(m for m, r in rows.items() if r.items)),
            info={"exact": exact, "solved": tuple(active)},
        )
        if sols:
            worst = max(sols, key=lambda s: (s.status is not solvers.Status.OPTIMAL, s.iterations))
            out.status, out.raw_status = worst.status, worst.raw_status
        return out

    def _diagnose(self, m: int, data: MStepData, rows: PlatformRows, sol: solvers.QPSolution) -> PmhtOptError:
        """Why platform ``m``'s constrained solve failed (:mod:`pmht_opt.mstep.diagnosis`), asked of
        Clarabel where it is installed: it takes this backend's rows, cones or polygons."""
        session_class = self.session_class
        if "clarabel" in solvers.available_solvers():
            session_class = solvers.get_session_class("clarabel")
        return diagnose(self.model, self.x0[m], self.T, m, rows, sol, session_class)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
