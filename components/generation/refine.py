"""Refinement of generated grasps (paper §"Multi-object Grasp Refinement"; DESIGN §5.3):

    min_H  E_g(H, O) = w_pen E_pen(H, O) + lambda_c E_contact(H, O; tau) + w_prior E_prior(H)

* E_pen: the synthesis energy's penetration (hand points in objects, object points in the hand, self
  penetration, hand below the table, with ``SynthesisConfig``'s default sub-weights), computed with the
  same code as :func:`components.synthesis.energy.energy` (:func:`components.synthesis.energy.penetration_energy`).
* E_contact (:func:`contact_energy`): hand surface points already within tau of an object surface are
  pulled onto it,  E_contact = 1 / (N_o |S|) sum_j sum_{x in S(H), |d(x, O_j)| < tau} |d(x, O_j)|,
  S(H) the hand's contact candidates (``HandModel.contact_candidates``: the palmar patches).  (The paper
  writes the sum with a minus sign and d <= tau; with |d| it is the stated intent: "guides floating
  fingers closer to the surfaces".)
* tau decreases linearly from ``tau_start_m`` (2 mm) to ``tau_end_m`` (1 mm) over the steps (:func:`tau_at`).
* E_prior: joint-limit violation; the joints are also clamped to their limits after every step.

Batched Adam on x = (p, rot6d, q) (:mod:`components.synthesis.pose`).

Optional second stage, force-closure refinement (``RefineConfig.fc_steps`` > 0; :func:`force_closure_refinement`):
the paper's objective only pulls hand points already within tau, so a sample that sits inside the objects is
backed out until nothing touches.  This stage runs the synthesis refinement
(:func:`components.synthesis.optimizer.refine`: Adam on the synthesis energy w_fc E_fc + w_dist E_dist +
w_pen E_pen + w_prior E_prior of the run's ``synthesis.optimizer``) for ``fc_steps`` steps, with each object's
``contacts_per_object`` contacts first assigned at the pose to the nearest candidates on distinct fingers
(:func:`components.synthesis.energy.nearest_contacts`) and then reassigned as the synthesis does.  It is the
synthesis' last stage seeded by the generator instead of the annealed chain.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor

from components.generation.config import RefineConfig
from components.hand import HandModel
from components.synthesis.config import SynthesisConfig
from components.synthesis.energy import GraspProblem, nearest_contacts, penetration_energy
from components.synthesis.pose import pack, unpack
from components.synthesis.scene_objects import SceneObjects

#: progress(step, total, info)
ProgressFn = Callable[[int, int, dict], None]


def refinement_problem(hand: HandModel, objects: SceneObjects, cfg: RefineConfig) -> GraspProblem:
    """The synthesis :class:`GraspProblem` (fixed object / hand surface samples) with this config's sample
    counts and coupling; the other synthesis settings (penetration sub-weights) keep their defaults."""
    synthesis = SynthesisConfig(object_surface_points=cfg.object_surface_points,
                                hand_point_spacing_m=cfg.hand_point_spacing_m,
                                couple_distal_joints=cfg.couple_distal_joints)
    return GraspProblem.build(hand, objects, synthesis)


def contact_energy(signed_distance: Tensor, tau: float) -> Tensor:
    """E_contact = 1 / (N_o |S|) sum_j sum_{x: |d(x, O_j)| < tau} |d(x, O_j)|  (m).
    signed_distance (B, |S|, N_o) of the hand points to each object -> (B,)."""
    near = signed_distance.abs() < tau
    return (signed_distance.abs() * near).sum((1, 2)) / (signed_distance.shape[1] * signed_distance.shape[2])


def tau_at(step: int, steps: int, cfg: RefineConfig) -> float:
    """tau_k = tau_start + (tau_end - tau_start) k / (steps - 1),  k = 0 .. steps-1 (tau_start if steps = 1)."""
    frac = step / (steps - 1) if steps > 1 else 0.0
    return cfg.tau_start_m + (cfg.tau_end_m - cfg.tau_start_m) * frac


def refinement_energy(problem: GraspProblem, x: Tensor, tau: float, cfg: RefineConfig) -> tuple[Tensor, dict]:
    """E_g (module docstring) of flat poses x (B, 31) -> (E_g (B,), terms {pen, contact, prior, depth} (B,))."""
    hand = problem.hand
    p, R, q = unpack(x)
    q = problem.effective_joints(q)
    frames = hand.forward_kinematics(q)  # one FK for both terms
    pen, depth = penetration_energy(problem, p, R, q, frames)
    contact = contact_energy(problem.objects.sdf(hand.contact_candidates(p, R, q, frames)), tau)
    prior = hand.joint_limit_violation(q)
    total = cfg.w_pen * pen + cfg.w_contact * contact + cfg.w_prior * prior
    return total, {"pen": pen.detach(), "contact": contact.detach(), "prior": prior.detach(), "depth": depth}


@dataclass
class RefineResult:
    """Refined poses p (B, 3), R (B, 3, 3), q (B, 22); E_g and the deepest penetration (m) before and after (B,)."""

    p: Tensor
    R: Tensor
    q: Tensor
    energy_before: Tensor
    energy_after: Tensor
    depth_before: Tensor
    depth_after: Tensor
    seconds: float


def force_closure_refinement(hand: HandModel, objects: SceneObjects, p: Tensor, R: Tensor, q: Tensor,
                             synthesis: SynthesisConfig, cfg: RefineConfig) -> tuple[Tensor, Tensor, Tensor]:
    """The synthesis refinement seeded by the given poses (module docstring, second stage): contacts from
    :func:`~components.synthesis.energy.nearest_contacts` at the pose, then
    :func:`components.synthesis.optimizer.refine` with ``synthesis`` and ``refine_steps = cfg.fc_steps``, E_pen sampled
    as the paper's stage samples it (``cfg.object_surface_points``, ``cfg.hand_point_spacing_m``), w_pen and refine_lr
    replaced by ``cfg.fc_w_pen`` / ``cfg.fc_lr`` when set.
    p (B, 3), R (B, 3, 3), q (B, 22) -> refined (p, R, q)."""
    from components.synthesis.optimizer import refine

    update = {"refine_steps": cfg.fc_steps, "object_surface_points": cfg.object_surface_points,
              "hand_point_spacing_m": cfg.hand_point_spacing_m}
    if cfg.fc_w_pen is not None:
        update["w_pen"] = cfg.fc_w_pen
    if cfg.fc_lr is not None:
        update["refine_lr"] = cfg.fc_lr
    problem = GraspProblem.build(hand, objects, synthesis.model_copy(update=update))
    x = pack(p, R, q).to(hand.dtype).detach()
    with torch.no_grad():
        points, normals = hand.contact_candidates_and_normals(p, R, problem.effective_joints(q))
        contacts = nearest_contacts(problem, points, normals)
    x, _, _ = refine(problem, x, contacts)
    p1, R1, q1 = unpack(x)
    return p1, R1, problem.effective_joints(q1)


def refine_grasps(hand: HandModel, objects: SceneObjects, p: Tensor, R: Tensor, q: Tensor, cfg: RefineConfig,
                  progress: Optional[ProgressFn] = None, problem: Optional[GraspProblem] = None,
                  synthesis: Optional[SynthesisConfig] = None) -> RefineResult:
    """Adam on x = (p, rot6d, q) for ``cfg.steps`` with tau_at(k) (module docstring); joints clamped to the limits
    after each step; with ``keep_best`` each row returns its lowest-E_g pose (evaluated at that step's tau).
    When ``cfg.fc_steps`` > 0, :func:`force_closure_refinement` with ``synthesis`` (the run's
    ``synthesis.optimizer`` for this many objects; required then) runs after these steps, or before them with
    ``fc_order='before'`` (the paper's objective then takes out the penetration the synthesis energy leaves).
    p (B, 3), R (B, 3, 3), q (B, 22) -> :class:`RefineResult`."""
    if cfg.fc_steps > 0 and synthesis is None:
        raise ValueError("refine.fc_steps > 0 needs the run's synthesis settings (refine_grasps(..., synthesis=...))")
    start = time.perf_counter()
    problem = problem if problem is not None else refinement_problem(hand, objects, cfg)
    lower, upper = hand.joint_limits.unbind(-1)
    x = pack(p, R, q).to(hand.dtype).detach().clone()
    with torch.no_grad():
        e0, t0 = refinement_energy(problem, x, cfg.tau_start_m, cfg)
    if cfg.fc_steps > 0 and cfg.fc_order == "before":
        x = pack(*force_closure_refinement(hand, objects, *unpack(x), synthesis, cfg)).to(x.dtype).clone()
    x.requires_grad_(True)
    optimiser = torch.optim.Adam([x], lr=cfg.lr)
    best_x, best_e = x.detach().clone(), torch.full_like(e0, float("inf"))
    with torch.enable_grad():
        for step in range(cfg.steps):
            e, terms = refinement_energy(problem, x, tau_at(step, cfg.steps, cfg), cfg)
            if cfg.keep_best:
                better = e.detach() < best_e
                best_e = torch.where(better, e.detach(), best_e)
                best_x = torch.where(better.unsqueeze(-1), x.detach(), best_x)
            optimiser.zero_grad(set_to_none=True)
            e.sum().backward()
            optimiser.step()
            with torch.no_grad():
                x[:, 9:] = torch.maximum(torch.minimum(x[:, 9:], upper), lower)
            if progress is not None:
                progress(step + 1, cfg.steps, {"energy_mean": float(e.mean()), "depth_max": float(terms["depth"].max())})
    x = x.detach()
    with torch.no_grad():
        e, _ = refinement_energy(problem, x, cfg.tau_end_m, cfg)
        if cfg.keep_best and cfg.steps > 0:
            x = torch.where((e < best_e).unsqueeze(-1), x, best_x)
    if cfg.fc_steps > 0 and cfg.fc_order == "after":
        x = pack(*force_closure_refinement(hand, objects, *unpack(x), synthesis, cfg)).to(x.dtype)
    with torch.no_grad():
        e1, t1 = refinement_energy(problem, x, cfg.tau_end_m, cfg)
    p1, R1, q1 = unpack(x)
    return RefineResult(p=p1, R=R1, q=problem.effective_joints(q1), energy_before=e0, energy_after=e1,
                        depth_before=t0["depth"], depth_after=t1["depth"], seconds=time.perf_counter() - start)
