"""Constraints on the planned paths, imposed in every M-step (``PMHTConfig(constraints=[...])``).

Each kind is one class sharing the protocol of :class:`~pmht_opt.constraints.base.Constraint`: the
rows it adds to a platform's M-step (backend-neutral conic rows), and how a plan is checked against
it. To add a kind, subclass :class:`Constraint` and implement :meth:`~Constraint.blocks`; with the
``cvxpy`` backend, :class:`CvxpyConstraint` takes any cvxpy expression instead.

=====================  =====================================  ===========================
kind                   what                                   OSQP
=====================  =====================================  ===========================
SpeedLimit, AccelLimit norm of velocity / acceleration        inner polygon (``sides``)
AreaBounds             box on positions                       exact
CircleObstacle         keep-out disc, linearised per step     exact (half-planes)
PolygonObstacle        keep-out convex polygon, linearised    exact (half-planes)
VisitAll               every locale within a radius           inner polygon
Terminal               final velocity / position              exact, or inner polygon
CvxpyConstraint        anything in cvxpy                      not supported (cvxpy only)
=====================  =====================================  ===========================
"""

from pmht_opt.constraints.area import AreaBounds
from pmht_opt.constraints.base import (
    Block,
    Constraint,
    ConstraintContext,
    ConstraintReport,
)
from pmht_opt.constraints.motion import AccelLimit, SpeedLimit
from pmht_opt.constraints.obstacles import CircleObstacle, PolygonObstacle
from pmht_opt.constraints.terminal import Terminal
from pmht_opt.constraints.user import CvxpyConstraint, CvxpyVariables
from pmht_opt.constraints.visits import VisitAll, choose_visits

__all__ = [
    "AccelLimit",
    "AreaBounds",
    "Block",
    "CircleObstacle",
    "Constraint",
    "ConstraintContext",
    "ConstraintReport",
    "CvxpyConstraint",
    "CvxpyVariables",
    "PolygonObstacle",
    "SpeedLimit",
    "Terminal",
    "VisitAll",
    "choose_visits",
]
