"""E_q1, the smooth Ferrari-Canny Q1 of synthesis (``w_q1``): analytic cases against the metric, the weakest-direction
refinement, the contact band, and its place in the total energy."""

import numpy as np
import pytest
import torch

from components.metrics import MetricsConfig
from components.metrics.q1 import q1_single_object
from components.synthesis import GraspProblem, SynthesisConfig, energy, pack
from components.synthesis.energy import q1_surrogate, wrench_directions

from tests.test_synthesis_energy import finger_in_sphere_pose

DTYPE = torch.float64
RADIUS = 0.05
AXES = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])


def surrogate(directions_n: int = 64, keep: int = 8, steps: int = 15, rows=slice(None), offsets_m=None,
              temperature: float = 0.003) -> float:
    """Q1~ of contacts on a ball of radius RADIUS at the points AXES[rows] * RADIUS (optionally lifted off by
    ``offsets_m``), friction 0.5, band 5 mm, the default search (64 directions, 8 refined by 15 steps)."""
    normals = torch.tensor(AXES[rows], dtype=DTYPE).unsqueeze(0)
    offsets = torch.zeros(normals.shape[:2], dtype=DTYPE) if offsets_m is None else torch.tensor([offsets_m], dtype=DTYPE)
    points = normals * (RADIUS + offsets.unsqueeze(-1))
    value = q1_surrogate(points, offsets, normals, torch.zeros(3, dtype=DTYPE), torch.tensor(RADIUS, dtype=DTYPE),
                         wrench_directions(directions_n, 0, DTYPE), 0.005, 0.5, temperature, keep, steps)
    return float(value[0])


def fine_metric(n: int) -> float:
    """The metric's Q1 of the first ``n`` contacts of AXES, with 64-edge cones (within 0.1 % of circular ones)."""
    return q1_single_object(AXES[:n] * RADIUS, AXES[:n], np.zeros(3), RADIUS, MetricsConfig(friction_cone_edges=64))


def test_contacts_on_a_ball_match_the_metric_with_fine_friction_cones():
    # 2, 3, 4 and 6 of the six axis contacts: Q1 0, 0.141, 0.330, 0.408; the search leaves the surrogate ~0.01 above
    counts = (2, 3, 4, 6)
    values = [surrogate(rows=slice(0, n)) for n in counts]
    metric = [fine_metric(n) for n in counts]
    assert metric[0] == 0.0 and metric[1] < metric[2] < metric[3]
    assert np.allclose(values, metric, atol=0.015)
    assert values[1] < values[2] < values[3]
    # the default 8-gon cones give the same six-contact value (their edges lie on the axes)
    assert q1_single_object(AXES * RADIUS, AXES, np.zeros(3), RADIUS, MetricsConfig()) == pytest.approx(metric[3])


def test_the_weakest_direction_search_finds_the_narrow_gap_that_random_directions_miss():
    # +x and -x resist no torque about x: Q1 = 0; the 64 random directions alone read it well above 0
    assert surrogate(rows=slice(0, 2), keep=0) > 0.05
    assert surrogate(rows=slice(0, 2)) < 0.02
    assert surrogate(keep=0) > surrogate() > fine_metric(6)  # the soft minimum over more directions comes lower


def test_a_sample_beyond_the_band_counts_for_nothing_and_one_half_in_it_for_half():
    five = surrogate(rows=slice(1, 6))  # without the +x contact
    assert surrogate(offsets_m=[0.01, 0, 0, 0, 0, 0]) == pytest.approx(five, abs=1e-9)  # +x 1 cm off: ignored
    half = surrogate(offsets_m=[0.0025, 0, 0, 0, 0, 0])  # 2.5 mm off: its wrenches at half length
    assert five < half < surrogate()
    sunk = surrogate(offsets_m=[-0.0025, 0, 0, 0, 0, 0])  # 2.5 mm inside: half as well (no reward for sinking in)
    assert sunk == pytest.approx(half, abs=1e-6)


def test_the_gradient_pulls_a_hovering_contact_onto_the_surface():
    normals = torch.tensor(AXES, dtype=DTYPE).unsqueeze(0)
    offsets = torch.tensor([[0.002, 0, 0, 0, 0, 0]], dtype=DTYPE, requires_grad=True)
    points = normals * (RADIUS + offsets.detach().unsqueeze(-1))
    value = q1_surrogate(points, offsets, normals, torch.zeros(3, dtype=DTYPE), torch.tensor(RADIUS, dtype=DTYPE),
                         wrench_directions(256, 0, DTYPE), 0.005, 0.5, 0.003)
    (grad,) = torch.autograd.grad(value.sum(), offsets)
    assert float(grad[0, 0]) < 0.0  # less distance, more Q1


def test_w_q1_enters_the_total_as_a_hinge_and_the_approach_stage_leaves_it_out(hand, library):
    p0, R0, q0, objects = finger_in_sphere_pose(hand, library, overlap=0.001)  # one finger touches: no closure
    cfg = SynthesisConfig(batch_size=1, w_q1=2.0, q1_target=0.4)
    problem = GraspProblem.build(hand, objects, cfg)
    contacts = torch.tensor([[[0, 50, 100]]])
    total, terms = energy(problem, pack(p0, R0, q0), contacts)
    without, off = energy(problem, pack(p0, R0, q0), contacts, w_q1=0.0)
    assert float(terms["q1"][0]) >= 0.4 - 1e-6  # relu(0.4 - Q1~) with Q1~ <= 0 for a one-sided touch
    assert float(off["q1"][0]) == 0.0
    assert torch.allclose(total - without, 2.0 * terms["q1"], rtol=1e-9)
    with pytest.raises(ValueError):
        SynthesisConfig(q1_stages="everywhere")
