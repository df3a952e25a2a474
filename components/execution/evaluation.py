"""Evaluating lift policies (paper §"Execution Policy", protocol of §"Experiments").

Success of one trial: at the end of the episode every object is more than ``eval_success_height_m``
(10 cm) above where it started.  Each pose gets ``trials`` trials (5 in the paper), each from the pose
perturbed by a generator seeded with (seed, pose, trial) (:meth:`LiftEnv.set_next_record`), so two
evaluations of one policy see the same trials.  ``succ`` = successful trials / all trials.

Policies are callables TensorDict -> TensorDict writing ``action``: a trained actor (run in its
deterministic mode, the mean action) or :class:`ScriptedLift`, the paper's "w/o RL" baseline.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Optional

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from components.execution.lift_env import N_ACTIONS, LiftEnv
from components.execution.lift_sim import N_JOINT_ACTIONS

#: Index of the +z base force in the action (after the 18 joint deltas: fx, fy, fz, tx, ty, tz).
FORCE_Z = N_JOINT_ACTIONS + 2


class ScriptedLift:
    """A constant-action controller.  With the defaults, the "w/o RL" baseline of the paper: keep the pre-grasp
    joint targets and push the base straight up with ``force_fraction`` of ``max_base_force_n`` (lift directly
    from the pre-grasp).  With ``squeeze`` > 0 it also closes the actuated joints ``squeeze_joints`` (indices
    into the 18 joint actions) by ``squeeze`` x ``joint_delta_rad`` per step while it lifts: the squeeze-and-lift
    that :func:`scripted_action` gives PPO as its starting mean."""

    def __init__(self, force_fraction: float = 0.5, squeeze: float = 0.0, squeeze_joints: Sequence[int] = ()):
        self.action = scripted_action(force_fraction, squeeze, squeeze_joints)

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        return td.set("action", self.action.clone())


def scripted_action(force_fraction: float, squeeze: float = 0.0, squeeze_joints: Sequence[int] = ()) -> torch.Tensor:
    """The (24,) action of :class:`ScriptedLift`: ``squeeze`` on the joint actions ``squeeze_joints``, ``force_fraction``
    on the +z base force, zero elsewhere."""
    action = torch.zeros(N_ACTIONS)
    action[list(squeeze_joints)] = squeeze
    action[FORCE_Z] = force_fraction
    return action


@dataclass
class LiftEvaluation:
    """Result of :func:`evaluate_lift`: ``succ`` over all trials, per-pose success counts, final lifts."""

    succ: float
    n_poses: int
    trials: int
    successes_per_pose: list[int] = field(default_factory=list)
    final_lifts: list[float] = field(default_factory=list)
    seed_keys: list[int] = field(default_factory=list)  # per evaluated pose, the key its trial seeds came from

    def row(self, setting: str) -> dict:
        return {"setting": setting, "succ": round(self.succ, 4), "n_poses": self.n_poses, "trials": self.trials}


def trial_seed(seed: int, pose: int, trial: int) -> int:
    """Seed of one trial's perturbation (distinct for every (pose, trial) of one evaluation seed)."""
    return (seed * 1_000_003 + pose) * 101 + trial


def evaluate_lift(env: LiftEnv, policy: Callable[[TensorDictBase], TensorDictBase], n_poses: Optional[int] = None,
                  trials: int = 5, seed: int = 0,
                  on_rollout: Optional[Callable[[int, int, TensorDictBase], None]] = None,
                  poses: Optional[Sequence[int]] = None, seed_keys: Optional[Sequence[int]] = None) -> LiftEvaluation:
    """Run ``trials`` perturbed episodes from each of the first ``n_poses`` records of ``env`` (module
    docstring), or from the records ``poses`` (indices into ``env.records``) when given.
    ``seed_keys``: one integer per evaluated pose that its trial seeds derive from (default: the record index), e.g.
    a key of the pre-grasp's identity, so that one pose gets the same perturbations in every env it is evaluated in.
    ``on_rollout(pose, trial, rollout)`` sees every rollout (e.g. to keep a few for GIFs)."""
    if poses is None:
        poses = range(len(env.records) if n_poses is None else min(n_poses, len(env.records)))
    n = len(poses)
    keys = list(poses) if seed_keys is None else [int(k) for k in seed_keys]
    if len(keys) != n:
        raise ValueError(f"evaluate_lift: {len(keys)} seed keys for {n} poses")
    per_pose, lifts = [], []
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for pose, key in zip(poses, keys):
            wins = 0
            for trial in range(trials):
                env.set_next_record(pose, trial_seed(seed, key, trial))
                rollout = env.rollout(env.cfg.max_steps, policy=policy, break_when_any_done=True)
                last = rollout[-1]
                wins += int(bool(last["next", "success"]))
                lifts.append(float(last["next", "lift"]))
                if on_rollout is not None:
                    on_rollout(pose, trial, rollout)
            per_pose.append(wins)
    total = n * trials
    return LiftEvaluation(succ=sum(per_pose) / total if total else 0.0, n_poses=n, trials=trials,
                          successes_per_pose=per_pose, final_lifts=lifts, seed_keys=keys)


def rollout_gif(env: LiftEnv, policy: Callable[[TensorDictBase], TensorDictBase], pose: int, seed: int, path,
                camera=None, every: int = 2, frame_ms: int = 80):
    """Replay one evaluation trial (``pose``, trial ``seed``) and write it as an animated GIF: a frame every
    ``every`` env steps from ``cameras.render_rgb`` (CPU renderer) looking at the objects' start centre.
    Returns (path, success)."""
    from pathlib import Path

    import numpy as np
    from PIL import Image

    from components.execution.cameras import CameraConfig, render_rgb

    cam = camera or CameraConfig(width=240, height=180, distance_m=0.7, yaw_deg=70.0, pitch_deg=-20.0)
    env.set_next_record(pose, seed)
    frames = []
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = env.reset()
        target = np.mean([pl.position for pl in env.world.record.scene.objects], axis=0) + np.array([0.0, 0.0, 0.06])
        frames.append(render_rgb(env.world.client, target, cam))
        success = False
        for step in range(env.cfg.max_steps):
            td = env.step(policy(td))["next"]
            if (step + 1) % every == 0:
                frames.append(render_rgb(env.world.client, target, cam))
            success = bool(td["success"])
            if bool(td["done"]):
                break
    images = [Image.fromarray(f) for f in frames]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.gif")
    images[0].save(tmp, save_all=True, append_images=images[1:], duration=frame_ms, loop=0)
    tmp.replace(path)
    return path, success
