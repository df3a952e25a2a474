"""The PyBullet world of the lift task: a free-floating Shadow Hand driven by a base wrench and joint
targets, a table, and the objects of one grasp record (paper §"Multi-object Grasp Execution").

One :class:`LiftWorld` owns one PyBullet client in DIRECT mode (no GUI, CPU).  The hand is loaded once
(the project's URDF, exported from the same MJCF as the FK); objects are created per record and reused
while consecutive records use the same objects.

Frames.  PyBullet reports a free base at its *centre of mass* (the URDF's inertial frame), not at the URDF
link frame; the palm frame of the FK is  T_palm = T_com * T_inertial^-1  with T_inertial the base's local
inertial frame (``getDynamicsInfo``).  Every pose this module takes or returns is the palm frame.

Actions (paper table: 24-D).  a[:18] in [-1, 1] moves the 18 actuated joint targets by
``joint_delta_rad * a`` per step (``joint_action_mode: delta``), or puts them at ``anchor + joint_offset_rad * a``
(``offset``; the anchor is the targets the episode starts from: the pre-grasp's angles, or the closure's targets);
J0 of FF/MF/RF/LF follows J1 (the tendon coupling); a[18:21] and a[21:24] are the
base force and torque in the world frame, times ``max_base_force_n`` / ``max_base_torque_nm``.  With
``gravity_compensation`` the hand's weight is cancelled at its centre of mass every physics step.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pybullet as pb
from scipy.spatial.transform import Rotation

from components.execution.cameras import CameraConfig, add_table
from components.execution.closure import closest_points, closure_targets, opposed_links
from components.execution.lift_config import LiftEnvConfig
from components.hand import HandModel
from components.objects import ObjectLibrary, Scene

#: Gravity (m/s^2) along -z.
GRAVITY = 9.81
#: Finger tips whose wrenches the policy observes, thumb last (paper table: 5 x 6).
FINGERTIPS = ("ff", "mf", "rf", "lf", "th")
#: Action layout: 18 joint-target deltas, then the 6-D base wrench (force, torque).
N_JOINT_ACTIONS, N_WRENCH = 18, 6


@dataclass
class GraspRecord:
    """A pre-grasp to lift: the scene (objects and placements) and the hand pose H = (p, R, q) in it."""

    scene: Scene
    p: np.ndarray  # (3,) palm position (m)
    R: np.ndarray  # (3, 3) palm rotation
    q: np.ndarray  # (22,) joint angles (rad)
    meta: dict = field(default_factory=dict)  # where it came from (scene id, split, ...)


@dataclass
class WorldState:
    """Everything the observation and reward read after a step (palm frame = FK palm frame).

    PyBullet gives poses and velocities as tuples; the state keeps them so (``*_tuple(s)``, quaternions (x, y, z, w))
    and builds the arrays (``palm_pos``, ``palm_rot``, ``obj_pos``, ...) only when read: the observation and the
    reward work on the tuples with Python floats and PyBullet's C helpers (~1 us a call), where each numpy call costs
    5-30 us between physics steps (benchmarks/sim.py)."""

    q: np.ndarray  # (22,) joint angles
    q_tuple: tuple  # the same as PyBullet's tuple (the reward's per-step sum runs on it)
    dq: np.ndarray  # (22,) joint velocities
    tau: np.ndarray  # (22,) applied motor torques
    tip_wrench: np.ndarray  # (5, 6) reaction force and torque at the joint of each fingertip link
    palm_pos_tuple: tuple  # (3,) palm frame origin (world)
    palm_quat: tuple  # (4,) palm frame rotation
    palm_vel_tuples: tuple  # ((3,), (3,)) linear and angular velocity of the hand's base (world)
    obj_pos_tuples: tuple  # n_obj x (3,) object origins (world)
    obj_quat: tuple  # n_obj x (4,)
    obj_vel_tuples: tuple  # n_obj x ((3,), (3,)) linear and angular velocities (world)
    #: PyBullet's ``getLinkStates`` of every hand link at this state (``LiftWorld.link_frames`` reads it), or None.
    link_states: tuple | None = field(default=None, repr=False)

    @cached_property
    def palm_pos(self) -> np.ndarray:
        """(3,)"""
        return np.array(self.palm_pos_tuple, dtype=np.float64)

    @cached_property
    def palm_rot(self) -> np.ndarray:
        """(3, 3)"""
        return np.array(self.palm_rot_tuple).reshape(3, 3)

    @cached_property
    def palm_lin_vel(self) -> np.ndarray:
        """(3,)"""
        return np.array(self.palm_vel_tuples[0], dtype=np.float64)

    @cached_property
    def palm_ang_vel(self) -> np.ndarray:
        """(3,)"""
        return np.array(self.palm_vel_tuples[1], dtype=np.float64)

    @cached_property
    def obj_pos(self) -> np.ndarray:
        """(n_obj, 3)"""
        return np.array(self.obj_pos_tuples, dtype=np.float64).reshape(-1, 3)

    @cached_property
    def obj_rot(self) -> np.ndarray:
        """(n_obj, 3, 3)"""
        return quat_matrices(self.obj_quat).reshape(-1, 3, 3)

    @cached_property
    def obj_lin_vel(self) -> np.ndarray:
        """(n_obj, 3)"""
        return np.array([v[0] for v in self.obj_vel_tuples], dtype=np.float64).reshape(-1, 3)

    @cached_property
    def obj_ang_vel(self) -> np.ndarray:
        """(n_obj, 3)"""
        return np.array([v[1] for v in self.obj_vel_tuples], dtype=np.float64).reshape(-1, 3)

    @cached_property
    def palm_rot_tuple(self) -> tuple:
        """palm_rot row-major as 9 floats (PyBullet's ``getMatrixFromQuaternion``, float64 exact)."""
        return pb.getMatrixFromQuaternion(self.palm_quat)

    @cached_property
    def objects_in_palm_pose(self) -> tuple[tuple, tuple]:
        """Each object's pose in the palm frame, computed once per state (observation and reward both read it):
        p^palm = R_palm^T (p - p_palm),  q^palm = q_palm^-1 q.  -> (n_obj positions, n_obj quaternions), tuples.
        Plain Python floats in float64 (PyBullet's ``multiplyTransforms`` / ``invertTransform`` round to float32)."""
        r = self.palm_rot_tuple
        px, py, pz = self.palm_pos_tuple
        positions = []
        for x, y, z in self.obj_pos_tuples:
            dx, dy, dz = x - px, y - py, z - pz
            positions.append((r[0] * dx + r[3] * dy + r[6] * dz, r[1] * dx + r[4] * dy + r[7] * dz,
                              r[2] * dx + r[5] * dy + r[8] * dz))
        return tuple(positions), tuple(quat_conj_mul(self.palm_quat, quat) for quat in self.obj_quat)

    @property
    def objects_in_palm(self) -> tuple[np.ndarray, np.ndarray]:
        """:attr:`objects_in_palm_pose` as arrays: p^palm (n_obj, 3) and R^palm = R_palm^T R (n_obj, 3, 3)."""
        pos, quats = self.objects_in_palm_pose
        return np.array(pos, dtype=np.float64).reshape(-1, 3), quat_matrices(quats).reshape(-1, 3, 3)


def quat_conj_mul(a, b) -> tuple[float, float, float, float]:
    """a^-1 b of unit quaternions (x, y, z, w) -- the rotation b seen from frame a -- in plain Python floats (float64;
    a few dozen flops cost less than one numpy call)."""
    px, py, pz, pw = -a[0], -a[1], -a[2], a[3]
    bx, by, bz, bw = b
    return (pw * bx + bw * px + py * bz - pz * by,
            pw * by + bw * py + pz * bx - px * bz,
            pw * bz + bw * pz + px * by - py * bx,
            pw * bw - px * bx - py * by - pz * bz)


def quat_matrices(quats) -> np.ndarray:
    """Rotation matrices of quaternions in PyBullet's (x, y, z, w) order, (n, 4) -> (n, 3, 3).  One
    ``pb.getMatrixFromQuaternion`` each: for the few dozen rotations of a step it is faster than a vectorised
    numpy formula (1.2 us per rotation against ~20 us of numpy call overhead, measured)."""
    return np.array([pb.getMatrixFromQuaternion(q) for q in quats]).reshape(-1, 3, 3)


class LiftWorld:
    """One PyBullet client with the hand, the table and the current record's objects (module docstring)."""

    def __init__(self, hand: HandModel, library: ObjectLibrary, urdf: Path, cfg: LiftEnvConfig,
                 table: CameraConfig | None = None):
        self.hand, self.library, self.cfg = hand, library, cfg
        self._offset_actions = cfg.joint_action_mode == "offset"  # decided once: set_action runs every step
        self.client = pb.connect(pb.DIRECT)
        c = self.client
        pb.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=c)
        # deterministicOverlappingPairs: Bullet solves the contact pairs in broadphase order, which otherwise depends
        # on the bodies' history (objects are re-created when the record's object set changes), so an episode's outcome
        # depended on the episodes run before it in the same world: the same squeeze on the same perturbed pre-grasp
        # ended with a final lift of 1.236 after a fresh start and 1.263 after two other episodes (twenty-third
        # session).  With sorted pairs an episode depends only on its record and seed
        # (test_an_episode_does_not_depend_on_the_episodes_before_it).
        pb.setPhysicsEngineParameter(fixedTimeStep=1.0 / cfg.physics_hz, numSolverIterations=cfg.solver_iterations,
                                     deterministicOverlappingPairs=1, physicsClientId=c)
        add_table(c, table or CameraConfig())
        self.body = pb.loadURDF(str(urdf), useFixedBase=False, flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)
        self.joint_index = hand.pybullet_joint_indices(self.body, c)  # (22,) in hand.joint_names order
        self.link_index = hand.pybullet_link_indices(self.body, c)  # (L,) -1 = palm (base)
        info = pb.getDynamicsInfo(self.body, -1, physicsClientId=c)
        self._inertial = (info[3], info[4])  # base COM in the palm frame
        self._inv_inertial = pb.invertTransform(*self._inertial)
        self._all_links = list(range(pb.getNumJoints(self.body, physicsClientId=c)))
        self._masses = np.array([pb.getDynamicsInfo(self.body, i, physicsClientId=c)[0] for i in [-1, *self._all_links]])
        self.mass = float(self._masses.sum())  # kg, the whole hand
        self._base_mass, self._link_masses = float(self._masses[0]), self._masses[1:].tolist()  # links in _all_links order
        self._child_links = [i for i in self.link_index if i >= 0]
        self._child_in_all = [self._all_links.index(i) for i in self._child_links]  # their rows in _all_links
        self._child_rows = np.flatnonzero(np.asarray(self.link_index) >= 0)  # rows of link_frames() they fill
        self._palm_rows = np.flatnonzero(np.asarray(self.link_index) < 0)
        for link in [-1, *self._child_links]:
            pb.changeDynamics(self.body, link, lateralFriction=cfg.hand_lateral_friction,
                              spinningFriction=cfg.hand_spinning_friction, physicsClientId=c)
        pb.changeDynamics(self.body, -1, linearDamping=cfg.base_linear_damping, angularDamping=cfg.base_angular_damping,
                          physicsClientId=c)
        # fingertip joints: the joint whose child is each finger's distal link; sensors report their wrench
        names = {pb.getJointInfo(self.body, j, physicsClientId=c)[12].decode(): j
                 for j in range(pb.getNumJoints(self.body, physicsClientId=c))}
        self.tip_joints = [next(j for n, j in names.items() if n.startswith(f) and n.endswith("distal")) for f in FINGERTIPS]
        for j in self.tip_joints:
            pb.enableJointForceTorqueSensor(self.body, j, True, physicsClientId=c)
        # rows of the tip joints (FFJ0 ... THJ0, among the 22) in joint_index: read() gets both from one call
        self._tip_rows = [self.joint_index.index(j) for j in self.tip_joints]
        index = {n: i for i, n in enumerate(hand.joint_names)}
        self._actuated = np.array([index[n] for n in hand.actuated_joint_names])  # (18,) positions in the 22
        couplings = list(hand.spec.couplings)  # J0 = clamp(offset + ratio * J1) (numpy copy of the FK's coupling)
        self._follower = np.array([index[c.follower] for c in couplings])
        self._leader = np.array([index[c.leader] for c in couplings])
        self._ratio = np.array([c.ratio for c in couplings])
        self._offset = np.array([c.offset for c in couplings])
        self.lower, self.upper = (hand.joint_limits.detach().cpu().numpy().T.astype(np.float64))  # (22,) x2
        self._follower_lower, self._follower_upper = self.lower[self._follower], self.upper[self._follower]
        # the same as Python lists, for set_action's per-step arithmetic
        self._lower_list, self._upper_list = self.lower.tolist(), self.upper.tolist()
        self._actuated_list = self._actuated.tolist()
        self._coupling_list = list(zip(self._follower.tolist(), self._leader.tolist(), self._ratio.tolist(),
                                       self._offset.tolist()))
        self._motor_gains = dict(forces=[cfg.joint_max_force_nm] * len(self.joint_index),
                                 positionGains=[cfg.joint_position_gain] * len(self.joint_index),
                                 velocityGains=[cfg.joint_velocity_gain] * len(self.joint_index))
        self.objects: list[int] = []
        self._object_names: tuple[str, ...] = ()
        self._targets: list = [0.0] * len(self.joint_index)  # (22,) current joint targets (:attr:`targets`)
        self._anchor: list = list(self._targets)  # (22,) targets that joint_action_mode 'offset' adds its offsets to
        self.record: GraspRecord | None = None
        #: Wall seconds spent in :meth:`step`'s physics substeps (wrench + ``stepSimulation``) since construction;
        #: ``multigrasp bench sim`` divides its change by the env loop's time (``physics_share``).
        self.physics_seconds = 0.0
        self._compensation: tuple | None = None  # (force, torque, base COM) of the last read() state
        self.last_action = [0.0] * (N_JOINT_ACTIONS + N_WRENCH)  # the last action set_action applied, clipped to [-1, 1]

    # ------------------------------------------------------------------ reset
    def set_palm_pose(self, p: np.ndarray, R: np.ndarray) -> None:
        """Place the base so that the palm frame is at (p, R), at rest."""
        quat = Rotation.from_matrix(R).as_quat()
        pos, orn = pb.multiplyTransforms(list(map(float, p)), list(map(float, quat)), *self._inertial)
        pb.resetBasePositionAndOrientation(self.body, pos, orn, physicsClientId=self.client)
        pb.resetBaseVelocity(self.body, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)

    def reset(self, record: GraspRecord) -> WorldState:
        """Hand and objects at the record's pre-grasp, everything at rest, joint targets = its joint angles."""
        c = self.client
        names = record.scene.names
        if names != self._object_names:
            for body in self.objects:
                pb.removeBody(body, physicsClientId=c)
            self.objects = [self.library.get(p.name).pybullet_body(c, p.position, p.quat_xyzw) for p in record.scene.objects]
            self._object_names = names
        for body, placement in zip(self.objects, record.scene.objects):
            pb.resetBasePositionAndOrientation(body, placement.position, placement.quat_xyzw, physicsClientId=c)
            pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=c)
        self.set_palm_pose(record.p, record.R)
        q = np.asarray(record.q, dtype=np.float64)
        for index, angle in zip(self.joint_index, q):
            pb.resetJointState(self.body, index, float(angle), 0.0, physicsClientId=c)
        self._targets = np.clip(q, self.lower, self.upper).tolist()
        self._anchor = list(self._targets)
        self._send_targets()
        self.record = record
        return self.read()

    def close_grasp(self) -> int:
        """Grasp closure before the lift (:mod:`components.execution.closure`): joint targets that press the links
        near the objects ``closure_depth_m`` into them, reached over ``closure_steps`` environment steps and held for
        ``closure_settle_steps`` more, while a PD wrench holds the palm at its current pose.  -> environment steps
        taken (0: closure off, or no link within ``closure_radius_m`` of an object: nothing to close on)."""
        cfg = self.cfg
        if cfg.closure_steps == 0:
            return 0
        rows, owners, points, directions = closest_points(self, cfg.closure_radius_m)
        if rows and cfg.closure_links == "opposed":
            keep = opposed_links(directions, owners, cfg.closure_opposed_above)
            rows, points, directions = [r for r, k in zip(rows, keep) if k], points[keep], directions[keep]
        if not rows:
            return 0
        p0, R0 = self.palm_pose()
        start = self.targets
        goal = closure_targets(self.hand, p0, R0, start, rows, points, directions, cfg.closure_depth_m,
                               cfg.closure_damping)
        c = self.client
        kp, kr = cfg.closure_hold_stiffness_n_per_m, cfg.closure_hold_stiffness_nm_per_rad
        kd = 2.0 * np.sqrt(kp * self.mass)  # critically damped for the whole hand's mass
        kw = cfg.closure_hold_damping_nms_per_rad
        total = cfg.closure_steps + cfg.closure_settle_steps
        action = np.zeros(N_JOINT_ACTIONS + N_WRENCH)
        for k in range(total):
            s = min(1.0, (k + 1) / cfg.closure_steps)
            self.set_joint_targets(self.coupled((1.0 - s) * start + s * goal))
            p, R = self.palm_pose()
            v, w = (np.asarray(x) for x in pb.getBaseVelocity(self.body, physicsClientId=c))
            force = -kp * (p - p0) - kd * v
            torque = -kr * Rotation.from_matrix(R @ R0.T).as_rotvec() - kw * w
            action[N_JOINT_ACTIONS:N_JOINT_ACTIONS + 3] = np.clip(force / cfg.max_base_force_n, -1.0, 1.0)
            action[N_JOINT_ACTIONS + 3:] = np.clip(torque / cfg.max_base_torque_nm, -1.0, 1.0)
            self.step(action)  # zero joint deltas: the targets set above stay
        self.last_action = [0.0] * (N_JOINT_ACTIONS + N_WRENCH)
        return total

    # ------------------------------------------------------------------ stepping
    def coupled(self, q22: np.ndarray) -> np.ndarray:
        """q clamped to the limits with J0 = clamp(offset + ratio * J1) on FF/MF/RF/LF (the tendon coupling)."""
        q = np.minimum(np.maximum(np.asarray(q22, dtype=np.float64), self.lower), self.upper)
        q[self._follower] = np.minimum(np.maximum(self._offset + self._ratio * q[self._leader], self._follower_lower),
                                       self._follower_upper)
        return q

    def perturbed(self, record: GraspRecord, rng: np.random.Generator, position_sigma: float,
                  joint_sigma: float) -> GraspRecord:
        """The record with the palm moved by N(0, position_sigma^2) per axis and the 18 actuated joints by
        N(0, joint_sigma^2), coupled and clamped (evaluation trials)."""
        q = np.asarray(record.q, dtype=np.float64).copy()
        q[self._actuated] += rng.normal(0.0, joint_sigma, len(self._actuated))
        p = np.asarray(record.p, dtype=np.float64) + rng.normal(0.0, position_sigma, 3)
        return GraspRecord(scene=record.scene, p=p, R=record.R, q=self.coupled(q), meta=record.meta)

    def set_joint_targets(self, q: np.ndarray) -> None:
        """Joint position targets (22,), clamped to the limits (reaching and the closure drive the fingers with them);
        they are also the anchor of ``joint_action_mode: offset``, so a zero action then holds them."""
        self._targets = np.clip(np.asarray(q, dtype=np.float64), self.lower, self.upper).tolist()
        self._anchor = list(self._targets)
        self._send_targets()

    @property
    def targets(self) -> np.ndarray:
        """(22,) the current joint position targets (rad), in ``hand.joint_names`` order.  Kept as a list: the
        per-step update is plain Python arithmetic (:meth:`set_action`)."""
        return np.array(self._targets)

    def _send_targets(self) -> None:
        pb.setJointMotorControlArray(self.body, self.joint_index, pb.POSITION_CONTROL, targetPositions=self._targets,
                                     physicsClientId=self.client, **self._motor_gains)

    def set_action(self, action: np.ndarray) -> tuple[list, list]:
        """Apply the joint part of a (24,) action to the targets; return the base (force, torque) it asks for.

        The same arithmetic as :meth:`coupled` on ``targets + joint_delta_rad * a`` (a clipped to [-1, 1]; with
        ``joint_action_mode: offset``, on ``anchor + joint_offset_rad * a``), done on Python floats: 24 numbers, for
        which each numpy call between physics steps costs more than the work."""
        values = action.tolist() if isinstance(action, np.ndarray) else list(action)  # float32 -> float exactly
        if any(x != x for x in values):  # NaN: min/max below would turn it into -1 without a word
            raise ValueError("the lift env got an action with NaN entries: the policy's output diverged (check its "
                             "learning rate / observation normalisation, or resume from an earlier checkpoint)")
        a = [min(1.0, max(-1.0, float(x))) for x in values]
        self.last_action = a
        lower, upper = self._lower_list, self._upper_list
        if self._offset_actions:
            scale, q = self.cfg.joint_offset_rad, list(self._anchor)
        else:
            scale, q = self.cfg.joint_delta_rad, list(self._targets)
        for i, k in enumerate(self._actuated_list):
            q[k] += scale * a[i]
        q = [min(hi, max(lo, x)) for x, lo, hi in zip(q, lower, upper)]
        for follower, leader, ratio, offset in self._coupling_list:
            q[follower] = min(upper[follower], max(lower[follower], offset + ratio * q[leader]))
        self._targets = q
        self._send_targets()
        force_scale, torque_scale = self.cfg.max_base_force_n, self.cfg.max_base_torque_nm
        force = [force_scale * x for x in a[N_JOINT_ACTIONS:N_JOINT_ACTIONS + 3]]
        torque = [torque_scale * x for x in a[N_JOINT_ACTIONS + 3:]]
        return force, torque

    def _weight_compensation(self, base_com, link_states) -> tuple[list, list, tuple]:
        """(force, torque, point) that cancel the hand's weight: the weight acts at the hand's COM, so lifting it
        at the base COM ``base_com`` (PyBullet's base position) needs the torque (com - base_com) x (0, 0, W) =
        W (dy, -dx, 0).  link_states: ``getLinkStates`` of every link ([0] = the link's COM, world).  Zero
        without ``gravity_compensation``.  Plain Python sums: 25 terms cost less than one numpy call."""
        weight = self.mass * GRAVITY if self.cfg.gravity_compensation else 0.0
        x, y = self._base_mass * base_com[0], self._base_mass * base_com[1]
        for mass, state in zip(self._link_masses, link_states):
            x += mass * state[0][0]
            y += mass * state[0][1]
        dx, dy = x / self.mass - base_com[0], y / self.mass - base_com[1]
        return [0.0, 0.0, weight], [weight * dy, -weight * dx, 0.0], base_com

    def _link_states(self) -> tuple:
        """``getLinkStates`` of every hand link with forward kinematics recomputed.  Without it PyBullet returns link
        transforms that lag the joint state after ``stepSimulation`` (2-6 mm, measured); with it, it also rewrites the
        cached transforms the next physics step starts from.  So every :meth:`read` asks this way, and the physics
        does not depend on when else someone asks (the env's feature updates did, before; README, fifteenth session)."""
        return pb.getLinkStates(self.body, self._all_links, computeForwardKinematics=True, physicsClientId=self.client)

    def _current_compensation(self) -> tuple[list, list, tuple]:
        """The weight compensation of the current state: the one :meth:`read` computed when the hand's base has not
        moved since (the state is the one it read), else computed afresh (someone stepped the client directly)."""
        base = pb.getBasePositionAndOrientation(self.body, physicsClientId=self.client)[0]
        cached = self._compensation
        if cached is not None and cached[2] == base:
            return cached
        return self._weight_compensation(base, self._link_states())

    def step(self, action: np.ndarray) -> WorldState:
        """One environment step: set the action, then ``substeps`` physics steps with the base wrench
        (and the weight compensation, at the hand's centre of mass) applied at each."""
        force, torque = self.set_action(action)
        c = self.client
        lift, lift_torque, base_com = self._current_compensation()
        total_force = [force[k] + lift[k] for k in range(3)]
        total_torque = [torque[k] + lift_torque[k] for k in range(3)]
        start = time.perf_counter()
        for _ in range(self.cfg.substeps):
            pb.applyExternalForce(self.body, -1, total_force, base_com, pb.WORLD_FRAME, physicsClientId=c)
            pb.applyExternalTorque(self.body, -1, total_torque, pb.WORLD_FRAME, physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
        self.physics_seconds += time.perf_counter() - start
        return self.read()

    def step_raw(self, n: int) -> float:
        """n bare physics steps -- no action, no state reads, only the constant weight compensation force (the
        same physical input as a zero action): the benchmark's reference cost of the physics alone.  -> the wall
        seconds of the n steps (the compensation, computed once before them, is not counted)."""
        c = self.client
        base = pb.getBasePositionAndOrientation(self.body, physicsClientId=c)[0]
        lift, torque, base_com = self._weight_compensation(base, self._link_states())
        start = time.perf_counter()
        for _ in range(n):
            pb.applyExternalForce(self.body, -1, lift, base_com, pb.WORLD_FRAME, physicsClientId=c)
            pb.applyExternalTorque(self.body, -1, torque, pb.WORLD_FRAME, physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
        return time.perf_counter() - start

    # ------------------------------------------------------------------ state
    def palm_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(p (3,), R (3, 3)) of the palm frame (module docstring)."""
        pos, orn = pb.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        p, quat = pb.multiplyTransforms(pos, orn, *self._inv_inertial)
        return np.asarray(p), np.asarray(pb.getMatrixFromQuaternion(quat)).reshape(3, 3)

    def read(self) -> WorldState:
        """The state now, with every rotation also as a quaternion (:class:`WorldState`).  It also keeps the link states
        and the weight compensation of this state, so that the next :meth:`step` and :meth:`link_frames` do not ask
        PyBullet again.  One call per quantity, plain tuples where numpy's per-call cost would dominate."""
        c, body = self.client, self.body
        q, dq, reactions, tau = zip(*pb.getJointStates(body, self.joint_index, physicsClientId=c))
        base_pos, base_orn = pb.getBasePositionAndOrientation(body, physicsClientId=c)
        palm_pos, palm_quat = pb.multiplyTransforms(base_pos, base_orn, *self._inv_inertial)
        lin, ang = pb.getBaseVelocity(body, physicsClientId=c)
        links = self._link_states()
        self._compensation = self._weight_compensation(base_pos, links)
        poses = [pb.getBasePositionAndOrientation(b, physicsClientId=c) for b in self.objects]
        velocities = [pb.getBaseVelocity(b, physicsClientId=c) for b in self.objects]
        return WorldState(q=np.array(q), q_tuple=q, dq=np.array(dq), tau=np.array(tau),
                          tip_wrench=np.array([reactions[k] for k in self._tip_rows]),  # (5, 6)
                          palm_pos_tuple=palm_pos, palm_quat=palm_quat, palm_vel_tuples=(lin, ang),
                          obj_pos_tuples=tuple(x[0] for x in poses), obj_quat=tuple(x[1] for x in poses),
                          obj_vel_tuples=tuple(velocities), link_states=links)

    def link_frames(self, state: WorldState | None = None) -> np.ndarray:
        """World frames (L, 4, 4) of the hand's links in ``HandModel.link_names`` order (the palm's = palm frame), of
        ``state`` (from its ``link_states``, no PyBullet call) or of the client's current state."""
        if state is None or state.link_states is None:
            state = self.read()
        links = state.link_states
        frames = np.zeros((len(self.link_index), 4, 4))
        frames[:, 3, 3] = 1.0
        child = self._child_rows
        frames[child, :3, 3] = [links[k][4] for k in self._child_in_all]  # URDF link frame (world)
        frames[child, :3, :3] = quat_matrices([links[k][5] for k in self._child_in_all])
        frames[self._palm_rows, :3, :3], frames[self._palm_rows, :3, 3] = state.palm_rot, state.palm_pos
        return frames

    def close(self) -> None:
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None
