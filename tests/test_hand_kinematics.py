"""Shadow Hand kinematics: FK vs PyBullet (URDF) and vs MuJoCo, coupling, joint sets, gradients."""

import mujoco
import numpy as np
import pybullet
import pytest
import torch

from components.hand import HandConfig, HandModel
from components.hand.mjcf import NAME_PREFIX, load_hand_spec

N_RANDOM_POSES = 100
POSITION_TOLERANCE = 1e-5  # m
ROTATION_TOLERANCE = 1e-5  # max abs difference of rotation-matrix entries


@pytest.fixture(scope="module")
def hand64():
    return HandModel(HandConfig(), dtype=torch.float64)


@pytest.fixture(scope="module")
def random_q(hand64):
    """Random joint vectors, each joint uniform in its own MJCF range (the coupling is not needed by FK)."""
    generator = torch.Generator().manual_seed(0)
    lower, upper = hand64.joint_limits.unbind(-1)
    return lower + torch.rand(N_RANDOM_POSES, 22, generator=generator, dtype=torch.float64) * (upper - lower)


@pytest.fixture()
def bullet(tmp_path, hand64):
    client = pybullet.connect(pybullet.DIRECT)
    urdf = hand64.export_urdf(tmp_path)
    body = pybullet.loadURDF(str(urdf), useFixedBase=True, physicsClientId=client)
    yield client, body
    pybullet.disconnect(client)


def test_fk_matches_pybullet_link_poses(hand64, random_q, bullet):
    client, body = bullet
    joint_index = hand64.pybullet_joint_indices(body, client)
    link_index = hand64.pybullet_link_indices(body, client)
    assert len(set(joint_index)) == 22
    frames = hand64.forward_kinematics(random_q).numpy()  # (P, L, 4, 4) palm frame = PyBullet world
    worst_pos, worst_rot = 0.0, 0.0
    for pose in range(N_RANDOM_POSES):
        for index, angle in zip(joint_index, random_q[pose].tolist()):
            pybullet.resetJointState(body, index, angle, physicsClientId=client)
        for link, index in enumerate(link_index):
            if index < 0:  # the base (palm): its frame is the identity by construction
                continue
            state = pybullet.getLinkState(body, index, computeForwardKinematics=1, physicsClientId=client)
            pos = np.array(state[4])
            rot = np.array(pybullet.getMatrixFromQuaternion(state[5])).reshape(3, 3)
            worst_pos = max(worst_pos, np.abs(pos - frames[pose, link, :3, 3]).max())
            worst_rot = max(worst_rot, np.abs(rot - frames[pose, link, :3, :3]).max())
    assert worst_pos < POSITION_TOLERANCE, worst_pos
    assert worst_rot < ROTATION_TOLERANCE, worst_rot


def test_urdf_base_frame_is_the_palm_frame(hand64, bullet):
    client, body = bullet
    base_pos, base_orn = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
    local_pos, local_orn = pybullet.getDynamicsInfo(body, -1, physicsClientId=client)[3:5]
    frame_pos, frame_orn = pybullet.multiplyTransforms(base_pos, base_orn,
                                                       *pybullet.invertTransform(local_pos, local_orn))
    assert np.allclose(frame_pos, 0.0, atol=1e-7)
    assert np.allclose(np.array(pybullet.getMatrixFromQuaternion(frame_orn)), np.eye(3).ravel(), atol=1e-7)


def test_urdf_collision_shapes_are_the_analytic_primitives(hand64, bullet):
    client, body = bullet
    link_index = dict(zip(hand64.link_names, hand64.pybullet_link_indices(body, client)))
    for geom in hand64.collision.geoms:
        shapes = pybullet.getCollisionShapeData(body, link_index[geom.body], physicsClientId=client)
        if geom.kind == "capsule":
            dims = [s[3] for s in shapes if s[2] == pybullet.GEOM_CAPSULE]
            assert any(np.allclose(d[:2], [2 * geom.size[1], geom.size[0]]) for d in dims), geom.name
        elif geom.kind == "box":
            dims = [s[3] for s in shapes if s[2] == pybullet.GEOM_BOX]
            assert any(np.allclose(d, 2 * geom.size) for d in dims), geom.name


def test_fk_matches_mujoco_body_frames(hand64, random_q):
    """pytorch-kinematics reads the MJCF the way MuJoCo does (palm frame = MuJoCo palm body frame)."""
    spec = load_hand_spec()
    model = mujoco.MjModel.from_xml_string(spec.xml)
    data = mujoco.MjData(model)
    qpos_of = {model.joint(j).name[len(NAME_PREFIX):]: int(model.jnt_qposadr[j]) for j in range(model.njnt)}
    frames = hand64.forward_kinematics(random_q[:10]).numpy()
    for pose in range(10):
        data.qpos[:] = 0.0
        for name, angle in zip(hand64.joint_names, random_q[pose].tolist()):
            data.qpos[qpos_of[name]] = angle
        mujoco.mj_kinematics(model, data)
        palm = model.body(NAME_PREFIX + "palm").id
        rot_palm, pos_palm = data.xmat[palm].reshape(3, 3), data.xpos[palm]
        for link, name in enumerate(hand64.link_names):
            body = model.body(NAME_PREFIX + name).id
            pos = rot_palm.T @ (data.xpos[body] - pos_palm)
            rot = rot_palm.T @ data.xmat[body].reshape(3, 3)
            assert np.allclose(pos, frames[pose, link, :3, 3], atol=1e-7), name
            assert np.allclose(rot, frames[pose, link, :3, :3], atol=1e-7), name


def test_joint_sets_and_limits_come_from_the_mjcf(hand64):
    assert hand64.joint_names == ["FFJ3", "FFJ2", "FFJ1", "FFJ0", "MFJ3", "MFJ2", "MFJ1", "MFJ0",
                                  "RFJ3", "RFJ2", "RFJ1", "RFJ0", "LFJ4", "LFJ3", "LFJ2", "LFJ1", "LFJ0",
                                  "THJ4", "THJ3", "THJ2", "THJ1", "THJ0"]
    assert len(hand64.actuated_joint_names) == 18
    assert not any(n in hand64.actuated_joint_names for n in ("FFJ0", "MFJ0", "RFJ0", "LFJ0"))
    model = mujoco.MjModel.from_xml_string(load_hand_spec().xml)
    for name, (lower, upper) in zip(hand64.joint_names, hand64.joint_limits.tolist()):
        assert np.allclose([lower, upper], model.joint(NAME_PREFIX + name).range)
    assert hand64.link_names[0] == "palm" and hand64.link_names[-2:] == ["wrist", "forearm"]


def test_coupling_roundtrip_and_tendon(hand64):
    generator = torch.Generator().manual_seed(1)
    q22 = hand64.sample_joint_angles(256, generator)
    lower, upper = hand64.joint_limits.unbind(-1)
    assert ((q22 >= lower) & (q22 <= upper)).all()
    q18 = hand64.actuated(q22)
    assert q18.shape == (256, 18)
    assert torch.equal(hand64.expand_actuated(q18), q22)
    assert torch.equal(hand64.actuated(hand64.expand_actuated(q18)), q18)
    # the J1c tendon length 0.00705 q0 - 0.00805 q1 stays within its +-1 mm range wherever J0 is not clamped
    index = {n: i for i, n in enumerate(hand64.joint_names)}
    for finger in ("FF", "MF", "RF", "LF"):
        q0, q1 = q22[:, index[finger + "J0"]], q22[:, index[finger + "J1"]]
        free = q0 < upper[index[finger + "J0"]]
        assert torch.allclose(0.00705 * q0[free] - 0.00805 * q1[free], torch.zeros_like(q0[free]), atol=1e-12)
    assert torch.allclose(hand64.kinematics.coupling_violation(q22), torch.zeros(256, 4, dtype=torch.float64))


def test_open_pose_is_within_limits(hand64):
    q = hand64.open_pose()
    lower, upper = hand64.joint_limits.unbind(-1)
    assert q.shape == (22,) and ((q >= lower) & (q <= upper)).all()
    assert hand64.joint_limit_violation(q[None]).item() == 0.0


def test_fk_is_differentiable_wrt_q(hand64, random_q):
    q = random_q[:3].clone().requires_grad_()

    def positions(qq):
        return hand64.forward_kinematics(qq)[..., :3, :].sum(-1)

    assert torch.autograd.gradcheck(positions, (q,), eps=1e-6, atol=1e-6)


def test_link_poses_are_differentiable_wrt_pose(hand64, random_q):
    generator = torch.Generator().manual_seed(2)
    p = torch.randn(2, 3, generator=generator, dtype=torch.float64, requires_grad=True)
    R = torch.linalg.qr(torch.randn(2, 3, 3, generator=generator, dtype=torch.float64))[0].requires_grad_()
    q = random_q[:2].clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda pp, rr, qq: hand64.link_poses(pp, rr, qq), (p, R, q), eps=1e-6,
                                    atol=1e-6)


def test_float32_chain_matches_float64(hand64, random_q):
    hand32 = HandModel(HandConfig(), dtype=torch.float32)
    frames32 = hand32.forward_kinematics(random_q.float())
    assert frames32.dtype == torch.float32
    assert torch.allclose(frames32.double(), hand64.forward_kinematics(random_q), atol=1e-6)


def test_hand_without_forearm(tmp_path):
    hand = HandModel(HandConfig(include_forearm=False), dtype=torch.float64)
    assert len(hand.link_names) == 23 and "forearm" not in hand.link_names
    assert not any(g.body in ("wrist", "forearm") for g in hand.collision.geoms)
    q = hand.sample_joint_angles(4, torch.Generator().manual_seed(3))
    frames = hand.forward_kinematics(q)
    assert frames.shape == (4, 23, 4, 4)
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(hand.export_urdf(tmp_path / "hand.urdf")), useFixedBase=True,
                                 physicsClientId=client)
        assert pybullet.getNumJoints(body, physicsClientId=client) == 22
        for index, angle in zip(hand.pybullet_joint_indices(body, client), q[0].tolist()):
            pybullet.resetJointState(body, index, angle, physicsClientId=client)
        link = hand.link_names.index("thdistal")
        state = pybullet.getLinkState(body, hand.pybullet_link_indices(body, client)[link],
                                      computeForwardKinematics=1, physicsClientId=client)
        assert np.allclose(state[4], frames[0, link, :3, 3].numpy(), atol=POSITION_TOLERANCE)
    finally:
        pybullet.disconnect(client)
    p, R = torch.zeros(4, 3, dtype=torch.float64), torch.eye(3, dtype=torch.float64).expand(4, 3, 3)
    points = torch.randn(4, 50, 3, dtype=torch.float64) * 0.05
    assert hand.signed_distance(points, p, R, q).shape == (4, 50)
    assert hand.self_penetration(q).shape == (4,)
