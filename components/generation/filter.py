"""The paper's filter of generated pre-grasps (§"Evaluation Protocols": generated poses "with significant penetration
or insufficient contact ratio" are discarded), :class:`~components.generation.config.GeneratedFilterConfig`.

    ratio = contact_ratio(hand, objects, p, R, q, synthesis.optimizer_for(n_objects), cfg.contact_distance_m)
    keep = keep_generated(pn_mm, ratio, cfg)

The contact ratio of a grasp is min over objects j of (1/C) #{c in contacts_j : |d_j(c)| <= contact_distance_m},
where contacts_j are the C = ``contacts_per_object`` hand candidates that
:func:`~components.synthesis.energy.nearest_contacts` assigns to object j at the pose (nearest, on distinct fingers):
the contacts the synthesis energy and filter judge a grasp by.
"""

from __future__ import annotations

import torch
from torch import Tensor

from components.generation.config import GeneratedFilterConfig
from components.hand import HandModel
from components.synthesis import SceneObjects, SynthesisConfig
from components.synthesis.energy import GraspProblem, nearest_contacts


def contact_ratio(hand: HandModel, objects: SceneObjects, p: Tensor, R: Tensor, q: Tensor,
                  synthesis: SynthesisConfig, distance_m: float) -> Tensor:
    """Contact ratio (module docstring) of each pose. p (B, 3), R (B, 3, 3), q (B, 22) -> (B,) in [0, 1]."""
    problem = GraspProblem.build(hand, objects, synthesis)
    with torch.no_grad():
        points, normals = hand.contact_candidates_and_normals(p, R, problem.effective_joints(q))
        contacts = nearest_contacts(problem, points, normals)  # (B, n_obj, C)
        distance = objects.sdf(points).abs().transpose(1, 2)  # (B, n_obj, K)
        touching = distance.gather(2, contacts) <= distance_m  # (B, n_obj, C)
        return touching.to(p.dtype).mean(-1).amin(-1)


def keep_generated(pn_mm: Tensor, ratio: Tensor, cfg: GeneratedFilterConfig) -> Tensor:
    """Which grasps the protocol keeps: PN within ``max_penetration_m`` and contact ratio at least
    ``min_contact_ratio`` (all of them when ``enabled`` is False). pn_mm, ratio (B,) -> bool (B,)."""
    if not cfg.enabled:
        return torch.ones_like(ratio, dtype=torch.bool)
    return (pn_mm <= cfg.max_penetration_m * 1000.0) & (ratio >= cfg.min_contact_ratio - 1e-9)
