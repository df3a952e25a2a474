"""Training data of the grasp generator: the synthesis stage's accepted grasps, palm-aligned (paper
§"Multi-object Grasp Generation", Fig. palm-align; DESIGN §5.2).

Input: a pandas DataFrame with the columns of ``grasps.parquet`` (:mod:`tasks.synthesize`):
``object_names`` (list), ``object_positions`` (n_obj x 3 flat), ``object_quats_xyzw`` (n_obj x 4 flat),
``p`` (3), ``R`` (9, row-major), ``q`` (22); ``accepted`` (kept only where True, if present) and
``split`` (optionally filtered) are used when present.

Per grasp, exactly as :func:`~components.generation.generator.generate_grasps` conditions at generation:

* **Object clouds.**  Each object's cloud is a fixed set of ``cfg.points_per_object`` surface samples in its
  own frame (``ObjectModel.sample_surface(n, seed=CLOUD_SEED)``, the same for every scene), posed in the
  world by the row's position and quaternion.  Slots beyond the scene's objects are zero and masked out.
* **Pivot.**  c = mean over the scene's objects of each posed cloud's mean (x, y; z = 0) -- the centroid
  generate_grasps uses.
* **Alignment.**  theta = yaw of the palm direction -R e_y (:func:`~components.generation.canonical.palm_direction`);
  ``AlignedFrame(theta, c)`` maps the hand pose and the clouds to the aligned frame, where the palm
  direction's table projection is +x and the objects' centroid is at the origin in x, y (heights kept).
* **Hand.**  x_0 = :func:`~components.generation.representation.to_representation` of the aligned pose
  (31 keypoints, 93 numbers, or (p, rot6d, q), 31 numbers).

No random z-rotation augmentation: the alignment removes yaw.  The clouds are stored once per distinct
scene (centred on the pivot, not rotated) and rotated by each grasp's yaw in :meth:`GraspDataset.batch`,
so memory grows with the scenes, not with the grasps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import pandas as pd
import torch
from scipy.spatial.transform import Rotation
from torch import Tensor

from components.errors import MultigraspError
from components.generation.canonical import AlignedFrame
from components.generation.config import GeneratorConfig
from components.generation.denoiser import ObjectInputs
from components.generation.representation import to_representation
from components.hand import HandModel

#: Seed of every object's fixed surface samples (the generation stage must use the same one).
CLOUD_SEED = 0
_REQUIRED = ("object_names", "object_positions", "object_quats_xyzw", "p", "R", "q")
_HAND_CHUNK = 2048


def object_cloud(library, name: str, points: int) -> np.ndarray:
    """The fixed surface samples (points, 3) of object ``name`` in its own frame (m)."""
    return np.asarray(library.get(name).sample_surface(points, seed=CLOUD_SEED), dtype=np.float64)


def posed_clouds(library, names: Sequence[str], positions: np.ndarray, quats_xyzw: np.ndarray, points: int,
                 max_objects: int, cache: Optional[dict] = None) -> tuple[np.ndarray, np.ndarray]:
    """World clouds (max_objects, points, 3) of one scene (zeros in empty slots) and its slot mask (max_objects,).
    positions (n_obj, 3) or flat, quats_xyzw (n_obj, 4) or flat.  ``cache`` maps name -> object_cloud."""
    names = [str(n) for n in names]
    if len(names) > max_objects:
        raise MultigraspError(
            f"a scene with {len(names)} objects ({'+'.join(names)}) is in the generator's data but "
            f"generator.max_objects = {max_objects}; raise generator.max_objects or leave that split out")
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    quats = np.asarray(quats_xyzw, dtype=np.float64).reshape(-1, 4)
    if len(positions) != len(names) or len(quats) != len(names):
        raise MultigraspError(
            f"a synthesis row lists {len(names)} objects but {len(positions)} positions / {len(quats)} quaternions; "
            "the grasps table is corrupt, rerun the synthesize stage")
    cache = {} if cache is None else cache
    clouds = np.zeros((max_objects, points, 3))
    mask = np.zeros(max_objects, dtype=bool)
    for j, name in enumerate(names):
        if name not in cache:
            cache[name] = object_cloud(library, name, points)
        clouds[j] = cache[name] @ Rotation.from_quat(quats[j]).as_matrix().T + positions[j]
        mask[j] = True
    return clouds, mask


def scene_pivot(clouds: Tensor, mask: Tensor) -> Tensor:
    """Mean over the valid objects of each cloud's mean -- the pivot of generate_grasps.
    clouds (B, n_obj, N, 3), mask (B, n_obj) -> (B, 3)."""
    weights = mask.to(clouds.dtype).unsqueeze(-1)
    return (clouds.mean(2) * weights).sum(1) / weights.sum(1).clamp_min(1.0)


def _stack(column: pd.Series, width: int, name: str) -> np.ndarray:
    try:
        out = np.stack([np.asarray(v, dtype=np.float64).reshape(-1) for v in column])
    except (ValueError, TypeError):
        out = None
    if out is None or out.shape[1] != width:
        raise MultigraspError(f"column '{name}' of the grasps table does not hold {width} numbers per row; "
                              "the table is corrupt, rerun the synthesize stage")
    return out


@dataclass
class GraspDataset:
    """Palm-aligned grasps and their scenes (module docstring).  Build with :meth:`from_frame`.

    Attributes (N grasps, S distinct scenes, K = max_objects, P = points_per_object):
    ``x0`` (N, D) float32 hand representations;  ``scene_index`` (N,) long;  ``yaw`` (N,) palm yaw (rad);
    ``pivot`` (N, 3) (z = 0);  ``scene_clouds`` (S, K, P, 3) float32 world clouds minus their pivot;
    ``scene_mask`` (S, K) bool;  ``p``, ``R``, ``q`` (N, 3), (N, 3, 3), (N, 22) the aligned poses (float32);
    ``cfg`` the GeneratorConfig the data was built for."""

    x0: Tensor
    scene_index: Tensor
    yaw: Tensor
    pivot: Tensor
    scene_clouds: Tensor
    scene_mask: Tensor
    p: Tensor
    R: Tensor
    q: Tensor
    cfg: GeneratorConfig

    @classmethod
    def from_frame(cls, frame: pd.DataFrame, library, hand: HandModel, cfg: GeneratorConfig,
                   splits: Optional[Sequence[str]] = None) -> "GraspDataset":
        """The dataset of the accepted rows of ``frame`` (of ``splits`` when given and ``split`` is a column)."""
        if frame is not None and len(frame):
            missing = [c for c in _REQUIRED if c not in frame.columns]
            if missing:
                raise MultigraspError(f"the grasps table lacks column(s) {', '.join(missing)}; rerun the synthesize stage")
            if "accepted" in frame.columns:
                frame = frame[frame["accepted"].astype(bool)]
            if splits is not None and "split" in frame.columns:
                frame = frame[frame["split"].isin(list(splits))]
        if frame is None or not len(frame):
            where = f" in split(s) {', '.join(splits)}" if splits is not None else ""
            raise MultigraspError(
                f"no grasps to train on; the synthesis stage accepted none{where} (see its report.md; synthesise more "
                "scenes or relax synthesize.optimizer's filter, then rerun multigrasp run --until train-generator)")
        frame = frame.reset_index(drop=True)
        n, k, points = len(frame), cfg.max_objects, cfg.points_per_object

        # ---------------------------------------------------------------- scenes (deduplicated)
        cache: dict = {}
        keys: dict = {}
        scene_of = np.empty(n, dtype=np.int64)
        clouds, masks = [], []
        for i, (names, pos, quat) in enumerate(zip(frame["object_names"], frame["object_positions"],
                                                    frame["object_quats_xyzw"])):
            names = tuple(str(x) for x in names)
            pos, quat = np.asarray(pos, dtype=np.float64), np.asarray(quat, dtype=np.float64)
            key = (names, pos.tobytes(), quat.tobytes())
            if key not in keys:
                cloud, mask = posed_clouds(library, names, pos, quat, points, k, cache)
                keys[key] = len(clouds)
                clouds.append(cloud)
                masks.append(mask)
            scene_of[i] = keys[key]
        world = torch.as_tensor(np.stack(clouds))  # (S, K, P, 3) float64
        scene_mask = torch.as_tensor(np.stack(masks))
        scene_pivots = scene_pivot(world, scene_mask)
        scene_pivots[:, 2] = 0.0
        centred = (world - scene_pivots[:, None, None, :]) * scene_mask[..., None, None]

        # ---------------------------------------------------------------- hands
        p = torch.as_tensor(_stack(frame["p"], 3, "p"))
        R = torch.as_tensor(_stack(frame["R"], 9, "R")).reshape(n, 3, 3)
        q = torch.as_tensor(_stack(frame["q"], 22, "q"))
        index = torch.as_tensor(scene_of)
        aligned = AlignedFrame.from_palm(R, scene_pivots[index])
        p_al, R_al = aligned.pose_to_aligned(p, R)
        x0 = []
        with torch.no_grad():
            for lo in range(0, n, _HAND_CHUNK):
                sl = slice(lo, lo + _HAND_CHUNK)
                args = [t[sl].to(device=hand.device, dtype=hand.dtype) for t in (p_al, R_al, q)]
                x0.append(to_representation(hand, *args, cfg.representation).detach().cpu().float())
        x0 = torch.cat(x0)
        if not bool(torch.isfinite(x0).all()):
            raise MultigraspError("the grasps table holds non-finite hand poses; rerun the synthesize stage")
        return cls(x0=x0, scene_index=index, yaw=aligned.yaw.float(), pivot=aligned.pivot.float(),
                   scene_clouds=centred.float(), scene_mask=scene_mask, p=p_al.float(), R=R_al.float(), q=q.float(),
                   cfg=cfg)

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return int(self.x0.shape[0])

    @property
    def dim(self) -> int:
        """D of the hand representation."""
        return int(self.x0.shape[1])

    @property
    def scenes(self) -> int:
        """Distinct scenes S."""
        return int(self.scene_clouds.shape[0])

    def objects(self, indices) -> ObjectInputs:
        """Aligned object clouds (B, K, P, 3) and slot mask (B, K) of grasps ``indices``."""
        indices = torch.as_tensor(indices, dtype=torch.long)
        scenes = self.scene_index[indices]
        frame = AlignedFrame(self.yaw[indices], torch.zeros(len(indices), 3))  # clouds are stored pivot-centred
        return ObjectInputs(frame.points_to_aligned(self.scene_clouds[scenes]), self.scene_mask[scenes])

    def batch(self, indices, device=None) -> tuple[Tensor, ObjectInputs]:
        """(x0 (B, D), ObjectInputs) of grasps ``indices`` (on ``device`` if given)."""
        indices = torch.as_tensor(indices, dtype=torch.long)
        x0, objects = self.x0[indices], self.objects(indices)
        if device is not None:
            x0 = x0.to(device)
            objects = ObjectInputs(objects.clouds.to(device), objects.mask.to(device))
        return x0, objects
