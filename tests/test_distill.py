"""The generalist's cameras and DAgger (components/learning): depth back-projection against a sphere's analytic
surface, the even re-sampling, the student's observation, the imitation fit, DAgger's data, mixture and resume."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest
import torch

from components.errors import MultigraspError
from components.execution import GraspRecord, LiftEnv, LiftEnvConfig
from components.execution.cameras import CameraConfig, add_table, preview_hand_pose
from components.execution.observations import observation_blocks
from components.execution.pointnet import PointNetConfig, PointNetEncoder
from components.learning.dagger import (Bin, DAggerConfig, StudentObserver, StudentPolicy, VisionPolicy, beta,
                                        data_folder, fit_student, hand_dim, load_student, run_dagger, student_blocks, student_dim)
from components.learning.vision import SceneCameras, VisionConfig, camera_points, farthest_points, voxel_thin
from components.objects import Placement, Scene

IDENTITY = (0.0, 0.0, 0.0, 1.0)
SMALL = VisionConfig(width=48, height=36, scene_points=64)


def test_depth_pixels_back_project_onto_a_spheres_surface():
    """A 3 cm sphere on the table seen by the three cameras: every kept pixel lies on its surface (to the depth
    buffer's precision), the table is dropped, and together the views see it from all around."""
    client = pb.connect(pb.DIRECT)
    try:
        add_table(client, CameraConfig())
        radius, centre = 0.03, np.array([0.01, -0.02, 0.03])
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=radius, physicsClientId=client)
        visual = pb.createVisualShape(pb.GEOM_SPHERE, radius=radius, physicsClientId=client)
        sphere = pb.createMultiBody(0.1, shape, visual, basePosition=centre.tolist(), physicsClientId=client)
        cfg = VisionConfig()
        views = [camera_points(client, centre, yaw, cfg, {sphere}) for yaw in cfg.camera_yaws_deg]
    finally:
        pb.disconnect(client)
    assert all(len(v) > 50 for v in views)
    points = np.concatenate(views)
    distance = np.linalg.norm(points - centre, axis=1)
    # the renderer draws the sphere as a tessellated mesh whose facets lie up to ~2 mm inside the true surface
    assert distance.max() <= radius + 1e-5 and distance.min() > radius - 2.5e-3
    assert points[:, 2].min() > 0.0  # nothing of the table
    direction = (points[:, :2] - centre[:2])
    angles = np.degrees(np.arctan2(direction[:, 1], direction[:, 0]))
    assert np.histogram(angles, bins=6, range=(-180, 180))[0].min() > 0  # seen from every side


def test_depth_pixels_back_project_onto_a_boxs_faces_exactly():
    """A box's faces are planar in the renderer too: its pixels come back onto them to 1e-6 m (the pixel convention
    of :func:`camera_points`; pixel centres would be ~1 mm off)."""
    client = pb.connect(pb.DIRECT)
    try:
        add_table(client, CameraConfig())
        half, centre = 0.02, np.array([0.15, 0.0, 0.02])
        box = pb.createMultiBody(0.1, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[half] * 3, physicsClientId=client),
                                 pb.createVisualShape(pb.GEOM_BOX, halfExtents=[half] * 3, physicsClientId=client),
                                 basePosition=centre.tolist(), physicsClientId=client)
        cfg = VisionConfig()
        points = np.concatenate([camera_points(client, centre, yaw, cfg, {box}) for yaw in (0.0, 33.0, 120.0, 240.0)])
    finally:
        pb.disconnect(client)
    assert len(points) > 500
    chebyshev = np.abs(points - centre).max(axis=1)  # on a face: the largest coordinate offset is the half side
    np.testing.assert_allclose(chebyshev, half, atol=1e-6)


def test_voxel_thinning_keeps_one_point_per_voxel_and_farthest_points_spread_them():
    rng = np.random.default_rng(0)
    dense = np.concatenate([rng.uniform(0, 0.01, (900, 3)), rng.uniform(0.1, 0.2, (100, 3))])
    thin = voxel_thin(dense, 0.01)
    cells = np.floor(thin / 0.01).astype(int)
    assert len(np.unique(cells, axis=0)) == len(thin)  # one per voxel
    assert (thin[:, 0] < 0.05).sum() <= 8  # the dense corner no longer outweighs the rest
    picked = farthest_points(thin, 16)
    assert picked.shape == (16, 3) and len(np.unique(picked, axis=0)) == 16
    assert farthest_points(thin[:3], 8).shape == (8, 3)  # repeated up to n
    assert np.all(farthest_points(np.zeros((0, 3)), 4) == 0)


def test_the_student_sees_the_hand_blocks_and_one_scene_feature_whatever_the_object_count():
    cfg = LiftEnvConfig()
    assert [name for name, _ in student_blocks(cfg)] == [n for n, _ in observation_blocks(cfg, 2)][:len(student_blocks(cfg))]
    assert not any(name.startswith("object_") for name, _ in student_blocks(cfg))
    assert student_dim(cfg) == hand_dim(cfg) + cfg.feature_dim == 438 + 256  # the paper table's hand rows
    assert student_dim(LiftEnvConfig(goal_observations=False)) == 438 - 50 + 256


def test_the_student_fits_its_teachers_actions():
    """Imitation on a known map: actions tanh(x W) of random states; the fit's loss falls by an order of magnitude
    and the normaliser holds the data set's statistics."""
    generator = torch.Generator().manual_seed(0)
    x = torch.randn(2048, 12, generator=generator) * 5.0 + 3.0
    W = torch.randn(12, 4, generator=generator) * 0.1
    y = torch.tanh((x - 3.0) @ W)
    student = StudentPolicy(12, 4, [64, 64])
    optimizer = torch.optim.Adam(student.parameters(), lr=3e-3)
    cfg = DAggerConfig(epochs=1, minibatch_size=128)
    first = fit_student(student, optimizer, x, y, cfg, generator)
    last = fit_student(student, optimizer, x, y, DAggerConfig(epochs=30, minibatch_size=128), generator)
    assert last < first / 10
    assert torch.allclose(student.mean, x.mean(0)) and torch.allclose(student.std, x.std(0, unbiased=False))
    assert student(x).abs().max() <= 1.0


def test_beta_hands_the_episodes_over_from_the_teachers():
    cfg = DAggerConfig(beta_start=1.0, beta_decay=0.5)
    assert [beta(cfg, k) for k in range(3)] == [1.0, 0.5, 0.25]


@pytest.fixture(scope="module")
def env(hand, library, tmp_path_factory):
    scene = Scene(objects=(Placement("cube", (0.0, -0.03, 0.02), IDENTITY), Placement("sphere", (0.0, 0.035, 0.025), IDENTITY)))
    p, R, q = preview_hand_pose(hand, scene, CameraConfig(), library)
    record = GraspRecord(scene=scene, p=p, R=R, q=q.astype(np.float64))
    urdf = hand.export_urdf(tmp_path_factory.mktemp("urdf"))
    environment = LiftEnv(hand, library, urdf, [record, record], LiftEnvConfig(max_steps=6, closure_steps=0),
                          PointNetEncoder(PointNetConfig()).eval())
    yield environment
    environment.close()


class ConstantTeacher:
    """A teacher whose action is a fixed vector (the label every state gets)."""

    def __init__(self, value: float):
        self.action = torch.full((24,), value)

    def __call__(self, td):
        return td.set("action", self.action.clone())


def test_the_scene_cloud_is_in_the_palm_frame_and_shows_hand_and_objects(env):
    env.reset()
    cameras = SceneCameras(SMALL)
    world_cloud = cameras.world_cloud(env.world)
    palm_cloud = cameras.scene_cloud(env.world)
    p, R = env.world.palm_pose()
    assert palm_cloud.shape == (SMALL.scene_points, 3)
    np.testing.assert_allclose(palm_cloud @ R.T + p, world_cloud, atol=1e-9)
    # near the objects (on the table, below the open hand) and on the hand above them
    assert world_cloud[:, 2].min() < 0.03 and world_cloud[:, 2].max() > 0.06
    observer = StudentObserver(env, cameras)
    obs = observer(env.reset())
    assert obs.shape == (student_dim(env.cfg),)
    torch.testing.assert_close(obs[: hand_dim(env.cfg)], env.reset()["observation"][: hand_dim(env.cfg)])


def test_dagger_labels_every_state_with_the_teacher_and_resumes_from_its_checkpoint(env, tmp_path):
    cameras = SceneCameras(SMALL)
    bins = [Bin(label="cube+sphere/0", env=env, teacher=ConstantTeacher(0.3), weight=2.0)]
    validations = []

    def validate(policy_for_env):
        validations.append(policy_for_env(env))
        return {"success": 0.0, "lift": 0.0}

    cfg = DAggerConfig(iterations=1, episodes_per_iteration=2, hidden=[16], epochs=40, minibatch_size=8, lr=3e-3)
    first = run_dagger(bins, cameras, cfg, tmp_path / "student.pt", validate=validate)
    assert first.samples == 2 * env.cfg.max_steps and first.history[0]["beta"] == 1.0
    assert isinstance(validations[0], VisionPolicy)
    student = load_student(tmp_path / "student.pt")
    pairs = torch.load(data_folder(tmp_path / "student.pt") / "iteration-0001.pt", weights_only=True)
    assert torch.allclose(pairs["labels"], torch.full_like(pairs["labels"], 0.3))  # every state: the teacher's action
    with torch.no_grad():  # it learned the teacher's action on its data, and acts near it from a fresh start
        assert (student(pairs["observations"]) - 0.3).abs().mean() < 0.03
        action = student(StudentObserver(env, cameras)(env.reset()))
    assert abs(float(action.mean()) - 0.3) < 0.1
    more = run_dagger(bins, cameras, cfg.model_copy(update={"iterations": 2}), tmp_path / "student.pt", validate=validate)
    assert more.resumed_from == 1 and [h["iteration"] for h in more.history] == [1, 2]
    assert more.samples == 4 * env.cfg.max_steps and more.history[1]["beta"] == 0.5
    again = run_dagger(bins, cameras, cfg.model_copy(update={"iterations": 2}), tmp_path / "student.pt")
    assert again.resumed_from == 2 and again.samples == more.samples  # finished: nothing collected
    # the data set lies beside the checkpoint, one file per iteration; a lost one is a one-line error
    chunks = sorted(data_folder(tmp_path / "student.pt").iterdir())
    assert [c.name for c in chunks] == ["iteration-0001.pt", "iteration-0002.pt"]
    chunks[0].unlink()
    with pytest.raises(MultigraspError, match=r"iteration-0001.pt is missing or corrupt \(FileNotFoundError\); delete"):
        run_dagger(bins, cameras, cfg.model_copy(update={"iterations": 3}), tmp_path / "student.pt")


def test_a_corrupt_checkpoint_and_no_specialists_are_one_line_errors(env, tmp_path):
    bad = tmp_path / "student.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(MultigraspError, match="corrupt.*delete it"):
        run_dagger([Bin("b", env, ConstantTeacher(0.0))], SceneCameras(SMALL), DAggerConfig(iterations=1), bad)
    with pytest.raises(MultigraspError, match="no specialists"):
        run_dagger([], SceneCameras(SMALL), DAggerConfig(), tmp_path / "other.pt")


# --------------------------------------------------------------------------- the curriculum's phases


def test_the_curriculum_mixes_each_phases_starts_in_its_shares():
    from collections import Counter

    from components.learning.curriculum import CurriculumConfig, mix, phase_starts

    synthetic, reached, generated = ["s1", "s2", "s3", "s4"], ["r1"], ["g1", "g2"]
    cfg = CurriculumConfig(phase2_imprecise_share=0.5, phase3_generated_share=0.8)
    assert phase_starts(1, synthetic, reached, generated, cfg) == synthetic
    two = Counter(x[0] for x in phase_starts(2, synthetic, reached, generated, cfg))
    assert two["s"] == two["r"] + two["g"]  # half imprecise
    three = phase_starts(3, synthetic, reached, generated, cfg)
    share = sum(x[0] == "g" for x in three) / len(three)
    assert abs(share - 0.8) < 0.05 and set(three) == set(synthetic + reached + generated)  # every start kept
    # an empty pool hands its share to the others: no generated starts, phase 3 is the synthetic and reached ones
    assert set(phase_starts(3, synthetic, reached, [], cfg)) == set(synthetic + reached)
    assert mix([([], 0.5), ([], 0.5)]) == []
    with pytest.raises(ValueError, match="phases 1 to 3"):
        phase_starts(4, synthetic, reached, generated, cfg)


def test_the_scene_cloud_benchmark_writes_its_timings(tmp_path):
    import json

    from benchmarks.scene_cloud import main

    out = tmp_path / "scene_cloud.json"
    assert main(["--json", str(out), "--repeats", "1", "--sizes", "32x24"]) == 0
    row, = json.loads(out.read_text())["rows"]
    assert row["width"] == 32 and row["cameras"] == 3 and 0 < row["render_s"] <= row["feature_s"]
    assert 0 < row["object_pixels"] < row["scene_pixels"]


def test_distill_with_no_specialist_to_distil_is_one_line(tmp_path, monkeypatch):
    """A config whose synthesis accepted nothing trains no specialist: distill says so in one line (the stages before
    it are kept), instead of failing inside DAgger."""
    import flows.distill
    from flows.config import load_config

    monkeypatch.setattr(flows.distill, "read_specialist_index", lambda manifest: {})
    cfg = load_config("smoke", workdir=tmp_path)
    with pytest.raises(MultigraspError, match="trained no specialist .* nothing to distil"):
        flows.distill.distill_flow.fn(cfg, None, {"curriculum": None, "pointnet": None})
