"""Div, the diversity of grasps (paper §"Pre-Grasp Proposals"; DESIGN §6).

Div = (1 / J) sum_j std_i(q_ij) in degrees: the standard deviation of each joint angle over the N grasp
samples, averaged over the J joints.  The population standard deviation is used,
std_j = sqrt((1 / N) sum_i (q_ij - mean_j)^2), so a set of identical grasps has Div = 0 and two grasps
at q and q + 2a have Div = a.  (The paper's text says "average variance"; its reported values, ~9 deg,
are in degrees, the unit of a standard deviation, as DESIGN §6 reads it.)
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from components.errors import MultigraspError


def per_joint_std_deg(q: Tensor) -> Tensor:
    """Population standard deviation of every joint over the samples, in degrees.   q (N, J) rad -> (J,)."""
    if q.dim() != 2 or q.shape[0] == 0:
        raise MultigraspError(f"diversity needs joint angles of shape (samples, joints), got {tuple(q.shape)}")
    return torch.rad2deg(q.double().std(dim=0, unbiased=False))


def joint_diversity_deg(q: Tensor) -> float:
    """Div = mean over joints of :func:`per_joint_std_deg` (deg).   q (N, J) rad -> float."""
    value = float(per_joint_std_deg(q).mean())
    return value if math.isfinite(value) else 0.0
