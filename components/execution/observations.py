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
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from components.execution.lift_config import LiftEnvConfig
from components.execution.lift_sim import N_JOINT_ACTIONS, N_WRENCH, WorldState, quat_conj_mul

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


def euler_of_quat(quat) -> tuple[float, float, float]:
    """:func:`euler_xyz` of one rotation given as a PyBullet quaternion (x, y, z, w), in plain Python floats: the
    same formula on the matrix entries written in the quaternion (R_21 = 2(yz + wx), R_22 = 1 - 2(x^2 + y^2),
    R_20 = 2(xz - wy), R_10 = 2(xy + wz), R_00 = 1 - 2(y^2 + z^2)).  ~1.5 us against ~20 us for the numpy formula
    between physics steps.  Not PyBullet's ``getEulerFromQuaternion``: it snaps rotations within 0.26 deg of
    pitch +-90 deg to roll 0 (a 4.5e-3 rad error there), which the definition above does not."""
    x, y, z, w = quat
    roll = math.atan2(2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(min(1.0, max(-1.0, -2.0 * (x * z - w * y))))
    yaw = math.atan2(2.0 * (x * y + w * z), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


_TWO_PI = 2.0 * math.pi


def _wrapped_difference(a, b) -> tuple[float, float, float]:
    """wrap_angle(a - b) of two 3-tuples in plain Python floats (same values as numpy's: both use floor modulo)."""
    return tuple((x - y + math.pi) % _TWO_PI - math.pi for x, y in zip(a, b))


@dataclass
class Goal:
    """The pre-grasp the policy is asked to keep: joint angles, palm rotation, object poses in the palm frame."""

    q: np.ndarray  # (22,)
    palm_rot: np.ndarray  # (3, 3)
    obj_pos_palm: np.ndarray  # (n_obj, 3)
    obj_rot_palm: np.ndarray  # (n_obj, 3, 3)
    # The same as tuples and quaternions for the per-step arithmetic in Python floats; derived from the arrays above
    # when not given (from_state gives PyBullet's own numbers).
    q_tuple: tuple = ()
    palm_quat: tuple = ()  # (x, y, z, w)
    obj_quat_palm: tuple = ()
    obj_pos_palm_tuples: tuple = ()

    def __post_init__(self) -> None:
        if not self.q_tuple:
            self.q_tuple = tuple(np.asarray(self.q, dtype=np.float64).tolist())
        if not self.palm_quat:
            self.palm_quat = tuple(Rotation.from_matrix(self.palm_rot).as_quat().tolist())
        if len(self.obj_quat_palm) != len(self.obj_rot_palm):
            self.obj_quat_palm = tuple(tuple(q) for q in Rotation.from_matrix(self.obj_rot_palm).as_quat().tolist()) \
                if len(self.obj_rot_palm) else ()
        if len(self.obj_pos_palm_tuples) != len(self.obj_pos_palm):
            self.obj_pos_palm_tuples = tuple(tuple(p) for p in np.asarray(self.obj_pos_palm, dtype=np.float64).tolist())

    @classmethod
    def from_state(cls, state: WorldState) -> "Goal":
        pos, rot = state.objects_in_palm
        pos_tuples, quats = state.objects_in_palm_pose
        return cls(q=state.q.copy(), palm_rot=state.palm_rot.copy(), obj_pos_palm=pos, obj_rot_palm=rot,
                   q_tuple=tuple(state.q_tuple), palm_quat=tuple(state.palm_quat), obj_quat_palm=tuple(quats),
                   obj_pos_palm_tuples=tuple(pos_tuples))


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
        # per-object slices, looked up once (not an f-string and a dict lookup per object and step)
        self._object_slices = [tuple(self.slices.get(f"object_{j}_{block}")
                                     for block in ("state", "pose_residue", "feature")) for j in range(n_objects)]
        self._buffer = np.zeros(start, dtype=np.float32)
        self._goal: Goal | None = None
        self._goal_euler: tuple = (0.0, 0.0, 0.0)
        self._goal_euler_palm: list = [(0.0, 0.0, 0.0)] * n_objects

    def start(self, goal: Goal) -> None:
        """Write the goal blocks of a new episode."""
        self._goal = goal
        if not self.cfg.goal_observations:
            return
        b, s = self._buffer, self.slices
        self._goal_euler = euler_of_quat(goal.palm_quat)
        self._goal_euler_palm = [euler_of_quat(quat) for quat in goal.obj_quat_palm]
        b[s["joint_goals"]] = goal.q
        b[s["orientation_goal"]] = self._goal_euler
        for j in range(self.n_objects):
            b[s[f"object_{j}_pose_goal"]] = (*goal.obj_pos_palm_tuples[j], *self._goal_euler_palm[j])

    def build(self, state: WorldState, last_action: np.ndarray, hand_feature: np.ndarray,
              object_features: np.ndarray) -> np.ndarray:
        """The observation of ``state`` (after :meth:`start`).  object_features (n_obj, feature_dim).  -> (D,) float32.
        Rotations become Euler angles from their quaternions (:func:`euler_of_quat`); the 3-vectors are written
        as tuples: between physics steps each numpy call costs 5-30 us, a PyBullet helper ~1 us."""
        if self._goal is None:
            raise RuntimeError("ObservationBuilder.build called before start(goal)")
        b, s, goal, goal_obs = self._buffer, self.slices, self._goal, self.cfg.goal_observations
        palm_euler = euler_of_quat(state.palm_quat)
        b[s["joint_angles"]] = state.q
        b[s["joint_velocities"]] = state.dq
        b[s["joint_forces"]] = state.tau
        b[s["fingertip_wrenches"]] = state.tip_wrench.reshape(-1)
        base = b[s["base_state"]]
        base[0:3], base[3:6], (base[6:9], base[9:12]) = state.palm_pos_tuple, palm_euler, state.palm_vel_tuples
        b[s["last_actions"]] = last_action
        if goal_obs:
            pos_palm, quat_palm = state.objects_in_palm_pose
            b[s["joint_residues"]] = state.q - goal.q
            b[s["orientation_residue"]] = _wrapped_difference(palm_euler, self._goal_euler)
        b[s["hand_feature"]] = hand_feature
        for j, (state_slice, residue_slice, feature_slice) in enumerate(self._object_slices):
            obj = b[state_slice]
            obj[0:3], obj[3:6], (obj[6:9], obj[9:12]) = (state.obj_pos_tuples[j], euler_of_quat(state.obj_quat[j]),
                                                         state.obj_vel_tuples[j])
            if goal_obs:
                residue = b[residue_slice]
                residue[0:3] = [x - y for x, y in zip(pos_palm[j], goal.obj_pos_palm_tuples[j])]
                residue[3:6] = _wrapped_difference(euler_of_quat(quat_palm[j]), self._goal_euler_palm[j])
            b[feature_slice] = object_features[j]
        return b.copy()


def rotation_angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Geodesic angle (rad) between two rotations:  arccos((tr(R_a^T R_b) - 1) / 2)."""
    cos = (float(np.vdot(R_a, R_b)) - 1.0) / 2.0  # tr(R_a^T R_b) = sum_ij (R_a)_ij (R_b)_ij
    return math.acos(min(1.0, max(-1.0, cos)))


def quaternion_angle(q_a, q_b) -> float:
    """:func:`rotation_angle` of two PyBullet quaternions (x, y, z, w):  2 atan2(|v|, |w|) of q_a^-1 q_b = (v, w)
    (the same angle; atan2 keeps full precision at small angles where the arccos of a trace loses ~1e-8 rad).
    ``components.objects.scenes`` measures the same angle with scipy (~30 us a call), fine for its once-per-scene
    settling check but not for every env step."""
    x, y, z, w = quat_conj_mul(q_a, q_b)
    return 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))


def lift_height(state: WorldState, start_heights: np.ndarray) -> float:
    """min_j (z_j - z_j(0)) (m): the lift of the lowest object."""
    return min(pos[2] - float(z0) for pos, z0 in zip(state.obj_pos_tuples, start_heights))  # Python: no numpy call


def worst_step_reward(cfg: LiftEnvConfig, n_objects: int, joint_ranges: Sequence[float],
                      start_heights: Sequence[float]) -> float:
    """A lower bound of one step's reward before an object falls: the lift of an object that started highest
    (``start_heights``, m) sunk to ``fall_height_m``, no bonus and, with goal observations, the palm turned by pi,
    every joint at the far end of its range (``joint_ranges``, rad) and every object displaced by
    ``object_distance_clip_m``.  The env adds the remaining steps times this to the step on which an object falls,
    as if the episode went on at the worst reward."""
    worst = -cfg.w_lift * max(0.0, max(start_heights, default=0.0) - cfg.fall_height_m)
    if cfg.goal_observations:
        worst -= (cfg.w_rotation * math.pi + cfg.w_joint * sum(joint_ranges) / len(joint_ranges)
                  + cfg.w_object * n_objects * cfg.object_distance_clip_m)
    return worst


def reward_terms(cfg: LiftEnvConfig, state: WorldState, goal: Goal, start_heights: np.ndarray) -> dict[str, float]:
    """The paper's reward (Eq. rl-rewards) and its terms:

        r = w_lift min(min_j h_j, lift_reward_cap) + w_succ 1[min_j h_j > success_height] + w_r r_r + w_q r_q + w_obj r_obj,
        h_j = z_j - z_j(0)  (no cap when lift_reward_cap_m is None, the paper's term),  r_r = -angle(R_goal^T R),  r_q = -mean |q - q_goal|,
        r_obj = -sum_j min(|p_j^palm - p_j^palm,goal|, object_distance_clip_m).

    Without goal observations ('w/o Goal') the three goal terms are off.  -> dict with 'reward' and terms.
    The rotations are compared as quaternions and the distances summed in plain Python: a handful of numbers, for
    which each numpy call would cost more than the arithmetic."""
    lift = lift_height(state, start_heights)
    success = float(lift > cfg.success_height_m)
    r_lift = lift if cfg.lift_reward_cap_m is None else min(lift, cfg.lift_reward_cap_m)
    terms = {"r_lift": r_lift, "r_success": success}
    reward = cfg.w_lift * r_lift + cfg.w_success * success
    if cfg.goal_observations:
        pos_palm, _ = state.objects_in_palm_pose
        terms["r_rot"] = -quaternion_angle(goal.palm_quat, state.palm_quat)
        terms["r_joint"] = -sum(abs(x - y) for x, y in zip(state.q_tuple, goal.q_tuple)) / len(goal.q_tuple)
        clip = cfg.object_distance_clip_m
        terms["r_object"] = -sum(min(math.dist(p, g), clip) for p, g in zip(pos_palm, goal.obj_pos_palm_tuples))
        reward += cfg.w_rotation * terms["r_rot"] + cfg.w_joint * terms["r_joint"] + cfg.w_object * terms["r_object"]
    terms["reward"] = reward
    terms["lift"] = lift
    return terms
