"""The studies behind the project's figures and tables, outside the installed core's import graph.

Each study is a module here with a trial function, a typed options dataclass and a ``run``; one parser
(:mod:`studies.cli`) runs them as ``pmht-opt study NAME`` or ``python -m studies NAME``. Trials run
through :mod:`studies.trials` into append-only JSON Lines files (:mod:`studies.store`) that carry their
provenance (:mod:`studies.provenance`). Needs the ``studies`` extra (pandas, tqdm).
"""

#: The distribution this package is installed by (see ``solvers.__distribution__``).
__distribution__ = "pmht-opt"
