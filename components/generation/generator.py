"""The grasp generator: denoiser + DDPM schedule + data standardisation, and palm-aligned generation
(paper §"Multi-object Grasp Generation", Fig. palm-align; DESIGN §5.2).

Training (data already palm-aligned with :class:`~components.generation.canonical.AlignedFrame`):
    z_0 = (x_0 - mean) / std  (:class:`~components.generation.diffusion.Standardizer`),  loss = diffusion_loss.
Generation for a desired palm yaw theta:
    O' = aligned frame of (theta, objects' centroid) applied to the object clouds,
    z_0 ~ DDPM(. | O'),  x'_0 = z_0 std + mean,  (p', R', q) = from_representation(x'_0),
    (p, R) = the aligned frame's inverse applied to (p', R')      (:func:`generate_grasps`).
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor, nn

from components.generation.canonical import AlignedFrame
from components.generation.config import GeneratorConfig, IKConfig, SamplerConfig
from components.generation.denoiser import GraspDenoiser, ObjectInputs
from components.generation.diffusion import NoiseSchedule, Standardizer, ddim_sample, diffusion_loss, sample
from components.generation.representation import from_representation, representation_dim
from components.hand import HandModel


class GraspGenerator(nn.Module):
    """Denoiser (eps- or v-model), schedule and standardiser of one representation (module docstring)."""

    def __init__(self, cfg: GeneratorConfig):
        super().__init__()
        self.cfg = cfg
        self.denoiser = GraspDenoiser.for_representation(cfg)
        self.schedule = NoiseSchedule.from_config(cfg)
        self.standardizer = Standardizer(representation_dim(cfg.representation))

    def loss(self, x0: Tensor, objects: ObjectInputs, generator: Optional[torch.Generator] = None) -> Tensor:
        """Denoising MSE (epsilon or v, ``cfg.prediction``) of raw (palm-aligned) representations x0 (B, D)
        given their object clouds."""
        return diffusion_loss(self.denoiser, self.schedule, self.standardizer.normalize(x0), objects, generator)

    @torch.no_grad()
    def sample(self, objects: ObjectInputs, per_scene: int = 1, generator: Optional[torch.Generator] = None,
               sampler: Optional[SamplerConfig] = None) -> Tensor:
        """``per_scene`` raw representations for each of the B scenes (scene-major), with ``sampler``
        (default: the ancestral DDPM over all T steps).   -> (B per_scene, D)."""
        self.eval()
        sampler = sampler if sampler is not None else SamplerConfig()
        context = self.denoiser.cache_keys_values(self.denoiser.encode(objects)).repeat_interleave(per_scene)
        shape = (objects.clouds.shape[0] * per_scene, self.denoiser.dim)
        where = {"device": objects.clouds.device, "dtype": objects.clouds.dtype}
        if sampler.method == "ddim":
            z = ddim_sample(self.denoiser, self.schedule, shape, context, min(sampler.steps, self.schedule.steps),
                            sampler.eta, generator, clip=self.cfg.clip_sample, spacing=sampler.spacing, **where)
        else:
            z = sample(self.denoiser, self.schedule, shape, context, generator, clip=self.cfg.clip_sample, **where)
        return self.standardizer.denormalize(z)


def generate_grasps(model: GraspGenerator, hand: HandModel, clouds: Tensor, palm_yaw: Tensor, ik: IKConfig,
                    mask: Optional[Tensor] = None, per_scene: int = 1,
                    generator: Optional[torch.Generator] = None,
                    sampler: Optional[SamplerConfig] = None) -> tuple[Tensor, Tensor, Tensor]:
    """Grasps in the world for object clouds (B, n_obj, N, 3) (world, m) and desired palm yaws (B,) (rad):
    rotate the objects into the aligned frame about their centroid, sample (``sampler``, default the
    ancestral DDPM), convert, rotate back.
    -> p (B per_scene, 3), R (B per_scene, 3, 3), q (B per_scene, 22)."""
    valid = mask if mask is not None else torch.ones(clouds.shape[:2], dtype=torch.bool, device=clouds.device)
    weights = valid.to(clouds.dtype).unsqueeze(-1)  # (B, n_obj, 1)
    centroid = (clouds.mean(2) * weights).sum(1) / weights.sum(1).clamp_min(1.0)  # (B, 3)
    frame = AlignedFrame.from_yaw(palm_yaw, centroid)
    aligned = frame.points_to_aligned(clouds)
    x = model.sample(ObjectInputs(aligned, mask), per_scene, generator, sampler)  # (B per_scene, D)
    p, R, q = from_representation(hand, x, model.cfg.representation, ik)
    rep = AlignedFrame(frame.yaw.repeat_interleave(per_scene), frame.pivot.repeat_interleave(per_scene, 0))
    p, R = rep.pose_from_aligned(p, R)
    return p, R, q
