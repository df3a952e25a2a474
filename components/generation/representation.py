"""Hand representations the generator diffuses (DESIGN §5.2; ``GeneratorConfig.representation``):

* ``keypoints``: the 31 keypoints of ``HandModel.keypoints``, flattened  x = vec(K) (B, 93) (m); back to
  (p, R, q) by :func:`components.generation.ik.solve_ik`.
* ``joints``: x = (p, rot6d, q) (B, 31) of :mod:`components.synthesis.pose`; back by Gram-Schmidt, the joints
  clamped to their limits and the J0s recomputed from J1 (coupling).
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from components.generation.config import IKConfig
from components.generation.ik import solve_ik
from components.hand import HandModel
from components.synthesis.pose import pack, unpack

Representation = Literal["keypoints", "joints"]


def representation_dim(kind: Representation) -> int:
    """D: 93 for keypoints, 31 for (p, rot6d, q)."""
    return 93 if kind == "keypoints" else 31


def to_representation(hand: HandModel, p: Tensor, R: Tensor, q: Tensor, kind: Representation) -> Tensor:
    """(p (B, 3), R (B, 3, 3), q (B, 22)) -> x (B, D)."""
    if kind == "keypoints":
        return hand.keypoints(p, R, q).reshape(p.shape[0], -1)
    return pack(p, R, q)


def from_representation(hand: HandModel, x: Tensor, kind: Representation, ik: IKConfig) -> tuple[Tensor, Tensor, Tensor]:
    """x (B, D) -> (p (B, 3), R (B, 3, 3), q (B, 22)) within the joint limits and coupled."""
    if kind == "keypoints":
        result = solve_ik(hand, x.reshape(x.shape[0], 31, 3), ik)
        return result.p, result.R, result.q
    p, R, q = unpack(x.to(hand.dtype))
    lower, upper = hand.joint_limits.unbind(-1)
    q = hand.expand_actuated(hand.actuated(torch.maximum(torch.minimum(q, upper), lower)))
    return p, R, q
