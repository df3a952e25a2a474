"""Grasp metrics of the paper's results table (DESIGN §6): Q1, PN and Div (success lives with execution).

Definitions are in the module docstrings: :mod:`~.q1` (Ferrari-Canny Q1, min over objects),
:mod:`~.penetration` (PN: deepest hand / object / table penetration, mm), :mod:`~.diversity`
(Div: mean per-joint standard deviation, deg)::

    from components.metrics import MetricsConfig, q1_grasps, penetration_depth, joint_diversity_deg
    q1, q1_per_object = q1_grasps(hand, scene_objects, p, R, q, MetricsConfig())
"""

from components.metrics.config import MetricsConfig
from components.metrics.diversity import joint_diversity_deg, per_joint_std_deg
from components.metrics.penetration import PenetrationReport, penetration_depth
from components.metrics.q1 import (
    object_contacts,
    primitive_wrenches,
    q1_from_wrenches,
    q1_grasps,
    q1_single_object,
)

__all__ = [
    "MetricsConfig",
    "PenetrationReport",
    "joint_diversity_deg",
    "object_contacts",
    "penetration_depth",
    "per_joint_std_deg",
    "primitive_wrenches",
    "q1_from_wrenches",
    "q1_grasps",
    "q1_single_object",
]
