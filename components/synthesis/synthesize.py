"""Synthesis of multi-object pre-grasps for one scene: init -> annealed MALA -> Adam refinement -> filter.

The paper's §"Preliminaries" pipeline (DFC extended to several objects), DESIGN §5.1::

    result = synthesize(hand, library, scene, SynthesisConfig(batch_size=64), torch.Generator().manual_seed(0))
    result.p[result.accepted], result.R[...], result.q[...]      # accepted pre-grasps
    result.reason_counts()                                         # {'accepted': 30, 'fc': 12, ...}
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from components.hand import HandModel
from components.objects import ObjectLibrary, Scene
from components.synthesis.config import SynthesisConfig
from components.synthesis.energy import CANDIDATE_POINTS, CONTACT_INDICES, GraspProblem, energy_and_grad, gather_contacts
from components.synthesis.filtering import count_reasons, filter_grasps
from components.synthesis.initializations import initial_poses
from components.synthesis.optimizer import ProgressFn, approach, refine, run_mala
from components.synthesis.pose import unpack
from components.synthesis.scene_objects import SceneObjects


@dataclass
class SynthesisResult:
    """Every candidate of one scene after synthesis (B = batch size, C = contacts per object).

    ``p`` (B, 3), ``R`` (B, 3, 3): palm pose in the world; ``q`` (B, 22): joint angles (J0 coupled when
    ``couple_distal_joints``); ``contacts`` (B, n_obj, C): candidate indices; ``contact_regions``
    (B, n_obj, C): their region indices (``HandModel.region_names``); ``contact_points`` (B, n_obj, C, 3):
    their world positions; ``energy`` (B,): E with the MALA
    weights (and w_q1 E_q1 when ``w_q1`` > 0, whatever ``q1_stages``); ``terms``: every term of :func:`components.synthesis.energy.energy` per row; ``accepted`` (B,);
    ``reasons``: per row ``"accepted"`` or the first failed filter criterion; ``stats``: timings and rates;
    ``lineage`` (B,): the candidate each row's chain descends from (its own index unless ``resample_at`` copied it).
    """

    scene: Scene
    object_names: list[str]
    p: Tensor
    R: Tensor
    q: Tensor
    contacts: Tensor
    contact_regions: Tensor
    contact_points: Tensor
    energy: Tensor
    terms: dict
    accepted: Tensor
    reasons: list[str]
    stats: dict = field(default_factory=dict)
    lineage: Optional[Tensor] = None

    @property
    def accept_rate(self) -> float:
        return float(self.accepted.float().mean())

    def reason_counts(self) -> dict[str, int]:
        return count_reasons(self.reasons)

    def to_numpy(self) -> dict[str, np.ndarray]:
        """Every tensor as a numpy array (for ``np.savez``); terms prefixed with ``term_``."""
        arrays = {k: getattr(self, k).detach().cpu().numpy()
                  for k in ("p", "R", "q", "contacts", "contact_regions", "contact_points", "energy", "accepted")}
        arrays.update({f"term_{k}": v.detach().cpu().numpy() for k, v in self.terms.items()})
        arrays["reasons"] = np.array(self.reasons)
        if self.lineage is not None:
            arrays["lineage"] = self.lineage.detach().cpu().numpy()
        return arrays


def synthesize(hand: HandModel, library: ObjectLibrary, scene: Scene, cfg: SynthesisConfig,
               generator: torch.Generator, progress: Optional[ProgressFn] = None) -> SynthesisResult:
    """Synthesise ``cfg.batch_size`` candidate pre-grasps of ``scene`` and filter them (module docstring).

    ``generator`` drives every random choice (initial poses and contacts, proposal noise, contact switches,
    Metropolis tests); ``progress(step, total, info)`` is called every ``cfg.progress_every`` steps of
    each stage (``info['stage']`` is ``'approach'`` (``approach_steps`` > 0), ``'mala'`` or ``'refine'``,
    with ``eta_s`` for that stage).
    """
    start = time.perf_counter()
    objects = SceneObjects(library, scene, hand.device, hand.dtype)
    problem = GraspProblem.build(hand, objects, cfg)
    x, contacts = initial_poses(problem, generator)
    approach_stats = {}
    if cfg.approach_steps > 0:
        x, contacts, approach_stats = approach(problem, x, contacts, progress)
    state, mala_stats = run_mala(problem, x, contacts, generator, progress)
    x, contacts, refine_stats = refine(problem, state.x, state.contacts, progress)
    energy, _, terms = energy_and_grad(problem, x, contacts)
    contacts = terms.pop(CONTACT_INDICES)  # the input ones, or those chosen by contact_assignment='nearest'
    contact_points = gather_contacts(terms.pop(CANDIDATE_POINTS), contacts)  # (B, n_obj, C, 3)
    accepted, reasons = filter_grasps(terms, cfg)
    p, R, q = unpack(x)
    q = problem.effective_joints(q)
    stats = {**approach_stats, **mala_stats, **refine_stats, "seconds": time.perf_counter() - start,
             "accept_rate": float(accepted.float().mean()),
             # distinct chains among the accepted rows (equals their number unless resample_at copied rows)
             "lineages_accepted": int(state.ancestor[accepted].unique().numel())}
    return SynthesisResult(scene=scene, object_names=list(objects.names), p=p, R=R, q=q, contacts=contacts,
                           contact_regions=hand.contact_region_of[contacts], contact_points=contact_points,
                           energy=energy, terms=terms,
                           accepted=accepted, reasons=reasons, stats=stats, lineage=state.ancestor)
