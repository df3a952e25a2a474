"""The lift policy's observation, block by block as the paper's Table "Observation and action definitions"
(state-based policy).  :func:`observation_blocks` is the layout; :class:`ObservationBuilder` fills it.

==========================================  =============  =========================================
block                                        dims           definition
==========================================  =============  =========================================
joint_angles / joint_velocities / forces     22 x 3         q, dq (rad, rad/s), applied motor torque (N m)
fingertip_wrenches                           5 x 6          reaction force / torque at each distal joint
base_state                                   12             palm position, XYZ Euler, linear, angular velocity
last_actions                                 24             the previous action (zeros after reset)
joint_goals, joint_residues                  22 + 22        q_goal (the pre-grasp) and q - q_goal
orientation_goal, orientation_residue        3 + 3          XYZ Euler of R_goal and wrap(euler(R) - euler(R_goal))
hand_feature                                 256            encoder(hand cloud in the palm frame)
object_j_state                               12             position, XYZ Euler, linear, angular velocity (world)
object_j_pose_goal, object_j_pose_residue    6 + 6          pose of O_j in the palm frame at the pre-grasp, and
                                                            current - goal (position m, Euler wrapped)
object_j_feature                             256            encoder(object cloud in the palm frame)
==========================================  =============  =========================================

The goal blocks are dropped with ``goal_observations=False`` (the paper's "w/o Goal").  All blocks are
concatenated in the order above into one float vector; with 2 objects and goals it has 998 entries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from components.execution.lift_config import LiftEnvConfig
from components.execution.lift_sim import N_JOINT_ACTIONS, N_WRENCH, WorldState

N_JOINTS, N_TIPS = 22, 5


def observation_blocks(cfg: LiftEnvConfig, n_objects: int) -> list[tuple[str, int]]:
    """(name, dims) of every block, in order (module docstring)."""
    goal = cfg.goal_observations
    blocks = [("joint_angles", N_JOINTS), ("joint_velocities", N_JOINTS), ("joint_forces", N_JOINTS),
              ("fingertip_wrenches", N_TIPS * 6), ("base_state", 12), ("last_actions", N_JOINT_ACTIONS + N_WRENCH)]
    if goal:
        blocks += [("joint_goals", N_JOINTS), ("joint_residues", N_JOINTS),
                   ("orientation_goal", 3), ("orientation_residue", 3)]
    blocks.append(("hand_feature", cfg.feature_dim))
    for j in range(n_objects):
        blocks.append((f"object_{j}_state", 12))
        if goal:
            blocks += [(f"object_{j}_pose_goal", 6), (f"object_{j}_pose_residue", 6)]
        blocks.append((f"object_{j}_feature", cfg.feature_dim))
    return blocks


def observation_dim(cfg: LiftEnvConfig, n_objects: int) -> int:
    return sum(d for _, d in observation_blocks(cfg, n_objects))


def euler_xyz(R: np.ndarray) -> np.ndarray:
    """XYZ Euler angles (roll, pitch, yaw) (rad) of rotation matrices (..., 3, 3), the paper's orientation
    encoding (Isaac Gym's ``get_euler_xyz``; scipy's extrinsic ``'xyz'``):  R = Rz(yaw) Ry(pitch) Rx(roll),

        roll = atan2(R_21, R_22),  pitch = asin(-R_20),  yaw = atan2(R_10, R_00).

    Closed form in numpy: scipy's ``Rotation`` costs ~0.3 ms per call, more than a physics step."""
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


@dataclass
class Goal:
    """The pre-grasp the policy is asked to keep: joint angles, palm rotation, object poses in the palm frame."""

    q: np.ndarray  # (22,)
    palm_rot: np.ndarray  # (3, 3)
    obj_pos_palm: np.ndarray  # (n_obj, 3)
    obj_rot_palm: np.ndarray  # (n_obj, 3, 3)

    @classmethod
    def from_state(cls, state: WorldState) -> "Goal":
        pos, rot = state.objects_in_palm
        return cls(q=state.q.copy(), palm_rot=state.palm_rot.copy(), obj_pos_palm=pos, obj_rot_palm=rot)


class ObservationBuilder:
    """Fills the observation vector (module docstring) into one preallocated float32 buffer.

    The layout's slices are computed once; the goal blocks, constant over an episode, are written by
    :meth:`start`; :meth:`build` writes only the blocks that change and converts every rotation of the
    step to Euler angles in one vectorised call.  Each call returns a fresh copy (the rollout keeps it)."""

    def __init__(self, cfg: LiftEnvConfig, n_objects: int):
        self.cfg, self.n_objects = cfg, n_objects
        self.slices: dict[str, slice] = {}
        start = 0
        for name, dims in observation_blocks(cfg, n_objects):
            self.slices[name] = slice(start, start + dims)
            start += dims
        self._buffer = np.zeros(start, dtype=np.float32)
        self._goal: Goal | None = None
        self._goal_euler = np.zeros(3)
        self._goal_euler_palm = np.zeros((n_objects, 3))

    def start(self, goal: Goal) -> None:
        """Write the goal blocks of a new episode."""
        self._goal = goal
        if not self.cfg.goal_observations:
            return
        b, s = self._buffer, self.slices
        self._goal_euler = euler_xyz(goal.palm_rot)
        self._goal_euler_palm = euler_xyz(goal.obj_rot_palm)
        b[s["joint_goals"]] = goal.q
        b[s["orientation_goal"]] = self._goal_euler
        for j in range(self.n_objects):
            b[s[f"object_{j}_pose_goal"]] = np.concatenate([goal.obj_pos_palm[j], self._goal_euler_palm[j]])

    def build(self, state: WorldState, last_action: np.ndarray, hand_feature: np.ndarray,
              object_features: np.ndarray) -> np.ndarray:
        """The observation of ``state`` (after :meth:`start`).  object_features (n_obj, feature_dim).  -> (D,) float32."""
        if self._goal is None:
            raise RuntimeError("ObservationBuilder.build called before start(goal)")
        b, s, n, goal = self._buffer, self.slices, self.n_objects, self._goal
        pos_palm, rot_palm = state.objects_in_palm
        euler = euler_xyz(np.concatenate([state.palm_rot[None], state.obj_rot, rot_palm]))  # (1 + 2n, 3)
        b[s["joint_angles"]] = state.q
        b[s["joint_velocities"]] = state.dq
        b[s["joint_forces"]] = state.tau
        b[s["fingertip_wrenches"]] = state.tip_wrench.reshape(-1)
        base = b[s["base_state"]]
        base[0:3], base[3:6], base[6:9], base[9:12] = state.palm_pos, euler[0], state.palm_lin_vel, state.palm_ang_vel
        b[s["last_actions"]] = last_action
        if self.cfg.goal_observations:
            b[s["joint_residues"]] = state.q - goal.q
            b[s["orientation_residue"]] = wrap_angle(euler[0] - self._goal_euler)
        b[s["hand_feature"]] = hand_feature
        for j in range(n):
            obj = b[s[f"object_{j}_state"]]
            obj[0:3], obj[3:6], obj[6:9], obj[9:12] = (state.obj_pos[j], euler[1 + j], state.obj_lin_vel[j],
                                                       state.obj_ang_vel[j])
            if self.cfg.goal_observations:
                residue = b[s[f"object_{j}_pose_residue"]]
                residue[0:3] = pos_palm[j] - goal.obj_pos_palm[j]
                residue[3:6] = wrap_angle(euler[1 + n + j] - self._goal_euler_palm[j])
            b[s[f"object_{j}_feature"]] = object_features[j]
        return b.copy()


def rotation_angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Geodesic angle (rad) between two rotations:  arccos((tr(R_a^T R_b) - 1) / 2)."""
    cos = (float(np.vdot(R_a, R_b)) - 1.0) / 2.0  # tr(R_a^T R_b) = sum_ij (R_a)_ij (R_b)_ij
    return math.acos(min(1.0, max(-1.0, cos)))


def lift_height(state: WorldState, start_heights: np.ndarray) -> float:
    """min_j (z_j - z_j(0)) (m): the lift of the lowest object."""
    return float(min(state.obj_pos[:, 2] - start_heights))  # builtin min: np.min costs ~5 us on 2 entries


def reward_terms(cfg: LiftEnvConfig, state: WorldState, goal: Goal, start_heights: np.ndarray) -> dict[str, float]:
    """The paper's reward (Eq. rl-rewards) and its terms:

        r = w_lift min_j h_j + w_succ 1[min_j h_j > success_height] + w_r r_r + w_q r_q + w_obj r_obj,
        h_j = z_j - z_j(0),  r_r = -angle(R_goal^T R),  r_q = -mean |q - q_goal|,
        r_obj = -sum_j |p_j^palm - p_j^palm,goal|.

    Without goal observations ('w/o Goal') the three goal terms are off.  -> dict with 'reward' and terms."""
    lift = lift_height(state, start_heights)
    success = float(lift > cfg.success_height_m)
    terms = {"r_lift": lift, "r_success": success}
    reward = cfg.w_lift * lift + cfg.w_success * success
    if cfg.goal_observations:
        pos_palm, _ = state.objects_in_palm
        terms["r_rot"] = -rotation_angle(goal.palm_rot, state.palm_rot)
        terms["r_joint"] = -float(np.abs(state.q - goal.q).sum()) / len(goal.q)  # np.mean's overhead ~5 us
        offset = pos_palm - goal.obj_pos_palm
        terms["r_object"] = -float(np.sqrt(np.einsum("ij,ij->i", offset, offset)).sum())
        reward += cfg.w_rotation * terms["r_rot"] + cfg.w_joint * terms["r_joint"] + cfg.w_object * terms["r_object"]
    terms["reward"] = reward
    terms["lift"] = lift
    return terms
