"""Div: mean per-joint standard deviation of joint angles, in degrees."""

import math

import numpy as np
import pytest
import torch

from components.errors import MultigraspError
from components.metrics import joint_diversity_deg, per_joint_std_deg


def test_identical_samples_have_zero_diversity():
    q = torch.tensor([[0.1, -0.3, 1.2]]).repeat(50, 1)
    assert joint_diversity_deg(q) == pytest.approx(0.0, abs=1e-9)


def test_two_samples_2a_apart_have_diversity_a():
    a = math.radians(7.5)
    q = torch.tensor([[0.2, 0.5], [0.2 + 2 * a, 0.5 - 2 * a]])
    assert joint_diversity_deg(q) == pytest.approx(7.5, rel=1e-6)


def test_diversity_matches_numpy_population_std():
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, size=(200, 22)) * rng.uniform(0.0, 1.0, size=22)  # a different spread per joint
    expected = np.degrees(q.std(axis=0, ddof=0))
    assert per_joint_std_deg(torch.as_tensor(q)).numpy() == pytest.approx(expected, rel=1e-9)
    assert joint_diversity_deg(torch.as_tensor(q)) == pytest.approx(expected.mean(), rel=1e-9)


def test_wrong_shape_is_a_one_line_error():
    with pytest.raises(MultigraspError):
        joint_diversity_deg(torch.zeros(22))
