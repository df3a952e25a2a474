"""Hand and object point clouds in the palm frame, and their features (the observation's 256-d blocks).

The hand cloud is a fixed subset of ``hand_cloud_points`` of the hand's surface samples
(:class:`components.synthesis.HandSurface`, large wrist/forearm geoms excluded), posed by the
link frames; each object's cloud is ``object_cloud_points`` fixed samples of its mesh surface, posed
by the object's pose.  Both are expressed in the palm frame (paper: "all within the palm's coordinate
frame") and encoded by a frozen encoder (the pre-trained PointNet), one batched forward per update.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
import trimesh

from components.execution.lift_config import LiftEnvConfig
from components.execution.pointnet import FusedPointNetEncoder, PointNetEncoder
from components.hand import HandModel
from components.objects import ObjectLibrary
from components.synthesis.energy import LARGE_HAND_GEOMS
from components.synthesis.hand_surface import HandSurface

#: encoder(clouds (n, N, 3) float32) -> features (n, feature_dim)
Encoder = Callable[[torch.Tensor], torch.Tensor]


class CloudFeaturizer:
    """Fixed hand / object surface samples, posed in the palm frame and encoded (module docstring)."""

    def __init__(self, hand: HandModel, library: ObjectLibrary, cfg: LiftEnvConfig, encoder: Encoder):
        # a frozen PointNet runs as its BatchNorm-folded copy: same features, less time per env step
        if isinstance(encoder, PointNetEncoder) and encoder.frozen:
            encoder = encoder.fused()
        self.cfg, self.library, self.encoder = cfg, library, encoder
        surface = HandSurface(hand, cfg.hand_cloud_spacing_m, exclude=LARGE_HAND_GEOMS)
        rng = np.random.default_rng(cfg.cloud_seed)
        pick = rng.choice(len(surface), size=cfg.hand_cloud_points, replace=len(surface) < cfg.hand_cloud_points)
        self.hand_link = surface.link.cpu().numpy()[pick]  # (N,)
        self.hand_local = surface.local.cpu().numpy().astype(np.float64)[pick]  # (N, 3)
        self._object_local: dict[str, np.ndarray] = {}

    def object_local(self, name: str) -> np.ndarray:
        """Fixed surface samples of an object, in its frame (cached).  -> (N, 3)."""
        if name not in self._object_local:
            mesh = self.library.get(name).mesh
            points, _ = trimesh.sample.sample_surface_even(mesh, self.cfg.object_cloud_points, seed=self.cfg.cloud_seed)
            if len(points) < self.cfg.object_cloud_points:  # even sampling may return fewer: top up uniformly
                extra, _ = trimesh.sample.sample_surface(mesh, self.cfg.object_cloud_points - len(points), seed=self.cfg.cloud_seed)
                points = np.concatenate([points, extra])
            self._object_local[name] = np.asarray(points, dtype=np.float64)
        return self._object_local[name]

    def clouds(self, link_frames: np.ndarray, palm_pos: np.ndarray, palm_rot: np.ndarray, names,
               obj_pos: np.ndarray, obj_rot: np.ndarray) -> np.ndarray:
        """Hand cloud then one cloud per object, in the palm frame:  x_palm = R_palm^T (x_world - p_palm).
        link_frames (L, 4, 4) world.  -> (1 + n_obj, N, 3) with N = hand_cloud_points (object clouds are
        resampled to that size when object_cloud_points differs, by repetition)."""
        frames = link_frames[self.hand_link]  # (N, 4, 4)
        hand_world = np.einsum("nij,nj->ni", frames[:, :3, :3], self.hand_local) + frames[:, :3, 3]
        clouds = [hand_world]
        for name, pos, rot in zip(names, obj_pos, obj_rot):
            clouds.append(self.object_local(name) @ rot.T + pos)
        n = self.cfg.hand_cloud_points
        out = np.empty((len(clouds), n, 3))
        for k, cloud in enumerate(clouds):
            cloud = cloud if len(cloud) == n else cloud[np.arange(n) % len(cloud)]
            out[k] = (cloud - palm_pos) @ palm_rot
        return out

    def features(self, clouds: np.ndarray) -> np.ndarray:
        """encoder(clouds) (1 + n_obj, feature_dim) float32.  The fused PointNet runs on the numpy arrays directly
        (:meth:`FusedPointNetEncoder.encode_numpy`: no grad-mode switch, fewest torch calls); any other encoder
        under ``torch.inference_mode``."""
        if isinstance(self.encoder, FusedPointNetEncoder):
            out = self.encoder.encode_numpy(clouds)
        else:
            with torch.inference_mode():
                out = self.encoder(torch.from_numpy(np.asarray(clouds, dtype=np.float32))).cpu().numpy()
        if out.shape[-1] != self.cfg.feature_dim:
            raise ValueError(f"the point-cloud encoder gives {out.shape[-1]}-d features but lift.feature_dim is "
                             f"{self.cfg.feature_dim}; set lift.feature_dim to the encoder's output size")
        return out.astype(np.float32, copy=False)
