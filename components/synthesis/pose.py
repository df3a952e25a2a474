"""The optimisation variable of synthesis: a hand pose H = (p, R, q) as one flat vector.

x = [p (3) | r6 (6) | q (22)]  (B, 31): the palm position (m), the 6-D continuous rotation
representation of Zhou et al. (CVPR 2019, "On the continuity of rotation representations": the first
two columns of R, re-orthonormalised by Gram-Schmidt) and the joint angles (rad, ``HandModel.joint_names``
order).  DESIGN §4 "Hand": R is stored as the 6-D representation during optimisation.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

#: Slices of the flat pose vector.
TRANSLATION = slice(0, 3)
ROTATION = slice(3, 9)
JOINTS = slice(9, None)


def rot6d_to_matrix(r6: Tensor) -> Tensor:
    """Gram-Schmidt:  c1 = a1 / |a1|,  c2 = (a2 - (c1.a2) c1) / |.|,  c3 = c1 x c2,  R = [c1 c2 c3].
    r6 = (a1, a2) (..., 6) -> R (..., 3, 3)."""
    a1, a2 = r6[..., :3], r6[..., 3:]
    c1 = F.normalize(a1, dim=-1)
    c2 = F.normalize(a2 - (c1 * a2).sum(-1, keepdim=True) * c1, dim=-1)
    c3 = torch.cross(c1, c2, dim=-1)
    return torch.stack([c1, c2, c3], dim=-1)


def matrix_to_rot6d(R: Tensor) -> Tensor:
    """The first two columns of R:  (..., 3, 3) -> (..., 6)."""
    return torch.cat([R[..., :, 0], R[..., :, 1]], dim=-1)


def pack(p: Tensor, R: Tensor, q: Tensor) -> Tensor:
    """(p (B, 3), R (B, 3, 3), q (B, J)) -> x (B, 9 + J)."""
    return torch.cat([p, matrix_to_rot6d(R), q], dim=-1)


def unpack(x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """x (B, 9 + J) -> (p (B, 3), R (B, 3, 3), q (B, J))."""
    return x[:, TRANSLATION], rot6d_to_matrix(x[:, ROTATION]), x[:, JOINTS]
