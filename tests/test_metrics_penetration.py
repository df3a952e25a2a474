"""PN: known hand-object, hand-table and object-object penetration depths are recovered (within 0.1 mm)."""

import pytest
import torch

from components.hand import HandModel
from components.metrics import MetricsConfig, penetration_depth
from components.objects import Placement, Scene
from components.synthesis import SceneObjects

DTYPE = torch.float64
SPHERE_RADIUS = 0.025  # m, the library's sphere
IDENTITY = (0.0, 0.0, 0.0, 1.0)
TOLERANCE_MM = 0.1


def open_hand_at(z: float, hand: HandModel):
    p = torch.tensor([[0.0, 0.0, z]], dtype=DTYPE)
    return p, torch.eye(3, dtype=DTYPE).unsqueeze(0), hand.open_pose().unsqueeze(0)


def test_sphere_overlapping_a_finger_by_3mm_gives_pn_3mm(hand, library):
    p, R, q = open_hand_at(0.3, hand)
    prims = hand.collision_primitives(p, R, q)
    k = [hand.collision_geom_names[i] for i in hand.collision.capsule_ids].index("C_ffdistal")
    a, b = prims.capsule_a[0, k], prims.capsule_b[0, k]
    radius = float(hand.collision.capsule_radius[k])
    palm_normal = -R[0, :, 1]  # -y of the palm frame
    centre = 0.5 * (a + b) + (radius + SPHERE_RADIUS - 0.003) * palm_normal
    # ground truth: a ball overlaps a union of convex geoms by r - d_H(centre) (the centre is outside the hand)
    depth_true = SPHERE_RADIUS - float(hand.signed_distance(centre.reshape(1, 1, 3), p, R, q))
    assert depth_true == pytest.approx(0.003, abs=1e-6)
    scene = Scene(objects=(Placement("sphere", tuple(centre.tolist()), IDENTITY),))
    report = penetration_depth(hand, SceneObjects(library, scene, dtype=DTYPE), p, R, q, MetricsConfig())
    assert float(report.pn_mm[0]) == pytest.approx(3.0, abs=TOLERANCE_MM)
    assert float(report.hand_object_mm[0, 0]) == pytest.approx(3.0, abs=TOLERANCE_MM)
    assert float(report.hand_table_mm[0]) == 0.0 and float(report.object_table_mm[0]) == 0.0


def test_hand_2mm_under_the_table_gives_pn_2mm(hand, library):
    p, R, q = open_hand_at(0.3, hand)
    lowest = float(hand.geom_lowest_heights(p, R, q).min())
    p[0, 2] -= lowest + 0.002  # lowest point of the hand at z = -2 mm
    scene = Scene(objects=(Placement("sphere", (0.5, 0.0, SPHERE_RADIUS), IDENTITY),))  # resting, far away
    report = penetration_depth(hand, SceneObjects(library, scene, dtype=DTYPE), p, R, q, MetricsConfig())
    assert float(report.pn_mm[0]) == pytest.approx(2.0, abs=1e-6)
    assert float(report.hand_object_mm[0, 0]) == 0.0
    assert float(report.object_table_mm[0]) < 1e-6


def test_overlapping_objects_are_part_of_pn(hand, library):
    p, R, q = open_hand_at(0.5, hand)  # hand far above
    scene = Scene(objects=(Placement("sphere", (0.0, 0.0, SPHERE_RADIUS), IDENTITY),
                           Placement("sphere", (2 * SPHERE_RADIUS - 0.004, 0.0, SPHERE_RADIUS), IDENTITY)))
    report = penetration_depth(hand, SceneObjects(library, scene, dtype=DTYPE), p, R, q, MetricsConfig())
    # the deepest point of one ball inside the other is 4 mm deep
    assert report.object_object_mm == pytest.approx(4.0, abs=TOLERANCE_MM)
    assert float(report.pn_mm[0]) == pytest.approx(4.0, abs=TOLERANCE_MM)
    assert float(report.hand_object_mm.max()) == 0.0 and float(report.hand_table_mm[0]) == 0.0


def test_separated_grasp_has_zero_pn(hand, library):
    p, R, q = open_hand_at(0.3, hand)
    scene = Scene(objects=(Placement("cube", (0.3, 0.3, 0.02), IDENTITY),))
    report = penetration_depth(hand, SceneObjects(library, scene, dtype=DTYPE), p.repeat(3, 1), R.repeat(3, 1, 1),
                               q.repeat(3, 1), MetricsConfig())
    assert report.pn_mm.shape == (3,)
    assert torch.all(report.pn_mm < 1e-6)
