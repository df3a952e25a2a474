"""Q1 (Ferrari-Canny): analytic grasps of a sphere, degenerate grasps, invariance, and the batched version."""

import math

import numpy as np
import pytest
import torch

from components.metrics import MetricsConfig, primitive_wrenches, q1_from_wrenches, q1_grasps, q1_single_object
from components.objects import Placement, Scene
from components.synthesis import SceneObjects

RADIUS = 0.025  # m
AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
RANK_TOL = MetricsConfig().q1_rank_tolerance


def six_axis_q1(mu: float, edges: int, centre=np.zeros(3)) -> float:
    """Six contacts at +-x, +-y, +-z of a sphere, forces along the inward normals."""
    cfg = MetricsConfig(friction_coefficient=mu, friction_cone_edges=edges)
    return q1_single_object(centre + RADIUS * AXES, AXES, centre, RADIUS, cfg)


@pytest.mark.parametrize("mu", [0.1, 0.5, 1.0])
def test_q1_of_six_axis_contacts_on_a_sphere_matches_the_analytic_value(mu):
    # Q1 = min over unit u of the support function h(u) = max_i u . w_i.  Normal forces through the centre
    # carry no torque, so only friction twists the sphere; along the torque diagonal u* = (0, 0, 0, 1, 1, 1)/sqrt(3):
    # * 4 edges aligned with the axes: every edge torque is +-mu along one axis, h(u*) = mu / sqrt(3);
    # * 8 edges: the 45-degree edge of each contact points along the projection of u* on its tangent plane,
    #   |proj| = sqrt(2/3), so h(u*) = mu sqrt(2/3).
    # The hull's nearest facet is the one normal to u*: Q1 equals h(u*).
    assert six_axis_q1(mu, 4) == pytest.approx(mu / math.sqrt(3.0), rel=1e-9)
    assert six_axis_q1(mu, 8) == pytest.approx(mu * math.sqrt(2.0 / 3.0), rel=1e-9)
    # independent lower bound for 4 edges: h(u) >= max(|v|_inf, mu |m|_inf) for u = (v, m)
    assert six_axis_q1(mu, 4) >= mu / math.sqrt(3.0 * (1.0 + mu * mu)) - 1e-12


def test_q1_is_the_minimum_of_the_support_function_over_directions():
    mu, edges = 0.5, 8
    wrenches = primitive_wrenches(RADIUS * AXES, AXES, np.zeros(3), RADIUS, mu, edges)
    q1 = q1_from_wrenches(wrenches, RANK_TOL)
    directions = np.random.default_rng(0).normal(size=(20000, 6))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    support = (directions @ wrenches.T).max(axis=1)  # h(u) for every sampled u
    assert q1 > 0.0
    assert support.min() >= q1 - 1e-9  # the inscribed ball fits under every supporting hyperplane
    assert support.min() <= 1.5 * q1  # and random directions come close to it


def test_one_or_two_contacts_have_zero_q1():
    cfg = MetricsConfig()
    x = RADIUS * AXES
    assert q1_single_object(x[:1], AXES[:1], np.zeros(3), RADIUS, cfg) == 0.0
    # two antipodal point contacts cannot resist a torque about the line joining them (rank-deficient)
    assert q1_single_object(x[:2], AXES[:2], np.zeros(3), RADIUS, cfg) == 0.0
    assert q1_single_object(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(3), RADIUS, cfg) == 0.0


def test_contacts_on_one_hemisphere_have_zero_q1():
    # every outward normal points up, so every contact force (along -n, within the cone) pushes down:
    # nothing can lift the object, the origin is outside the wrench hull
    rng = np.random.default_rng(1)
    normals = rng.normal(size=(12, 3))
    normals[:, 2] = np.abs(normals[:, 2]) + 2.0
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    assert q1_single_object(RADIUS * normals, normals, np.zeros(3), RADIUS, MetricsConfig(friction_coefficient=0.1)) == 0.0


def test_q1_is_invariant_to_translating_the_object_and_its_contacts():
    rng = np.random.default_rng(2)
    normals = rng.normal(size=(10, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cfg = MetricsConfig()
    here = q1_single_object(RADIUS * normals, normals, np.zeros(3), RADIUS, cfg)
    shift = np.array([0.3, -0.2, 0.5])
    there = q1_single_object(RADIUS * normals + shift, normals, shift, RADIUS, cfg)
    assert here > 0.0
    assert there == pytest.approx(here, rel=1e-9)


def test_q1_grows_with_friction_and_is_scale_free():
    assert six_axis_q1(0.2, 8) < six_axis_q1(0.6, 8)
    cfg = MetricsConfig()
    big = q1_single_object(3 * RADIUS * AXES, AXES, np.zeros(3), 3 * RADIUS, cfg)  # torques normalised by radius
    assert big == pytest.approx(six_axis_q1(cfg.friction_coefficient, cfg.friction_cone_edges), rel=1e-9)


# ----------------------------------------------------------------------------- batched, with the hand


# hand (float64) and library (cube, cylinder, sphere): session fixtures of tests/conftest.py


def test_q1_grasps_is_invariant_to_moving_hand_and_objects_together(hand, library):
    # a sphere pressed into the palm between the fingers: many hand samples within 5 mm of it
    p = torch.tensor([[0.0, 0.0, 0.3]], dtype=torch.float64)
    R = torch.eye(3, dtype=torch.float64).unsqueeze(0)
    q = hand.open_pose().unsqueeze(0)
    q[0, [1, 2, 5, 6, 9, 10, 14, 15]] = 1.2  # curl the fingers
    centre = (0.0, -0.035, 0.38)
    cfg = MetricsConfig(q1_max_contacts=12)
    shift = torch.tensor([0.2, -0.1, 0.05], dtype=torch.float64)
    values = []
    for offset in (torch.zeros(3, dtype=torch.float64), shift):
        scene = Scene(objects=(Placement("sphere", tuple((torch.tensor(centre) + offset).tolist()), (0.0, 0.0, 0.0, 1.0)),))
        objects = SceneObjects(library, scene, dtype=torch.float64)
        q1, per_object = q1_grasps(hand, objects, p + offset, R, q, cfg)
        assert q1.shape == (1,) and per_object.shape == (1, 1)
        values.append(float(q1[0]))
    assert values[0] > 0.0  # the curled fingers and the palm hold the sphere
    assert values[1] == pytest.approx(values[0], abs=1e-9)


def test_contacts_without_a_defined_normal_are_skipped_not_fatal():
    from components.metrics import MetricsConfig
    from components.metrics.q1 import object_contacts

    distances = np.array([0.001, -0.002, 0.0])
    points = np.array([[0.02, 0.0, 0.0], [-0.018, 0.0, 0.0], [0.0, 0.0, 0.0]])
    normals = np.array([[2.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # last: zero gradient
    surface, normal = object_contacts(distances, points, normals, MetricsConfig())
    assert len(surface) == 2
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0)
    assert np.allclose(surface[0], [0.019, 0.0, 0.0])


# ----------------------------------------------------------------------------- other Q1 conventions


def test_torque_scale_replaces_the_radius_normalisation():
    cfg = MetricsConfig()
    by_radius = q1_single_object(RADIUS * AXES, AXES, np.zeros(3), RADIUS, cfg)
    # lambda = 1 / r is the same wrench set
    same = q1_single_object(RADIUS * AXES, AXES, np.zeros(3), RADIUS, MetricsConfig(q1_torque_scale_per_m=1.0 / RADIUS))
    assert same == pytest.approx(by_radius, rel=1e-9)
    # six axis contacts: only friction twists the sphere, torque rows are lambda r mu-sized, so a smaller
    # lambda r shrinks Q1 in proportion (it is set by the torque directions): lambda r = 0.25 -> Q1 / 4
    small = q1_single_object(RADIUS * AXES, AXES, np.zeros(3), RADIUS, MetricsConfig(q1_torque_scale_per_m=0.25 / RADIUS))
    assert small == pytest.approx(by_radius / 4.0, rel=1e-6)


def test_per_link_mode_keeps_the_nearest_touching_sample_of_each_link():
    from components.metrics.q1 import object_contacts

    cfg = MetricsConfig(q1_contact_mode="per_link", contact_distance_m=0.01)
    distances = np.array([0.004, 0.001, 0.02, 0.003, 0.009, -0.001])
    links = np.array([0, 0, 1, 1, 2, 2])
    points = np.stack([np.full(3, float(k)) for k in range(6)])
    normals = np.tile([0.0, 0.0, 1.0], (6, 1))
    surface, normal = object_contacts(distances, points, normals, cfg, links)
    # link 0: sample 1 (1 mm); link 1: sample 3 (sample 2 is 2 cm away); link 2: sample 5 (inside)
    expected = points[[1, 3, 5]] - distances[[1, 3, 5], None] * normals[[1, 3, 5]]
    assert np.allclose(surface, expected)
    with pytest.raises(ValueError, match="link index"):
        object_contacts(distances, points, normals, cfg)


def test_per_link_q1_of_a_held_sphere_is_positive(hand, library):
    # the curled fingers and the palm around a sphere: one contact per touching link still makes force closure
    p = torch.tensor([[0.0, 0.0, 0.3]], dtype=torch.float64)
    R = torch.eye(3, dtype=torch.float64).unsqueeze(0)
    q = hand.open_pose().unsqueeze(0)
    q[0, [1, 2, 5, 6, 9, 10, 14, 15]] = 1.2
    scene = Scene(objects=(Placement("sphere", (0.0, -0.035, 0.38), (0.0, 0.0, 0.0, 1.0)),))
    objects = SceneObjects(library, scene, dtype=torch.float64)
    per_link, _ = q1_grasps(hand, objects, p, R, q, MetricsConfig(q1_contact_mode="per_link", contact_distance_m=0.01))
    assert float(per_link[0]) > 0.0
    # the same sphere 20 cm away: no link within 1 cm, Q1 = 0
    far = SceneObjects(library, Scene(objects=(Placement("sphere", (0.2, -0.035, 0.38), (0.0, 0.0, 0.0, 1.0)),)),
                       dtype=torch.float64)
    none, _ = q1_grasps(hand, far, p, R, q, MetricsConfig(q1_contact_mode="per_link", contact_distance_m=0.01))
    assert float(none[0]) == 0.0


def test_group_q1_of_a_sphere_grasp_split_between_two_objects_is_the_whole_grasps_q1():
    # the six-axis grasp of a sphere, its contacts split between two "objects" (the +x/+y/+z half and the
    # -x/-y/-z half): neither half is in force closure on its own (Q1 0), the group -- both halves about their
    # common centre, with the sphere's radius as the group radius -- is the whole grasp.
    from components.metrics.q1 import q1_group

    cfg = MetricsConfig()
    x = RADIUS * AXES
    halves = [(x[0::2], AXES[0::2]), (x[1::2], AXES[1::2])]
    for points, normals in halves:
        assert q1_single_object(points, normals, np.zeros(3), RADIUS, cfg) == 0.0
    whole = q1_single_object(x, AXES, np.zeros(3), RADIUS, cfg)
    assert whole > 0.0
    assert q1_group(halves, np.zeros(3), RADIUS, cfg) == pytest.approx(whole, rel=1e-12)


# ----------------------------------------------------------------------------- the exact solver over every contact


def _sphere_contacts(n: int, seed: int, upper_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
    normals = np.random.default_rng(seed).normal(size=(n, 3))
    if upper_only:  # within ~20 degrees of +z: every cone of friction 0.5 (26.6 degrees) pushes down
        normals[:, 2] = np.abs(normals[:, 2]) + 3.0
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return RADIUS * normals, normals


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_constraint_generation_finds_the_hull_of_every_wrench_from_a_small_start(seed):
    from components.metrics.q1 import q1_constraint_generation

    points, normals = _sphere_contacts(40, seed)
    wrenches = primitive_wrenches(points, normals, np.zeros(3), RADIUS, 0.5, 8)  # 320 wrenches: qhull takes them all
    whole = q1_from_wrenches(wrenches, RANK_TOL)
    exact, rounds = q1_constraint_generation(wrenches, np.arange(4 * 8), RANK_TOL, rounds=100, facets=16)
    assert whole > 0.0 and exact == pytest.approx(whole, abs=1e-9)
    assert 1 < rounds < 100  # it had to grow the start, and stopped before the fallback
    # a start that holds every wrench stops in one round
    assert q1_constraint_generation(wrenches, np.arange(len(wrenches)), RANK_TOL, 100, 16) == (pytest.approx(whole), 1)


def test_constraint_generation_reports_no_closure_as_zero():
    from components.metrics.q1 import q1_constraint_generation

    points, normals = _sphere_contacts(30, 3, upper_only=True)  # every force pushes down
    wrenches = primitive_wrenches(points, normals, np.zeros(3), RADIUS, 0.5, 8)
    assert q1_constraint_generation(wrenches, np.arange(4 * 8), RANK_TOL, 100, 16)[0] == 0.0


def test_the_exact_solver_reads_every_contact_and_the_cap_a_lower_bound():
    points, normals = _sphere_contacts(60, 4)
    exact = q1_single_object(points, normals, np.zeros(3), RADIUS, MetricsConfig(q1_solver="exact", q1_exact_start=6))
    whole = q1_from_wrenches(primitive_wrenches(points, normals, np.zeros(3), RADIUS, 0.5, 8), RANK_TOL)
    assert exact == pytest.approx(whole, abs=1e-9)
    from components.metrics.q1 import object_contacts

    distances = np.zeros(len(points))  # every sample on the surface: all are contacts
    for cap in (6, 24):
        cfg = MetricsConfig(q1_solver="capped", q1_max_contacts=cap)
        subset, subset_normals = object_contacts(distances, points, normals, cfg)
        assert len(subset) == cap
        assert q1_single_object(subset, subset_normals, np.zeros(3), RADIUS, cfg) <= exact + 1e-12
    every, _ = object_contacts(distances, points, normals, MetricsConfig(q1_solver="exact", q1_exact_start=6))
    assert len(every) == 60
