"""The E-step: assignment weights, prior updates and the EM objective (paper eqs 9-12).

:mod:`~pmht_opt.estep.core` is the entry (:func:`estep`, :func:`estep_scored`, :class:`EStepResult`);
the other modules are its parts, from the bottom up: the log-domain arithmetic shared by every E-step
(:mod:`~pmht_opt.estep.likelihood`), the dense computation (:mod:`~pmht_opt.estep.dense`), the gated
one (:mod:`~pmht_opt.estep.candidates`, :mod:`~pmht_opt.estep.gating`,
:mod:`~pmht_opt.estep.gated_sums`) and how the weights are held (:mod:`~pmht_opt.estep.weights`).
"""

from pmht_opt.estep.core import (
    EStepResult,
    estep,
    estep_scored,
    gate_margin,
    log_likelihood,
    safe_log,
)
from pmht_opt.estep.weights import EStepSummary

__all__ = [
    "EStepResult",
    "EStepSummary",
    "estep",
    "estep_scored",
    "gate_margin",
    "log_likelihood",
    "safe_log",
]
