"""Shadow Hand collision geometry: analytic distances vs brute force, self-penetration, gradients."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from components.hand import (
    HandConfig,
    HandModel,
    capsule_box_signed_distance,
    capsule_capsule_signed_distance,
    capsule_cylinder_signed_distance,
    point_box_signed_distance,
    point_capsule_signed_distance,
    point_cylinder_signed_distance,
)
from components.hand.geometry import (
    capsule_prism_penetrating_distance,
    capsule_prism_signed_distance,
    nearest_capsule,
    nearest_prism,
    point_prism_signed_distance,
    to_local,
)

EPS = HandConfig().distance_epsilon
PARALLEL_EPS = 1e-12
ITERATIONS = HandConfig().golden_section_iterations
BRUTE_FORCE_TOLERANCE = 5e-4  # m
SURFACE_STEP = 2e-4  # m, spacing of the brute-force surface samples
N_QUERY = 2000
DTYPE = torch.float64


@pytest.fixture(scope="module")
def hand():
    return HandModel(HandConfig(), dtype=torch.float64)


def grid(lo, hi, step):
    return np.linspace(lo, hi, max(2, int(math.ceil((hi - lo) / step)) + 1))


def capsule_surface(radius, half_length, step):
    """Dense samples of a z-axis capsule surface centred at 0."""
    n_around = int(math.ceil(2 * math.pi * radius / step))
    phi = np.linspace(0, 2 * math.pi, n_around, endpoint=False)
    z = grid(-half_length, half_length, step)
    zz, pp = np.meshgrid(z, phi)
    side = np.stack([radius * np.cos(pp), radius * np.sin(pp), zz], -1).reshape(-1, 3)
    polar = grid(0, math.pi / 2, step / radius)
    caps = []
    for theta in polar:
        n = max(1, int(math.ceil(2 * math.pi * radius * math.sin(theta) / step)))
        ring = np.linspace(0, 2 * math.pi, n, endpoint=False)
        for sign in (1, -1):
            caps.append(np.stack([radius * math.sin(theta) * np.cos(ring), radius * math.sin(theta) * np.sin(ring),
                                  np.full(n, sign * (half_length + radius * math.cos(theta)))], -1))
    return np.concatenate([side] + caps)


def box_surface(half, step):
    faces = []
    for axis in range(3):
        u, v = [k for k in range(3) if k != axis]
        gu, gv = np.meshgrid(grid(-half[u], half[u], step), grid(-half[v], half[v], step))
        for sign in (1, -1):
            face = np.zeros(gu.shape + (3,))
            face[..., axis], face[..., u], face[..., v] = sign * half[axis], gu, gv
            faces.append(face.reshape(-1, 3))
    return np.concatenate(faces)


def cylinder_surface(radius, half_length, step):
    n_around = int(math.ceil(2 * math.pi * radius / step))
    phi = np.linspace(0, 2 * math.pi, n_around, endpoint=False)
    zz, pp = np.meshgrid(grid(-half_length, half_length, step), phi)
    side = np.stack([radius * np.cos(pp), radius * np.sin(pp), zz], -1).reshape(-1, 3)
    gx, gy = np.meshgrid(grid(-radius, radius, step), grid(-radius, radius, step))
    disk = np.stack([gx.ravel(), gy.ravel()], -1)
    disk = disk[(disk ** 2).sum(-1) <= radius ** 2]
    caps = [np.concatenate([disk, np.full((len(disk), 1), s * half_length)], -1) for s in (1, -1)]
    return np.concatenate([side] + caps)


def brute_force(surface, queries, inside):
    distance, _ = cKDTree(surface).query(queries)
    return np.where(inside, -distance, distance)


def random_queries(extent, seed):
    return np.random.default_rng(seed).uniform(-extent, extent, size=(N_QUERY, 3))


def test_point_capsule_distance_matches_brute_force():
    radius, half = 0.01, 0.0225
    queries = random_queries(np.array([0.03, 0.03, 0.05]), seed=0)
    seg_t = np.clip(queries[:, 2], -half, half)
    inside = np.linalg.norm(queries - np.stack([0 * seg_t, 0 * seg_t, seg_t], -1), axis=-1) < radius
    expected = brute_force(capsule_surface(radius, half, SURFACE_STEP), queries, inside)
    a, b = torch.tensor([0.0, 0.0, -half], dtype=DTYPE), torch.tensor([0.0, 0.0, half], dtype=DTYPE)
    got = point_capsule_signed_distance(torch.tensor(queries), a, b, torch.tensor(radius, dtype=DTYPE), eps=EPS)
    assert inside.any() and (~inside).any()
    assert np.abs(got.numpy() - expected).max() < BRUTE_FORCE_TOLERANCE


def test_point_box_distance_matches_brute_force():
    half = np.array([0.032, 0.0111, 0.049])
    queries = random_queries(half + 0.02, seed=1)
    inside = (np.abs(queries) < half).all(-1)
    expected = brute_force(box_surface(half, SURFACE_STEP), queries, inside)
    got = point_box_signed_distance(torch.tensor(queries), torch.tensor(half), eps=EPS)
    assert inside.any() and (~inside).any()
    assert np.abs(got.numpy() - expected).max() < BRUTE_FORCE_TOLERANCE


def test_point_cylinder_distance_matches_brute_force():
    radius, half = 0.03, 0.05
    queries = random_queries(np.array([0.05, 0.05, 0.07]), seed=2)
    inside = (np.linalg.norm(queries[:, :2], axis=-1) < radius) & (np.abs(queries[:, 2]) < half)
    expected = brute_force(cylinder_surface(radius, half, SURFACE_STEP), queries, inside)
    got = point_cylinder_signed_distance(torch.tensor(queries), torch.tensor(radius, dtype=DTYPE),
                                         torch.tensor(half, dtype=DTYPE), eps=EPS)
    assert inside.any() and (~inside).any()
    assert np.abs(got.numpy() - expected).max() < BRUTE_FORCE_TOLERANCE


def test_batched_nearest_capsule_matches_the_primitive_formula():
    generator = torch.Generator().manual_seed(3)
    x = torch.randn(4, 500, 3, generator=generator) * 0.05
    a = torch.randn(4, 16, 3, generator=generator) * 0.05
    b = a + torch.randn(4, 16, 3, generator=generator) * 0.02
    radius = torch.rand(16, generator=generator) * 0.01 + 0.005
    reference = point_capsule_signed_distance(x[:, :, None], a[:, None], b[:, None], radius, eps=EPS).min(-1)
    value, index = nearest_capsule(x, a, b, radius)
    assert torch.allclose(value, reference.values, atol=2e-6)  # float32 Gram form
    assert (index == reference.indices).float().mean() > 0.99


def test_parallel_capsules_at_known_distance():
    def t(v):
        return torch.tensor(v, dtype=DTYPE)

    d = capsule_capsule_signed_distance(t([0, 0, 0]), t([0, 0, 1]), t(0.01), t([0.05, 0, 0]), t([0.05, 0, 1]), t(0.02),
                                        eps=EPS, parallel_eps=PARALLEL_EPS)
    assert abs(d.item() - 0.02) < 1e-9
    # parallel, end to end: the distance is between the nearest end points
    d = capsule_capsule_signed_distance(t([0, 0, 0]), t([0, 0, 1]), t(0.01), t([0.03, 0, 1.5]), t([0.03, 0, 2.5]),
                                        t(0.01), eps=EPS, parallel_eps=PARALLEL_EPS)
    assert abs(d.item() - (math.hypot(0.03, 0.5) - 0.02)) < 1e-9


def test_crossing_and_skew_capsules():
    def t(v):
        return torch.tensor(v, dtype=DTYPE)

    crossing = capsule_capsule_signed_distance(t([-1, 0, 0]), t([1, 0, 0]), t(0.01), t([0, -1, 0.01]),
                                               t([0, 1, 0.01]), t(0.01), eps=EPS, parallel_eps=PARALLEL_EPS)
    assert abs(crossing.item() + 0.01) < 1e-9  # 1 cm of penetration
    skew = capsule_capsule_signed_distance(t([-1, 0, 0]), t([1, 0, 0]), t(0.01), t([0.3, -1, 0.1]),
                                           t([0.3, 1, 0.1]), t(0.02), eps=EPS, parallel_eps=PARALLEL_EPS)
    assert abs(skew.item() - 0.07) < 1e-9


def test_segment_distance_matches_dense_sampling():
    rng = np.random.default_rng(4)
    segments = rng.normal(size=(200, 4, 3)) * 0.05
    samples = np.linspace(0, 1, 1001)
    for seg in segments[:50]:
        p1, q1, p2, q2 = seg
        s1 = p1 + samples[:, None] * (q1 - p1)
        s2 = p2 + samples[:, None] * (q2 - p2)
        expected = cKDTree(s2).query(s1)[0].min()
        got = capsule_capsule_signed_distance(*[torch.tensor(v) for v in (p1, q1)], torch.tensor(0.0, dtype=DTYPE),
                                              *[torch.tensor(v) for v in (p2, q2)], torch.tensor(0.0, dtype=DTYPE),
                                              eps=EPS, parallel_eps=PARALLEL_EPS)
        assert got.item() <= expected + 1e-9
        assert expected - got.item() < 1e-4


def test_capsule_box_and_cylinder_distances_match_dense_line_search():
    rng = np.random.default_rng(5)
    half = torch.tensor([0.032, 0.0111, 0.049], dtype=DTYPE)
    t_dense = torch.linspace(0, 1, 100001, dtype=DTYPE)
    for _ in range(12):
        a, b = (torch.tensor(rng.uniform(-0.08, 0.08, 3)) for _ in range(2))
        rot = torch.tensor(np.linalg.qr(rng.normal(size=(3, 3)))[0])
        centre = torch.tensor(rng.uniform(-0.01, 0.01, 3))
        axis = a + t_dense[:, None] * (b - a)
        local = (axis - centre) @ rot
        expected = point_box_signed_distance(local, half, eps=EPS).min() - 0.01
        got = capsule_box_signed_distance(a, b, torch.tensor(0.01, dtype=DTYPE), centre, rot, half,
                                          iterations=ITERATIONS, eps=EPS)
        assert expected.item() - 1e-6 < got.item() < expected.item() + 1e-7  # golden search ~ the 1e-5 grid
        as_prism = capsule_prism_signed_distance(a, b, torch.tensor(0.01, dtype=DTYPE), centre, rot, half,
                                                 torch.tensor(0.0, dtype=DTYPE), iterations=ITERATIONS, eps=EPS)
        assert abs(as_prism.item() - got.item()) < 1e-8  # two sqrt(eps) smoothings
        expected = point_cylinder_signed_distance(local, torch.tensor(0.03, dtype=DTYPE),
                                                  torch.tensor(0.05, dtype=DTYPE), eps=EPS).min() - 0.01
        got = capsule_cylinder_signed_distance(a, b, torch.tensor(0.01, dtype=DTYPE), centre, rot,
                                               torch.tensor(0.03, dtype=DTYPE), torch.tensor(0.05, dtype=DTYPE),
                                               iterations=ITERATIONS, eps=EPS)
        assert expected.item() - 1e-6 < got.item() < expected.item() + 1e-7


def test_capsule_parallel_to_box_face():
    half = torch.tensor([0.02, 0.01, 0.03], dtype=DTYPE)
    a, b = torch.tensor([-0.01, 0.025, 0.0], dtype=DTYPE), torch.tensor([0.01, 0.025, 0.0], dtype=DTYPE)
    d = capsule_box_signed_distance(a, b, torch.tensor(0.005, dtype=DTYPE), torch.zeros(3, dtype=DTYPE),
                                    torch.eye(3, dtype=DTYPE), half, iterations=ITERATIONS, eps=EPS)
    assert abs(d.item() - 0.01) < 1e-9


def test_screened_capsule_prism_search_equals_the_full_search_where_pairs_overlap():
    """capsule_prism_penetrating_distance = min(d, 0) of the full golden-section search, values and gradients,
    on random capsules around a box and a rounded prism: near, touching, overlapping and far."""
    rng = np.random.default_rng(11)
    batch, n_pairs = 64, 2
    half = torch.tensor([[0.032, 0.0111, 0.049], [0.0, 0.0, 0.03]], dtype=DTYPE)  # a box, a cylinder
    rounding = torch.tensor([0.0, 0.025], dtype=DTYPE)
    radius = torch.tensor([0.01, 0.008], dtype=DTYPE)
    a = torch.tensor(rng.uniform(-0.05, 0.05, (batch, n_pairs, 3)), requires_grad=True)
    b = (a.detach() + torch.tensor(rng.normal(0, 0.03, (batch, n_pairs, 3)))).requires_grad_(True)
    rot = torch.tensor(np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(batch * n_pairs)]))
    rot = rot.reshape(batch, n_pairs, 3, 3)
    centre = torch.tensor(rng.uniform(-0.01, 0.01, (batch, n_pairs, 3)))
    full = capsule_prism_signed_distance(a, b, radius, centre, rot, half, rounding, iterations=ITERATIONS, eps=EPS)
    overlapping = int((full < 0).sum())
    assert 0.2 * full.numel() < overlapping < 0.8 * full.numel()  # both kinds of pairs are exercised
    for samples in (2, 5):
        # pairs farther than the bound's slack are certainly screened out: the test exercises both paths
        slack = (b - a).detach().norm(dim=-1) / (2 * (samples - 1))
        assert int((full.detach() > slack).sum()) >= 0.1 * full.numel()
        screened = capsule_prism_penetrating_distance(a, b, radius, centre, rot, half, rounding,
                                                      iterations=ITERATIONS, samples=samples, eps=EPS)
        assert torch.equal(screened, full.clamp_max(0.0))
        grads_full = torch.autograd.grad(full.clamp_max(0.0).sum(), (a, b), retain_graph=True)
        grads_screened = torch.autograd.grad(screened.sum(), (a, b))
        for g_full, g_screened in zip(grads_full, grads_screened):
            assert torch.equal(g_full, g_screened)


def test_pair_penetrating_distances_are_the_clipped_pair_distances(hand):
    q = hand.sample_joint_angles(128, torch.Generator().manual_seed(3)).to(DTYPE)
    prims = hand.collision.pose(hand.forward_kinematics(q))
    full = hand.collision.pair_signed_distances(prims)
    assert bool((full < 0).any()) and bool((full > 0).any())
    assert torch.equal(hand.collision.pair_penetrating_distances(prims), full.clamp_max(0.0))


def test_open_pose_has_no_self_penetration(hand):
    assert hand.self_penetration(hand.open_pose()[None]).item() < 1e-9


def test_fingers_forced_together_self_penetrate(hand):
    q = hand.open_pose().clone()
    q[hand.joint_names.index("FFJ3")] = -0.349  # index finger abducted towards the middle finger
    q[hand.joint_names.index("MFJ3")] = 0.349  # middle finger towards the index finger
    assert hand.self_penetration(q[None]).item() > 1e-3


def test_fist_does_not_self_penetrate(hand):
    q18 = torch.zeros(18, dtype=DTYPE)
    for finger in ("FF", "MF", "RF", "LF"):
        q18[hand.actuated_joint_names.index(finger + "J2")] = 1.571
        q18[hand.actuated_joint_names.index(finger + "J1")] = 1.571
    assert hand.self_penetration(hand.expand_actuated(q18)[None]).item() < 1e-9


def test_prism_is_exactly_box_and_cylinder():
    generator = torch.Generator().manual_seed(9)
    x = torch.randn(5000, 3, generator=generator, dtype=DTYPE) * 0.05
    half = torch.tensor([0.032, 0.0111, 0.049], dtype=DTYPE)
    zero = torch.tensor(0.0, dtype=DTYPE)
    assert torch.allclose(point_prism_signed_distance(x, half, zero, eps=EPS),
                          point_box_signed_distance(x, half, eps=EPS), atol=1e-12)
    radius, length = torch.tensor(0.03, dtype=DTYPE), torch.tensor(0.04, dtype=DTYPE)
    cylinder_half = torch.tensor([0.0, 0.0, 0.04], dtype=DTYPE)
    assert torch.allclose(point_prism_signed_distance(x, cylinder_half, radius, eps=EPS),
                          point_cylinder_signed_distance(x, radius, length, eps=EPS), atol=1e-12)


def test_batched_nearest_prism_matches_the_primitive_formula():
    generator = torch.Generator().manual_seed(10)
    x = torch.randn(3, 700, 3, generator=generator) * 0.05
    centre = torch.randn(3, 4, 3, generator=generator) * 0.02
    rot = torch.linalg.qr(torch.randn(3, 4, 3, 3, generator=generator))[0]
    half = torch.tensor([[0.032, 0.0111, 0.049], [0.011, 0.0111, 0.025], [0.0095, 0.0111, 0.025], [0, 0, 0.11]])
    rounding = torch.tensor([0.0, 0.0, 0.0, 0.069])
    local = to_local(x[:, :, None], centre[:, None], rot[:, None])
    reference = point_prism_signed_distance(local, half, rounding, eps=EPS).min(-1)
    value, index = nearest_prism(x, centre, rot, half, rounding)
    assert torch.allclose(value, reference.values, atol=1e-6)
    assert (index == reference.indices).float().mean() > 0.99


def test_hand_signed_distance_matches_per_geom_minimum(hand):
    """The union distance equals the minimum over every geom of the primitive formulas."""
    generator = torch.Generator().manual_seed(6)
    q = hand.sample_joint_angles(3, generator)
    p = torch.randn(3, 3, generator=generator, dtype=DTYPE) * 0.1
    R = torch.linalg.qr(torch.randn(3, 3, 3, generator=generator, dtype=DTYPE))[0]
    local = torch.randn(3, 400, 3, generator=generator, dtype=DTYPE) * 0.06 + torch.tensor([0, 0, 0.08], dtype=DTYPE)
    points = local @ R.transpose(1, 2) + p[:, None]
    prims = hand.collision_primitives(p, R, q)
    per_geom = [point_capsule_signed_distance(points[:, :, None], prims.capsule_a[:, None], prims.capsule_b[:, None],
                                              hand.collision.capsule_radius, eps=EPS)]
    for geom, index in zip(hand.collision.geoms, range(len(hand.collision.geoms))):
        if geom.kind == "capsule":
            continue
        k = hand.collision.prism_ids.index(index)
        x_local = to_local(points, prims.prism_centre[:, None, k], prims.prism_rot[:, None, k])
        if geom.kind == "box":
            per_geom.append(point_box_signed_distance(x_local, torch.tensor(geom.size), eps=EPS)[..., None])
        else:
            per_geom.append(point_cylinder_signed_distance(x_local, torch.tensor(geom.size[0]),
                                                           torch.tensor(geom.size[1]), eps=EPS)[..., None])
    expected = torch.cat(per_geom, -1).amin(-1)
    with torch.no_grad():
        got_no_grad = hand.signed_distance(points, p, R, q)
    got = hand.signed_distance(points.clone().requires_grad_(), p, R, q)  # the differentiable path
    assert torch.allclose(got_no_grad, expected, atol=1e-9)
    assert torch.allclose(got, expected, atol=1e-9)
    assert (got < 0).any() and (got > 0).any()


def test_signed_distance_is_differentiable(hand):
    generator = torch.Generator().manual_seed(7)
    q = hand.sample_joint_angles(2, generator).requires_grad_()
    p = (torch.randn(2, 3, generator=generator, dtype=DTYPE) * 0.01).requires_grad_()
    R = torch.linalg.qr(torch.randn(2, 3, 3, generator=generator, dtype=DTYPE))[0].requires_grad_()
    local = torch.randn(2, 40, 3, generator=generator, dtype=DTYPE) * 0.05 + torch.tensor([0, 0, 0.08], dtype=DTYPE)
    points = (local @ R.detach().transpose(1, 2) + p.detach()[:, None]).requires_grad_()
    assert torch.autograd.gradcheck(lambda x, pp, rr, qq: hand.signed_distance(x, pp, rr, qq), (points, p, R, q),
                                    eps=1e-7, atol=1e-5, fast_mode=True)


def test_self_penetration_is_differentiable(hand):
    q = hand.open_pose().clone()
    q[hand.joint_names.index("FFJ3")] = -0.3
    q[hand.joint_names.index("MFJ3")] = 0.3
    q[hand.joint_names.index("THJ4")] = 1.0
    q[hand.joint_names.index("THJ3")] = 1.1
    q = q[None].clone().requires_grad_()
    assert hand.self_penetration(q).item() > 0
    assert torch.autograd.gradcheck(hand.self_penetration, (q,), eps=1e-7, atol=1e-5)


def test_geom_lowest_heights_bound_the_surface(hand):
    generator = torch.Generator().manual_seed(8)
    q = hand.sample_joint_angles(2, generator)
    p = torch.zeros(2, 3, dtype=DTYPE)
    R = torch.linalg.qr(torch.randn(2, 3, 3, generator=generator, dtype=DTYPE))[0]
    lowest = hand.geom_lowest_heights(p, R, q).amin(-1)  # (B,)
    # points just below the lowest point are outside the hand; the hand reaches down to it
    grid_xy = torch.stack(torch.meshgrid(torch.linspace(-0.3, 0.3, 121, dtype=DTYPE),
                                         torch.linspace(-0.3, 0.3, 121, dtype=DTYPE), indexing="ij"), -1).reshape(-1, 2)
    for b in range(2):
        below = torch.cat([grid_xy, torch.full((len(grid_xy), 1), lowest[b].item() - 1e-4, dtype=DTYPE)], -1)
        assert (hand.signed_distance(below[None], p[b:b + 1], R[b:b + 1], q[b:b + 1]) > 0).all()

