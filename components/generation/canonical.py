"""Palm alignment (paper §"Multi-object Grasp Generation", Fig. palm-align; DESIGN §5.2).

Training data are rotated about the world z axis so that the palm direction, projected on the table,
points along +x; the generator then learns palm-aligned grasps, and a desired palm direction is obtained
at generation time by rotating the objects into the aligned frame and the generated hand back.

    palm direction   n = -R e_y                      (the palm normal, -y of the palm frame; components.hand)
    yaw              theta = atan2(n_y, n_x)         (of its projection on the table)
    to aligned       x' = Rz(-theta) (x - c),   p' = Rz(-theta) (p - c),   R' = Rz(-theta) R
    back             x  = Rz(theta) x' + c,     p  = Rz(theta) p' + c,     R  = Rz(theta) R'

with c = (c_x, c_y, 0) an optional vertical pivot (e.g. the objects' centroid: the aligned frame then
also removes the scene's position on the table; heights are kept).  A palm pointing straight down has
no projected direction: theta = atan2(0, 0) = 0 there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor


def palm_direction(R: Tensor) -> Tensor:
    """n = -R e_y, the palm normal in the world.   R (B, 3, 3) -> (B, 3)."""
    return -R[..., :, 1]


def yaw_of(direction: Tensor) -> Tensor:
    """theta = atan2(d_y, d_x) of the projection of a direction on the table.   (B, 2 or 3) -> (B,)."""
    return torch.atan2(direction[..., 1], direction[..., 0])


def rotation_z(angle: Tensor) -> Tensor:
    """Rz(a) = [[cos a, -sin a, 0], [sin a, cos a, 0], [0, 0, 1]].   (B,) -> (B, 3, 3)."""
    c, s = angle.cos(), angle.sin()
    zero, one = torch.zeros_like(angle), torch.ones_like(angle)
    return torch.stack([torch.stack([c, -s, zero], -1), torch.stack([s, c, zero], -1),
                        torch.stack([zero, zero, one], -1)], dim=-2)


@dataclass
class AlignedFrame:
    """The rotation about a vertical axis through ``pivot`` (B, 3) (z = 0) by -``yaw`` (B,) (module docstring)."""

    yaw: Tensor
    pivot: Tensor

    @classmethod
    def from_yaw(cls, yaw: Tensor, pivot: Optional[Tensor] = None) -> "AlignedFrame":
        """Frame that maps the direction of angle ``yaw`` (B,) on the table to +x; pivot (B, 3) or None (origin)."""
        if pivot is None:
            pivot = yaw.new_zeros(yaw.shape[0], 3)
        pivot = torch.cat([pivot[:, :2], torch.zeros_like(pivot[:, 2:])], dim=-1)
        return cls(yaw=yaw, pivot=pivot)

    @classmethod
    def from_palm(cls, R: Tensor, pivot: Optional[Tensor] = None) -> "AlignedFrame":
        """Frame of the training alignment: the hand's own palm direction goes to +x.   R (B, 3, 3)."""
        return cls.from_yaw(yaw_of(palm_direction(R)), pivot)

    @classmethod
    def from_direction(cls, direction: Tensor, pivot: Optional[Tensor] = None) -> "AlignedFrame":
        """Frame of generation: a desired palm direction (B, 2 or 3) goes to +x."""
        return cls.from_yaw(yaw_of(direction), pivot)

    @property
    def to_aligned_rotation(self) -> Tensor:
        """Rz(-theta) (B, 3, 3)."""
        return rotation_z(-self.yaw)

    def points_to_aligned(self, x: Tensor) -> Tensor:
        """x' = Rz(-theta) (x - c).   (B, ..., 3) -> (B, ..., 3)."""
        return self._apply(x - self._bcast(self.pivot, x), rotation_z(-self.yaw))

    def points_from_aligned(self, x: Tensor) -> Tensor:
        """x = Rz(theta) x' + c.   (B, ..., 3) -> (B, ..., 3)."""
        return self._apply(x, rotation_z(self.yaw)) + self._bcast(self.pivot, x)

    def pose_to_aligned(self, p: Tensor, R: Tensor) -> tuple[Tensor, Tensor]:
        """(p', R') = (Rz(-theta)(p - c), Rz(-theta) R).   p (B, 3), R (B, 3, 3)."""
        return self.points_to_aligned(p), rotation_z(-self.yaw).to(R.dtype) @ R

    def pose_from_aligned(self, p: Tensor, R: Tensor) -> tuple[Tensor, Tensor]:
        """(p, R) = (Rz(theta) p' + c, Rz(theta) R').   p (B, 3), R (B, 3, 3)."""
        return self.points_from_aligned(p), rotation_z(self.yaw).to(R.dtype) @ R

    @staticmethod
    def _bcast(v: Tensor, like: Tensor) -> Tensor:
        """(B, 3) -> (B, 1, ..., 1, 3) to broadcast against like (B, ..., 3)."""
        return v.reshape(v.shape[0], *([1] * (like.dim() - 2)), 3).to(like.dtype)

    @staticmethod
    def _apply(x: Tensor, rot: Tensor) -> Tensor:
        """y = rot x for x (B, ..., 3), rot (B, 3, 3)."""
        flat = x.reshape(x.shape[0], -1, 3)  # (B, N, 3)
        return (flat @ rot.to(x.dtype).transpose(1, 2)).reshape(x.shape)
