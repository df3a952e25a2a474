"""Synthesis energy: each term on an analytic case, culled penetration == dense, finite gradients, initial poses."""

import math

import pytest
import torch

from components.objects import Placement, Scene
from components.synthesis import (
    GraspProblem,
    HandSurface,
    SceneObjects,
    SynthesisConfig,
    contact_distance_energy,
    energy,
    energy_and_grad,
    contact_alignment_energy,
    force_closure_error,
    friction_tilted_forces,
    initial_poses,
    matrix_to_rot6d,
    pack,
    rot6d_to_matrix,
    table_penetration,
    unpack,
)
from components.synthesis.energy import (group_force_closure_error, hand_points_object_distances, near_normals,
                                         object_points_hand_distances, surround_energy)
from components.synthesis.initializations import palm_centre_local

DTYPE = torch.float64
SPHERE_RADIUS = 0.025
IDENTITY = (0.0, 0.0, 0.0, 1.0)


@pytest.fixture(scope="module")
def sphere(library):
    scene = Scene(objects=(Placement("sphere", (0.01, -0.02, SPHERE_RADIUS), IDENTITY),))
    return SceneObjects(library, scene, dtype=DTYPE)


def equator_points(objects: SceneObjects, angles_deg, radius_scale: float = 1.0) -> torch.Tensor:
    angles = torch.tensor(angles_deg, dtype=DTYPE) * math.pi / 180
    ring = torch.stack([torch.cos(angles), torch.sin(angles), torch.zeros_like(angles)], dim=-1)
    return (objects.positions[0] + radius_scale * SPHERE_RADIUS * ring).unsqueeze(0)  # (1, C, 3)


def test_contacts_on_the_sphere_surface_have_zero_distance_energy(sphere):
    points = equator_points(sphere, [0.0, 77.0, 200.0])
    d, _ = sphere.object_sdf_and_normal(0, points)
    assert float(contact_distance_energy(d)[0]) == pytest.approx(0.0, abs=1e-9)
    d_out, _ = sphere.object_sdf_and_normal(0, equator_points(sphere, [0.0, 77.0, 200.0], radius_scale=1.2))
    assert float(contact_distance_energy(d_out)[0]) == pytest.approx(3 * 0.2 * SPHERE_RADIUS, rel=1e-9)


def test_three_contacts_at_120_degrees_are_in_force_closure_and_three_on_one_side_are_not(sphere):
    centre, radius = sphere.positions[0], sphere.radii[0]
    balanced = equator_points(sphere, [0.0, 120.0, 240.0])
    _, n = sphere.object_sdf_and_normal(0, balanced)
    # |G n|^2 = |sum n|^2 + |sum x x n|^2 = 0: the normals cancel and pass through the centre
    assert float(force_closure_error(balanced, n, centre, radius, margin=0.0)[0]) == pytest.approx(0.0, abs=1e-12)
    one_side = equator_points(sphere, [0.0, 20.0, 40.0])
    _, n = sphere.object_sdf_and_normal(0, one_side)
    expected = float((n.sum(1) ** 2).sum())  # no torque: only the unbalanced force remains
    assert float(force_closure_error(one_side, n, centre, radius, margin=0.0)[0]) == pytest.approx(expected, rel=1e-9)
    assert expected > 7.0  # |sum n| ~ 2.8 for three nearly parallel unit normals
    assert float(force_closure_error(one_side, n, centre, radius, margin=0.2)[0]) == pytest.approx(expected - 0.2)


def test_torque_rows_of_the_force_closure_error_use_lever_arms_over_the_radius(sphere):
    centre = sphere.positions[0]
    points = centre + torch.tensor([[[0.02, 0.0, 0.0], [-0.02, 0.0, 0.0]]], dtype=DTYPE)
    normals = torch.tensor([[[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]], dtype=DTYPE)  # a pure couple
    # sum n = 0; sum x x n = 2 * (0.02 / r) e_z
    value = force_closure_error(points, normals, centre, torch.tensor(0.025, dtype=DTYPE), margin=0.0)
    assert float(value[0]) == pytest.approx((2 * 0.02 / 0.025) ** 2, rel=1e-9)


def test_table_penetration_sums_the_depth_of_geoms_below_the_table():
    lowest = torch.tensor([[0.01, -0.002, -0.003, 0.0]], dtype=DTYPE)
    assert float(table_penetration(lowest, 0.0)[0]) == pytest.approx(0.005)


def test_rot6d_round_trip_and_orthonormality():
    rot = rot6d_to_matrix(torch.randn(16, 6, dtype=DTYPE, generator=torch.Generator().manual_seed(0)))
    assert torch.allclose(rot.transpose(1, 2) @ rot, torch.eye(3, dtype=DTYPE).expand(16, 3, 3), atol=1e-12)
    assert torch.allclose(torch.det(rot), torch.ones(16, dtype=DTYPE))
    assert torch.allclose(rot6d_to_matrix(matrix_to_rot6d(rot)), rot, atol=1e-12)


# ----------------------------------------------------------------------------- penetration with culling


def finger_in_sphere_pose(hand, library, overlap: float):
    """Open hand, a sphere pushed ``overlap`` into the FF distal capsule from the palm side."""
    p = torch.tensor([[0.0, 0.0, 0.3]], dtype=DTYPE)
    R = torch.eye(3, dtype=DTYPE).unsqueeze(0)
    q = hand.open_pose().unsqueeze(0)
    prims = hand.collision_primitives(p, R, q)
    k = [hand.collision_geom_names[i] for i in hand.collision.capsule_ids].index("C_ffdistal")
    radius = float(hand.collision.capsule_radius[k])
    centre = 0.5 * (prims.capsule_a[0, k] + prims.capsule_b[0, k]) - (radius + SPHERE_RADIUS - overlap) * R[0, :, 1]
    scene = Scene(objects=(Placement("sphere", tuple(centre.tolist()), IDENTITY),))
    return p, R, q, SceneObjects(library, scene, dtype=DTYPE)


def test_culled_penetration_distances_match_the_dense_ones_in_value_and_gradient(hand, library):
    p0, R0, q0, objects = finger_in_sphere_pose(hand, library, overlap=0.004)
    points = objects.surface_points(512, 0).reshape(1, -1, 3)
    x0 = pack(p0, R0, q0)

    def penetration(fn) -> tuple:
        x = x0.clone().requires_grad_(True)
        p, R, q = unpack(x)
        value = fn(p, R, q)
        (grad,) = torch.autograd.grad(value, x)
        return float(value.detach()), grad

    def culled(p, R, q):
        prims = hand.collision.pose(hand.forward_kinematics(q))
        return torch.relu(-object_points_hand_distances(hand, points, p, R, prims)).sum()

    def dense(p, R, q):
        return torch.relu(-hand.signed_distance(points, p, R, q)).sum()

    (v_culled, g_culled), (v_dense, g_dense) = penetration(culled), penetration(dense)
    assert v_dense > 0.0
    assert v_culled == pytest.approx(v_dense, rel=1e-12)
    assert torch.allclose(g_culled, g_dense, rtol=1e-9, atol=1e-12)

    surface = HandSurface(hand, 0.005)

    def culled_hand(p, R, q):
        return torch.relu(-hand_points_object_distances(objects, surface.world(hand, p, R, q))).sum()

    def dense_hand(p, R, q):
        return torch.relu(-objects.sdf(surface.world(hand, p, R, q))).sum()

    (v_culled, g_culled), (v_dense, g_dense) = penetration(culled_hand), penetration(dense_hand)
    assert v_dense > 0.0
    assert v_culled == pytest.approx(v_dense, rel=1e-12)
    assert torch.allclose(g_culled, g_dense, rtol=1e-9, atol=1e-12)


def test_energy_terms_of_a_finger_in_a_sphere(hand, library):
    p, R, q, objects = finger_in_sphere_pose(hand, library, overlap=0.004)
    problem = GraspProblem.build(hand, objects, SynthesisConfig(batch_size=1))
    contacts = torch.tensor([[[0, 50, 100]]])
    total, terms = energy(problem, pack(p, R, q), contacts)
    assert terms["pen_object_points"][0, 0] > 0 and terms["pen_hand_points"][0, 0] > 0
    assert float(terms["penetration_depth_objects"][0, 0]) == pytest.approx(0.004, abs=5e-4)  # sampled, 256 points
    assert float(terms["pen_table"][0]) == 0.0 and float(terms["prior"][0]) == 0.0
    cfg = problem.cfg
    expected = (cfg.w_fc * terms["fc"] + cfg.w_dist * terms["dist"] + cfg.w_pen * terms["pen"]
                + cfg.w_prior * terms["prior"] + cfg.w_align * terms["align"])
    assert torch.allclose(total.detach(), expected)
    # out of the joint limits -> prior; below the table -> pen_table
    q_bad = q.clone()
    q_bad[0, 1] = float(hand.joint_limits[1, 1]) + 0.2
    _, terms = energy(problem, pack(p, R, q_bad), contacts)
    assert float(terms["prior"][0]) == pytest.approx(0.2, rel=1e-6)
    _, terms = energy(problem, pack(p - torch.tensor([[0.0, 0.0, 0.35]], dtype=DTYPE), R, q), contacts)
    assert float(terms["pen_table"][0]) > 0.0 and float(terms["penetration_depth_table"][0]) > 0.04


def test_energy_gradients_are_finite_for_random_initial_poses(hand, library):
    scene = Scene(objects=(Placement("cube", (-0.03, 0.0, 0.02), IDENTITY), Placement("sphere", (0.03, 0.01, SPHERE_RADIUS), IDENTITY)))
    problem = GraspProblem.build(hand, SceneObjects(library, scene, dtype=DTYPE), SynthesisConfig(batch_size=6))
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    total, grad, terms = energy_and_grad(problem, x, contacts)
    assert total.shape == (6,) and grad.shape == x.shape == (6, 31)
    assert torch.isfinite(total).all() and torch.isfinite(grad).all()
    assert grad[:, :9].abs().sum() > 0  # the pose moves
    for name in ("fc_per_object", "dist_per_object", "pen_object_points", "pen_hand_points"):
        assert terms[name].shape == (6, 2)


def test_initial_poses_face_the_objects_from_above_at_the_configured_distance(hand, library):
    scene = Scene(objects=(Placement("cube", (-0.03, 0.0, 0.02), IDENTITY), Placement("sphere", (0.03, 0.01, SPHERE_RADIUS), IDENTITY)))
    objects = SceneObjects(library, scene, dtype=DTYPE)
    cfg = SynthesisConfig(batch_size=64, init_jitter_deg=0.0)
    problem = GraspProblem.build(hand, objects, cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(1))
    p, R, q = unpack(x)
    palm_centre = p + R @ palm_centre_local(hand)
    offset = palm_centre - objects.centroid
    distance = offset.norm(dim=-1) - objects.bounding_radius
    assert torch.all(distance >= cfg.init_distance_min_m - 1e-9) and torch.all(distance <= cfg.init_distance_max_m + 1e-9)
    u = offset / offset.norm(dim=-1, keepdim=True)
    assert torch.all(u[:, 2] >= math.cos(math.radians(cfg.init_max_polar_deg)) - 1e-9)  # above the objects
    palm_normal = -R[:, :, 1]
    assert torch.allclose((palm_normal * -u).sum(-1), torch.ones(64, dtype=DTYPE))  # facing the centroid
    lower, upper = hand.joint_limits.unbind(-1)
    assert torch.all(q >= lower - 1e-9) and torch.all(q <= upper + 1e-9)
    flat = contacts.reshape(64, -1)
    assert all(len(set(row.tolist())) == flat.shape[1] for row in flat)  # distinct contacts per row
    assert contacts.shape == (64, 2, cfg.contacts_per_object)


def test_friction_lets_a_pinch_plus_a_third_face_contact_balance():
    """Box faces +x, -x, +z: frictionless |sum n|^2 = 1; with mu = 0.5 the two side contacts take 1/3 of the
    residual each along their tangent planes, leaving |sum f|^2 = (1/3)^2."""
    normals = torch.tensor([[[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]], dtype=DTYPE)
    points = torch.tensor([[[0.02, 0.0, 0.0], [-0.02, 0.0, 0.0], [0.0, 0.0, 0.02]]], dtype=DTYPE)
    centre, radius = torch.zeros(3, dtype=DTYPE), torch.tensor(0.02, dtype=DTYPE)
    frictionless = force_closure_error(points, normals, centre, radius, margin=0.0)
    assert float(frictionless[0]) == pytest.approx(1.0, rel=1e-9)  # torques cancel, net force = n_3
    with_friction = force_closure_error(points, normals, centre, radius, margin=0.0, friction=0.5)
    assert float(with_friction[0]) == pytest.approx(1.0 / 9.0, rel=1e-9)
    forces = friction_tilted_forces(normals, 0.5)
    tangential = forces - (forces * normals).sum(-1, keepdim=True) * normals
    assert float(tangential.norm(dim=-1).max()) <= 0.5 + 1e-12  # inside the Coulomb cones
    tight = friction_tilted_forces(normals, 0.1)
    assert float((tight - normals).norm(dim=-1).max()) == pytest.approx(0.1, rel=1e-9)  # clamped to mu
    # more steps hand the residual on: 1/3^k after k steps (each side contact takes 1/3 of it, within mu = 0.5)
    for k in (2, 4):
        error = force_closure_error(points, normals, centre, radius, margin=0.0, friction=0.5, friction_iterations=k)
        assert float(error[0]) == pytest.approx((1.0 / 3.0) ** (2 * k), rel=1e-9)
        forces = friction_tilted_forces(normals, 0.5, k)
        tangential = forces - (forces * normals).sum(-1, keepdim=True) * normals
        assert float(tangential.norm(dim=-1).max()) <= 0.5 + 1e-12
    # two contacts at 90 degrees cannot balance within cones of 0.5: the tilt stops at the cone edges
    square = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]], dtype=DTYPE)
    residual = friction_tilted_forces(square, 0.5, 20).sum(1)
    assert float((residual * residual).sum()) == pytest.approx(0.5, rel=1e-6)


def test_contact_alignment_is_zero_for_opposed_normals_and_two_for_equal_ones():
    up = torch.tensor([[[0.0, 0.0, 1.0]]], dtype=DTYPE)
    assert float(contact_alignment_energy(-up, up)[0]) == 0.0
    assert float(contact_alignment_energy(up, up)[0]) == pytest.approx(2.0)


def test_contact_candidate_normals_are_outward_unit_normals_of_the_hand_surface(hand):
    batch = 3
    generator = torch.Generator().manual_seed(3)
    q = hand.sample_joint_angles(batch, generator).to(DTYPE)
    p = torch.zeros(batch, 3, dtype=DTYPE)
    R = torch.eye(3, dtype=DTYPE).expand(batch, 3, 3)
    points, normals = hand.contact_candidates_and_normals(p, R, q)
    assert torch.allclose(points, hand.contact_candidates(p, R, q))
    assert torch.allclose(normals.norm(dim=-1), torch.ones(normals.shape[:2], dtype=DTYPE))
    outside = hand.signed_distance(points + 0.002 * normals, p, R, q)  # 2 mm out along the normal
    assert float(outside.median()) == pytest.approx(0.002, abs=1e-4)


def test_contact_gate_weights_sum_to_the_contact_count_and_drop_hovering_contacts():
    """w_i = C exp(-|d_i|/s) / sum_j exp(-|d_j|/s): equal distances -> all ones; d = (0, 0, 3 s) -> the third
    weight is 3 e^-3 / (2 + e^-3); detached (no gradient through the weights)."""
    from components.synthesis.energy import contact_gate_weights

    s = 0.01
    equal = contact_gate_weights(torch.full((1, 3), 0.02, dtype=DTYPE), s)
    assert torch.allclose(equal, torch.ones(1, 3, dtype=DTYPE))
    d = torch.tensor([[0.0, -0.0, 3 * s]], dtype=DTYPE, requires_grad=True)
    w = contact_gate_weights(d, s)
    e3 = math.exp(-3.0)
    assert float(w[0, 2]) == pytest.approx(3 * e3 / (2 + e3), rel=1e-9)
    assert float(w[0, 0]) == pytest.approx(3 / (2 + e3), rel=1e-9)
    assert float(w.sum()) == pytest.approx(3.0, rel=1e-12) and not w.requires_grad
    assert torch.equal(contact_gate_weights(d.detach(), 0.0), torch.ones(1, 3, dtype=DTYPE))


def test_gated_force_closure_ignores_a_hovering_contact():
    """Two antipodal contacts on the sphere's equator plus a third one: with the gate, moving the third contact
    far off the surface leaves (nearly) the antipodal pair's error, which is 0."""
    from components.synthesis.energy import contact_gate_weights

    normals = torch.tensor([[[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]], dtype=DTYPE)
    points = 0.02 * normals
    centre, radius = torch.zeros(3, dtype=DTYPE), torch.tensor(0.02, dtype=DTYPE)
    plain = force_closure_error(points, normals, centre, radius, margin=0.0)
    assert float(plain[0]) == pytest.approx(1.0)  # the third normal is unbalanced
    w = contact_gate_weights(torch.tensor([[0.0, 0.0, 0.1]], dtype=DTYPE), 0.005)  # third 10 cm off
    gated = force_closure_error(points, normals, centre, radius, margin=0.0, weights=w)
    assert float(gated[0]) < 1e-15


def test_pair_initialisation_puts_the_palm_above_the_pair_facing_down_fingers_across(hand, library):
    scene = Scene(objects=(Placement("cube", (-0.03, 0.0, 0.02), IDENTITY), Placement("sphere", (0.03, 0.0, SPHERE_RADIUS), IDENTITY)))
    objects = SceneObjects(library, scene, dtype=DTYPE)
    cfg = SynthesisConfig(batch_size=32, init_mode="pair", init_jitter_deg=0.0, init_pair_height_m=(0.01, 0.03))
    problem = GraspProblem.build(hand, objects, cfg)
    x, _ = initial_poses(problem, torch.Generator().manual_seed(0))
    p, R, q = unpack(x)
    palm_centre = p + R @ palm_centre_local(hand)
    assert torch.allclose(palm_centre[:, :2], objects.centroid[:2].expand(32, 2))
    top = 0.05  # the sphere's top (z = 0.025 + 0.025; its mesh's highest vertex within 1 mm)
    assert torch.all(palm_centre[:, 2] >= top + 0.01 - 1e-3) and torch.all(palm_centre[:, 2] <= top + 0.03 + 1e-6)
    assert torch.allclose(-R[:, :, 1], torch.tensor([0.0, 0.0, -1.0], dtype=DTYPE).expand(32, 3))  # palm down
    assert torch.allclose(R[:, 0, 2].abs(), torch.zeros(32, dtype=DTYPE), atol=1e-9)  # fingers across the x line
    assert torch.allclose(R[:, 1, 2].abs(), torch.ones(32, dtype=DTYPE))
    assert (R[:, 1, 2] > 0).any() and (R[:, 1, 2] < 0).any()  # both signs drawn
    along = GraspProblem.build(hand, objects, cfg.model_copy(update={"init_pair_roll": "along"}))
    _, R2, _ = unpack(initial_poses(along, torch.Generator().manual_seed(0))[0])
    assert torch.allclose(R2[:, 0, 2].abs(), torch.ones(32, dtype=DTYPE))


def test_contact_excess_is_zero_within_the_tolerance_and_quadratic_beyond():
    from components.synthesis.energy import contact_excess_energy

    d = torch.tensor([[0.001, -0.002, 0.0]], dtype=DTYPE)
    assert float(contact_excess_energy(d, 0.002)) == 0.0
    far = torch.tensor([[0.006, -0.004, 0.0]], dtype=DTYPE)  # (4/2)^2 + (2/2)^2
    assert float(contact_excess_energy(far, 0.002)) == pytest.approx(5.0)
    assert float(contact_excess_energy(far, 0.0)) == 0.0  # off


def test_excess_and_alignment_weights_enter_the_total(hand, library):
    scene = Scene(objects=(Placement("sphere", (0.0, 0.0, SPHERE_RADIUS), IDENTITY),))
    objects = SceneObjects(library, scene, dtype=DTYPE)
    cfg = SynthesisConfig(batch_size=4, w_contact_excess=2.0, contact_excess_m=0.002, w_align=1.0)
    problem = GraspProblem.build(hand, objects, cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    total, terms = energy(problem, x, contacts)
    no_align, _ = energy(problem, x, contacts, w_align=0.0)
    assert torch.allclose(total - no_align, terms["align"], atol=1e-5)
    plain = GraspProblem.build(hand, objects, cfg.model_copy(update={"w_contact_excess": 0.0}))
    base, _ = energy(plain, x, contacts)
    assert torch.all(terms["excess"] > 0)  # the initial poses hover centimetres away
    assert torch.allclose(total - base, 2.0 * terms["excess"], rtol=1e-5)


def test_surround_energy_is_zero_for_pushes_from_around_and_a_quarter_for_one_push():
    centre, radius = torch.zeros(1, 3, dtype=DTYPE), torch.tensor([0.02], dtype=DTYPE)
    axes = torch.eye(3, dtype=DTYPE)
    normals = torch.cat([axes, -axes]).reshape(1, 6, 1, 3)  # outward normals of the six face centres of a ball
    points = 0.02 * normals.squeeze(2)  # on the surface
    zero = torch.zeros(1, 6, 1, dtype=DTYPE)
    around = surround_energy(points, zero, normals, centre, radius, band=0.005)
    assert float(around) == pytest.approx(0.0, abs=1e-12)
    one_side = surround_energy(points[:, :1], zero[:, :1], normals[:, :1], centre, radius, band=0.005)
    assert float(one_side) == pytest.approx(0.25)  # |u|^2 / (1 + 1)^2, no torque through the centre
    # a sample 2.5 mm off weighs half; one 5 mm off or more weighs nothing
    half = surround_energy(points[:, :1] * 1.125, zero[:, :1] + 0.0025, normals[:, :1], centre, radius, band=0.005)
    assert float(half) == pytest.approx(0.25 / 2.25)  # (0.5)^2 / (1.5)^2
    far = surround_energy(points[:, :1] * 1.5, zero[:, :1] + 0.01, normals[:, :1], centre, radius, band=0.005)
    assert float(far) == 0.0


def test_surround_weight_enters_the_total_with_the_dense_gradient(hand, library):
    p0, R0, q0, objects = finger_in_sphere_pose(hand, library, overlap=-0.002)  # a finger 2 mm off the sphere
    cfg = SynthesisConfig(batch_size=1, w_surround=3.0, surround_band_m=0.005)
    problem = GraspProblem.build(hand, objects, cfg)
    contacts = torch.tensor([[[0, 50, 100]]])
    total, terms = energy(problem, pack(p0, R0, q0), contacts)
    without, _ = energy(problem, pack(p0, R0, q0), contacts, w_surround=0.0)
    assert float(terms["surround"][0]) > 0.0  # the finger touches from one side
    assert torch.allclose(total - without, 3.0 * terms["surround"], rtol=1e-9)
    x0 = pack(p0, R0, q0)

    def value_and_grad(distances_fn) -> tuple:
        x = x0.clone().requires_grad_(True)
        p, R, q = unpack(x)
        points = problem.hand_surface.world(hand, p, R, q)
        d = distances_fn(points)
        n = near_normals(objects, points.detach(), d.detach(), 0.005)
        value = surround_energy(points, d, n, objects.positions, problem.lever_lengths, 0.005).sum()
        return float(value.detach()), torch.autograd.grad(value, x)[0]

    v_culled, g_culled = value_and_grad(lambda pts: hand_points_object_distances(objects, pts, 0.005))
    v_dense, g_dense = value_and_grad(objects.sdf)
    assert v_culled == pytest.approx(v_dense, rel=1e-12) and g_culled.abs().sum() > 0
    assert torch.allclose(g_culled, g_dense, rtol=1e-9, atol=1e-12)


def test_group_force_closure_balances_a_pinch_of_two_touching_cubes_that_neither_cube_balances_alone(hand, library):
    # two cubes side by side along x, pinched from the outside: one contact on the left face of the left cube
    # (outward normal -x) and one on the right face of the right cube (+x), both on the line through the centroid.
    # Per object one unit force is unbalanced (E_fc = |n|^2 = 1 with margin 0); as one body the two cancel in force
    # and (lever arms parallel to the forces) in torque: E_fc^group = 0.
    half = 0.02  # the library cube's half side (m)
    scene = Scene(objects=(Placement("cube", (-half, 0.0, half), IDENTITY), Placement("cube", (half, 0.0, half), IDENTITY)))
    objects = SceneObjects(library, scene, dtype=DTYPE)
    points = torch.tensor([[[[-2 * half, 0.0, half]], [[2 * half, 0.0, half]]]], dtype=DTYPE)  # (B, n_obj, C, 3)
    normals = torch.tensor([[[[-1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]]]], dtype=DTYPE)
    cfg = SynthesisConfig(fc_margin=0.0, fc_friction=0.0, contacts_per_object=1)
    group = GraspProblem.build(hand, objects, cfg.model_copy(update={"fc_mode": "group"}))
    assert float(group_force_closure_error(group, points, normals)[0]) == pytest.approx(0.0, abs=1e-12)
    for j in range(2):
        alone = force_closure_error(points[:, j], normals[:, j], objects.positions[j], torch.tensor(1.0, dtype=DTYPE), 0.0)
        assert float(alone[0]) == pytest.approx(1.0)
    # an unbalanced pair (both pushes from the left) is not in group closure: |2 n|^2 = 4
    same = torch.tensor([[[[-1.0, 0.0, 0.0]], [[-1.0, 0.0, 0.0]]]], dtype=DTYPE)
    assert float(group_force_closure_error(group, points, same)[0]) == pytest.approx(4.0)
    # lever arms are normalised by the group's bounding radius (both cubes' centres +-half from the centroid)
    assert float(group.group_lever_length) == pytest.approx(objects.bounding_radius)


def test_group_mode_energy_reports_one_force_closure_error_for_every_object(hand, library):
    scene = Scene(objects=(Placement("cube", (-0.03, 0.0, 0.02), IDENTITY), Placement("sphere", (0.03, 0.01, SPHERE_RADIUS), IDENTITY)))
    objects = SceneObjects(library, scene, dtype=DTYPE)
    cfg = SynthesisConfig(batch_size=4, fc_mode="group")
    problem = GraspProblem.build(hand, objects, cfg)
    x, contacts = initial_poses(problem, torch.Generator().manual_seed(0))
    total, grad, terms = energy_and_grad(problem, x, contacts)
    assert torch.isfinite(grad).all()
    assert terms["fc_per_object"].shape == (4, 2)
    assert torch.equal(terms["fc_per_object"][:, 0], terms["fc_per_object"][:, 1])
    assert torch.equal(terms["fc"], terms["fc_per_object"][:, 0])  # the total counts the group once
    per_object = GraspProblem.build(hand, objects, cfg.model_copy(update={"fc_mode": "per_object"}))
    _, other = energy(per_object, x, contacts)
    assert not torch.allclose(other["fc"], terms["fc"])  # a different criterion, same poses and contacts
    assert torch.allclose(other["dist"], terms["dist"]) and torch.allclose(other["pen"], terms["pen"])



def test_opposition_energy_is_zero_for_a_pinch_and_grows_as_the_contacts_turn_to_one_side(sphere):
    from components.synthesis.energy import contact_opposition_energy

    _, pinch = sphere.object_sdf_and_normal(0, equator_points(sphere, [0.0, 90.0, 180.0]))
    assert float(contact_opposition_energy(pinch, 0.5)[0]) == pytest.approx(0.0, abs=1e-12)  # 0 and 180 deg oppose
    _, quarter = sphere.object_sdf_and_normal(0, equator_points(sphere, [0.0, 45.0, 90.0]))
    # best pair 90 deg apart: -cos 90 = 0, so 0.5 - 0 short of 120 deg
    assert float(contact_opposition_energy(quarter, 0.5)[0]) == pytest.approx(0.5, abs=1e-9)
    _, wide = sphere.object_sdf_and_normal(0, equator_points(sphere, [0.0, 10.0, 130.0]))
    assert float(contact_opposition_energy(wide, 0.5)[0]) == pytest.approx(0.0, abs=1e-12)  # 130 deg > 120
    same = torch.tensor([[[1.0, 0.0, 0.0]] * 3], dtype=DTYPE)
    assert float(contact_opposition_energy(same, 0.5)[0]) == pytest.approx(1.5)  # 1 + tau: all push the same way


def test_opposition_weight_follows_the_force_closure_weight_and_enters_the_total(hand, library):
    from components.synthesis.energy import opposition_weight

    cfg = SynthesisConfig(batch_size=1, w_fc=20.0, w_opposition=10.0)
    assert opposition_weight(cfg, 20.0) == pytest.approx(10.0)
    assert opposition_weight(cfg, 10.0) == pytest.approx(5.0)  # the MALA ramp
    assert opposition_weight(cfg, 0.0) == 0.0  # the approach stage
    assert opposition_weight(SynthesisConfig(batch_size=1), 1.0) == 0.0  # off by default
    p0, R0, q0, objects = finger_in_sphere_pose(hand, library, overlap=-0.002)
    contacts = torch.tensor([[[0, 50, 100]]])
    for normals in ("object", "hand"):
        problem = GraspProblem.build(hand, objects, cfg.model_copy(update={"opposition_normals": normals}))
        total, terms = energy(problem, pack(p0, R0, q0), contacts)
        without, _ = energy(problem, pack(p0, R0, q0), contacts, w_fc=0.0)
        with_fc_only = without + 20.0 * terms["fc"]
        assert torch.allclose(total - with_fc_only, 10.0 * terms["opposition"], rtol=1e-9, atol=1e-12)
        assert 0.0 <= float(terms["opposition"][0]) <= 1.5
