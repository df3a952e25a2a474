"""PN, the maximal penetration depth between hand, objects and table (paper §"Pre-Grasp Proposals"; DESIGN §6).

PN of a grasp (mm) = the largest of

* **hand-object**, per object O: max( max over object surface samples o of -d_H(o),
  max over hand surface samples h of -d_O(h) ), with d_H the hand's exact signed distance (capsules, boxes,
  forearm cylinder; negative inside) and d_O the object's SDF.  ``pn_object_points`` samples per object
  (``ObjectModel.sample_surface``), hand samples every ``pn_hand_point_spacing_m`` on every collision
  primitive (:class:`components.synthesis.HandSurface`).  Each side is a sampled maximum, i.e. a lower bound
  of the deepest point that converges as the samples densify; for smooth contact the error is about
  s^2 / 8 (1 / r_1 + 1 / r_2) for sample spacing s and curvature radii r_1, r_2 (< 0.05 mm with the defaults
  for a 5 cm ball against a finger);
* **hand-table**: z_table - (lowest point of the hand), exact (support function of every primitive);
* **object-table**: z_table - (lowest object surface sample or mesh vertex), per object;
* **object-object**: for each pair, the deepest surface sample of one inside the other (both ways).

Hand self-penetration is not part of PN (the paper's definition names hand, objects and table).
Every depth is clamped at 0 (separated = 0).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch
from torch import Tensor

from components.hand import HandModel
from components.metrics.config import MetricsConfig
from components.synthesis.hand_surface import HandSurface
from components.synthesis.scene_objects import SceneObjects

#: Millimetres per metre (PN is reported in mm).
MM_PER_M = 1000.0


@dataclass
class PenetrationReport:
    """Depths in mm (module docstring): ``pn_mm`` (B,) the grasp's PN; its parts ``hand_object_mm`` (B, n_obj),
    ``hand_table_mm`` (B,), ``object_table_mm`` (n_obj,), ``object_object_mm`` (scalar, the scene's)."""

    pn_mm: Tensor
    hand_object_mm: Tensor
    hand_table_mm: Tensor
    object_table_mm: Tensor
    object_object_mm: float


def scene_penetration_m(objects: SceneObjects, cfg: MetricsConfig) -> tuple[Tensor, float]:
    """Object-table depth per object (n_obj,) and the deepest object-object penetration of the scene (m)."""
    samples = objects.surface_points(cfg.pn_object_points, cfg.surface_seed)  # (n_obj, P, 3)
    lowest = torch.stack([torch.minimum(samples[j, :, 2].min(), objects.mesh_vertices(j)[:, 2].min())
                          for j in range(objects.n_objects)])
    object_table = torch.relu(objects.table_height - lowest)
    object_object = 0.0
    with torch.no_grad():
        for a, b in itertools.permutations(range(objects.n_objects), 2):
            object_object = max(object_object, float(torch.relu(-objects.object_sdf(b, samples[a])).max()))
    return object_table, object_object


def hand_penetration_m(hand: HandModel, objects: SceneObjects, p: Tensor, R: Tensor, q: Tensor, cfg: MetricsConfig,
                       hand_surface: HandSurface) -> tuple[Tensor, Tensor]:
    """Hand-object depths (B, n_obj) and hand-table depths (B,) in metres (module docstring)."""
    n_obj = objects.n_objects
    object_points = objects.surface_points(cfg.pn_object_points, cfg.surface_seed)  # (n_obj, P, 3)
    flat = object_points.reshape(1, -1, 3)
    hand_object, hand_table = [], []
    with torch.no_grad():
        for start in range(0, p.shape[0], cfg.batch_chunk):
            pc, Rc, qc = p[start:start + cfg.batch_chunk], R[start:start + cfg.batch_chunk], q[start:start + cfg.batch_chunk]
            batch = pc.shape[0]
            d_hand = hand.signed_distance(flat.expand(batch, -1, -1), pc, Rc, qc).reshape(batch, n_obj, -1)
            d_obj = objects.sdf(hand_surface.world(hand, pc, Rc, qc))  # (b, M, n_obj)
            hand_object.append(torch.maximum(torch.relu(-d_hand).amax(-1), torch.relu(-d_obj).amax(1)))
            hand_table.append(torch.relu(objects.table_height - hand.geom_lowest_heights(pc, Rc, qc).amin(-1)))
    return torch.cat(hand_object), torch.cat(hand_table)


def penetration_depth(hand: HandModel, objects: SceneObjects, p: Tensor, R: Tensor, q: Tensor, cfg: MetricsConfig,
                      hand_surface: HandSurface | None = None) -> PenetrationReport:
    """PN (mm) of every grasp H = (p (B, 3), R (B, 3, 3), q (B, 22)) in the scene of ``objects``."""
    samples = hand_surface if hand_surface is not None else HandSurface(hand, cfg.pn_hand_point_spacing_m)
    hand_object, hand_table = hand_penetration_m(hand, objects, p, R, q, cfg, samples)
    object_table, object_object = scene_penetration_m(objects, cfg)
    scene_max = max(float(object_table.max()), object_object)
    pn = torch.maximum(hand_object.amax(-1), hand_table).clamp_min(scene_max)
    return PenetrationReport(pn_mm=pn * MM_PER_M, hand_object_mm=hand_object * MM_PER_M, hand_table_mm=hand_table * MM_PER_M,
                             object_table_mm=object_table * MM_PER_M, object_object_mm=object_object * MM_PER_M)
