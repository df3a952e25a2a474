"""Optimisers of the grasp energy: annealed MALA with contact switching, then Adam refinement (DESIGN §5.1).

:class:`Annealer` follows DexGraspNet's ``Annealing`` optimiser (``try_step`` / ``accept_step``) with the
MultiGrasp schedule.  One step t, for every row b of the batch:

1. proposal  x' = x - s_t * k * g / (sqrt(v) + eps) + s_t * k * sigma * xi,   xi ~ N(0, I),
   with g = grad_x E(x, c) at the current state, v the EMA (decay ``rmsprop_decay``) of g^2 per parameter,
   averaged over the batch as in DexGraspNet (or per row with ``rmsprop_per_row``) -- RMSProp
   preconditioning --, k the per-group multiplier (translation / rotation / joints) and
   sigma = ``langevin_noise``.  With ``mala_step_rule='release'`` instead the official release's
   x' = x - s_t^2 / 2 * m * g~ + s_t * sigma * xi (plain gradient steps; rotation gradient x 10, joint gradient
   normalised by the EMA of its batch-mean |g| and weighted 85 -> 25; :meth:`Annealer._release_direction`);
2. contacts  c': with probability ``contact_switch_probability`` one random contact of every object
   (``contact_switch_mode='per_step'``, the official MultiGrasp rule) or each contact independently
   (``'per_contact'``, DexGraspNet's rule) moves to a uniformly drawn candidate used by no contact of the
   row -- of its own hand region with probability ``contact_switch_local_probability`` (a slide along the
   link, standing in for the official release's continuous contact weights within a region), else of
   any region -- so all contacts of a row stay distinct;
3. Metropolis test at temperature T_t:  accept with probability min(1, exp((E(x, c) - E(x', c')) / T_t));
   a rejected row keeps its state, energy and gradient.

Schedules:  s_t = s_0 * decay^floor(t / P_s),  T_t = T_0 * decay^floor(t / P_T)  (official s_0 = 0.01,
T_0 = 8, decay 0.95, P_s = 100, P_T = 50; both periods scaled to the run length when
``compress_schedule``).  Like the official code and DexGraspNet, the proposal is not corrected by the
reverse-move density, so this is annealed Langevin with a Metropolis energy test rather than exact MALA.

:func:`refine` then runs Adam on the same energy (E_dist weighted by ``refine_w_dist``) with the
contacts fixed, keeping each row's lowest-energy pose.  The optional smooth-Q1 term E_q1 (``w_q1``) acts in
the refinement only, or in MALA as well (``q1_stages``); the approach stage never sees it.

Optional population resampling (``resample_at``, not in the paper): at the given fractions of the MALA chain the
``resample_fraction`` worst rows by score (E, plus ``resample_w_q1`` times the smooth-Q1 hinge) restart from
copies of the best rows (:func:`resample_sources`, :meth:`Annealer.resample`); ``AnnealerState.ancestor`` keeps
each row's original index, so the number of distinct lineages among the accepted grasps can be reported.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor

from components.synthesis.config import SynthesisConfig
from components.synthesis.energy import CONTACT_INDICES, GraspProblem, best_contacts, energy, energy_and_grad
from components.synthesis.pose import JOINTS, ROTATION, TRANSLATION, unpack

#: progress(step, total, info): called every ``progress_every`` steps with a dict of scalars
#: (stage, energy_mean, accept_rate, step_size, temperature, elapsed_s, eta_s).
ProgressFn = Callable[[int, int, dict], None]


def step_size_at(t: int, cfg: SynthesisConfig) -> float:
    """s_t = s_0 * decay^floor(t / P_s)  (module docstring)."""
    period, _ = cfg.schedule_periods()
    return cfg.step_size * cfg.step_size_decay ** (t // period)


def temperature_at(t: int, cfg: SynthesisConfig) -> float:
    """T_t = T_0 * decay^floor(t / P_T)  (module docstring)."""
    _, period = cfg.schedule_periods()
    return cfg.temperature * cfg.temperature_decay ** (t // period)


def fc_weight_at(t: int, cfg: SynthesisConfig) -> float:
    """Staged objective (``w_fc_ramp_fraction`` = f): w_fc(t) = w_fc * floor(10 t / (f N)) / 10 for t < f N
    (N = ``mala_steps``), w_fc afterwards -- ten piecewise-constant levels from 0."""
    ramp = cfg.w_fc_ramp_fraction * cfg.mala_steps
    if ramp <= 0.0 or t >= ramp:
        return cfg.w_fc
    return cfg.w_fc * math.floor(10.0 * t / ramp) / 10.0


def reassign_contacts(problem: GraspProblem, x: Tensor, contacts: Tensor, w_fc: Optional[float] = None,
                      w_dist: Optional[float] = None, w_align: Optional[float] = None) -> Tensor:
    """:func:`~components.synthesis.energy.best_contacts` at the poses x (B, D).  -> contacts (B, n_obj, C)."""
    with torch.no_grad():
        p, R, q = unpack(x)
        points, normals = problem.hand.contact_candidates_and_normals(p, R, problem.effective_joints(q))
        return best_contacts(problem, points, normals, contacts, w_fc=w_fc, w_dist=w_dist, w_align=w_align)


def switch_contacts(contacts: Tensor, region_of: Tensor, cfg: SynthesisConfig, generator: torch.Generator,
                    finger_of: Optional[Tensor] = None, log_weights: Optional[Tensor] = None,
                    candidate_allowed: Optional[Tensor] = None) -> Tensor:
    """Stochastic contact switching (module docstring, step 2).

    Which contacts switch: with ``contact_switch_mode='per_step'``, with probability p a row switches one
    uniformly chosen contact of every object; with ``'per_contact'`` each contact switches independently
    with probability p (p = ``contact_switch_probability``).  Where to, among the *allowed* candidates --
    used by no contact of the row (itself included, so a switch always changes it) and, when ``finger_of``
    (K,) is given, on no finger already touching the same object through another of its contacts, and, when
    ``candidate_allowed`` (K,) bool is given, among those it allows (``contact_regions_excluded``):

    * with probability ``contact_switch_local_probability``, uniformly in the contact's own hand region
      (it slides along its link; falls back to the next rule when the region has no allowed candidate);
    * else, when ``log_weights`` (B, n_obj, K) is given, with probability
      ``contact_switch_guided_probability``, candidate k with probability proportional to
      exp(log_weights[b, j, k]) (the guided proposal of :meth:`Annealer.try_step`);
    * else uniformly.

    Draws use the exponential race:  argmin_k E_k / w_k  with E_k ~ Exp(1) picks k with probability
    w_k / sum(w).   contacts (B, n_obj, C), region_of (K,) -> (B, n_obj, C).
    """
    batch, n_obj, per_object = contacts.shape
    n_candidates = region_of.shape[0]
    flat = contacts.reshape(batch, -1).clone()  # (B, S)
    n_slots = flat.shape[1]

    def uniform(*shape: int) -> Tensor:
        return torch.rand(*shape, generator=generator, device=generator.device).to(flat.device)

    if cfg.contact_switch_mode == "per_contact":
        switch = uniform(batch, n_slots) < cfg.contact_switch_probability
    else:
        row = uniform(batch, 1) < cfg.contact_switch_probability  # (B, 1)
        which = torch.randint(per_object, (batch, n_obj), generator=generator, device=generator.device).to(flat.device)
        switch = row & torch.nn.functional.one_hot(which, per_object).bool().reshape(batch, n_slots)
    local = uniform(batch, n_slots) < cfg.contact_switch_local_probability  # (B, S)
    guided = uniform(batch, n_slots) < cfg.contact_switch_guided_probability  # (B, S)
    for slot in range(n_slots):
        rows = switch[:, slot].nonzero().squeeze(-1)  # (R,)
        if rows.numel() == 0:
            continue
        obj = slot // per_object
        allowed = torch.ones(rows.numel(), n_candidates, dtype=torch.bool, device=flat.device)
        allowed.scatter_(1, flat[rows], False)  # (R, K): no candidate used in the row
        if candidate_allowed is not None:
            allowed &= candidate_allowed.unsqueeze(0)
        if finger_of is not None:
            siblings = [obj * per_object + c for c in range(per_object) if obj * per_object + c != slot]
            for other in siblings:  # no finger already on this object
                allowed &= finger_of.unsqueeze(0) != finger_of[flat[rows, other]].unsqueeze(1)
        same_region = region_of.unsqueeze(0) == region_of[flat[rows, slot]].unsqueeze(1)  # (R, K)
        local_ok = allowed & same_region
        use_local = local[rows, slot] & local_ok.any(1)  # (R,)
        allowed = torch.where(use_local.unsqueeze(1), local_ok, allowed)
        # a row with no allowed candidate at all (only with very few candidates) keeps its contact
        stuck = ~allowed.any(1)
        race = -torch.log(uniform(rows.numel(), n_candidates).clamp_min(torch.finfo(torch.float32).tiny))  # Exp(1)
        keys = race.log()
        if log_weights is not None:
            use_guide = (guided[rows, slot] & ~use_local).unsqueeze(1)
            keys = keys - torch.where(use_guide, log_weights[rows, obj].to(keys.dtype), torch.zeros_like(keys))
        keys = keys.masked_fill(~allowed, float("inf"))
        flat[rows, slot] = torch.where(stuck, flat[rows, slot], keys.argmin(1))
    return flat.reshape(contacts.shape)


def resample_sources(score: Tensor, fraction: float) -> Tensor:
    """Elitist resampling of a population of B rows ranked by ``score`` (B,), lower is better (non-finite last):
    the k = floor(``fraction`` B) worst rows take the state of the best survivors, the best first and each survivor
    at most ceil(k / (B - k)) times; every other row keeps its own.  -> source (B,) long: row b continues from
    row source[b]."""
    n = score.shape[0]
    k = min(int(fraction * n), n - 1)
    source = torch.arange(n, device=score.device)
    if k <= 0:
        return source
    ranked = torch.where(torch.isfinite(score), score, torch.full_like(score, float("inf")))
    order = torch.argsort(ranked, stable=True)  # best first
    survivors, replaced = order[: n - k], order[n - k:]
    source[replaced] = survivors[torch.arange(k, device=score.device) % (n - k)]
    return source


@dataclass
class AnnealerState:
    """The chain of every row: pose x (B, D), contacts (B, n_obj, C), energy (B,), gradient (B, D), terms, and
    ancestor (B,): the index of the row each chain descends from (itself unless resampled)."""

    x: Tensor
    contacts: Tensor
    energy: Tensor
    grad: Tensor
    terms: dict
    ancestor: Optional[Tensor] = None

    def __post_init__(self) -> None:
        if self.ancestor is None:
            self.ancestor = torch.arange(self.x.shape[0], device=self.x.device)


class Annealer:
    """Annealed MALA with RMSProp preconditioning and contact switching (module docstring)."""

    def __init__(self, problem: GraspProblem, x: Tensor, contacts: Tensor, generator: torch.Generator):
        self.problem, self.cfg, self.generator = problem, problem.cfg, generator
        self.w_fc = fc_weight_at(0, self.cfg)
        self.w_q1 = self.cfg.w_q1 if self.cfg.q1_stages == "mala_refine" else 0.0
        energy, grad, terms = energy_and_grad(problem, x, contacts, w_fc=self.w_fc, w_q1=self.w_q1)
        self.state = AnnealerState(x.detach(), terms[CONTACT_INDICES], energy, grad, terms)
        self.grad_sq_ema = self._grad_sq(grad)  # (D,) or (B, D), initialised with the first gradient
        self.scale = torch.ones_like(x[0])  # (D,) per-group step multipliers
        self.scale[TRANSLATION] = self.cfg.step_scale_translation
        self.scale[ROTATION] = self.cfg.step_scale_rotation
        self.scale[JOINTS] = self.cfg.step_scale_joints
        self.joint_abs_ema: Optional[Tensor] = None  # (D_q,) EMA of the batch-mean |joint gradient| ('release' rule)
        self.step = 0
        self._proposal: Optional[tuple[Tensor, Tensor]] = None

    def _grad_sq(self, grad: Tensor) -> Tensor:
        """g^2 averaged over the batch (D,), or per row (B, D) with ``rmsprop_per_row``."""
        return grad * grad if self.cfg.rmsprop_per_row else (grad * grad).mean(0)

    def try_step(self) -> tuple[Tensor, Tensor]:
        """Propose (x', c') from the current state (steps 1 and 2); returns and remembers the proposal."""
        cfg, state = self.cfg, self.state
        s = step_size_at(self.step, cfg)
        decay = cfg.rmsprop_decay
        noise = torch.randn(state.x.shape, generator=self.generator, dtype=state.x.dtype,
                            device=self.generator.device).to(state.x.device)
        if cfg.mala_step_rule == "release":
            x_new = state.x - 0.5 * s * s * self._release_direction() + s * cfg.langevin_noise * noise
        else:
            self.grad_sq_ema = decay * self.grad_sq_ema + (1.0 - decay) * self._grad_sq(state.grad)
            precond = state.grad / (self.grad_sq_ema.sqrt() + cfg.rmsprop_epsilon)  # (B, D)
            x_new = state.x - s * self.scale * precond + s * self.scale * cfg.langevin_noise * noise
        if cfg.contact_assignment == "nearest":  # the energy chooses the contacts from the pose
            contacts_new = state.contacts
        else:
            contacts_new = switch_contacts(state.contacts, self.problem.hand.contact_region_of, cfg, self.generator,
                                           finger_of=self.problem.finger_of if cfg.contact_distinct_fingers else None,
                                           log_weights=self._guide_log_weights(),
                                           candidate_allowed=self.problem.candidate_allowed)
        self._proposal = (x_new, contacts_new)
        return x_new, contacts_new

    def release_joint_weight(self) -> float:
        """w(t) of the 'release' step rule: release_joint_weight_start falling linearly to release_joint_weight_end
        at release_joint_weight_fraction of the chain, constant afterwards."""
        cfg = self.cfg
        span = cfg.release_joint_weight_fraction * cfg.mala_steps
        left = max(span - self.step, 0.0) / span if span > 0 else 0.0
        return cfg.release_joint_weight_end + (cfg.release_joint_weight_start - cfg.release_joint_weight_end) * left

    def _release_direction(self) -> Tensor:
        """m * g~ of the 'release' step rule (SynthesisConfig.mala_step_rule): the translation gradient as is, the
        rotation gradient times release_rotation_gradient_scale, the joint gradient over the EMA of its batch-mean
        |g| (per joint, decay rmsprop_decay, started at the first gradient) times w(t).  (B, D)."""
        cfg, grad = self.cfg, self.state.grad
        joint_abs = grad[:, JOINTS].abs().mean(0)  # (D_q,)
        if self.joint_abs_ema is None:
            self.joint_abs_ema = joint_abs
        else:
            self.joint_abs_ema = cfg.rmsprop_decay * self.joint_abs_ema + (1.0 - cfg.rmsprop_decay) * joint_abs
        direction = grad.clone()
        direction[:, ROTATION] = grad[:, ROTATION] * cfg.release_rotation_gradient_scale
        direction[:, JOINTS] = grad[:, JOINTS] / (self.joint_abs_ema + cfg.rmsprop_epsilon) * self.release_joint_weight()
        return direction

    def _guide_log_weights(self) -> Optional[Tensor]:
        """log w[b, j, k] = -|d_j(candidate k of row b)| / ``contact_switch_guide_scale_m``: guided switches favour
        hand candidates already near the object (None when guided switches are off).  (B, n_obj, K)."""
        if self.cfg.contact_switch_guided_probability <= 0.0 or self.cfg.contact_switch_probability <= 0.0:
            return None
        points = self.state.terms["candidate_points"]  # (B, K, 3) of the current pose
        distance = self.problem.objects.sdf(points).abs()  # (B, K, n_obj)
        return -(distance / self.cfg.contact_switch_guide_scale_m).transpose(1, 2)

    def accept_step(self) -> Tensor:
        """Evaluate the proposal, apply the Metropolis test at T_t (step 3), advance t.  -> accept mask (B,)."""
        if self._proposal is None:
            raise RuntimeError("accept_step needs a proposal: call try_step first")
        x_new, contacts_new = self._proposal
        self._proposal = None
        energy_new, grad_new, terms_new = energy_and_grad(self.problem, x_new, contacts_new, w_fc=self.w_fc,
                                                          w_q1=self.w_q1)
        state = self.state
        temperature = temperature_at(self.step, self.cfg)
        alpha = torch.rand(state.energy.shape, generator=self.generator, dtype=state.energy.dtype,
                           device=self.generator.device).to(state.energy.device)
        # non-finite proposals (e.g. a degenerate rotation) are always rejected
        accept = (alpha < torch.exp((state.energy - energy_new) / temperature)) & torch.isfinite(energy_new)
        keep = accept.unsqueeze(-1)
        state.x = torch.where(keep, x_new, state.x)
        state.grad = torch.where(keep, grad_new, state.grad)
        state.contacts = torch.where(keep.unsqueeze(-1), terms_new[CONTACT_INDICES], state.contacts)
        state.energy = torch.where(accept, energy_new, state.energy)
        state.terms = {k: torch.where(accept.reshape(-1, *[1] * (v.dim() - 1)), terms_new[k], v)
                       for k, v in state.terms.items()}
        self.step += 1
        self._between_steps()
        return accept

    def resample_score(self) -> Tensor:
        """Score of every row for :meth:`resample` (lower is better): E + ``resample_w_q1`` sum_j relu(q1_target -
        Q1~_j), the smooth-Q1 hinge computed here (no gradient) when ``resample_w_q1`` > 0.  -> (B,)."""
        score = self.state.energy
        if self.cfg.resample_w_q1 > 0:
            with torch.no_grad():
                _, terms = energy(self.problem, self.state.x, self.state.contacts, w_fc=self.w_fc, w_q1=1.0)
            score = score + self.cfg.resample_w_q1 * terms["q1"]
        return score

    def resample(self, source: Tensor) -> None:
        """Row b continues from row source[b]'s state (pose, contacts, energy, gradient, terms, ancestor and, per
        row, the squared-gradient EMA); see :func:`resample_sources`.  The copies' palm positions and joint
        angles then get Gaussian noise of ``resample_jitter_translation_m`` / ``resample_jitter_joints_rad``
        (their energy, gradient and terms recomputed)."""
        cfg, state = self.cfg, self.state
        state.x, state.contacts = state.x[source], state.contacts[source]
        state.energy, state.grad = state.energy[source], state.grad[source]
        state.terms = {k: v[source] for k, v in state.terms.items()}
        state.ancestor = state.ancestor[source]
        if self.grad_sq_ema.dim() == 2:
            self.grad_sq_ema = self.grad_sq_ema[source]
        if cfg.resample_jitter_translation_m <= 0 and cfg.resample_jitter_joints_rad <= 0:
            return
        copies = (source != torch.arange(source.shape[0], device=source.device)).unsqueeze(-1)  # (B, 1)
        noise = torch.randn(state.x.shape, generator=self.generator, dtype=state.x.dtype,
                            device=self.generator.device).to(state.x.device)
        scale = torch.zeros_like(state.x[0])
        scale[TRANSLATION], scale[JOINTS] = cfg.resample_jitter_translation_m, cfg.resample_jitter_joints_rad
        state.x = state.x + copies * scale * noise
        state.energy, state.grad, state.terms = energy_and_grad(self.problem, state.x, state.contacts, w_fc=self.w_fc,
                                                                w_q1=self.w_q1)
        state.contacts = state.terms[CONTACT_INDICES]

    def _between_steps(self) -> None:
        """Schedule changes after step t: a new E_fc weight level (``w_fc_ramp_fraction``) and the periodic
        contact reassignment (``contact_reassign_every``); either re-evaluates the state's energy and gradient."""
        cfg, state = self.cfg, self.state
        w_fc = fc_weight_at(self.step, cfg)
        reassign = cfg.contact_reassign_every > 0 and self.step % cfg.contact_reassign_every == 0 \
            and cfg.contact_assignment != "nearest"
        if w_fc == self.w_fc and not reassign:
            return
        self.w_fc = w_fc
        if reassign:
            state.contacts = reassign_contacts(self.problem, state.x, state.contacts, w_fc=w_fc)
        state.energy, state.grad, state.terms = energy_and_grad(self.problem, state.x, state.contacts, w_fc=w_fc,
                                                                w_q1=self.w_q1)
        state.contacts = state.terms[CONTACT_INDICES]


def _report(progress: Optional[ProgressFn], cfg: SynthesisConfig, step: int, total: int, start: float, info: dict) -> None:
    if progress is None or not (step % cfg.progress_every == 0 or step == total):
        return
    elapsed = time.perf_counter() - start
    progress(step, total, {**info, "elapsed_s": elapsed, "eta_s": elapsed / max(step, 1) * (total - step)})


def run_mala(problem: GraspProblem, x: Tensor, contacts: Tensor, generator: torch.Generator,
             progress: Optional[ProgressFn] = None) -> tuple[AnnealerState, dict]:
    """``cfg.mala_steps`` annealer steps from (x, contacts).  -> (final state, stats: mean accept rate, seconds)."""
    cfg = problem.cfg
    annealer = Annealer(problem, x, contacts, generator)
    resample_steps = resample_steps_of(cfg)
    start, accepted, replaced = time.perf_counter(), 0.0, 0
    for t in range(cfg.mala_steps):
        annealer.try_step()
        accept = annealer.accept_step()
        accepted += float(accept.float().mean())
        if t + 1 in resample_steps:
            source = resample_sources(annealer.resample_score(), cfg.resample_fraction)
            annealer.resample(source)
            replaced += int((source != torch.arange(source.shape[0], device=source.device)).sum())
        _report(progress, cfg, t + 1, cfg.mala_steps, start,
                {"stage": "mala", "energy_mean": float(annealer.state.energy.mean()),
                 "accept_rate": float(accept.float().mean()), "step_size": step_size_at(t, cfg),
                 "temperature": temperature_at(t, cfg)})
    stats = {"mala_accept_rate": accepted / max(cfg.mala_steps, 1), "mala_seconds": time.perf_counter() - start,
             "resampled_rows": replaced}
    return annealer.state, stats


def resample_steps_of(cfg: SynthesisConfig) -> set[int]:
    """The MALA steps after which :func:`run_mala` resamples: round(f * mala_steps) for f in ``resample_at``,
    kept when strictly inside the chain (1 .. mala_steps - 1)."""
    return {s for s in (round(f * cfg.mala_steps) for f in cfg.resample_at) if 0 < s < cfg.mala_steps}


def approach(problem: GraspProblem, x: Tensor, contacts: Tensor,
             progress: Optional[ProgressFn] = None) -> tuple[Tensor, Tensor, dict]:
    """Approach stage (``approach_steps`` > 0), run before MALA: Adam (lr ``approach_lr``) on

        E_approach = w_dist E_dist + w_pen E_pen + w_prior E_prior      (w_fc = w_surround = w_q1 = 0, w_align = approach_w_align),

    with the contacts reassigned every ``approach_reassign_every`` steps by
    :func:`~components.synthesis.energy.best_contacts` scored by distance (and alignment) only, so each
    object's contacts follow the fingers that are nearest to it.  Brings the fingers onto the objects
    without force closure pulling contacts through their SDF normals; the last pose is returned (E_approach
    has no force-closure term that keep-best would have to trade against).
    -> (x (B, D), contacts (B, n_obj, C), stats)."""
    cfg = problem.cfg
    start = time.perf_counter()
    w_dist = cfg.w_dist if cfg.approach_w_dist is None else cfg.approach_w_dist
    weights = {"w_fc": 0.0, "w_align": cfg.approach_w_align, "w_dist": w_dist}
    x = x.detach().clone().requires_grad_(True)
    optimizer = torch.optim.Adam([x], lr=cfg.approach_lr)
    every = cfg.approach_reassign_every if cfg.contact_assignment != "nearest" else 0
    for t in range(cfg.approach_steps):
        if every > 0 and t % every == 0:
            contacts = reassign_contacts(problem, x.detach(), contacts, **weights)
        energy, grad, terms = energy_and_grad(problem, x.detach(), contacts, w_surround=0.0, w_q1=0.0, **weights)
        contacts = terms[CONTACT_INDICES]
        optimizer.zero_grad()
        x.grad = grad
        optimizer.step()
        _report(progress, cfg, t + 1, cfg.approach_steps, start,
                {"stage": "approach", "energy_mean": float(energy.mean())})
    x = x.detach()
    if every > 0 and cfg.approach_steps > 0:
        contacts = reassign_contacts(problem, x, contacts, **weights)
    return x, contacts, {"approach_seconds": time.perf_counter() - start}


def refine(problem: GraspProblem, x: Tensor, contacts: Tensor,
           progress: Optional[ProgressFn] = None) -> tuple[Tensor, Tensor, dict]:
    """Adam on E (with E_dist weighted by ``refine_w_dist``), contacts fixed (or reassigned by
    ``contact_reassign_every`` / ``contact_reassign_refine``), ``refine_steps`` steps.  With ``keep_best``
    each row returns its lowest-energy pose and the contacts it had there.
    -> (x (B, D), contacts (B, n_obj, C), stats)."""
    cfg = problem.cfg
    start = time.perf_counter()
    reassign = cfg.contact_reassign_every > 0 and cfg.contact_assignment != "nearest"
    if reassign:
        contacts = reassign_contacts(problem, x, contacts, w_dist=cfg.refine_w_dist)
    x = x.detach().clone().requires_grad_(True)
    optimizer = torch.optim.Adam([x], lr=cfg.refine_lr)
    best_x = x.detach().clone()
    best_energy = torch.full(x.shape[:1], float("inf"), dtype=x.dtype, device=x.device)  # (B,)
    best_contacts_ = contacts
    for t in range(cfg.refine_steps):
        if reassign and cfg.contact_reassign_refine and t > 0 and t % cfg.contact_reassign_every == 0:
            contacts = reassign_contacts(problem, x.detach(), contacts, w_dist=cfg.refine_w_dist)
        energy, grad, terms = energy_and_grad(problem, x.detach(), contacts, w_dist=cfg.refine_w_dist)
        contacts = terms[CONTACT_INDICES]
        if cfg.keep_best:
            better = energy < best_energy  # False for non-finite energies
            best_energy = torch.where(better, energy, best_energy)
            best_x = torch.where(better.unsqueeze(-1), x.detach(), best_x)
            best_contacts_ = torch.where(better.reshape(-1, 1, 1), contacts, best_contacts_)
        optimizer.zero_grad()
        x.grad = grad
        optimizer.step()
        _report(progress, cfg, t + 1, cfg.refine_steps, start,
                {"stage": "refine", "energy_mean": float(energy.mean())})
    x = x.detach()
    if cfg.keep_best and cfg.refine_steps > 0:
        energy, _, terms = energy_and_grad(problem, x, contacts, w_dist=cfg.refine_w_dist)
        last = (energy < best_energy)
        x = torch.where(last.unsqueeze(-1), x, best_x)
        contacts = torch.where(last.reshape(-1, 1, 1), terms[CONTACT_INDICES], best_contacts_)
    return x, contacts, {"refine_seconds": time.perf_counter() - start}
