"""The parts of the M-step backend study (``pmht-opt study solvers``, :mod:`studies.compare_solvers`).

One concept per module: which backends are compared and how their outcomes are classified
(:mod:`~studies.solver_study.backends`), the EM iterates whose M-steps are solved
(:mod:`~studies.solver_study.iterates`), timing one backend on one M-step
(:mod:`~studies.solver_study.measure`), the single M-step rows (:mod:`~studies.solver_study.msteps`),
whole plans (:mod:`~studies.solver_study.plans`), the summaries (:mod:`~studies.solver_study.summary`),
the markdown tables (:mod:`~studies.solver_study.markdown`) and the figure
(:mod:`~studies.solver_study.plot`).
"""
