"""TorchRL environment of the lift task over PyBullet (paper §"Learning a Multi-Object Lifting Policy").

    env = LiftEnv(hand, library, urdf, records, LiftEnvConfig(), encoder)
    check_env_specs(env)
    rollout = env.rollout(150, policy)

An episode starts from the pre-grasp of one :class:`GraspRecord` (hand and objects as the record puts
them, at rest; drawn at random -- uniformly or by learnability, ``LiftEnvConfig.start_sampling`` -- or in
turn, ``record_order``), closed on the objects by the grasp closure
(:mod:`components.execution.closure`, ``closure_steps`` > 0; the goals, start heights and step count start
after it), then each step applies a 24-D action in
[-1, 1] (:mod:`components.execution.lift_sim`) for ``substeps`` physics steps, held for ``action_repeat``
such env steps (their rewards summed; 1 by default).  Output keys:

* ``observation`` (D,) float32 -- :mod:`components.execution.observations` (998 entries for 2 objects);
* ``reward`` (1,) -- :func:`components.execution.observations.reward_terms`; on the step an object falls, plus
  the remaining steps times :func:`~components.execution.observations.worst_step_reward` (ending the episode by
  knocking an object off the table is never better than holding on);
* ``lift`` (1,) -- min_j (z_j - z_j(0)) (m);  ``success`` (1,) bool -- lift > ``eval_success_height_m``;
* ``done`` / ``terminated`` (an object fell below ``fall_height_m``) / ``truncated`` (``max_steps`` reached).

Every record of one env must have the same number of objects (the observation's size depends on it);
the specialists of one bin satisfy this.  Non-batched (batch_size ``[]``): parallel rollouts come from
several env copies in collector workers.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Literal, Optional, Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from components.errors import MultigraspError
from components.execution.clouds import CloudFeaturizer, Encoder
from components.execution.lift_config import LiftEnvConfig
from components.execution.lift_sim import N_JOINT_ACTIONS, N_WRENCH, GraspRecord, LiftWorld, WorldState
from components.execution.observations import Goal, ObservationBuilder, observation_dim, reward_terms, worst_step_reward
from components.execution.start_sampling import LearnabilitySampler
from components.hand import HandModel
from components.objects import ObjectLibrary

N_ACTIONS = N_JOINT_ACTIONS + N_WRENCH


@dataclass
class Episode:
    """What the env tracks within an episode.  A plain object rather than attributes of the env: EnvBase is an
    ``nn.Module``, whose ``__setattr__`` checks parameters, buffers and submodules on every assignment (~3 % of a
    step in the benchmark's loop, measured with py-spy)."""

    goal: Optional[Goal] = None
    start_heights: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (n_obj,) object heights at reset (m)
    worst_step: float = 0.0  # reward of each step left when an object falls (observations.worst_step_reward)
    last_action: list = field(default_factory=lambda: [0.0] * N_ACTIONS)  # (24,) as applied (clipped)
    features: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.float32))  # (1 + n_obj, F)
    t: int = 0  # steps since reset


class LiftEnv(EnvBase):
    """The lift task as a TorchRL env (module docstring)."""

    batch_locked = True

    def __init__(self, hand: HandModel, library: ObjectLibrary, urdf: Path, records: Sequence[GraspRecord],
                 cfg: LiftEnvConfig, encoder: Encoder, record_order: Literal["random", "cycle"] = "random",
                 seed: int = 0, start_counts: Optional[np.ndarray] = None,
                 start_counts_lock: Optional[Callable[[], AbstractContextManager]] = None):
        """``start_counts``: with ``cfg.start_sampling`` 'learnability', an (N records, 2) int64 array of (episodes,
        successes) to count into and draw from, shared by the envs of several collector workers when it is a memory
        map of one file (:func:`components.execution.factory.open_start_counts`); ``start_counts_lock``: the lock
        every count update holds then (:class:`components.execution.start_sampling.FileLock` of that file)."""
        super().__init__(device="cpu", batch_size=torch.Size([]))
        if not records:
            raise MultigraspError("the lift env got no grasp records; run the synthesis stage first "
                                  "(multigrasp run --until synthesize) or pass records")
        counts = {len(r.scene.objects) for r in records}
        if len(counts) != 1:
            raise MultigraspError(f"the lift env's records mix {sorted(counts)} objects per scene; give one env the "
                                  "records of one object count (one specialist bin)")
        self.cfg, self.records, self.record_order = cfg, list(records), record_order
        self.n_objects = counts.pop()
        self.world = LiftWorld(hand, library, urdf, cfg)
        self.featurizer = CloudFeaturizer(hand, library, cfg, encoder)
        self._rng = np.random.default_rng(seed)
        self._next = 0
        self.sampler = None  # LiftEnvConfig.start_sampling 'learnability': outcome counts per record
        if cfg.start_sampling == "learnability":
            self.sampler = LearnabilitySampler(len(self.records), cfg.learnability_prior, cfg.learnability_power,
                                               cfg.learnability_uniform_mix, start_counts, start_counts_lock)
        self._current: Optional[int] = None  # record index of a drawn (training) episode; None when forced
        dim = observation_dim(cfg, self.n_objects)
        self._joint_ranges = (self.world.upper - self.world.lower).tolist()  # rad, for worst_step_reward
        self._observations = ObservationBuilder(cfg, self.n_objects)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(dim,), dtype=torch.float32),
            lift=Unbounded(shape=(1,), dtype=torch.float32),
            success=Categorical(n=2, shape=(1,), dtype=torch.bool))
        self.action_spec = Bounded(low=-1.0, high=1.0, shape=(N_ACTIONS,), dtype=torch.float32)
        self.reward_spec = Unbounded(shape=(1,), dtype=torch.float32)
        self.done_spec = Composite(done=Categorical(n=2, shape=(1,), dtype=torch.bool),
                                   terminated=Categorical(n=2, shape=(1,), dtype=torch.bool),
                                   truncated=Categorical(n=2, shape=(1,), dtype=torch.bool))
        self.episode = Episode(start_heights=np.zeros(self.n_objects),
                               features=np.zeros((1 + self.n_objects, cfg.feature_dim), dtype=np.float32))
        self._forced: Optional[tuple[int, Optional[int]]] = None  # (record, trial seed) of the next reset

    # ------------------------------------------------------------------ records
    def _pick_record(self) -> int:
        """Index of the next training episode's record: in turn (``record_order`` 'cycle'), else drawn per
        ``cfg.start_sampling``."""
        if self.record_order == "cycle":
            index = self._next % len(self.records)
            self._next += 1
            return index
        if self.sampler is not None:
            return self.sampler.draw(self._rng)
        return int(self._rng.integers(len(self.records)))

    def set_next_record(self, index: int, trial_seed: Optional[int] = None) -> None:
        """Make the next reset start from record ``index`` (evaluation), whatever ``record_order``; with
        ``trial_seed`` the pre-grasp is perturbed (``trial_position_noise_m``, ``trial_joint_noise_rad``)
        by a generator seeded with it."""
        self._forced = (index, trial_seed)

    # ------------------------------------------------------------------ EnvBase
    def _update_features(self, state: WorldState) -> None:
        clouds = self.featurizer.clouds(self.world.link_frames(state), state.palm_pos, state.palm_rot,
                                        self.world.record.scene.names, state.obj_pos, state.obj_rot)
        self.episode.features = self.featurizer.features(clouds)

    def _output(self, state: WorldState, lift: float, reward: float = 0.0, terminated: bool = False,
                truncated: bool = False) -> dict:
        """The step's output entries.  The (1,) scalars are views of two fresh arrays (one float, one bool): one
        ``torch.from_numpy`` each instead of one per entry."""
        ep = self.episode
        obs = self._observations.build(state, ep.last_action, ep.features[0], ep.features[1:])
        floats = torch.from_numpy(np.array([lift, reward], dtype=np.float32))
        flags = torch.from_numpy(np.array([lift > self.cfg.eval_success_height_m, terminated or truncated, terminated,
                                           truncated]))
        return {"observation": torch.from_numpy(obs), "lift": floats[0:1], "reward": floats[1:2],
                "success": flags[0:1], "done": flags[1:2], "terminated": flags[2:3], "truncated": flags[3:4]}

    def _reset(self, tensordict: Optional[TensorDictBase] = None, **kwargs) -> TensorDictBase:
        forced, self._forced = self._forced, None
        if forced is None:
            self._current = self._pick_record()
            record = self.records[self._current]
            if self.cfg.train_perturbation:  # a training start drawn as an evaluation trial is (LiftEnvConfig)
                record = self.world.perturbed(record, self._rng, self.cfg.trial_position_noise_m,
                                              self.cfg.trial_joint_noise_rad)
        else:
            self._current = None
            record = self.records[forced[0]]
            if forced[1] is not None:
                record = self.world.perturbed(record, np.random.default_rng(forced[1]), self.cfg.trial_position_noise_m,
                                              self.cfg.trial_joint_noise_rad)
        state = self.world.reset(record)
        if self.world.close_grasp():  # grasp closure (LiftEnvConfig.closure_steps); the episode starts closed
            state = self.world.read()
        ep = self.episode
        ep.goal = Goal.from_state(state)
        self._observations.start(ep.goal)
        ep.start_heights = state.obj_pos[:, 2].copy()
        ep.worst_step = worst_step_reward(self.cfg, self.n_objects, self._joint_ranges, ep.start_heights.tolist())
        ep.last_action = [0.0] * N_ACTIONS
        ep.t = 0
        self._update_features(state)
        out = self._output(state, 0.0)
        del out["reward"]
        return TensorDict(out, batch_size=self.batch_size)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action")
        try:  # one torch call in the usual case (a CPU tensor without grad); detach().cpu() otherwise
            action = action.numpy()
        except (RuntimeError, TypeError):
            action = action.detach().cpu().numpy()
        ep = self.episode
        period = self.cfg.feature_period
        t0, reward, terminated, truncated = ep.t, 0.0, False, False
        for _ in range(self.cfg.action_repeat):  # the action is held for action_repeat inner steps (LiftEnvConfig)
            state = self.world.step(action)
            ep.t += 1
            terms = reward_terms(self.cfg, state, ep.goal, ep.start_heights)
            reward += terms["reward"]
            terminated = any(pos[2] < self.cfg.fall_height_m for pos in state.obj_pos_tuples)
            truncated = ep.t >= self.cfg.max_steps
            if terminated:  # as if the episode went on at the worst reward: dropping objects never pays
                reward += (self.cfg.max_steps - ep.t) * ep.worst_step
            if terminated or truncated:
                break
        ep.last_action = self.world.last_action  # the action as applied, clipped to [-1, 1]
        if (terminated or truncated) and self.sampler is not None and self._current is not None:
            self.sampler.update(self._current, terms["lift"] > self.cfg.eval_success_height_m)
        if ep.t // period != t0 // period:  # an inner step reached a feature update (every feature_period steps)
            self._update_features(state)
        out = self._output(state, terms["lift"], reward, terminated, truncated)
        if self.run_type_checks:
            return TensorDict(out, batch_size=self.batch_size)
        # the same entries as every reset's checked TensorDict (fixed keys, shapes and dtypes): built without the
        # per-entry checks, as torchrl's own GymLikeEnv does once its output is validated (~20 us a step here)
        return TensorDict._new_unsafe(out, batch_size=self.batch_size)

    def _step_proc_data(self, next_tensordict_out: TensorDictBase) -> TensorDictBase:
        """EnvBase's post-step hook reshapes the reward to its spec and fills missing done keys; :meth:`_step`
        already returns the reward as (1,) and every done key, so this skips it (~0.08 ms of a ~3.5 ms step in
        the benchmark's loop, measured).  With ``run_type_checks`` the base hook runs as usual."""
        if self.run_type_checks:
            return super()._step_proc_data(next_tensordict_out)
        return next_tensordict_out

    def _set_seed(self, seed: Optional[int]) -> None:
        self._rng = np.random.default_rng(seed)

    def close(self, *, raise_if_closed: bool = True) -> None:
        self.world.close()
        super().close(raise_if_closed=raise_if_closed)
