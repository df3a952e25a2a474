"""Penetration guidance of the sampler (``SamplerConfig.guidance``; not in the paper, which only refines after
sampling -- the idea of SceneDiffuser's / DexDiffuser's guided sampling, applied to the clean estimate).

The hand is stood in for by spheres on its keypoint chains (:class:`KeypointSpheres`): the 31 keypoints and
``segment_points`` points evenly between consecutive keypoints of each finger chain (mcp - pip - dip - tip),
each a fixed interpolation c_s = sum_k W_sk k_k of the keypoints, with radius r_s = the depth of c_s inside the
hand's collision geometry at the open pose (joint centres: the phalanx radius; tips, pads, palm faces: 0).
With d(x) = min over objects of the signed distance (and, with ``table``, the height above the table plane):

    E(K) = 1/2 sum_s relu(r_s - d(c_s))^2,      K' = K - lambda grad_K E                (:func:`guidance_step`)

For a lone sphere in a locally flat object, grad E = -relu(r - d) n, so one step moves it out along the normal n by
lambda times its depth (lambda = ``scale``; 1 = just onto the surface, never past it).  At every sampler step with
t <= ``start_t`` the clean estimate x0^ is replaced by its guided version before the step is taken
(:func:`components.generation.diffusion.p_sample` / ``ddim_step``'s ``guide``), so the denoiser re-fits the other
keypoints of the hand to the moved ones in the following steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from components.generation.config import GuidanceConfig
from components.hand import HandModel

#: world points (B, N, 3) -> signed distance to the nearest object (B, N) (m, negative inside)
DistanceFn = Callable[[Tensor], Tensor]
#: finger chains of the keypoint names, base to tip
FINGER_CHAINS = tuple((f"{f}_mcp", f"{f}_pip", f"{f}_dip", f"{f}_tip") for f in ("ff", "mf", "rf", "lf", "th"))


@dataclass
class KeypointSpheres:
    """Spheres on the keypoint chains (module docstring): centres c = W K, radii r."""

    weights: Tensor  # (S, 31) interpolation of the keypoints
    radii: Tensor  # (S,) m

    @classmethod
    def from_hand(cls, hand: HandModel, segment_points: int) -> "KeypointSpheres":
        """The 31 keypoints plus ``segment_points`` evenly spaced points inside each chain segment; radii from the
        hand's signed distance at the open pose."""
        names = list(hand.keypoint_names)
        n_kp = len(names)
        rows = [torch.eye(n_kp, dtype=hand.dtype)]
        for chain in FINGER_CHAINS:
            index = [names.index(n) for n in chain]
            for a, b in zip(index[:-1], index[1:]):
                for m in range(1, segment_points + 1):
                    w = torch.zeros(n_kp, dtype=hand.dtype)
                    frac = m / (segment_points + 1)
                    w[a], w[b] = 1.0 - frac, frac
                    rows.append(w[None])
        weights = torch.cat(rows).to(hand.device)
        p = torch.zeros(1, 3, dtype=hand.dtype, device=hand.device)
        R = torch.eye(3, dtype=hand.dtype, device=hand.device)[None]
        q = hand.open_pose().to(hand.device, hand.dtype).reshape(1, -1)
        centres = weights @ hand.keypoints(p, R, q)[0]  # (S, 3)
        radii = torch.relu(-hand.signed_distance(centres[None], p, R, q)[0])
        return cls(weights=weights, radii=radii)

    def centres(self, keypoints: Tensor) -> Tensor:
        """c = W K.   keypoints (B, 31, 3) -> (B, S, 3)."""
        return self.weights.to(keypoints.dtype) @ keypoints


def guidance_energy(keypoints: Tensor, spheres: KeypointSpheres, distance: DistanceFn,
                    table_height: float | None) -> Tensor:
    """E = 1/2 sum_s relu(r_s - d(c_s))^2 (module docstring; the table plane counts when ``table_height`` is given).
    keypoints (B, 31, 3) (world) -> (B,) (m^2)."""
    centres = spheres.centres(keypoints)
    d = distance(centres)
    if table_height is not None:
        d = torch.minimum(d, centres[..., 2] - table_height)
    depth = torch.relu(spheres.radii.to(d.dtype) - d)
    return 0.5 * (depth ** 2).sum(-1)


def guidance_step(keypoints: Tensor, spheres: KeypointSpheres, distance: DistanceFn, table_height: float | None,
                  scale: float) -> Tensor:
    """K' = K - scale grad_K E (module docstring).   keypoints (B, 31, 3) (world) -> (B, 31, 3)."""
    with torch.enable_grad():
        k = keypoints.detach().requires_grad_(True)
        energy = guidance_energy(k, spheres, distance, table_height)
        (grad,) = torch.autograd.grad(energy.sum(), k)
    return (keypoints - scale * grad).detach()


def make_guide(cfg: GuidanceConfig, spheres: KeypointSpheres, distance: DistanceFn, table_height: float,
               to_world: Callable[[Tensor], Tensor], from_world: Callable[[Tensor], Tensor],
               denormalize: Callable[[Tensor], Tensor], normalize: Callable[[Tensor], Tensor]
               ) -> Callable[[Tensor, int], Tensor]:
    """The sampler's hook guide(z0^, t) -> z0^' on standardised keypoint vectors (B, 93): unchanged for
    t > ``start_t``, else denormalise, map the aligned keypoints to the world (``to_world``), :func:`guidance_step`,
    map back and normalise."""
    table = table_height if cfg.table else None

    def guide(z0: Tensor, t: int) -> Tensor:
        if t > cfg.start_t or cfg.scale == 0.0:
            return z0
        keypoints = to_world(denormalize(z0).reshape(z0.shape[0], -1, 3))
        moved = guidance_step(keypoints, spheres, distance, table, cfg.scale)
        return normalize(from_world(moved).reshape(z0.shape[0], -1)).to(z0.dtype)

    return guide
