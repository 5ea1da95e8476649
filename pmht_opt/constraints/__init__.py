"""Constraints on the planned paths, imposed in every M-step (``PMHTConfig(constraints=[...])``).

Each kind is one class sharing the protocol of :class:`~pmht_opt.constraints.base.Constraint`: the
rows it adds to a platform's M-step (backend-neutral conic rows), and how a plan is checked against
it. To add a kind, subclass :class:`Constraint`, declare what it :attr:`~Constraint.needs` and
implement :meth:`~Constraint.blocks`; with the ``cvxpy`` backend, :class:`CvxpyConstraint` takes any
cvxpy expression instead.

======================  =====================================  ===================================
kind                    what                                   needs (without cones)
======================  =====================================  ===================================
SpeedLimit, AccelLimit  norm of velocity / acceleration        soc (inner polygon, ``sides``)
AreaBounds              box on positions                       linear
StayNear                near the area (implied by VisitAll)    linear
CircleObstacle          keep-out disc, linearised per step     linear (half-planes)
PolygonObstacle         keep-out convex polygon, linearised    linear (half-planes)
VisitAll                every locale within a radius           soc (inner polygon)
Terminal                final velocity / position              linear, soc for a radius
CvxpyConstraint         anything in cvxpy                      cvxpy (the cvxpy backend only)
======================  =====================================  ===================================
"""

from pmht_opt.constraints.area import AreaBounds, StayNear
from pmht_opt.constraints.base import (
    CAPABILITIES,
    Constraint,
    ConstraintContext,
    ConstraintReport,
)
from pmht_opt.constraints.blocks import Block
from pmht_opt.constraints.motion import AccelLimit, SpeedLimit
from pmht_opt.constraints.obstacles import CircleObstacle, PolygonObstacle
from pmht_opt.constraints.terminal import Terminal
from pmht_opt.constraints.user import CvxpyConstraint, CvxpyVariables
from pmht_opt.constraints.visits import VisitAll, choose_visits

__all__ = [
    "CAPABILITIES",
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
    "StayNear",
    "Terminal",
    "VisitAll",
    "choose_visits",
]
