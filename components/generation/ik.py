"""Inverse kinematics: 31 keypoints -> hand pose H = (p, R, q) (paper §"Multi-object Grasp Generation":
"an optimization-based IK solver derives joint angles from these keypoints"; DESIGN §5.2).

1. **Palm frame** (:func:`kabsch`).  The 6 palm keypoints are fixed in the palm frame (``palm_*`` of
   ``assets/hand/keypoints.yaml``): their positions P (6, 3) in the palm frame and the targets Y (B, 6, 3)
   give the least-squares rigid fit  min_{R, p} sum_k |R P_k + p - Y_k|^2  (Kabsch / Procrustes).
2. **Joints** (:func:`solve_ik`).  The 18 actuated angles a (J0 of FF/MF/RF/LF coupled to J1 by
   ``HandModel.expand_actuated``) minimise the keypoint error

       E_ik(a) = sum_{k=1..31} |FK_k(p, R, expand(a)) - y_k|^2

   by batched Adam (cosine-decayed learning rate), a clamped to the joint limits after each step; with
   ``refit_palm`` (p, rot6d) are optimised too, starting from the Kabsch fit.  Several starts per target
   (``restarts``), the best final E_ik kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from components.generation.config import IKConfig
from components.hand import HandModel
from components.synthesis.pose import matrix_to_rot6d, rot6d_to_matrix

#: Prefix of the keypoints fixed on the palm.
PALM_KEYPOINT_PREFIX = "palm"


def palm_keypoint_indices(hand: HandModel) -> list[int]:
    """Indices (into ``hand.keypoint_names``) of the keypoints fixed on the palm."""
    return [i for i, n in enumerate(hand.keypoint_names) if n.startswith(PALM_KEYPOINT_PREFIX)]


def palm_keypoints_local(hand: HandModel) -> Tensor:
    """Palm keypoints in the palm frame (independent of q).   -> (P, 3)."""
    eye = torch.eye(3, dtype=hand.dtype, device=hand.device).unsqueeze(0)
    zero = torch.zeros(1, 3, dtype=hand.dtype, device=hand.device)
    return hand.keypoints(zero, eye, hand.open_pose().unsqueeze(0))[0, palm_keypoint_indices(hand)]


def kabsch(local: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """Least-squares rigid fit  min_{R in SO(3), p} sum_k |R x_k + p - y_k|^2:
    H = sum_k (x_k - xbar)(y_k - ybar)^T = U S V^T,  R = V diag(1, 1, det(V U^T)) U^T,  p = ybar - R xbar.
    local (P, 3) or (B, P, 3), target (B, P, 3) -> p (B, 3), R (B, 3, 3)."""
    local = local.expand_as(target)
    x_mean, y_mean = local.mean(1, keepdim=True), target.mean(1, keepdim=True)  # (B, 1, 3)
    cov = (local - x_mean).transpose(1, 2) @ (target - y_mean)  # (B, 3, 3) = H
    U, _, Vh = torch.linalg.svd(cov)
    V = Vh.transpose(1, 2)
    d = torch.det(V @ U.transpose(1, 2))  # (B,)
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], dim=-1))
    R = V @ D @ U.transpose(1, 2)
    p = y_mean.squeeze(1) - (R @ x_mean.transpose(1, 2)).squeeze(-1)
    return p, R


def keypoint_error(hand: HandModel, p: Tensor, R: Tensor, q: Tensor, target: Tensor) -> Tensor:
    """E_ik = sum_k |FK_k(p, R, q) - y_k|^2 (m^2).   target (B, 31, 3) -> (B,)."""
    return (hand.keypoints(p, R, q) - target).square().sum(-1).sum(-1)


@dataclass
class IKResult:
    """Solved poses: p (B, 3), R (B, 3, 3), q (B, 22) (coupled, within limits) and the per-row keypoint
    errors of the solution: ``mean_error`` and ``max_error`` (B,) in m."""

    p: Tensor
    R: Tensor
    q: Tensor
    mean_error: Tensor
    max_error: Tensor


def initial_actuated(hand: HandModel, cfg: IKConfig, batch: int, generator: torch.Generator) -> Tensor:
    """Starts of the 18 actuated angles, restart-major: (restarts B, 18).  Start 0: ``cfg.init``
    ('open' = 0, 'mid' = middle of the ranges); the others uniform in the ranges."""
    lower, upper = hand.actuated(hand.joint_limits.T)  # (18,), (18,)
    first = torch.zeros_like(lower) if cfg.init == "open" else 0.5 * (lower + upper)
    starts = [first.expand(batch, -1)]
    for _ in range(cfg.restarts - 1):
        u = torch.rand(batch, lower.shape[0], generator=generator, dtype=hand.dtype,
                       device=generator.device).to(hand.device)
        starts.append(lower + u * (upper - lower))
    return torch.cat(starts, dim=0)


def solve_ik(hand: HandModel, keypoints: Tensor, cfg: IKConfig) -> IKResult:
    """Keypoints (B, 31, 3) (``hand.keypoint_names`` order, world, m) -> :class:`IKResult` (module docstring)."""
    target = keypoints.to(hand.dtype)
    batch = target.shape[0]
    p0, R0 = kabsch(palm_keypoints_local(hand), target[:, palm_keypoint_indices(hand)])
    generator = torch.Generator(device="cpu").manual_seed(cfg.seed)
    n = cfg.restarts
    lower, upper = hand.actuated(hand.joint_limits.T)
    with torch.enable_grad():
        a = initial_actuated(hand, cfg, batch, generator).clone().requires_grad_(True)  # (n B, 18)
        p = p0.repeat(n, 1).clone().requires_grad_(cfg.refit_palm)  # (n B, 3)
        r6 = matrix_to_rot6d(R0).repeat(n, 1).clone().requires_grad_(cfg.refit_palm)  # (n B, 6)
        targets = target.repeat(n, 1, 1)
        groups = [{"params": [a], "lr": cfg.lr}]
        if cfg.refit_palm:
            groups += [{"params": [p], "lr": cfg.palm_lr_m}, {"params": [r6], "lr": cfg.palm_lr_rot}]
        optimiser = torch.optim.Adam(groups)
        base = [g["lr"] for g in optimiser.param_groups]
        for step in range(cfg.steps):
            decay = cfg.lr_final_fraction + (1 - cfg.lr_final_fraction) * 0.5 * (1 + math.cos(math.pi * step / max(cfg.steps, 1)))
            for g, lr in zip(optimiser.param_groups, base):
                g["lr"] = lr * decay
            loss = keypoint_error(hand, p, rot6d_to_matrix(r6), hand.expand_actuated(a), targets).sum()
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            with torch.no_grad():
                a.copy_(torch.maximum(torch.minimum(a, upper), lower))
    with torch.no_grad():
        R = rot6d_to_matrix(r6)
        q = hand.expand_actuated(a)
        dist = (hand.keypoints(p, R, q) - targets).norm(dim=-1)  # (n B, 31)
        err = dist.square().sum(-1).reshape(n, batch)
        best = err.argmin(0)  # (B,)
        rows = best * batch + torch.arange(batch, device=best.device)
        return IKResult(p=p.detach()[rows], R=R[rows], q=q[rows], mean_error=dist[rows].mean(-1),
                        max_error=dist[rows].amax(-1))
