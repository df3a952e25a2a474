"""Penetration guidance of the sampler (components.generation.guidance, ``SamplerConfig.guidance``) against analytic
answers: sphere radii from the hand's geometry, one guidance step of a lone sphere in a ball object moves it out by
scale x depth along the normal, the samplers apply the guide to x0^ only where asked, and the generator refuses
guidance it cannot do with a one-line error."""

import math

import pytest
import torch

from components.errors import MultigraspError
from components.generation import (
    AlignedFrame,
    GeneratorConfig,
    GraspGenerator,
    GuidanceConfig,
    IKConfig,
    KeypointSpheres,
    NoiseSchedule,
    SamplerConfig,
    ddim_sample,
    generate_grasps,
    guidance_energy,
    guidance_step,
    make_guide,
    p_sample,
)
from components.generation.guidance import FINGER_CHAINS
from components.hand import HandConfig, HandModel
from tests.test_ddim import SMALL


def _ball(centre, radius):
    """Signed distance to a ball: |x - c| - r."""
    return lambda x: (x - torch.as_tensor(centre, dtype=x.dtype)).norm(dim=-1) - radius


def _one_sphere(radius):
    """A single sphere on the first (and only) keypoint."""
    return KeypointSpheres(weights=torch.eye(1, dtype=torch.float64), radii=torch.tensor([radius], dtype=torch.float64))


def test_spheres_sit_on_the_keypoint_chains_with_radii_from_the_hand(hand):
    spheres = KeypointSpheres.from_hand(hand, segment_points=2)
    n_kp = len(hand.keypoint_names)
    assert spheres.weights.shape == (n_kp + 2 * 3 * len(FINGER_CHAINS), n_kp)
    torch.testing.assert_close(spheres.weights.sum(-1), torch.ones(spheres.weights.shape[0], dtype=hand.dtype))
    radius = dict(zip(hand.keypoint_names, spheres.radii[:n_kp].tolist()))
    for name, r in radius.items():
        if name.endswith(("_tip", "_pad")) or name.startswith("palm"):
            assert r == pytest.approx(0.0, abs=1e-6), name  # surface points of the hand
        else:  # joint centres: inside a phalanx (capsule radii 7-13 mm)
            assert 0.005 < r < 0.015, name
    assert (spheres.radii[n_kp:] > 0.005).all()  # points inside the segments lie on the phalanx axes
    keypoints = torch.randn(3, n_kp, 3, dtype=hand.dtype)
    torch.testing.assert_close(spheres.centres(keypoints)[:, :n_kp], keypoints)


def test_one_step_moves_a_lone_sphere_out_of_a_ball_by_scale_times_its_depth():
    spheres = _one_sphere(0.01)
    distance = _ball([0.0, 0.0, 0.1], 0.03)
    direction = torch.tensor([0.6, 0.0, 0.8], dtype=torch.float64)
    centre = torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64) + 0.025 * direction  # d = -5 mm, depth 15 mm
    for scale in (0.5, 1.0):
        moved = guidance_step(centre.reshape(1, 1, 3), spheres, distance, None, scale)
        expected = centre + scale * 0.015 * direction
        torch.testing.assert_close(moved[0, 0], expected, rtol=0, atol=1e-12)
    outside = torch.tensor([[[0.0, 0.0, 0.15]]], dtype=torch.float64)  # 2 cm clear of the ball: untouched
    torch.testing.assert_close(guidance_step(outside, spheres, distance, None, 1.0), outside)
    assert float(guidance_energy(outside, spheres, distance, None)) == 0.0
    low = torch.tensor([[[0.5, 0.5, 0.004]]], dtype=torch.float64)  # 6 mm into the table plane z = 0
    torch.testing.assert_close(guidance_step(low, spheres, distance, 0.0, 1.0)[0, 0, 2],
                               torch.tensor(0.01, dtype=torch.float64), rtol=0, atol=1e-12)


def test_the_guide_acts_only_at_or_below_start_t_and_round_trips_the_frame_and_scaling():
    spheres = _one_sphere(0.01)
    frame = AlignedFrame.from_yaw(torch.tensor([0.7], dtype=torch.float64),
                                  torch.tensor([[0.1, -0.2, 0.0]], dtype=torch.float64))
    guide = make_guide(GuidanceConfig(scale=1.0, start_t=10), spheres, _ball([0.1, -0.2, 0.05], 0.03), 0.0,
                       frame.points_from_aligned, frame.points_to_aligned, lambda z: 0.1 * z, lambda x: 10.0 * x)
    z = torch.tensor([[0.0, 0.0, 0.7]], dtype=torch.float64)  # aligned (0, 0, 0.07): 2 cm above the ball's centre
    assert guide(z, 11) is z  # above start_t: unchanged
    out = guide(z, 10)  # depth 0.03 + 0.01 - 0.02 = 2 cm, straight up
    torch.testing.assert_close(out, torch.tensor([[0.0, 0.0, 0.9]], dtype=torch.float64), rtol=0, atol=1e-9)
    off = make_guide(GuidanceConfig(scale=0.0), spheres, _ball([0, 0, 0], 1.0), 0.0, frame.points_from_aligned,
                     frame.points_to_aligned, lambda z: z, lambda x: x)
    assert off(z, 0) is z


def test_samplers_hand_the_clean_estimate_to_the_guide_and_step_with_its_answer():
    schedule = NoiseSchedule(100, 1e-4, 0.01)
    target = torch.tensor([[0.3, -1.2, 2.0]], dtype=torch.float64)

    def model(x, t, cond):  # an arbitrary noise model: the guide overrides its x0^
        return torch.sin(x + 0.01 * t[:, None].to(x.dtype))

    seen = []

    def guide(x0, t):
        seen.append(t)
        return target.expand_as(x0)

    out = ddim_sample(model, schedule, (4, 3), None, 5, generator=torch.Generator().manual_seed(0),
                      dtype=torch.float64, guide=guide)
    torch.testing.assert_close(out, target.expand(4, 3), rtol=0, atol=1e-9)  # the last step returns x0^
    assert seen == [80, 60, 40, 20, 0]
    x = torch.randn(4, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    identity = p_sample(model, schedule, x, 30, None, torch.Generator().manual_seed(2), guide=lambda x0, t: x0)
    plain = p_sample(model, schedule, x, 30, None, torch.Generator().manual_seed(2))
    torch.testing.assert_close(identity, plain)


def test_generate_grasps_with_guidance_samples_finite_poses_and_refuses_what_it_cannot_guide():
    torch.manual_seed(0)
    hand = HandModel(HandConfig())
    model = GraspGenerator(GeneratorConfig(diffusion_steps=10, **SMALL))
    clouds = 0.03 * torch.randn(2, 2, 64, 3) + torch.tensor([0.0, 0.0, 0.05])
    yaws = torch.tensor([0.0, math.pi / 2])
    sampler = SamplerConfig(method="ddim", steps=3, guidance=GuidanceConfig(scale=1.0))
    ik = IKConfig(steps=2, restarts=1)
    p, R, q = generate_grasps(model, hand, clouds, yaws, ik, sampler=sampler, distance=_ball([0.0, 0.0, 0.05], 0.03),
                              generator=torch.Generator().manual_seed(1))
    assert torch.isfinite(p).all() and torch.isfinite(R).all() and torch.isfinite(q).all()
    with pytest.raises(MultigraspError, match="signed distance"):
        generate_grasps(model, hand, clouds, yaws, ik, sampler=sampler)
    joints = GraspGenerator(GeneratorConfig(diffusion_steps=10, representation="joints", **SMALL))
    with pytest.raises(MultigraspError, match="keypoint representation only"):
        generate_grasps(joints, hand, clouds, yaws, ik, sampler=sampler, distance=_ball([0.0, 0.0, 0.05], 0.03))
