"""DDPM (Ho et al. 2020) for the grasp generator (paper §"Multi-object Grasp Generation", Eq.
grasp-diffuser-denoising-process; DESIGN §5.2).  Written here (``diffusers`` is not in the environment),
with diffusers' conventions: timesteps t = 0 .. T-1, beta_t linear from ``beta_start`` to ``beta_end``.

    alpha_t = 1 - beta_t,   abar_t = prod_{s <= t} alpha_s,   abar_{-1} = 1
    forward:   q(x_t | x_0) = N(sqrt(abar_t) x_0, (1 - abar_t) I)                              (:func:`q_sample`)
    training:  L = E_{x_0, t, eps} |eps - eps_theta(x_t, t, O)|^2                              (:func:`diffusion_loss`)
               or, with prediction = 'v', |v - v_theta|^2, v = sqrt(abar_t) eps - sqrt(1 - abar_t) x_0
    reverse:   x0^ = (x_t - sqrt(1 - abar_t) eps_theta) / sqrt(abar_t)
               (v: x0^ = sqrt(abar_t) x_t - sqrt(1 - abar_t) v_theta,
                   eps^ = sqrt(1 - abar_t) x_t + sqrt(abar_t) v_theta;  :func:`model_estimates`)
               mu_{t-1} = sqrt(abar_{t-1}) beta_t / (1 - abar_t) x0^ + sqrt(alpha_t) (1 - abar_{t-1}) / (1 - abar_t) x_t
                        (= (x_t - beta_t / sqrt(1 - abar_t) eps_theta) / sqrt(alpha_t) without clipping)
               x_{t-1} = mu_{t-1} + sigma_t z,  z ~ N(0, I) (z = 0 at t = 0),
               sigma_t^2 = beta~_t = (1 - abar_{t-1}) / (1 - abar_t) beta_t  or  beta_t          (:func:`p_sample`)
    sampling:  x_{T-1} ~ N(0, I), then p_sample for t = T-1 .. 0                               (:func:`sample`)
    strided:   DDIM (Song et al. 2021) on S of the T timesteps, t_i = i floor(T / S) ("leading" spacing), i = S-1 .. 0:
               x_{t_{i-1}} = sqrt(abar_{t_{i-1}}) x0^ + sqrt(1 - abar_{t_{i-1}} - s_i^2) eps_theta + s_i z,
               s_i = eta sqrt((1 - abar_{t_{i-1}}) / (1 - abar_{t_i})) sqrt(1 - abar_{t_i} / abar_{t_{i-1}}),
               abar_{t_{-1}} = 1 (the last step returns x0^); eta = 0 is deterministic  (:func:`ddim_sample`).
               The same trained eps-model serves both samplers.

Zero terminal SNR (Lin et al. 2024, Algorithm 1; ``zero_terminal_snr``): sqrt(abar_t) of the linear schedule is
shifted and scaled, s'_t = (s_t - s_{T-1}) s_0 / (s_0 - s_{T-1}), so that abar_{T-1} = 0 and abar_0 is unchanged;
betas follow from the ratios abar_t / abar_{t-1} (beta_{T-1} = 1).  Needs v-prediction.

The model is any callable ``model(x_t (B, D), t (B,) long, cond) -> eps (B, D)`` (or v (B, D) with prediction
'v'); ``cond`` is passed through untouched (the denoiser's encoded objects, or None).  Data are standardised
per dimension by :class:`Standardizer` before diffusion (keypoints in metres are ~0.05 wide; the schedule
assumes ~unit scale).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Optional

import torch
from torch import Tensor, nn

from components.generation.config import GeneratorConfig

#: model(x_t, t, cond) -> predicted noise
EpsModel = Callable[[Tensor, Tensor, Any], Tensor]
#: batch(step, generator) -> (x_0 (B, D) normalised, cond)
BatchFn = Callable[[int, torch.Generator], tuple[Tensor, Any]]
#: progress(step, total, info)
ProgressFn = Callable[[int, int, dict], None]
#: guide(x0^ (B, D), t) -> x0^' (B, D): a correction of the clean estimate before a sampler step (or None)
GuideFn = Callable[[Tensor, int], Tensor]


# ============================================================================ schedule
def linear_beta_schedule(steps: int, beta_start: float, beta_end: float, dtype=torch.float64) -> Tensor:
    """beta_t = beta_start + (beta_end - beta_start) t / (T - 1),  t = 0 .. T-1.   -> (T,)."""
    return torch.linspace(beta_start, beta_end, steps, dtype=dtype)


def rescale_zero_terminal_snr(betas: Tensor) -> Tensor:
    """Lin et al. 2024, Algorithm 1: betas whose sqrt(abar_t) is the given one's shifted to 0 at t = T-1 and
    scaled back to its value at t = 0 (module docstring).   (T,) -> (T,), last entry 1."""
    root = torch.cumprod(1.0 - betas, dim=0).sqrt()
    first, last = root[0].clone(), root[-1].clone()
    abar = ((root - last) * first / (first - last)).square()
    alphas = torch.cat([abar[:1], abar[1:] / abar[:-1]])
    return 1.0 - alphas


class NoiseSchedule(nn.Module):
    """The DDPM constants of the module docstring as buffers (float64 on construction, follow ``.to()``):
    ``betas``, ``alphas``, ``alphas_cumprod`` (abar_t), ``alphas_cumprod_prev`` (abar_{t-1}),
    ``posterior_variance`` (beta~_t), all (T,)."""

    def __init__(self, steps: int, beta_start: float, beta_end: float, variance: str = "posterior",
                 zero_terminal_snr: bool = False, prediction: str = "epsilon"):
        super().__init__()
        if zero_terminal_snr and (prediction != "v" or steps < 2):
            raise ValueError("a zero-terminal-SNR schedule needs prediction='v' and at least 2 steps")
        betas = linear_beta_schedule(steps, beta_start, beta_end)
        if zero_terminal_snr:
            betas = rescale_zero_terminal_snr(betas)
        alphas = 1.0 - betas
        abar = torch.cumprod(alphas, dim=0)
        abar_prev = torch.cat([abar.new_ones(1), abar[:-1]])
        self.steps, self.variance, self.prediction = steps, variance, prediction
        self.register_buffer("betas", betas)
        self.register_buffer("alphas", alphas)
        self.register_buffer("alphas_cumprod", abar)
        self.register_buffer("alphas_cumprod_prev", abar_prev)
        self.register_buffer("posterior_variance", betas * (1.0 - abar_prev) / (1.0 - abar))

    @classmethod
    def from_config(cls, cfg: GeneratorConfig) -> "NoiseSchedule":
        return cls(cfg.diffusion_steps, cfg.beta_start, cfg.beta_end, cfg.posterior_variance, cfg.zero_terminal_snr,
                   cfg.prediction)

    def at(self, name: str, t: Tensor, like: Tensor) -> Tensor:
        """Schedule constant ``name`` at timesteps t (B,), shaped to broadcast against ``like`` (B, ...)."""
        value = getattr(self, name).to(like.device)[t].to(like.dtype)
        return value.reshape(-1, *([1] * (like.dim() - 1)))


# ============================================================================ forward process and loss
def q_sample(schedule: NoiseSchedule, x0: Tensor, t: Tensor, noise: Tensor) -> Tensor:
    """x_t = sqrt(abar_t) x_0 + sqrt(1 - abar_t) eps.   x0, noise (B, D), t (B,) long -> (B, D)."""
    abar = schedule.at("alphas_cumprod", t, x0)
    return abar.sqrt() * x0 + (1.0 - abar).sqrt() * noise


def velocity(schedule: NoiseSchedule, x0: Tensor, t: Tensor, noise: Tensor) -> Tensor:
    """v = sqrt(abar_t) eps - sqrt(1 - abar_t) x_0 (Salimans & Ho 2022).   (B, D) -> (B, D)."""
    abar = schedule.at("alphas_cumprod", t, x0)
    return abar.sqrt() * noise - (1.0 - abar).sqrt() * x0


def diffusion_loss(model: EpsModel, schedule: NoiseSchedule, x0: Tensor, cond: Any,
                   generator: Optional[torch.Generator] = None) -> Tensor:
    """Denoising loss  L = mean over batch and dims of (target - model(x_t, t, cond))^2 with t ~ U{0..T-1} and
    eps ~ N(0, I) per row; target = eps, or v (:func:`velocity`) when ``schedule.prediction == 'v'``.
    x0 (B, D) -> scalar."""
    gen_device = generator.device if generator is not None else x0.device
    t = torch.randint(schedule.steps, (x0.shape[0],), generator=generator, device=gen_device).to(x0.device)
    noise = torch.randn(x0.shape, generator=generator, device=gen_device, dtype=x0.dtype).to(x0.device)
    target = velocity(schedule, x0, t, noise) if schedule.prediction == "v" else noise
    return (model(q_sample(schedule, x0, t, noise), t, cond) - target).square().mean()


# ============================================================================ reverse process
def predict_x0(schedule: NoiseSchedule, x_t: Tensor, t: Tensor, eps: Tensor) -> Tensor:
    """x0^ = (x_t - sqrt(1 - abar_t) eps) / sqrt(abar_t).   (B, D) -> (B, D)."""
    abar = schedule.at("alphas_cumprod", t, x_t)
    return (x_t - (1.0 - abar).sqrt() * eps) / abar.sqrt()


def model_estimates(schedule: NoiseSchedule, x_t: Tensor, t: Tensor, output: Tensor) -> tuple[Tensor, Tensor]:
    """(x0^, eps^) from the model's output at x_t: the noise (prediction 'epsilon', :func:`predict_x0`) or v
    (x0^ = sqrt(abar_t) x_t - sqrt(1 - abar_t) v, eps^ = sqrt(1 - abar_t) x_t + sqrt(abar_t) v).
    (B, D) each."""
    if schedule.prediction != "v":
        return predict_x0(schedule, x_t, t, output), output
    abar = schedule.at("alphas_cumprod", t, x_t)
    return abar.sqrt() * x_t - (1.0 - abar).sqrt() * output, (1.0 - abar).sqrt() * x_t + abar.sqrt() * output


def posterior_mean(schedule: NoiseSchedule, x_t: Tensor, t: Tensor, x0: Tensor) -> Tensor:
    """mu~_t(x_t, x0) = sqrt(abar_{t-1}) beta_t / (1 - abar_t) x0 + sqrt(alpha_t) (1 - abar_{t-1}) / (1 - abar_t) x_t."""
    beta, alpha = schedule.at("betas", t, x_t), schedule.at("alphas", t, x_t)
    abar, abar_prev = schedule.at("alphas_cumprod", t, x_t), schedule.at("alphas_cumprod_prev", t, x_t)
    return (abar_prev.sqrt() * beta / (1.0 - abar)) * x0 + (alpha.sqrt() * (1.0 - abar_prev) / (1.0 - abar)) * x_t


@torch.no_grad()
def p_sample(model: EpsModel, schedule: NoiseSchedule, x_t: Tensor, t: int, cond: Any,
             generator: Optional[torch.Generator] = None, clip: float = 0.0,
             guide: Optional[GuideFn] = None) -> Tensor:
    """One ancestral step x_t -> x_{t-1} = mu_{t-1} + sigma_t z (module docstring); no noise at t = 0.
    ``clip`` > 0 clamps x0^ to [-clip, clip] first; then ``guide`` (if given) corrects x0^.   x_t (B, D) -> (B, D)."""
    tt = torch.full((x_t.shape[0],), t, dtype=torch.long, device=x_t.device)
    x0, _ = model_estimates(schedule, x_t, tt, model(x_t, tt, cond))
    if clip > 0.0:
        x0 = x0.clamp(-clip, clip)
    if guide is not None:
        x0 = guide(x0, t)
    mean = posterior_mean(schedule, x_t, tt, x0)
    if t == 0:
        return mean
    var = schedule.at("posterior_variance" if schedule.variance == "posterior" else "betas", tt, x_t)
    gen_device = generator.device if generator is not None else x_t.device
    z = torch.randn(x_t.shape, generator=generator, device=gen_device, dtype=x_t.dtype).to(x_t.device)
    return mean + var.sqrt() * z


@torch.no_grad()
def sample(model: EpsModel, schedule: NoiseSchedule, shape: tuple[int, ...], cond: Any,
           generator: Optional[torch.Generator] = None, clip: float = 0.0, device=None,
           dtype=torch.float32, guide: Optional[GuideFn] = None) -> Tensor:
    """Ancestral sampling: x_{T-1} ~ N(0, I) of ``shape`` (B, D), then :func:`p_sample` for t = T-1 .. 0.  -> x_0 (B, D)."""
    device = torch.device(device) if device is not None else schedule.betas.device
    gen_device = generator.device if generator is not None else device
    x = torch.randn(shape, generator=generator, device=gen_device, dtype=dtype).to(device)
    return denoise_from(model, schedule, x, schedule.steps - 1, cond, generator, clip, guide)


def denoise_from(model: EpsModel, schedule: NoiseSchedule, x_t: Tensor, t: int, cond: Any,
                 generator: Optional[torch.Generator] = None, clip: float = 0.0,
                 guide: Optional[GuideFn] = None) -> Tensor:
    """Ancestral sampling from a given x_t: :func:`p_sample` for t, t-1, .. 0.  With x_t = q_sample(x0, t) this
    is a partial noising and denoising of x0 (SDEdit, Meng et al. 2022); t = T-1 from N(0, I) is :func:`sample`.
    x_t (B, D) -> x_0 (B, D)."""
    if not 0 <= t < schedule.steps:
        raise ValueError(f"t must be in 0 .. {schedule.steps - 1} (the schedule's T - 1), got {t}")
    x = x_t
    for step in reversed(range(t + 1)):
        x = p_sample(model, schedule, x, step, cond, generator, clip, guide)
    return x


def ddim_timesteps(train_steps: int, sampling_steps: int, spacing: str = "leading") -> list[int]:
    """The S timesteps of the strided sampler (S = T gives every step), as diffusers spaces them:
    'leading' t_i = i floor(T / S), i = 0 .. S-1 (the first sampled step is below T-1); 'trailing'
    t_i = round(T - (S-1-i) T / S) - 1, which starts at t = T-1 (Lin et al. 2024: with a zero-terminal-SNR schedule
    only that step sees pure noise).   -> ascending list of S ints."""
    if not 1 <= sampling_steps <= train_steps:
        raise ValueError(f"sampling_steps must be in 1 .. {train_steps} (the schedule's T), got {sampling_steps}")
    if spacing == "trailing":
        return [round(train_steps - (sampling_steps - 1 - i) * train_steps / sampling_steps) - 1
                for i in range(sampling_steps)]
    stride = train_steps // sampling_steps
    return [i * stride for i in range(sampling_steps)]


@torch.no_grad()
def ddim_step(model: EpsModel, schedule: NoiseSchedule, x_t: Tensor, t: int, t_prev: int, cond: Any, eta: float = 0.0,
              generator: Optional[torch.Generator] = None, clip: float = 0.0,
              guide: Optional[GuideFn] = None) -> Tensor:
    """One DDIM step x_t -> x_{t_prev} (module docstring; t_prev = -1: abar = 1, returns x0^); ``clip`` and
    ``guide`` change x0^ as in :func:`p_sample`, and eps^ is then the noise consistent with the changed x0^.
    (B, D) -> (B, D)."""
    tt = torch.full((x_t.shape[0],), t, dtype=torch.long, device=x_t.device)
    x0, eps = model_estimates(schedule, x_t, tt, model(x_t, tt, cond))
    if clip > 0.0 or guide is not None:
        if clip > 0.0:
            x0 = x0.clamp(-clip, clip)
        if guide is not None:
            x0 = guide(x0, t)
        abar_t = schedule.at("alphas_cumprod", tt, x_t)
        eps = (x_t - abar_t.sqrt() * x0) / (1.0 - abar_t).sqrt()  # the noise consistent with the changed x0^
    if t_prev < 0:
        return x0
    abar_t = float(schedule.alphas_cumprod[t])
    abar_prev = float(schedule.alphas_cumprod[t_prev])
    sigma = eta * ((1.0 - abar_prev) / (1.0 - abar_t)) ** 0.5 * (1.0 - abar_t / abar_prev) ** 0.5
    out = abar_prev ** 0.5 * x0 + max(1.0 - abar_prev - sigma ** 2, 0.0) ** 0.5 * eps
    if sigma > 0.0:
        gen_device = generator.device if generator is not None else x_t.device
        out = out + sigma * torch.randn(x_t.shape, generator=generator, device=gen_device, dtype=x_t.dtype).to(x_t.device)
    return out


@torch.no_grad()
def ddim_sample(model: EpsModel, schedule: NoiseSchedule, shape: tuple[int, ...], cond: Any, steps: int,
                eta: float = 0.0, generator: Optional[torch.Generator] = None, clip: float = 0.0, device=None,
                dtype=torch.float32, spacing: str = "leading", guide: Optional[GuideFn] = None) -> Tensor:
    """Strided sampling: x_{t_{S-1}} ~ N(0, I) of ``shape`` (B, D), then :func:`ddim_step` down the
    :func:`ddim_timesteps` (``spacing``).  -> x_0 (B, D)."""
    device = torch.device(device) if device is not None else schedule.betas.device
    gen_device = generator.device if generator is not None else device
    x = torch.randn(shape, generator=generator, device=gen_device, dtype=dtype).to(device)
    timesteps = ddim_timesteps(schedule.steps, steps, spacing)
    for i in reversed(range(len(timesteps))):
        x = ddim_step(model, schedule, x, timesteps[i], timesteps[i - 1] if i > 0 else -1, cond, eta, generator, clip,
                      guide)
    return x


# ============================================================================ data scaling
class Standardizer(nn.Module):
    """Per-dimension standardisation  z = (x - mean) / std  and back  x = z std + mean  (buffers, (D,))."""

    def __init__(self, dim: int, min_std: float = 1e-6):
        super().__init__()
        self.min_std = min_std
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    @torch.no_grad()
    def fit(self, data: Tensor) -> "Standardizer":
        """Set mean / std from data (N, D); a std below ``min_std`` is raised to it."""
        self.mean.copy_(data.mean(0))
        self.std.copy_(data.std(0).clamp_min(self.min_std))
        return self

    def normalize(self, x: Tensor) -> Tensor:
        return (x - self.mean) / self.std

    def denormalize(self, z: Tensor) -> Tensor:
        return z * self.std + self.mean


# ============================================================================ training loop
def train_diffusion(model: nn.Module, schedule: NoiseSchedule, batch: BatchFn, cfg: GeneratorConfig,
                    steps: Optional[int] = None, progress: Optional[ProgressFn] = None,
                    device=None) -> list[dict]:
    """AdamW on :func:`diffusion_loss` for ``steps`` (default ``cfg.train_steps``) minibatches from ``batch``
    (``cfg.lr``, ``cfg.weight_decay``, ``cfg.grad_clip``; noise and timesteps from a generator seeded with
    ``cfg.seed``).  ``model(x_t, t, cond)`` is an nn.Module.  Returns the history [{step, loss, seconds}]
    (one entry every ``cfg.log_every`` steps and at the last)."""
    steps = cfg.train_steps if steps is None else steps
    device = torch.device(device) if device is not None else next(model.parameters()).device
    generator = torch.Generator(device=device).manual_seed(cfg.seed)
    optimiser = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    model.train()
    history, start, running = [], time.perf_counter(), 0.0
    for step in range(1, steps + 1):
        x0, cond = batch(step, generator)
        loss = diffusion_loss(model, schedule, x0, cond, generator)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        optimiser.step()
        running += float(loss.detach())
        if step % cfg.log_every == 0 or step == steps:
            count = step % cfg.log_every or cfg.log_every
            info = {"step": step, "loss": running / count, "seconds": time.perf_counter() - start}
            history.append(info)
            running = 0.0
            if progress is not None:
                progress(step, steps, info)
    model.eval()
    return history
