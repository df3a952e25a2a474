"""The Shadow Hand model: MJCF of gymnasium-robotics -> FK, coupling, contact candidates, keypoints,
analytic collision geometry (capsules, boxes and the forearm cylinder) and a URDF for PyBullet.

Entry points: :class:`HandConfig` (config section) and :class:`HandModel`.  The distance primitives
of :mod:`components.hand.geometry` are exported for tests and other components.
"""

from components.hand.config import HandConfig
from components.hand.geometry import (
    capsule_box_signed_distance,
    capsule_capsule_signed_distance,
    capsule_cylinder_signed_distance,
    capsule_prism_signed_distance,
    point_box_signed_distance,
    point_capsule_signed_distance,
    point_cylinder_signed_distance,
    point_prism_signed_distance,
    segment_segment_closest_parameters,
)
from components.hand.model import HandModel

__all__ = [
    "HandConfig",
    "HandModel",
    "capsule_box_signed_distance",
    "capsule_capsule_signed_distance",
    "capsule_cylinder_signed_distance",
    "capsule_prism_signed_distance",
    "point_box_signed_distance",
    "point_capsule_signed_distance",
    "point_cylinder_signed_distance",
    "point_prism_signed_distance",
    "segment_segment_closest_parameters",
]
