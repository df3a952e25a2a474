"""IK from keypoints, palm-aligned generation back to the world, and refinement against penetration."""

import math

import pytest
import torch

from components.generation import (
    GeneratedFilterConfig,
    GeneratorConfig,
    IKConfig,
    RefineConfig,
    contact_energy,
    contact_ratio,
    from_representation,
    generate_grasps,
    kabsch,
    keep_generated,
    palm_direction,
    palm_keypoint_indices,
    refine_grasps,
    rotation_z,
    solve_ik,
    tau_at,
    to_representation,
    yaw_of,
)
from components.hand import HandConfig, HandModel
from components.objects import Placement, Scene
from components.synthesis import SceneObjects
from components.synthesis.pose import rot6d_to_matrix

torch.set_num_threads(1)
SPHERE_RADIUS = 0.025


@pytest.fixture(scope="module")
def hand32():
    return HandModel(HandConfig(), dtype=torch.float32)


def random_poses(hand: HandModel, n: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    q = hand.sample_joint_angles(n, generator=g)
    R = rot6d_to_matrix(torch.randn(n, 6, generator=g))
    p = 0.1 * torch.randn(n, 3, generator=g)
    return p, R, q


def rotation_angle(R1: torch.Tensor, R2: torch.Tensor) -> torch.Tensor:
    cos = ((R1.transpose(1, 2) @ R2).diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2
    return torch.arccos(cos.clamp(-1, 1))


def test_kabsch_recovers_a_rigid_transform_of_the_palm_keypoints(hand32):
    p, R, q = random_poses(hand32, 8, seed=3)
    palm = hand32.keypoints(p, R, q)[:, palm_keypoint_indices(hand32)]  # (8, 6, 3)
    local = hand32.keypoints(torch.zeros(1, 3), torch.eye(3)[None], q[:1])[0, palm_keypoint_indices(hand32)]
    p_fit, R_fit = kabsch(local, palm)
    assert torch.allclose(p_fit, p, atol=1e-5) and torch.allclose(R_fit, R, atol=1e-4)


def test_ik_reproduces_the_keypoints_of_random_valid_poses_within_2mm(hand32):
    p, R, q = random_poses(hand32, 16, seed=1)
    target = hand32.keypoints(p, R, q)
    result = solve_ik(hand32, target, IKConfig(steps=300, restarts=1))
    error = (hand32.keypoints(result.p, result.R, result.q) - target).norm(dim=-1)  # (16, 31)
    assert float(error.median()) <= 0.002
    assert float(error.mean()) <= 0.002
    assert float((result.p - p).norm(dim=-1).median()) < 0.001  # palm position (m)
    assert float(rotation_angle(result.R, R).median()) < math.radians(1.0)  # palm orientation
    lower, upper = hand32.joint_limits.unbind(-1)
    assert bool(((result.q >= lower - 1e-6) & (result.q <= upper + 1e-6)).all())
    assert torch.allclose(result.q, hand32.expand_actuated(hand32.actuated(result.q)))  # J0 coupled to J1
    assert torch.allclose(result.mean_error, error.mean(-1), atol=1e-6)


def test_joint_representation_round_trips(hand32):
    p, R, q = random_poses(hand32, 4, seed=2)
    x = to_representation(hand32, p, R, q, "joints")
    assert x.shape == (4, 31)
    p2, R2, q2 = from_representation(hand32, x, "joints", IKConfig())
    assert torch.allclose(p2, p) and torch.allclose(R2, R, atol=1e-5) and torch.allclose(q2, q)
    assert to_representation(hand32, p, R, q, "keypoints").shape == (4, 93)


class FixedSampler(torch.nn.Module):
    """Stands in for a trained GraspGenerator: 'samples' fixed aligned-frame keypoints."""

    def __init__(self, keypoints: torch.Tensor):
        super().__init__()
        self.cfg = GeneratorConfig(representation="keypoints")
        self.keypoints = keypoints
        self.seen = None

    def sample(self, objects, per_scene=1, generator=None, sampler=None, guide=None):
        self.seen = objects.clouds
        return self.keypoints.reshape(1, -1).repeat(objects.clouds.shape[0] * per_scene, 1)


def test_generation_rotates_the_objects_into_the_aligned_frame_and_the_hand_back(hand32):
    # an aligned-frame grasp: palm facing +x (yaw 0), as the generator learns them: R e_y = -x, fingers up
    R_a = rotation_z(torch.tensor([math.pi / 2]))
    assert float(yaw_of(palm_direction(R_a))[0]) == pytest.approx(0.0, abs=1e-6)
    p_a, q = torch.tensor([[-0.05, 0.0, 0.1]]), hand32.open_pose()[None]
    sampler = FixedSampler(hand32.keypoints(p_a, R_a, q)[0])
    centre = torch.tensor([0.3, -0.2, 0.0])
    clouds = centre + 0.02 * torch.randn(2, 2, 32, 3)
    yaw = torch.tensor([0.7, -2.0])
    p, R, q_out = generate_grasps(sampler, hand32, clouds, yaw, IKConfig(steps=0, restarts=1, refit_palm=False))
    assert torch.allclose(yaw_of(palm_direction(R)), yaw, atol=1e-4)  # the palm faces the desired direction
    centroid = clouds.mean((1, 2))
    centroid[:, 2] = 0.0
    # the hand's position relative to the objects' centroid is the aligned one rotated by the yaw
    expected = (rotation_z(yaw) @ p_a.T).squeeze(-1) + centroid
    assert torch.allclose(p, expected, atol=1e-4)
    assert torch.allclose(sampler.seen.mean((1, 2))[:, :2], torch.zeros(2, 2), atol=1e-5)  # objects centred


def test_contact_energy_counts_only_points_within_tau_and_tau_decreases_linearly():
    d = torch.tensor([[[0.0005], [-0.0015], [0.003], [-0.01]]])  # (1, |S| = 4, N_o = 1)
    assert float(contact_energy(d, 0.002)[0]) == pytest.approx((0.0005 + 0.0015) / 4)
    assert float(contact_energy(d, 0.001)[0]) == pytest.approx(0.0005 / 4)
    cfg = RefineConfig(steps=11)
    assert tau_at(0, 11, cfg) == pytest.approx(0.002) and tau_at(10, 11, cfg) == pytest.approx(0.001)
    assert tau_at(5, 11, cfg) == pytest.approx(0.0015)


def hand_pressed_into_a_sphere(hand: HandModel, library):
    """A sphere on the table and two open hands pressed into its top: palm facing down (palm normal -R e_y = -z),
    fingers along +x, the palmar face centre (palm frame (0.011, -0.0111, 0.038)) 3 / 5 mm below the top.
    -> (SceneObjects, p (2, 3), R (2, 3, 3), q (2, 22))."""
    scene = Scene(objects=(Placement("sphere", (0.0, 0.0, SPHERE_RADIUS), (0.0, 0.0, 0.0, 1.0)),))
    R = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]).expand(2, 3, 3)
    palm_face = R[0] @ torch.tensor([0.011, -0.0111, 0.038])
    p = torch.stack([torch.tensor([0.0, 0.0, 2 * SPHERE_RADIUS - sink]) - palm_face for sink in (0.003, 0.005)])
    return SceneObjects(library, scene), p, R, hand.open_pose().expand(2, -1)


def test_refinement_lowers_the_penetration_of_a_hand_pressed_into_a_sphere(hand32, library):
    objects, p, R, q = hand_pressed_into_a_sphere(hand32, library)
    result = refine_grasps(hand32, objects, p, R, q, RefineConfig(steps=30, lr=5e-4))
    assert bool((result.depth_before > 0.002).all())
    assert bool((result.depth_after < 0.5 * result.depth_before).all())
    assert bool((result.energy_after < result.energy_before).all())


def _assigned_contact_distances(hand: HandModel, objects: SceneObjects, result) -> torch.Tensor:
    """|d| (B, C) of the contacts nearest_contacts assigns to the first object at the refined poses."""
    from components.synthesis import SynthesisConfig
    from components.synthesis.energy import GraspProblem, nearest_contacts

    problem = GraspProblem.build(hand, objects, SynthesisConfig())
    with torch.no_grad():
        points, normals = hand.contact_candidates_and_normals(result.p, result.R, result.q)
        contacts = nearest_contacts(problem, points, normals)
        return objects.sdf(points)[..., 0].gather(1, contacts[:, 0, :]).abs()


def test_force_closure_refinement_pulls_the_contacts_the_paper_refinement_leaves(hand32, library):
    """fc_steps runs the synthesis refinement after the paper's: the paper's objective backs a pressed hand out of
    the sphere and leaves the fingers where they were; the synthesis energy's E_dist pulls the assigned contacts in."""
    from components.synthesis import SynthesisConfig

    objects, p, R, q = hand_pressed_into_a_sphere(hand32, library)
    synthesis = SynthesisConfig()
    paper = refine_grasps(hand32, objects, p, R, q, RefineConfig(steps=30), synthesis=synthesis)
    both = refine_grasps(hand32, objects, p, R, q, RefineConfig(steps=30, fc_steps=100), synthesis=synthesis)
    assert bool((both.depth_after < 0.5 * both.depth_before).all())
    before, after = _assigned_contact_distances(hand32, objects, paper), _assigned_contact_distances(hand32, objects, both)
    assert bool((after.sum(-1) < 0.75 * before.sum(-1)).all())
    with pytest.raises(ValueError, match="fc_steps"):
        refine_grasps(hand32, objects, p, R, q, RefineConfig(steps=1, fc_steps=1))


def test_contact_ratio_counts_the_assigned_contacts_that_touch(hand32, library):
    """Pressed into the sphere, the ratio is the fraction of the 3 assigned contacts within the distance; lifted 1 m
    above it, no contact touches; any contact touches within 10 m."""
    from components.synthesis import SynthesisConfig

    objects, p, R, q = hand_pressed_into_a_sphere(hand32, library)
    synthesis = SynthesisConfig()
    pressed = type("Pose", (), {"p": p, "R": R, "q": q})
    distances = _assigned_contact_distances(hand32, objects, pressed)  # (2, 3)
    for d in (0.002, 0.005, 0.02):
        expected = (distances <= d).float().mean(-1)
        assert torch.allclose(contact_ratio(hand32, objects, p, R, q, synthesis, d), expected)
    lifted = p + torch.tensor([0.0, 0.0, 1.0])
    assert bool((contact_ratio(hand32, objects, lifted, R, q, synthesis, 0.005) == 0).all())
    assert bool((contact_ratio(hand32, objects, lifted, R, q, synthesis, 10.0) == 1).all())


def test_keep_generated_applies_the_penetration_and_contact_ratio_thresholds():
    cfg = GeneratedFilterConfig()  # 5 mm, 2/3
    pn = torch.tensor([5.0, 5.1, 1.0, 1.0, 0.0])
    ratio = torch.tensor([1.0, 1.0, 2.0 / 3.0, 1.0 / 3.0, 0.0])
    assert keep_generated(pn, ratio, cfg).tolist() == [True, False, True, False, False]
    assert keep_generated(pn, ratio, cfg.model_copy(update={"enabled": False})).all()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_force_closure_refinement_runs_on_cuda_as_on_the_cpu(library):
    """The two refinement stages on cuda (hand, objects and poses there) keep the CPU's outcome: the hand backed out
    of the sphere and the assigned contacts pulled in, with every result on the device."""
    from components.synthesis import SynthesisConfig

    hand_cpu = HandModel(HandConfig(), dtype=torch.float32)
    hand_gpu = HandModel(HandConfig(), device="cuda", dtype=torch.float32)
    objects, p, R, q = hand_pressed_into_a_sphere(hand_cpu, library)
    objects_gpu = SceneObjects(library, objects.scene, device="cuda")
    cfg, synthesis = RefineConfig(steps=30, fc_steps=100), SynthesisConfig()
    cpu = refine_grasps(hand_cpu, objects, p, R, q, cfg, synthesis=synthesis)
    gpu = refine_grasps(hand_gpu, objects_gpu, p.cuda(), R.cuda(), q.cuda(), cfg, synthesis=synthesis)
    assert gpu.p.is_cuda and gpu.q.is_cuda and bool(torch.isfinite(gpu.q).all())
    assert bool((gpu.depth_after < 0.5 * gpu.depth_before).all())
    paper = refine_grasps(hand_gpu, objects_gpu, p.cuda(), R.cuda(), q.cuda(), RefineConfig(steps=30), synthesis=synthesis)
    pulled = _assigned_contact_distances(hand_gpu, objects_gpu, gpu).sum(-1)
    assert bool((pulled < 0.75 * _assigned_contact_distances(hand_gpu, objects_gpu, paper).sum(-1)).all())
    assert float((gpu.p.cpu() - cpu.p).norm(dim=-1).max()) < 0.01  # same basin: within 1 cm of the CPU's wrist
