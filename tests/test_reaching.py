"""Reaching: the planned path keeps its ends, is no worse than the straight one, and executing it in
PyBullet brings the hand to the pre-grasp and records the end-of-reach state."""

import numpy as np
import pytest
import torch

from components.execution import GraspRecord, LiftEnvConfig, LiftWorld
from components.execution.cameras import CameraConfig, preview_hand_pose
from components.execution.reaching import ReachingConfig, execute_reach, linear_path, plan_reach, smoothness
from components.objects import Placement, Scene
from components.synthesis import SceneObjects

IDENTITY = (0.0, 0.0, 0.0, 1.0)


@pytest.fixture(scope="module")
def reach_case(library):
    from components.hand import HandConfig, HandModel

    hand = HandModel(HandConfig())  # float32, as the pipeline
    scene = Scene(objects=(Placement("cube", (0.0, -0.03, 0.02), IDENTITY), Placement("sphere", (0.0, 0.035, 0.025), IDENTITY)))
    p, R, _ = preview_hand_pose(hand, scene, CameraConfig(), library)
    q = 0.5 * hand.joint_limits.mean(-1).numpy()  # half-closed fingers, palm 2.5 cm lower: the straight path touches
    return hand, scene, GraspRecord(scene, p - np.array([0.0, 0.0, 0.025]), R, q.astype(float))


def test_linear_path_and_smoothness_are_exact():
    path = linear_path(torch.zeros(3, dtype=torch.float64), torch.tensor([3.0, 0.0, 6.0], dtype=torch.float64), 4)
    assert torch.allclose(path[1], torch.tensor([1.0, 0.0, 2.0], dtype=torch.float64))
    assert float(smoothness(path)) == pytest.approx(0.0, abs=1e-12)  # a straight, evenly spaced path
    bent = path.clone()
    bent[1, 1] = 1.0
    assert float(smoothness(bent)) == pytest.approx(1.0 + 4.0)  # (1 - 0)^2 from t=1, (0 - 2)^2 from t=2


def test_plan_keeps_the_ends_and_does_not_add_penetration(reach_case, library):
    hand, scene, record = reach_case
    waypoints, stats = plan_reach(hand, SceneObjects(library, scene), record, ReachingConfig(steps=20))
    assert waypoints.shape == (16, 31)
    assert np.allclose(waypoints[-1, :3], record.p, atol=1e-6) and np.allclose(waypoints[-1, 9:], record.q, atol=1e-6)
    assert np.allclose(waypoints[0, 9:], 0.0)  # starts from the open hand
    assert stats["penetration_planned"] <= stats["penetration_straight"] + 1e-9


def test_executed_reach_arrives_and_records_the_end_state(reach_case, library, tmp_path):
    hand, scene, record = reach_case
    waypoints, _ = plan_reach(hand, SceneObjects(library, scene), record, ReachingConfig(steps=0))
    world = LiftWorld(hand, library, hand.export_urdf(tmp_path), LiftEnvConfig())
    try:
        end = execute_reach(world, record, waypoints, ReachingConfig())
    finally:
        world.close()
    assert end.meta["reached"] and end.meta["palm_error_m"] < 0.01
    assert np.abs(end.q - record.q).max() < 0.05
    assert max(end.meta["object_displacement_m"]) < 0.01
    assert end.scene.names == scene.names  # same objects, where they now are
