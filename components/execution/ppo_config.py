"""PPO hyper-parameters (:class:`PPOConfig`) for :mod:`components.execution.ppo`, apart from the training code
so that reading a config does not import torchrl (as :mod:`components.execution.lift_config` for the env)."""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import Field, PositiveInt, model_validator

from components.config_base import Section

#: PPOConfig fields a finished training can be continued across: raising ``iterations`` trains on from the last
#: checkpoint (``checkpoint_every`` only says when checkpoints are written).
EXTENDABLE_FIELDS = frozenset({"iterations", "checkpoint_every"})


class PPOConfig(Section):
    """PPO hyper-parameters (defaults: torchrl's MuJoCo PPO recipe, scaled to a 2-core CPU)."""

    iterations: int = Field(50, ge=1, description="Collector batches (PPO iterations) to train for.")
    frames_per_batch: int = Field(2000, ge=1, description="Environment steps collected per iteration (all workers together).")
    workers: int = Field(
        1, ge=1,
        description="Collector processes: 1 runs the env in this process (Collector); more use MultiSyncCollector "
        "(2 processes gave 1.9x on 2 cores).")
    epochs: int = Field(5, ge=1, description="Passes over each batch.")
    minibatch_size: int = Field(250, ge=1, description="Transitions per gradient step.")
    lr: float = Field(3e-4, gt=0.0, description="Adam learning rate of actor and critic.")
    max_grad_norm: float = Field(1.0, gt=0.0, description="Gradient-norm clip.")
    gamma: float = Field(0.99, gt=0.0, le=1.0, description="Discount.")
    lmbda: float = Field(0.95, ge=0.0, le=1.0, description="GAE lambda.")
    clip_epsilon: float = Field(0.2, gt=0.0, description="PPO ratio clip.")
    entropy_coeff: float = Field(0.0, ge=0.0, description="Entropy bonus weight.")
    critic_coeff: float = Field(0.5, ge=0.0, description="Value loss weight.")
    hidden: tuple[PositiveInt, ...] = Field((256, 256), description="Hidden widths of the actor and critic MLPs.")
    init_scale: float = Field(
        0.05, gt=0.0,
        description="Initial action standard deviation (before the tanh).  0.05 (was 0.2, before that 0.5): around a "
        "closed grasp, noise on every action drops what the mean action lifts (README 'Grasp closure': 1/60 at 0.5 "
        "against 4/60 without noise), so the sampled episodes hardly ever succeed and PPO has nothing to learn from.  "
        "Bench pairs, 2 bins x 400 k frames (README 'The lift reward, and the specialists after the closure'): 0.2 at "
        "lr 3e-4 took the Syn-Pl success from its start's 9.2 % to 1.8 %, 0.05 at lr 1e-4 to 6.0 %, 0.05 at lr 3e-4 to "
        "1.0 % (the learning rate made the difference; 0.05 kept as the best measured setting).")
    init_scale_by_block: Optional[dict[Literal["joints", "base_force", "base_torque"], float]] = Field(
        None,
        description="std_mode 'independent' or exploration 'gsde' only: initial action standard deviation per block of the lift env's action "
        "(joints a[:18], base_force a[18:21], base_torque a[21:24]); blocks not named keep init_scale.  What it is for: "
        "noise on the joint entries drops the squeeze's grasp, noise on the base force does not (docs/experiments.md, "
        "'Joint offsets instead of joint rates': the squeeze on 10 pre-grasps lifted 30 %, 7 % with joint noise 0.5, "
        "27 % with base-force noise 0.5), so exploration can be wide on the force and narrow on the fingers.  PPO on those 10 "
        "pre-grasps with {joints: 0.02, base_force: 0.3}: 26 % against the squeeze's 27 % (100 episodes), no gain.")
    normalize_observations: bool = Field(True, description="Standardise observations with running mean / std (updated from each batch).")
    normalizer_frozen_after: Optional[int] = Field(
        None, ge=1,
        description="Stop updating the normaliser's statistics after this many iterations (None = never).  Each update "
        "moves every later policy without PPO's clip (kl_start with 'before_update'; the same move lands on the next "
        "batch's collecting policy with 'after_update'), and an observation entry that hardly varied early on is "
        "divided by a tiny deviation once it does.  With std_mode 'independent' and critic_warmup_iterations >= this "
        "value, the statistics settle while the actor is still exactly its start (zero mean rows), and afterwards only "
        "PPO's steps move the policy, as torchrl's recipes with ObservationNorm.init_stats do.")
    normalizer_update: Literal["after_update", "before_update"] = Field(
        "after_update",
        description="When a batch's observations enter the normaliser's statistics.  The normaliser is the actor's first "
        "layer, so changing it changes the policy.  'after_update' (default since the thirty-second session): after "
        "the batch's PPO update, so the update starts from the very policy that collected the batch (probability "
        "ratios 1, kl_start 0) and the clip bounds the whole step; the first batch still sets the statistics before "
        "its update (the untrained mean ignores them: its rows start at zero).  'before_update': the recipe until "
        "then, where every update started from a policy the normaliser had already moved, outside the clip's control.  "
        "The history's kl_start measures that move.")
    std_mode: Literal["state", "independent"] = Field(
        "state",
        description="How the actor's standard deviation is parametrised.  'state': a second output of the actor MLP "
        "(biased softplus, floor 0.01; the recipe until the thirty-first session) -- without an entropy bonus it can "
        "shrink or grow per state, and in run D of docs/experiments.md it collapsed (entropy -38 -> -97).  'independent': one "
        "learned log-std per action dimension (tensordict's AddStateIndependentNormalScale, as torchrl's MuJoCo PPO "
        "recipe), starting at init_scale, floored at min_scale.")
    exploration: Literal["gaussian", "gsde"] = Field(
        "gaussian",
        description="How the collecting policy explores.  'gaussian': fresh noise at every step (std per std_mode).  "
        "'gsde': generalised state-dependent exploration (Raffin, Kober & Stulp 2021, 'Smooth Exploration for Robotic "
        "Reinforcement Learning'): the pre-tanh action is mean + (sigma * eps)^T z, with z the actor's last hidden "
        "layer (detached, scaled to unit length) and eps a noise matrix held for gsde_resample_every policy steps, so "
        "the perturbation is a smooth function of the state instead of white noise.  What it is for: white noise on "
        "the finger entries at every step drops the squeeze's grasp (docs/experiments.md, 'Joint offsets instead of "
        "joint rates').  sigma (hidden width x action entries, learned) starts at init_scale (init_scale_by_block per "
        "block), so the per-entry std starts at init_scale as in 'gaussian'; std_mode is not used.  Measured with "
        "lift.joint_action_mode offset on 10 pre-grasps (docs/experiments.md, 'State-dependent exploration, gSDE'): the "
        "sampled episodes lift 23-33 % against 15-17 % with white noise, and PPO raises its reward 1.2 -> 4.3, but by "
        "lifting higher, not more often (deterministic 19-26 % against the squeeze's 27 %).")
    gsde_resample_every: int = Field(
        100, ge=1,
        description="exploration 'gsde': policy steps each noise matrix is held for in a collector (100 = one episode "
        "of the lift env's default max_steps).  Counted per collector process; deterministic calls (validation, "
        "evaluation, the loss) neither use nor advance it.")
    min_scale: float = Field(1e-3, gt=0.0, description="Lower bound of the state-independent standard deviation (std_mode 'independent').")
    grad_clip: Literal["joint", "separate"] = Field(
        "separate",
        description="'separate': the actor's and the critic's gradients are clipped to max_grad_norm each.  'joint' "
        "(until the thirty-first session): one clip over both -- the critic's gradient norm (~14-21 on the lift's "
        "value targets) then scales the actor's down to ~5 % of itself, by a factor that changes with every batch.")
    reward_scale: float = Field(
        1.0, gt=0.0,
        description="Rewards are multiplied by this before GAE (the history's 'reward' stays unscaled).  The lift's "
        "returns reach about +100 (success) and -100 to -170 (a fall pays the rest of the episode at once), while a fresh "
        "critic outputs ~0: its L2 loss then swings between ~3 and ~500 from batch to batch.")
    critic_warmup_iterations: int = Field(
        0, ge=0,
        description="First iterations in which only the critic learns (the actor's loss is not applied).  The actor "
        "starts from a scripted controller (specialists.init_policy) and the critic from random weights: without a "
        "warm-up the first actor updates follow the advantages of an untrained critic.")
    target_kl: Optional[float] = Field(
        None, gt=0.0,
        description="Stop a batch's remaining epochs once the mean approximate KL between the acting and the updated "
        "policy (policy_kl, the k3 estimator over the whole batch after each epoch) exceeds this; None: always all epochs.  "
        "The history records kl_approx, clip_fraction and the epochs done.")
    lr_schedule: Literal["constant", "kl_adaptive"] = Field(
        "constant",
        description="'constant': Adam at ``lr`` throughout.  'kl_adaptive': the KL-adaptive schedule of rl_games (the "
        "PPO of the Isaac Gym environments the paper trained in): after every epoch, the learning rate is divided by "
        "``lr_adapt_factor`` when that epoch's policy_kl exceeds 2 x ``target_kl`` and multiplied by it when the KL is "
        "below target_kl / 2, within [lr_min, lr_max].  Needs ``target_kl``.  The rate lives in the optimiser's state, "
        "so a resumed run continues from the adapted rate; the history records it per iteration ('lr').")
    lr_adapt_factor: float = Field(1.5, gt=1.0, description="Factor of one kl_adaptive step (rl_games: 1.5).")
    lr_min: float = Field(1e-6, gt=0.0, description="Lowest learning rate of the kl_adaptive schedule (rl_games: 1e-6).")
    lr_max: float = Field(1e-2, gt=0.0, description="Highest learning rate of the kl_adaptive schedule (rl_games: 1e-2).")
    checkpoint_every: int = Field(5, ge=1, description="Iterations between checkpoints (also written at the end).")
    validate_every: int = Field(
        10, ge=0,
        description="Iterations between validations of the deterministic policy on the caller's fixed episodes "
        "(also before the first update and at the end); the best validated actor is kept and is the one evaluated.  "
        "0 = no validation, the last actor is evaluated.  Validation runs in the learner's process while the "
        "collectors wait (the specialists: specialists.validation_poses x validation_trials episodes).")
    seed: int = Field(0, ge=0, description="Seed of the networks and the collectors.")

    @model_validator(mode="after")
    def _block_scales_need_independent_std(self) -> "PPOConfig":
        if self.init_scale_by_block is not None:
            if self.std_mode != "independent" and self.exploration != "gsde":
                raise ValueError("init_scale_by_block needs std_mode 'independent' or exploration 'gsde' (a state std has no "
                                 "per-entry start); set specialists.ppo.std_mode=independent or drop init_scale_by_block")
            if any(not v > 0 for v in self.init_scale_by_block.values()):
                raise ValueError("init_scale_by_block: every scale must be positive")
        return self

    @model_validator(mode="after")
    def _adaptive_lr_needs_a_target(self) -> "PPOConfig":
        if self.lr_schedule == "kl_adaptive":
            if self.target_kl is None:
                raise ValueError("lr_schedule 'kl_adaptive' adapts the rate to target_kl; set specialists.ppo.target_kl "
                                 "(e.g. 0.02) or use lr_schedule=constant")
            if not self.lr_min <= self.lr <= self.lr_max:
                raise ValueError(f"lr {self.lr} is outside [lr_min {self.lr_min}, lr_max {self.lr_max}] of the "
                                 "kl_adaptive schedule; change lr or the bounds")
        return self


# ============================================================================ networks
