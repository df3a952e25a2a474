"""Reaching: bring an open hand to a pre-grasp without knocking the objects (paper §"Multi-object Grasp
Execution": "a motion planning module plans the reaching trajectory from a flat hand to the desired pose").

1. **Plan** (:func:`plan_reach`): T waypoints x_t = (p_t, rot6d_t, q_t).  Start: the open hand (q = 0) at the
   pre-grasp rotation, moved ``retreat_m`` back along the palm normal (away from the objects); end: the
   pre-grasp.  The initial path is the linear interpolation; the inner waypoints are then optimised (Adam)
   on

       E = sum_t E_pen(x_t) + w_smooth sum_t |x_{t+1} - 2 x_t + x_{t-1}|^2,

   with E_pen the synthesis energy's penetration (hand <-> objects both ways, hand below the table, self)
   and the endpoints fixed.
2. **Execute** (:func:`execute_reach`) in a :class:`LiftWorld`: the hand starts at the first waypoint and
   tracks each waypoint for ``steps_per_waypoint`` physics steps -- joint targets = q_t, base wrench =
   PD on the palm pose (with the weight compensation) -- then the world's state at the end is the
   **end-of-reach record**: the same scene with the objects where they now are (possibly pushed) and
   the hand as it arrived.  Its ``meta`` holds the objects' displacement.
"""

from __future__ import annotations

import numpy as np
import pybullet as pb
import torch
from pydantic import Field
from scipy.spatial.transform import Rotation

from components.config_base import Section
from components.execution.lift_sim import GRAVITY, GraspRecord, LiftWorld
from components.objects import Placement, Scene
from components.synthesis.config import SynthesisConfig
from components.synthesis.energy import GraspProblem, penetration_energy
from components.synthesis.pose import pack, unpack


class ReachingConfig(Section):
    """Reaching trajectories: the plan (waypoints, optimisation) and its execution in PyBullet."""

    waypoints: int = Field(16, ge=2, description="Waypoints of the path, both ends included.")
    retreat_m: float = Field(0.08, ge=0.0, description="The path starts this far back from the pre-grasp along the palm normal (m).")
    steps: int = Field(100, ge=0, description="Adam steps of the path optimisation (0 = the linear interpolation).")
    lr: float = Field(2e-3, gt=0.0, description="Adam learning rate (m, rad per step).")
    w_smooth: float = Field(10.0, ge=0.0, description="Weight of the second-difference smoothness term.")
    steps_per_waypoint: int = Field(24, ge=1, description="Physics steps spent tracking each waypoint (0.1 s at 240 Hz).")
    settle_steps: int = Field(48, ge=0, description="Physics steps holding the final waypoint before the state is recorded.")
    position_gain: float = Field(400.0, gt=0.0, description="Base PD: force per metre of palm position error (N/m).")
    velocity_gain: float = Field(40.0, ge=0.0, description="Base PD: force per m/s of palm velocity (N s/m).")
    rotation_gain: float = Field(20.0, gt=0.0, description="Base PD: torque per radian of palm rotation error (N m/rad).")
    angular_velocity_gain: float = Field(2.0, ge=0.0, description="Base PD: torque per rad/s of palm angular velocity.")


def palm_normal(hand, R: np.ndarray) -> np.ndarray:
    """World palm normal (out of the palm, towards grasped objects) of a palm rotation R."""
    from components.execution.cameras import palm_axes

    normal, _ = palm_axes(hand)
    return R @ normal


def linear_path(start: torch.Tensor, end: torch.Tensor, n: int) -> torch.Tensor:
    """x_t = (1 - s_t) start + s_t end, s_t = t / (n - 1).   (D,) x2 -> (n, D)."""
    s = torch.linspace(0.0, 1.0, n, dtype=start.dtype).unsqueeze(-1)
    return (1.0 - s) * start + s * end


def path_penetration(problem: GraspProblem, path: torch.Tensor) -> torch.Tensor:
    """E_pen of every waypoint (T,), differentiable (the synthesis energy's penetration term, joints
    coupled as the energy sees them)."""
    p, R, q = unpack(path)
    return penetration_energy(problem, p, R, problem.effective_joints(q))[0]


def smoothness(path: torch.Tensor) -> torch.Tensor:
    """sum_t |x_{t+1} - 2 x_t + x_{t-1}|^2."""
    return ((path[2:] - 2.0 * path[1:-1] + path[:-2]) ** 2).sum()


def plan_reach(hand, objects, record: GraspRecord, cfg: ReachingConfig,
               energy_cfg: SynthesisConfig | None = None) -> tuple[np.ndarray, dict]:
    """Waypoints (T, 9 + 22) of a reach to ``record``'s pre-grasp (module docstring) and stats (penetration
    of the straight path and of the plan, summed over waypoints)."""
    dtype = hand.dtype
    problem = GraspProblem.build(hand, objects, energy_cfg or SynthesisConfig(batch_size=cfg.waypoints))
    R = torch.as_tensor(record.R, dtype=dtype)
    p_end = torch.as_tensor(record.p, dtype=dtype)
    p_start = p_end - cfg.retreat_m * torch.as_tensor(palm_normal(hand, record.R), dtype=dtype)
    start = pack(p_start[None], R[None], hand.open_pose()[None].to(dtype))[0]
    end = pack(p_end[None], R[None], torch.as_tensor(record.q, dtype=dtype)[None])[0]
    path = linear_path(start, end, cfg.waypoints)
    with torch.no_grad():
        straight = float(path_penetration(problem, path).sum())
    inner = path[1:-1].clone().requires_grad_(True)
    optimizer = torch.optim.Adam([inner], lr=cfg.lr)
    for _ in range(cfg.steps):
        full = torch.cat([path[:1], inner, path[-1:]])
        loss = path_penetration(problem, full).sum() + cfg.w_smooth * smoothness(full)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    planned = torch.cat([path[:1], inner.detach(), path[-1:]])
    with torch.no_grad():
        after = float(path_penetration(problem, planned).sum())
    return planned.numpy(), {"penetration_straight": straight, "penetration_planned": after}


def _track(world: LiftWorld, p_goal: np.ndarray, R_goal: np.ndarray, cfg: ReachingConfig, steps: int) -> None:
    """Hold the palm on (p_goal, R_goal) with a PD base wrench for ``steps`` physics steps."""
    c, body = world.client, world.body
    for _ in range(steps):
        p, R = world.palm_pose()
        v, w = (np.asarray(a) for a in pb.getBaseVelocity(body, physicsClientId=c))
        force = cfg.position_gain * (p_goal - p) - cfg.velocity_gain * v + np.array([0.0, 0.0, world.mass * GRAVITY])
        rot_err = Rotation.from_matrix(R_goal @ R.T).as_rotvec()
        torque = cfg.rotation_gain * rot_err - cfg.angular_velocity_gain * w
        com = np.asarray(pb.getBasePositionAndOrientation(body, physicsClientId=c)[0])
        pb.applyExternalForce(body, -1, force.tolist(), com.tolist(), pb.WORLD_FRAME, physicsClientId=c)
        pb.applyExternalTorque(body, -1, torque.tolist(), pb.WORLD_FRAME, physicsClientId=c)
        pb.stepSimulation(physicsClientId=c)


def execute_reach(world: LiftWorld, record: GraspRecord, waypoints: np.ndarray, cfg: ReachingConfig) -> GraspRecord:
    """Run the reach in ``world`` (module docstring) and return the end-of-reach record."""
    x = torch.as_tensor(waypoints)
    p_all, R_all, q_all = (t.numpy() for t in unpack(x))
    first = GraspRecord(scene=record.scene, p=p_all[0], R=R_all[0], q=q_all[0], meta=record.meta)
    world.reset(first)
    for p, R, q in zip(p_all, R_all, q_all):
        world.set_joint_targets(q)
        _track(world, p, R, cfg, cfg.steps_per_waypoint)
    _track(world, p_all[-1], R_all[-1], cfg, cfg.settle_steps)
    state = world.read()
    start = np.array([pl.position for pl in record.scene.objects])
    objects = tuple(Placement(pl.name, tuple(map(float, pos)), tuple(map(float, Rotation.from_matrix(rot).as_quat())))
                    for pl, pos, rot in zip(record.scene.objects, state.obj_pos, state.obj_rot))
    displacement = np.linalg.norm(state.obj_pos - start, axis=-1)
    meta = {**record.meta, "reached": True, "object_displacement_m": displacement.round(6).tolist(),
            "palm_error_m": float(np.linalg.norm(state.palm_pos - record.p))}
    return GraspRecord(scene=Scene(objects=objects), p=state.palm_pos, R=state.palm_rot, q=state.q, meta=meta)
