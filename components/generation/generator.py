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
from components.generation.diffusion import GuideFn, NoiseSchedule, Standardizer, ddim_sample, diffusion_loss, sample
from components.generation.guidance import DistanceFn, KeypointSpheres, make_guide
from components.generation.representation import from_representation, representation_dim
from components.errors import MultigraspError
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
               sampler: Optional[SamplerConfig] = None, guide: Optional[GuideFn] = None) -> Tensor:
        """``per_scene`` raw representations for each of the B scenes (scene-major), with ``sampler``
        (default: the ancestral DDPM over all T steps) and an optional ``guide`` of the standardised clean
        estimate (:mod:`components.generation.guidance`).   -> (B per_scene, D)."""
        self.eval()
        sampler = sampler if sampler is not None else SamplerConfig()
        context = self.denoiser.cache_keys_values(self.denoiser.encode(objects)).repeat_interleave(per_scene)
        shape = (objects.clouds.shape[0] * per_scene, self.denoiser.dim)
        where = {"device": objects.clouds.device, "dtype": objects.clouds.dtype}
        if sampler.method == "ddim":
            z = ddim_sample(self.denoiser, self.schedule, shape, context, min(sampler.steps, self.schedule.steps),
                            sampler.eta, generator, clip=self.cfg.clip_sample, spacing=sampler.spacing, guide=guide,
                            **where)
        else:
            z = sample(self.denoiser, self.schedule, shape, context, generator, clip=self.cfg.clip_sample, guide=guide,
                       **where)
        return self.standardizer.denormalize(z)


def generate_grasps(model: GraspGenerator, hand: HandModel, clouds: Tensor, palm_yaw: Tensor, ik: IKConfig,
                    mask: Optional[Tensor] = None, per_scene: int = 1,
                    generator: Optional[torch.Generator] = None,
                    sampler: Optional[SamplerConfig] = None, distance: Optional[DistanceFn] = None,
                    table_height: float = 0.0) -> tuple[Tensor, Tensor, Tensor]:
    """Grasps in the world for object clouds (B, n_obj, N, 3) (world, m) and desired palm yaws (B,) (rad):
    rotate the objects into the aligned frame about their centroid, sample (``sampler``, default the
    ancestral DDPM), convert, rotate back.  With ``sampler.guidance.scale`` > 0 the sampler is guided out of the
    objects: ``distance`` maps world points (B per_scene, N, 3) to their signed distance to the nearest object
    (every row must be served, e.g. ``SceneObjects.sdf(x).amin(-1)`` when all B scenes are one), ``table_height``
    is the table plane's z.
    -> p (B per_scene, 3), R (B per_scene, 3, 3), q (B per_scene, 22)."""
    valid = mask if mask is not None else torch.ones(clouds.shape[:2], dtype=torch.bool, device=clouds.device)
    weights = valid.to(clouds.dtype).unsqueeze(-1)  # (B, n_obj, 1)
    centroid = (clouds.mean(2) * weights).sum(1) / weights.sum(1).clamp_min(1.0)  # (B, 3)
    frame = AlignedFrame.from_yaw(palm_yaw, centroid)
    aligned = frame.points_to_aligned(clouds)
    rep = AlignedFrame(frame.yaw.repeat_interleave(per_scene), frame.pivot.repeat_interleave(per_scene, 0))
    guide = None
    if sampler is not None and sampler.guidance.scale > 0.0:
        guide = guidance_hook(model, hand, sampler, rep, distance, table_height)
    x = model.sample(ObjectInputs(aligned, mask), per_scene, generator, sampler, guide=guide)  # (B per_scene, D)
    p, R, q = from_representation(hand, x, model.cfg.representation, ik)
    p, R = rep.pose_from_aligned(p, R)
    return p, R, q


def guidance_hook(model: GraspGenerator, hand: HandModel, sampler: SamplerConfig, frame: AlignedFrame,
                  distance: Optional[DistanceFn], table_height: float) -> GuideFn:
    """The sampler's guide for ``sampler.guidance`` (:func:`components.generation.guidance.make_guide`) in the
    aligned ``frame`` of every sample; a one-line error where guidance cannot apply."""
    if model.cfg.representation != "keypoints":
        raise MultigraspError("generator.sampler.guidance works on the keypoint representation only; this model "
                              f"diffuses {model.cfg.representation!r} -- set generator.sampler.guidance.scale=0")
    if distance is None:
        raise MultigraspError("generator.sampler.guidance.scale > 0 needs the objects' signed distance; this caller "
                              "passes none -- set generator.sampler.guidance.scale=0")
    spheres = KeypointSpheres.from_hand(hand, sampler.guidance.segment_points)
    std = model.standardizer
    return make_guide(sampler.guidance, spheres, distance, table_height, frame.points_from_aligned,
                      frame.points_to_aligned, std.denormalize, std.normalize)
