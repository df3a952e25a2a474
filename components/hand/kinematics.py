"""Forward kinematics of the 22-DoF Shadow Hand in the palm frame, and the J0-J1 coupling.

* **Chain.**  pytorch-kinematics ``build_chain_from_mjcf`` on the composed MJCF
  (:func:`components.hand.mjcf.compose_hand_xml`), rooted at the palm body, so its joints are exactly
  the 22 finger hinges (the palm's own hinge WRJ0 is dropped with the root, WRJ1 lies above it).
  pytorch-kinematics builds its offsets in float32; the chain is cast to the requested dtype
  and device explicitly (it does not follow its input's dtype).
* **Palm frame.**  The origin and axes of the MJCF body ``robot0:palm``: origin on the wrist axis
  WRJ0 at the base of the palm, +z along the middle finger, +x towards the thumb / first finger,
  -y out of the palm (the palm normal; fingers flex towards -y).  pytorch-kinematics applies the
  root body's own offset (palm in wrist, 34 mm along z) to every frame; it is removed with a
  constant left multiplication.
* **Wrist and forearm** are rigid in the palm frame while WRJ1 = WRJ0 = 0: their constant frames
  are appended after the 23 palm-and-finger frames when they are part of the model.
* **Link order** (``link_names``): palm, the 22 finger bodies in MJCF order (ffknuckle, ffproximal,
  ffmiddle, ffdistal, mf..., rf..., lfmetacarpal, lfknuckle, lf..., thbase, thproximal, thhub,
  thmiddle, thdistal), then wrist and forearm when ``include_forearm``; a finger link has the same
  index with or without the forearm.
* **Coupling.**  q[J0] = clamp(offset + ratio * q[J1], J0 range) on FF/MF/RF/LF (see
  :mod:`components.hand.mjcf` for where ratio = 0.00805 / 0.00705 comes from).
"""

import numpy as np
import pytorch_kinematics as pk
import torch
from torch import Tensor

from components.hand.mjcf import NAME_PREFIX, PALM_BODY, HandSpec, quat_to_matrix


def rigid_transform(pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """(4, 4) homogeneous matrix of x -> R(quat) x + pos (quat = w, x, y, z)."""
    mat = np.eye(4)
    mat[:3, :3] = quat_to_matrix(quat)
    mat[:3, 3] = pos
    return mat


def coupled_joint_angle(q_leader: Tensor, ratio: Tensor, offset: Tensor, lower: Tensor, upper: Tensor) -> Tensor:
    """Follower angle of a tendon coupling: q_f = clamp(offset + ratio * q_l, lower_f, upper_f)."""
    return torch.clamp(offset + ratio * q_leader, lower, upper)


def transform_points(transforms: Tensor, points: Tensor) -> Tensor:
    """Apply rigid transforms to points: y = R x + t.   transforms (..., 4, 4), points (..., 3) -> (..., 3)."""
    return (transforms[..., :3, :3] @ points.unsqueeze(-1)).squeeze(-1) + transforms[..., :3, 3]


class HandKinematics:
    """The pytorch-kinematics chain plus the index bookkeeping of the 22 / 18 joints and the links."""

    def __init__(self, spec: HandSpec, include_forearm: bool, device="cpu", dtype=torch.float32):
        self.device, self.dtype = torch.device(device), dtype
        chain = pk.build_chain_from_mjcf(spec.xml, body=NAME_PREFIX + PALM_BODY)
        self.chain = chain.to(dtype=dtype, device=self.device)

        self.joint_names = [j.name for j in spec.joints]  # (22,) MJCF order
        chain_joints = [n[len(NAME_PREFIX):] for n in self.chain.get_joint_parameter_names()]
        if chain_joints != self.joint_names:
            raise RuntimeError(f"pytorch-kinematics joint order {chain_joints} differs from the MJCF's")
        followers = {c.follower: c for c in spec.couplings}
        self.actuated_joint_names = [n for n in self.joint_names if n not in followers]  # (18,)

        finger_bodies = [b.name for b in spec.bodies if b.joint is not None]
        rigid_bodies = [b.name for b in spec.bodies if b.joint is None and b.name != PALM_BODY]
        self.link_names = [PALM_BODY] + finger_bodies + (rigid_bodies if include_forearm else [])
        self._frame_indices = self.chain.get_frame_indices(*[NAME_PREFIX + n for n in finger_bodies])

        # constant frames: palm-in-chain-root^-1 and the rigid wrist/forearm frames in the palm frame
        with torch.no_grad():
            root = self.chain.forward_kinematics_tensor(torch.zeros(1, len(self.joint_names), dtype=dtype,
                                                                    device=self.device))[0, 0]
        self._root_inv = torch.linalg.inv(root)  # (4, 4)
        rigid = [np.eye(4)]
        if include_forearm:
            pose_in_palm = {PALM_BODY: np.eye(4)}
            for body in spec.bodies:
                if body.name in rigid_bodies:
                    pose_in_palm[body.name] = pose_in_palm[body.parent] @ rigid_transform(body.pos, body.quat)
            rigid += [pose_in_palm[n] for n in rigid_bodies]
        self._palm_frame = torch.tensor(np.stack(rigid[:1]), dtype=dtype, device=self.device)  # (1, 4, 4)
        self._rigid_frames = torch.tensor(np.stack(rigid[1:]) if len(rigid) > 1 else np.zeros((0, 4, 4)),
                                          dtype=dtype, device=self.device)  # (0 or 2, 4, 4)

        limits = [[j.lower, j.upper] for j in spec.joints]
        self.joint_limits = torch.tensor(limits, dtype=dtype, device=self.device)  # (22, 2)
        index = {n: i for i, n in enumerate(self.joint_names)}
        self.actuated_index = torch.tensor([index[n] for n in self.actuated_joint_names], device=self.device)
        couplings = list(spec.couplings)
        self._follower_index = torch.tensor([index[c.follower] for c in couplings], device=self.device)
        self._leader_index = torch.tensor([index[c.leader] for c in couplings], device=self.device)
        self._ratio = torch.tensor([c.ratio for c in couplings], dtype=dtype, device=self.device)
        self._offset = torch.tensor([c.offset for c in couplings], dtype=dtype, device=self.device)

    # ---------------------------------------------------------------- coupling
    def expand_actuated(self, q18: Tensor) -> Tensor:
        """(..., 18) actuated angles -> (..., 22) with every J0 set from its J1 (:func:`coupled_joint_angle`)."""
        q22 = q18.new_zeros(*q18.shape[:-1], len(self.joint_names))
        q22 = q22.index_copy(-1, self.actuated_index, q18)
        lower, upper = self.joint_limits[self._follower_index].unbind(-1)
        follower = coupled_joint_angle(q22.index_select(-1, self._leader_index), self._ratio, self._offset,
                                       lower, upper)  # (..., 4)
        return q22.index_copy(-1, self._follower_index, follower)

    def actuated(self, q22: Tensor) -> Tensor:
        """(..., 22) joint angles -> the (..., 18) actuated ones (the J0s are dropped)."""
        return q22.index_select(-1, self.actuated_index)

    def coupling_violation(self, q22: Tensor) -> Tensor:
        """(..., 4) q[J0] - coupled_joint_angle(q[J1]): zero for a pose that respects the coupling."""
        lower, upper = self.joint_limits[self._follower_index].unbind(-1)
        expected = coupled_joint_angle(q22.index_select(-1, self._leader_index), self._ratio, self._offset,
                                       lower, upper)
        return q22.index_select(-1, self._follower_index) - expected

    # ---------------------------------------------------------------- FK
    def forward_kinematics(self, q: Tensor) -> Tensor:
        """Every link frame in the palm frame.   q (B, 22) -> (B, L, 4, 4), differentiable wrt q."""
        frames = self.chain.forward_kinematics_tensor(q)[self._frame_indices]  # (22, B, 4, 4) in chain root
        fingers = (self._root_inv @ frames).transpose(0, 1)  # (B, 22, 4, 4) in the palm frame
        batch = q.shape[0]
        palm = self._palm_frame.expand(batch, -1, -1, -1)  # (B, 1, 4, 4)
        rigid = self._rigid_frames.expand(batch, -1, -1, -1)  # (B, 0 or 2, 4, 4)
        return torch.cat([palm, fingers, rigid], dim=1)
