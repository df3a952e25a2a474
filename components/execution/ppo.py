"""PPO for the lift policy with TorchRL (paper §"Learning a Multi-Object Lifting Policy"), in the style of
torchrl's ``sota-implementations/ppo``: a tanh-Gaussian actor and a value net (MLPs over the observation,
each behind a running observation normaliser; ``exploration: gsde`` makes the actor's noise state-dependent and
held over steps, :class:`GSDEHead`), ``ClipPPOLoss`` + ``GAE``, a ``Collector`` (1 worker,
in process) or ``MultiSyncCollector`` (several processes), checkpoints with resume.

    result = train_ppo(env_factory, PPOConfig(...), checkpoint_path, progress=print)
    result.actor, result.history                       # [{'iteration', 'frames', 'reward', 'success', ...}]

Each history row also has ``collect_s`` (waiting for the batch), ``update_s`` (the PPO epochs and the weight
push to the workers) and ``frames_per_s`` (the iteration's frames over both), so a run says where its time went.

Best policy: with ``validate_every`` > 0 and a ``validate`` callable (the caller's fixed set of seeded
episodes, run with the deterministic policy), the actor is validated before the first update and every
``validate_every`` iterations; the checkpoint keeps the best validated actor (``best``, highest success, then
highest mean lift) beside the last one, and :func:`load_actor` serves it.  PPO's sampled-episode success
says little about the mean action the evaluation runs, and a run can end below where it started.

Resume: a checkpoint (actor, critic, normaliser, optimiser, iteration, frames, history, validations, best) is written
atomically every ``checkpoint_every`` iterations and at the end; ``train_ppo`` on an existing
checkpoint continues from its iteration (a finished one returns at once), also when ``iterations`` was raised
(:data:`EXTENDABLE_FIELDS`: a finished training continued to more iterations, as a resume after a crash is).  A corrupt checkpoint is a
one-line error naming the file to delete.
"""

from __future__ import annotations

import copy
import io
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import torch
from tensordict import TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule
from torch import nn
from torch.distributions.utils import _sum_rightmost
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from components.errors import MultigraspError
from components.execution.lift_sim import N_JOINT_ACTIONS, N_WRENCH
from components.execution.ppo_config import EXTENDABLE_FIELDS, PPOConfig  # noqa: F401  (re-exported)
from components.fileio import atomic_write_bytes

#: PPOConfig.init_scale_by_block's blocks: (first, last) entries of the lift env's action.
ACTION_BLOCKS = {"joints": (0, N_JOINT_ACTIONS), "base_force": (N_JOINT_ACTIONS, N_JOINT_ACTIONS + 3),
                 "base_torque": (N_JOINT_ACTIONS + 3, N_JOINT_ACTIONS + N_WRENCH)}


#: The batch key GAE reads: the env's reward times ``PPOConfig.reward_scale`` (the env's own reward stays as it is).
SCALED_REWARD = "reward_scaled"

#: progress(iteration, total, info) after every iteration (info: reward, success, losses, eta_s, ...).
ProgressFn = Callable[[int, int, dict], None]
#: validate(actor) -> {"success": rate, "lift": mean final lift (m)} of the deterministic actor on fixed episodes.
ValidateFn = Callable[["ProbabilisticActor"], dict]


class RunningNorm(nn.Module):
    """y = (x - mean) / sqrt(var + eps) with mean / var running over every observation seen by :meth:`update`
    (parallel-variance merge of batches); identity until the first update.

    Why not torchrl's ``VecNorm`` / ``ObservationNorm`` transforms: those keep the statistics in the env,
    i.e. in every collector worker (VecNorm shares them through shared memory), and a trained policy
    would need the env's transform state saved and restored beside it.  As the first layer of the actor
    and critic the statistics are buffers of the policy: updated once per batch in the learner, shipped to
    the workers with the weights, and saved in the same checkpoint the evaluation loads."""

    def __init__(self, dim: int, eps: float = 1e-6):
        super().__init__()
        self.eps = eps
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("var", torch.ones(dim))
        self.register_buffer("count", torch.zeros(()))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        x = x.reshape(-1, x.shape[-1]).to(self.mean)
        n = x.shape[0]
        mean, var = x.mean(0), x.var(0, unbiased=False)
        total = self.count + n
        delta = mean - self.mean
        self.var.copy_((self.var * self.count + var * n + delta * delta * self.count * n / total) / total)
        self.mean.add_(delta * n / total)
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return ((x - self.mean) / torch.sqrt(self.var + self.eps)).clamp(-10.0, 10.0)


class HeldNoiseTanhNormal(TanhNormal):
    """TanhNormal(loc, scale) whose single draws are tanh(loc + noise) with a given ``noise`` (gSDE's state-dependent
    perturbation, :class:`GSDEHead`) instead of fresh Gaussian noise.  Densities, deterministic samples and draws of
    a sample shape (entropy estimates) are TanhNormal's: given the state, gSDE's pre-tanh action is Normal(loc,
    scale) with scale the head's marginal std, so the log-probability PPO's ratio needs is the usual one."""

    def __init__(self, loc: torch.Tensor, scale: torch.Tensor, noise: Optional[torch.Tensor] = None, **kwargs):
        super().__init__(loc, scale, **kwargs)
        self.noise = noise

    def _held_preimage(self, sample_shape) -> Optional[torch.Tensor]:
        if self.noise is None or len(torch.Size(sample_shape)) > 0:
            return None
        return self.root_dist.loc + self.noise

    def _squash(self, preimage: torch.Tensor) -> torch.Tensor:
        for t in self.transforms:
            preimage = t(preimage)
        return preimage

    def rsample(self, sample_shape=torch.Size()):
        pre = self._held_preimage(sample_shape)
        return super().rsample(sample_shape) if pre is None else self._squash(pre)

    def sample(self, sample_shape=torch.Size()):
        pre = self._held_preimage(sample_shape)
        return super().sample(sample_shape) if pre is None else self._squash(pre).detach()

    def _held_and_log_prob(self, pre: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The draw of the pre-tanh value ``pre`` and its log-probability, scored at ``pre`` itself (as TanhNormal's
        *_and_log_prob: inverting a saturated tanh would score a different value)."""
        transform = self.transforms[0]
        sample = transform(pre)
        log_prob = self.base_dist.log_prob(pre) - _sum_rightmost(transform.log_abs_det_jacobian(pre, sample),
                                                                   len(self.event_shape))
        return sample, log_prob

    def rsample_and_log_prob(self, sample_shape=torch.Size()):
        pre = self._held_preimage(sample_shape)
        return super().rsample_and_log_prob(sample_shape) if pre is None else self._held_and_log_prob(pre)

    def sample_and_log_prob(self, sample_shape=torch.Size()):
        pre = self._held_preimage(sample_shape)
        if pre is None:
            return super().sample_and_log_prob(sample_shape)
        sample, log_prob = self._held_and_log_prob(pre)
        return sample.detach(), log_prob


class GSDEHead(nn.Module):
    """Generalised state-dependent exploration (Raffin, Kober & Stulp 2021) over the actor's last hidden layer z:

        loc = W z + b,   z' = stopgrad(z) / |z|,   scale_j = sqrt(sum_i z'_i^2 sigma_ij^2),
        noise_j = sum_i z'_i sigma_ij eps_ij   (only when exploring; 0 otherwise),

    sigma = exp(log_sigma) (floored at ``min_scale``; hidden x action, learned), eps ~ N(0, 1) of the same shape,
    drawn again every ``resample_every`` exploring calls or when the batch shape changes.  z is scaled to unit length
    so that a uniform sigma gives every action entry that std whatever the state (torchrl's ``gSDEModule`` and SB3
    use z as it is).  eps is per-process exploration state, not a buffer: the learner's weight pushes do not
    overwrite a collector's draw, and checkpoints do not hold it."""

    def __init__(self, latent_dim: int, act_dim: int, init_scale: torch.Tensor, min_scale: float, resample_every: int):
        super().__init__()
        self.mean = nn.Linear(latent_dim, act_dim)
        self.log_sigma = nn.Parameter(torch.log(init_scale).expand(latent_dim, act_dim).clone())
        self.min_scale = min_scale
        self.resample_every = resample_every
        self._eps: Optional[torch.Tensor] = None
        self._calls = 0

    def forward(self, latent: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        loc = self.mean(latent)
        z = nn.functional.normalize(latent.detach(), dim=-1)
        sigma = self.log_sigma.exp().clamp_min(self.min_scale)
        scale = (z.pow(2) @ sigma.pow(2)).clamp_min(1e-12).sqrt()
        if exploration_type() != ExplorationType.RANDOM:
            return loc, scale, torch.zeros_like(loc)
        shape = (*z.shape, sigma.shape[-1])
        if self._eps is None or self._eps.shape != shape or self._calls % self.resample_every == 0:
            self._eps = torch.randn(shape, dtype=sigma.dtype, device=sigma.device)
        self._calls += 1
        noise = (z.unsqueeze(-2) @ (sigma * self._eps)).squeeze(-2)
        return loc, scale, noise


def _mlp(dim_in: int, dim_out: int, cfg: PPOConfig) -> MLP:
    return MLP(in_features=dim_in, out_features=dim_out, num_cells=list(cfg.hidden), activation_class=nn.Tanh)


def build_actor_critic(env: EnvBase, cfg: PPOConfig, init_action: Optional[torch.Tensor] = None
                       ) -> tuple[ProbabilisticActor, ValueOperator, RunningNorm]:
    """Actor (tanh-Gaussian over the action box) and critic, sharing one observation normaliser.
    ``init_action`` (act_dim,), inside the action box: the untrained actor's mean action (default: the box's
    centre), e.g. a scripted controller's action so that PPO explores around it."""
    torch.manual_seed(cfg.seed)
    obs_dim = env.observation_spec["observation"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    norm = RunningNorm(obs_dim)
    if cfg.exploration == "gsde":
        return _build_gsde_actor(env, cfg, init_action, norm), _critic(norm, obs_dim, cfg), norm
    independent = cfg.std_mode == "independent"
    head = _mlp(obs_dim, act_dim if independent else 2 * act_dim, cfg)
    with torch.no_grad():
        # the mean rows start at zero weight, so the untrained mean action is init_action whatever the observation
        # (and whatever the normaliser's statistics); gradients still reach them through the hidden activations
        head[-1].weight[:act_dim].zero_()
        head[-1].weight[act_dim:].mul_(0.01)  # state std: scale = biased softplus(x), starting near init_scale
        head[-1].bias.zero_()
        unit = _init_unit(env, init_action)
        if unit is not None:
            head[-1].bias[:act_dim] = unit  # TanhNormal's mean action is tanh(loc) in the box
    if independent:
        scale = AddStateIndependentNormalScale(act_dim, scale_mapping="exp", scale_lb=cfg.min_scale,
                                               init_value=math.log(cfg.init_scale))
        if cfg.init_scale_by_block:
            if act_dim != N_JOINT_ACTIONS + N_WRENCH:
                raise MultigraspError(f"specialists.ppo.init_scale_by_block names the lift env's 24 action entries, but "
                                      f"this env has {act_dim}; drop init_scale_by_block")
            with torch.no_grad():
                for block, value in cfg.init_scale_by_block.items():
                    first, last = ACTION_BLOCKS[block]
                    scale.state_independent_scale[first:last] = math.log(value)
    else:
        scale = NormalParamExtractor(scale_mapping=f"biased_softplus_{cfg.init_scale}")
    actor_net = nn.Sequential(norm, head, scale)
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], spec=env.action_spec, distribution_class=TanhNormal,
        distribution_kwargs={"low": env.action_spec.space.low, "high": env.action_spec.space.high},
        return_log_prob=True)
    return actor, _critic(norm, obs_dim, cfg), norm


def _critic(norm: RunningNorm, obs_dim: int, cfg: PPOConfig) -> ValueOperator:
    return ValueOperator(nn.Sequential(norm, _mlp(obs_dim, 1, cfg)), in_keys=["observation"])


def _init_unit(env: EnvBase, init_action: Optional[torch.Tensor]) -> Optional[torch.Tensor]:
    """atanh of ``init_action`` mapped into (-1, 1): the pre-tanh bias whose TanhNormal mean action is it."""
    if init_action is None:
        return None
    low, high = env.action_spec.space.low, env.action_spec.space.high
    return torch.atanh((2.0 * (init_action.to(low) - low) / (high - low) - 1.0).clamp(-0.999, 0.999))


def _build_gsde_actor(env: EnvBase, cfg: PPOConfig, init_action: Optional[torch.Tensor], norm: RunningNorm
                      ) -> ProbabilisticActor:
    """exploration 'gsde': normaliser -> hidden MLP (tanh after every layer) -> :class:`GSDEHead` -> tanh-Gaussian
    whose draws are the head's held noise (:class:`HeldNoiseTanhNormal`)."""
    obs_dim = env.observation_spec["observation"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    hidden = list(cfg.hidden)
    body = MLP(in_features=obs_dim, out_features=hidden[-1], num_cells=hidden[:-1], activation_class=nn.Tanh,
               activate_last_layer=True)
    init_scale = torch.full((act_dim,), float(cfg.init_scale))
    if cfg.init_scale_by_block:
        if act_dim != N_JOINT_ACTIONS + N_WRENCH:
            raise MultigraspError(f"specialists.ppo.init_scale_by_block names the lift env's 24 action entries, but "
                                  f"this env has {act_dim}; drop init_scale_by_block")
        for block, value in cfg.init_scale_by_block.items():
            first, last = ACTION_BLOCKS[block]
            init_scale[first:last] = value
    head = GSDEHead(hidden[-1], act_dim, init_scale, cfg.min_scale, cfg.gsde_resample_every)
    with torch.no_grad():  # the untrained mean action is init_action whatever the observation (as the gaussian actor)
        head.mean.weight.zero_()
        head.mean.bias.zero_()
        unit = _init_unit(env, init_action)
        if unit is not None:
            head.mean.bias.copy_(unit)
    net = TensorDictModule(nn.Sequential(norm, body, head), in_keys=["observation"],
                           out_keys=["loc", "scale", "gsde_noise"])
    return ProbabilisticActor(
        net, in_keys={"loc": "loc", "scale": "scale", "noise": "gsde_noise"}, spec=env.action_spec,
        distribution_class=HeldNoiseTanhNormal,
        distribution_kwargs={"low": env.action_spec.space.low, "high": env.action_spec.space.high},
        return_log_prob=True)


# ============================================================================ training
@dataclass
class PPOResult:
    actor: ProbabilisticActor
    critic: ValueOperator
    history: list[dict] = field(default_factory=list)
    resumed_from: int = 0  # iterations found in the checkpoint at start
    validations: list[dict] = field(default_factory=list)  # {'iteration', 'success', 'lift', 'validate_s'}
    best: Optional[dict] = None  # the best validation row (no weights); None without validation


def _save(path: Path, actor, critic, optimizer, iteration: int, frames: int, history: list, cfg: PPOConfig,
          validations: list, best: Optional[dict]) -> None:
    buffer = io.BytesIO()
    torch.save({"format": "multigrasp-ppo", "version": 1, "actor": actor.state_dict(), "critic": critic.state_dict(),
                "optimizer": optimizer.state_dict(), "iteration": iteration, "frames": frames, "history": history,
                "validations": validations, "best": best, "config": cfg.model_dump(mode="json")}, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def _validate(validate: ValidateFn, actor, iteration: int, best: Optional[dict]) -> tuple[dict, Optional[dict]]:
    """One validation row, and the best entry (row + actor weights) after it: higher success wins, then higher lift;
    a tie keeps the earlier actor."""
    start = time.perf_counter()
    scores = validate(actor)
    row = {"iteration": iteration, "success": float(scores["success"]), "lift": float(scores["lift"]),
           "validate_s": round(time.perf_counter() - start, 3)}
    if best is None or (row["success"], row["lift"]) > (best["success"], best["lift"]):
        best = {**row, "actor": copy.deepcopy(actor.state_dict())}
    return row, best


def _without_weights(best: Optional[dict]) -> Optional[dict]:
    return None if best is None else {k: v for k, v in best.items() if k != "actor"}


def load_checkpoint(path: Path) -> dict:
    """The checkpoint dict (one-line error if it is not a readable PPO checkpoint)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 -- any unreadable file gets the same advice
        raise MultigraspError(f"PPO checkpoint {path} is corrupt ({type(exc).__name__}); delete it to retrain "
                              "from scratch") from None
    if not isinstance(state, dict) or state.get("format") != "multigrasp-ppo":
        raise MultigraspError(f"{path} is not a PPO checkpoint of this project; delete it to retrain")
    return state


def _make_collector(env_factory: Callable[[], EnvBase], actor, cfg: PPOConfig, frames: int, seed: int):
    if cfg.workers == 1:
        collector = Collector(env_factory, actor, frames_per_batch=cfg.frames_per_batch, total_frames=frames,
                              auto_register_policy_transforms=False)
    else:
        collector = MultiSyncCollector([env_factory] * cfg.workers, actor, frames_per_batch=cfg.frames_per_batch,
                                       total_frames=frames)
    collector.set_seed(seed)
    return collector


def train_ppo(env_factory: Callable[[], EnvBase], cfg: PPOConfig, checkpoint: Path,
              progress: Optional[ProgressFn] = None, init_action: Optional[torch.Tensor] = None,
              validate: Optional[ValidateFn] = None) -> PPOResult:
    """Train (or resume) a lift policy; see the module docstring.  ``env_factory`` must be picklable when
    ``cfg.workers`` > 1 (it is called in each worker).  ``init_action``: the untrained actor's mean action
    (:func:`build_actor_critic`; ignored on resume).  ``validate``: scores the deterministic actor (module
    docstring, 'Best policy'); used when ``cfg.validate_every`` > 0."""
    probe = env_factory()
    actor, critic, norm = build_actor_critic(probe, cfg, init_action)
    probe.close()
    loss_module = ClipPPOLoss(actor_network=actor, critic_network=critic, clip_epsilon=cfg.clip_epsilon,
                              entropy_coeff=cfg.entropy_coeff, critic_coeff=cfg.critic_coeff,
                              loss_critic_type="l2", normalize_advantage=True)
    advantage = GAE(gamma=cfg.gamma, lmbda=cfg.lmbda, value_network=critic, average_gae=False)
    advantage.set_keys(reward=SCALED_REWARD)
    clip_groups = _clip_groups(actor, critic, cfg)
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=cfg.lr)
    start_iteration, frames, history, validations, best = 0, 0, [], [], None
    checkpoint = Path(checkpoint)
    if checkpoint.exists():
        state = load_checkpoint(checkpoint)
        actor.load_state_dict(state["actor"])
        critic.load_state_dict(state["critic"])
        optimizer.load_state_dict(state["optimizer"])
        start_iteration, frames, history = state["iteration"], state["frames"], list(state["history"])
        validations, best = list(state.get("validations") or []), state.get("best")
    validating = validate is not None and cfg.validate_every > 0
    result = PPOResult(actor=actor, critic=critic, history=history, resumed_from=start_iteration,
                       validations=validations, best=_without_weights(best))
    remaining = cfg.iterations - start_iteration
    if remaining <= 0:
        return result
    if validating and not validations:  # the untrained actor (e.g. the scripted start) is the first candidate
        row, best = _validate(validate, actor, start_iteration, best)
        validations.append(row)
        if progress is not None:
            progress(start_iteration, cfg.iterations, {"validation": row})

    collector = _make_collector(env_factory, actor, cfg, remaining * cfg.frames_per_batch, cfg.seed + start_iteration)
    buffer = ReplayBuffer(storage=LazyTensorStorage(cfg.frames_per_batch), sampler=SamplerWithoutReplacement(),
                          batch_size=cfg.minibatch_size)
    start = time.perf_counter()
    iteration = start_iteration
    collect_start = start
    try:
        for data in collector:
            collected = time.perf_counter()
            iteration += 1
            frames += data.numel()
            normalising = cfg.normalize_observations and (cfg.normalizer_frozen_after is None
                                                          or iteration <= cfg.normalizer_frozen_after)
            normalise_first = normalising and (cfg.normalizer_update == "before_update" or float(norm.count) == 0.0)
            if normalise_first:
                norm.update(data["observation"])
            kl_start = policy_kl(actor, data)  # how far the update's starting policy is from the collecting one
            data["next", SCALED_REWARD] = data["next", "reward"] * cfg.reward_scale
            losses = _ppo_update(data, advantage, loss_module, optimizer, buffer, cfg,
                                 train_actor=iteration > cfg.critic_warmup_iterations,
                                 clip_groups=clip_groups)
            if normalising and not normalise_first:
                norm.update(data["observation"])  # the next batch is collected with these statistics
            losses["kl_start"] = kl_start
            collector.update_policy_weights_()
            updated = time.perf_counter()
            # where an iteration's wall time goes: waiting for the collector's batch, then the learner
            timing = {"collect_s": round(collected - collect_start, 3), "update_s": round(updated - collected, 3),
                      "frames_per_s": round(data.numel() / max(updated - collect_start, 1e-9), 1)}
            collect_start = updated
            row = {"iteration": iteration, "frames": frames, **losses, **episode_stats(data), **timing}
            validated = validating and (iteration % cfg.validate_every == 0 or iteration == cfg.iterations)
            if validated:
                check, best = _validate(validate, actor, iteration, best)
                validations.append(check)
                row.update(val_success=check["success"], val_lift=check["lift"])
            history.append(row)
            if progress is not None:
                elapsed = time.perf_counter() - start
                done_here = iteration - start_iteration
                progress(iteration, cfg.iterations, {**row, "eta_s": elapsed / done_here * (cfg.iterations - iteration)})
            if validated or iteration % cfg.checkpoint_every == 0 or iteration == cfg.iterations:
                _save(checkpoint, actor, critic, optimizer, iteration, frames, history, cfg, validations, best)
    finally:
        collector.shutdown()
    result.best = _without_weights(best)
    return result


def _clip_groups(actor, critic, cfg: PPOConfig) -> list[list[torch.Tensor]]:
    """The parameter groups whose gradients are clipped to ``max_grad_norm`` each (``grad_clip``)."""
    actor_params, critic_params = list(actor.parameters()), list(critic.parameters())
    if cfg.grad_clip == "joint":
        return [actor_params + critic_params]
    return [actor_params, critic_params]


@torch.no_grad()
def policy_kl(actor, data: TensorDictBase) -> float:
    """KL(acting policy || current policy) over a batch, estimated as mean((r - 1) - log r) with r the probability
    ratio of the batch's actions (Schulman's k3 estimator: unbiased and never negative, unlike the plain mean of
    -log r that ClipPPOLoss reports as kl_approx).  Ratios of actions at the box's edge (tanh saturated) are clamped
    to e^+-20."""
    flat = data.reshape(-1)
    log_ratio = actor.get_dist(flat).log_prob(flat["action"]) - flat["action_log_prob"]
    log_ratio = log_ratio[torch.isfinite(log_ratio)].clamp(-20.0, 20.0)
    return float((torch.expm1(log_ratio) - log_ratio).mean()) if log_ratio.numel() else 0.0


def _ppo_update(data: TensorDictBase, advantage: GAE, loss_module: ClipPPOLoss, optimizer, buffer: ReplayBuffer,
                cfg: PPOConfig, train_actor: bool = True, clip_groups: Optional[list] = None) -> dict:
    """Up to ``epochs`` passes of minibatch PPO over one batch (advantages recomputed each epoch, as torchrl's
    recipe).  ``train_actor`` False: the critic's loss only (``critic_warmup_iterations``).  After an epoch whose
    :func:`policy_kl` exceeds ``target_kl`` the batch's remaining epochs are skipped.  Returns the mean losses, the
    last epoch's ``kl_approx`` (:func:`policy_kl`) and ``clip_fraction``, and the ``epochs`` done."""
    sums: dict[str, float] = {}
    steps, epochs_done, epoch_kl, epoch_clip = 0, 0, 0.0, 0.0
    groups = clip_groups if clip_groups is not None else [list(loss_module.parameters())]
    for _ in range(cfg.epochs):
        with torch.no_grad():
            data = advantage(data)
        buffer.empty()
        buffer.extend(data.reshape(-1))
        clips = []
        for batch in buffer:
            loss = loss_module(batch)
            total = loss["loss_critic"]
            if train_actor:
                total = total + loss["loss_objective"] + loss.get("loss_entropy", torch.zeros(()))
            optimizer.zero_grad()
            total.backward()
            for params in groups:
                torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
            optimizer.step()
            for key in ("loss_objective", "loss_critic", "entropy"):
                if key in loss.keys():
                    sums[key] = sums.get(key, 0.0) + float(loss[key].detach())
            if "clip_fraction" in loss.keys():
                clips.append(float(loss["clip_fraction"].detach()))
            steps += 1
        epochs_done += 1
        epoch_kl = policy_kl(loss_module.actor_network, data)
        epoch_clip = sum(clips) / max(len(clips), 1)
        if train_actor and cfg.lr_schedule == "kl_adaptive":
            adapt_lr(optimizer, epoch_kl, cfg)
        if train_actor and cfg.target_kl is not None and epoch_kl > cfg.target_kl:
            break
    out = {k: v / max(steps, 1) for k, v in sums.items()}
    out.update(kl_approx=epoch_kl, clip_fraction=epoch_clip, epochs=epochs_done, actor_trained=train_actor,
               lr=optimizer.param_groups[0]["lr"])
    return out


def adapt_lr(optimizer, kl: float, cfg: PPOConfig) -> float:
    """One step of the KL-adaptive learning rate (``lr_schedule`` 'kl_adaptive', rl_games' AdaptiveScheduler):
    lr / f when kl > 2 target_kl, lr x f when kl < target_kl / 2, else unchanged, clamped to [lr_min, lr_max]
    (f = ``lr_adapt_factor``).  Sets every parameter group's rate and returns it."""
    lr = optimizer.param_groups[0]["lr"]
    if kl > 2.0 * cfg.target_kl:
        lr = max(lr / cfg.lr_adapt_factor, cfg.lr_min)
    elif kl < 0.5 * cfg.target_kl:
        lr = min(lr * cfg.lr_adapt_factor, cfg.lr_max)
    for group in optimizer.param_groups:
        group["lr"] = lr
    return lr


def episode_stats(data: TensorDictBase) -> dict:
    """Mean reward per step, and over the episodes that ended in the batch: success rate and final lift."""
    done = data["next", "done"].squeeze(-1)
    out = {"reward": float(data["next", "reward"].mean())}
    if bool(done.any()):
        out["success"] = float(data["next", "success"].squeeze(-1)[done].float().mean())
        out["final_lift"] = float(data["next", "lift"].squeeze(-1)[done].mean())
        out["episodes"] = int(done.sum())
    return out


def load_actor(path: Path, env: EnvBase, which: str = "best") -> ProbabilisticActor:
    """The trained actor of a checkpoint, for ``env``'s specs (observation normaliser included).  ``which``:
    ``best`` -- the best validated actor (module docstring), the last one when the run did not validate;
    ``last`` -- the actor of the last iteration."""
    if which not in ("best", "last"):
        raise ValueError(f"load_actor: which={which!r}, expected 'best' or 'last'")
    state = load_checkpoint(Path(path))
    cfg = PPOConfig(**state["config"])
    actor, _, _ = build_actor_critic(env, cfg)
    best = state.get("best")
    weights = best["actor"] if which == "best" and best is not None else state["actor"]
    try:
        actor.load_state_dict(weights)
    except RuntimeError:
        raise MultigraspError(f"PPO checkpoint {path} does not fit this environment's observation / action sizes; "
                              "retrain it (multigrasp run --until specialists)") from None
    return actor.eval()
