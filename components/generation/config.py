"""Config sections of multi-object grasp generation (DESIGN §5.2-5.3; paper §"Multi-object Grasp Generation"
and §"Multi-object Grasp Refinement").

* :class:`GeneratorConfig` -- the conditional DDPM: PointNet++ object encoder, cross-attention denoiser,
  noise schedule (100 steps, linear beta 1e-4 -> 0.01, as SceneDiffuser / the paper) and its training.
* :class:`SamplerConfig` -- how a trained model is sampled: the paper's 100-step ancestral DDPM, or strided DDIM;
  optional penetration guidance (:class:`GuidanceConfig`).
* :class:`IKConfig` -- keypoints -> (p, R, q): palm frame by Kabsch, then the 18 actuated joints by Adam.
* :class:`RefineConfig` -- the refinement energy E_g = E_pen + lambda_c E_contact with tau 2 mm -> 1 mm.

Numbers that are not the paper's are documented choices of this project.
"""

from typing import Literal, Optional

from pydantic import Field, PositiveInt, model_validator

from components.config_base import Section


class GeneratorConfig(Section):
    """Conditional DDPM over a palm-aligned hand representation, conditioned on object point clouds."""

    # ------------------------------------------------------------------ representation / inputs
    representation: Literal["keypoints", "joints"] = Field(
        "keypoints",
        description="Hand representation the diffusion runs on: 'keypoints' = the 31 hand keypoints (31 x 3, m, "
        "palm-aligned frame; the paper's choice, one token per keypoint) or 'joints' = (p, rot6d, q) of "
        "components.synthesis.pose (3 + 6 + 22 = 31 numbers, one token; the paper's ablation).")
    points_per_object: int = Field(
        512, ge=8, description="Points in each object's input cloud (the PointNet++ input N).")
    max_objects: int = Field(
        3, ge=1, description="Object slots of the condition (learnable slot embeddings); scenes with fewer objects "
        "mask the missing slots out of the attention.")
    input_scale_m: float = Field(
        0.1, gt=0.0, description="Object coordinates (m) are divided by this fixed scale before PointNet++.")

    # ------------------------------------------------------------------ PointNet++ object encoder
    sa1_points: int = Field(64, ge=1, description="Centroids picked by farthest point sampling in set abstraction level 1.")
    sa1_radius_m: float = Field(0.01, gt=0.0, description="Ball-query radius (m) of level 1.")
    sa1_neighbours: int = Field(16, ge=1, description="Points grouped per centroid in level 1 (k of the ball query).")
    sa1_widths: tuple[PositiveInt, ...] = Field((32, 32, 64), description="Shared MLP widths of level 1.")
    sa2_points: int = Field(16, ge=1, description="Centroids of level 2 = object tokens per object (M).")
    sa2_radius_m: float = Field(0.02, gt=0.0, description="Ball-query radius (m) of level 2.")
    sa2_neighbours: int = Field(16, ge=1, description="Points grouped per centroid in level 2.")
    sa2_widths: tuple[PositiveInt, ...] = Field((64, 64, 128), description="Shared MLP widths of level 2.")
    global_widths: tuple[PositiveInt, ...] = Field(
        (128, 128), description="Shared MLP widths of the group-all level that gives each object's global token.")

    # ------------------------------------------------------------------ denoiser
    model_dim: int = Field(128, ge=8, description="Width of the hand tokens and of the attention (object tokens are projected to it).")
    heads: int = Field(4, ge=1, description="Attention heads (model_dim must be divisible by it).")
    blocks: int = Field(3, ge=1, description="Denoiser blocks (self-attention, cross-attention to the objects, MLP).")
    mlp_ratio: int = Field(2, ge=1, description="Hidden width of each block's MLP = mlp_ratio * model_dim.")
    time_embedding_dim: int = Field(64, ge=2, description="Width of the sinusoidal timestep embedding (even).")
    dropout: float = Field(0.0, ge=0.0, lt=1.0, description="Dropout of attention and MLPs.")
    use_object_embedding: bool = Field(
        True,
        description="Add a learnable embedding per object slot to every token of that object (paper: identical for "
        "one object, different across objects); False = the ablation without it.")

    # ------------------------------------------------------------------ diffusion (DDPM, Ho et al. 2020)
    diffusion_steps: int = Field(100, ge=1, description="T, the number of diffusion steps (paper / SceneDiffuser: 100).")
    beta_start: float = Field(1e-4, gt=0.0, lt=1.0, description="beta_1 of the linear schedule (SceneDiffuser: 1e-4).")
    beta_end: float = Field(
        0.01, gt=0.0, lt=1.0,
        description="beta_T of the linear schedule (SceneDiffuser: 0.01).  Note: with T = 100 this leaves "
        "alpha_bar_T = prod(1 - beta_t) ~ 0.60, so x_T still carries signal; sampling starts from N(0, I) anyway "
        "(as SceneDiffuser does) on data normalised to unit variance.")
    zero_terminal_snr: bool = Field(
        False,
        description="Rescale the betas so that alpha_bar_T = 0 (Lin et al. 2024, 'Common diffusion noise schedules and "
        "sample steps are flawed', Algorithm 1: sqrt(alpha_bar_t) shifted and scaled so its last value is 0 and its "
        "first unchanged).  The last step then trains on pure noise, which is what sampling starts from; with the "
        "paper's schedule (False) the model never sees a signal-free input.  Departs from the paper; needs "
        "prediction='v' (x_0 cannot be read from a noise prediction at alpha_bar = 0).")
    prediction: Literal["epsilon", "v"] = Field(
        "epsilon",
        description="What the denoiser is trained to output: 'epsilon' = the noise (paper / SceneDiffuser); 'v' = "
        "sqrt(alpha_bar_t) eps - sqrt(1 - alpha_bar_t) x_0 (Salimans & Ho 2022), well defined at every noise level.")
    posterior_variance: Literal["posterior", "beta"] = Field(
        "posterior",
        description="Sigma_t^2 of the reverse step: 'posterior' = beta~_t = (1 - abar_{t-1}) / (1 - abar_t) beta_t, "
        "'beta' = beta_t (both from Ho et al. 2020).")
    clip_sample: float = Field(
        0.0, ge=0.0,
        description="If > 0, the x_0 estimate of each reverse step is clamped to [-c, c] (normalised units) before "
        "the posterior mean is formed; 0 = off (the plain epsilon form).")

    # ------------------------------------------------------------------ training
    lr: float = Field(2e-4, gt=0.0, description="AdamW learning rate.")
    weight_decay: float = Field(0.0, ge=0.0, description="AdamW weight decay.")
    batch_size: int = Field(128, ge=1, description="Grasps per training minibatch.")
    train_steps: int = Field(100_000, ge=0, description="Optimiser steps of training.")
    grad_clip: float = Field(1.0, ge=0.0, description="Max global gradient norm (0 = no clipping).")
    seed: int = Field(0, description="Seed of the weight initialisation, minibatches, noise and timesteps.")
    log_every: int = Field(100, ge=1, description="Steps between progress callbacks.")
    checkpoint_every: int = Field(
        1000, ge=1, description="Optimiser steps between training checkpoints (one is also written at the end); "
        "an interrupted run resumes from the last one.")

    @model_validator(mode="after")
    def _check(self) -> "GeneratorConfig":
        if self.model_dim % self.heads:
            raise ValueError("model_dim must be divisible by heads")
        if self.time_embedding_dim % 2:
            raise ValueError("time_embedding_dim must be even")
        if self.sa2_points > self.sa1_points or self.sa1_points > self.points_per_object:
            raise ValueError("need sa2_points <= sa1_points <= points_per_object")
        if self.beta_end < self.beta_start:
            raise ValueError("beta_end must be >= beta_start")
        if self.zero_terminal_snr and self.prediction != "v":
            raise ValueError("zero_terminal_snr needs prediction='v' (set generator.model.prediction=v)")
        if self.zero_terminal_snr and self.diffusion_steps < 2:
            raise ValueError("zero_terminal_snr needs diffusion_steps >= 2 (it rescales the schedule between its ends)")
        return self


class GuidanceConfig(Section):
    """Penetration guidance of the sampler (not in the paper, which only refines after sampling; the same idea as
    SceneDiffuser's / DexDiffuser's guided sampling).  At every guided step the clean estimate x0^ (keypoints) is
    moved so that spheres along the hand's keypoint chains leave the objects (and the table); the denoiser then
    re-fits the whole hand to the moved keypoints in the next steps (:mod:`components.generation.guidance`).
    Only the keypoint representation; off by default."""

    scale: float = Field(
        0.0, ge=0.0, le=1.0,
        description="Fraction of each sphere's penetration depth removed from x0^ per guided step (one gradient step "
        "of 1/2 sum relu(r - d)^2 on the keypoints); 0 = off.")
    start_t: int = Field(
        99, ge=0,
        description="Guide only the steps with timestep t <= start_t (0 = the last step only; >= T-1 = every step).")
    segment_points: int = Field(
        2, ge=0,
        description="Spheres placed evenly between consecutive keypoints of each finger chain (mcp-pip-dip-tip) "
        "besides the 31 keypoints; each sphere's radius is its depth inside the hand's collision geometry at the "
        "open pose (0 for the surface keypoints: tips, pads, palm faces).")
    table: bool = Field(True, description="Also push the spheres above the table plane.")


class SamplerConfig(Section):
    """Reverse process used at generation time (not part of the trained model: changing it retrains nothing)."""

    method: Literal["ddpm", "ddim"] = Field(
        "ddpm", description="ddpm: ancestral sampling over all T steps (the paper). ddim: deterministic strided "
        "sampling (Song et al. 2021) over ``steps`` of the T timesteps, with the same trained model.")
    steps: int = Field(
        25, ge=1, description="method=ddim: denoiser calls per sample (<= the model's diffusion_steps; every "
        "floor(T / steps)-th timestep; a larger value is read as T).  Each call costs the same, so sampling time "
        "scales with it.")
    spacing: Literal["leading", "trailing"] = Field(
        "leading",
        description="method=ddim: which timesteps: 'leading' = 0, T/S, 2T/S, .. (the first step is below T-1); "
        "'trailing' = .., T-1-T/S, T-1, which starts at the last training step (Lin et al. 2024; use it with a "
        "zero_terminal_snr model, whose pure-noise input only that step was trained on).")
    eta: float = Field(
        0.0, ge=0.0, le=1.0, description="method=ddim: noise of each step, 0 = deterministic; 1 with steps = T is "
        "the ancestral DDPM.")
    guidance: GuidanceConfig = Field(
        default_factory=GuidanceConfig,
        description="Penetration guidance during sampling (``GuidanceConfig``; off by default, not in the paper).")


class IKConfig(Section):
    """Inverse kinematics from the 31 keypoints (ik module docstring)."""

    steps: int = Field(
        100, ge=0,
        description="Adam steps on the 18 actuated joint angles.  100: on 256 keypoint sets of random poses the median "
        "error is 0.01 mm (exact targets) and 3.961 mm against 3.953 mm at 300 steps (targets with 3 mm noise, as no "
        "pose fits generated keypoints exactly), in a third of the time: 2.3-2.7 s against 7.5-9.8 s on 2 threads "
        "(python -m benchmarks.ik_steps; benchmarks/results/ik_steps.json).")
    lr: float = Field(0.1, gt=0.0, description="Adam learning rate of the joint angles (rad per step, roughly).")
    lr_final_fraction: float = Field(
        0.05, gt=0.0, le=1.0, description="The learning rate decays by cosine to lr * this fraction at the last step.")
    init: Literal["open", "mid"] = Field(
        "mid", description="Initial joint angles: 'open' = every joint 0, 'mid' = the middle of every actuated range.")
    restarts: int = Field(
        2, ge=1,
        description="Independent starts per target: start 0 is `init`, the others are uniform in the limits "
        "(seeded); the start with the lowest final keypoint error is kept.")
    refit_palm: bool = Field(
        True, description="Also optimise the palm pose (p, rot6d), starting from the Kabsch fit, with the joints.")
    palm_lr_m: float = Field(5e-4, gt=0.0, description="With refit_palm: Adam learning rate of the palm position (m per step).")
    palm_lr_rot: float = Field(5e-3, gt=0.0, description="With refit_palm: Adam learning rate of the 6-D rotation parameters.")
    seed: int = Field(0, description="Seed of the random restarts.")


class RefineConfig(Section):
    """Grasp refinement E_g = E_pen + lambda_c E_contact (refine module docstring; paper §Refinement)."""

    steps: int = Field(200, ge=0, description="Adam steps.")
    lr: float = Field(5e-4, gt=0.0, description="Adam learning rate (about 0.5 mm / 0.5 mrad per step).")
    tau_start_m: float = Field(0.002, gt=0.0, description="Contact threshold tau at the first step (paper: 2 mm).")
    tau_end_m: float = Field(0.001, gt=0.0, description="Contact threshold tau at the last step, linear in between (paper: 1 mm).")
    w_pen: float = Field(1.0, ge=0.0, description="Weight of E_pen (synthesis energy's penetration, its own sub-weights).")
    w_contact: float = Field(
        1.0, ge=0.0,
        description="lambda_c: weight of the contact term (1 / (N_o |S|)) sum |d(x, O_j)| over hand points x "
        "within tau of object j.")
    w_prior: float = Field(10.0, ge=0.0, description="Weight of the joint-limit prior (joints are also clamped).")
    couple_distal_joints: bool = Field(True, description="Evaluate with the J0s of FF/MF/RF/LF following J1.")
    object_surface_points: int = Field(256, ge=1, description="Object surface samples tested against the hand SDF.")
    hand_point_spacing_m: float = Field(0.01, gt=0.0, description="Spacing (m) of the hand surface samples tested against the objects.")
    keep_best: bool = Field(True, description="Return, per grasp, the pose of lowest E_g seen.")
    fc_steps: int = Field(
        0, ge=0,
        description="Force-closure refinement after the paper's (0 = off, the paper's objective only): Adam steps on "
        "the synthesis energy E = w_fc E_fc + w_dist E_dist + w_pen E_pen + w_prior E_prior of the run's "
        "synthesis.optimizer (its weights, refine_lr, refine_w_dist, keep_best and contact reassignment; E_pen sampled "
        "with this section's object_surface_points / hand_point_spacing_m), each "
        "object's contacts first assigned at the refined pose to the nearest candidates of distinct fingers. Pulls the "
        "chosen fingertips onto the surfaces and into opposition, which the paper's tau-band pull does not.")
    fc_w_pen: Optional[float] = Field(
        None, ge=0.0,
        description="w_pen of the force-closure refinement (None = synthesis.optimizer.w_pen). The synthesis filters "
        "out its penetrating candidates and keeps the rest; a generated grasp that penetrates is only discarded "
        "afterwards (the evaluation's generator.eval_filter), so a stiffer E_pen stands in for the synthesis filter.")
    fc_lr: Optional[float] = Field(None, gt=0.0, description="Adam lr of the force-closure refinement (None = synthesis.optimizer.refine_lr).")
    fc_order: Literal["after", "before"] = Field(
        "after",
        description="When the force-closure refinement runs: 'after' the paper's steps, or 'before' them (the paper's "
        "objective then removes the penetration the synthesis energy leaves).")

    @model_validator(mode="after")
    def _check(self) -> "RefineConfig":
        if self.tau_end_m > self.tau_start_m:
            raise ValueError("tau_end_m must be <= tau_start_m (coarse to fine)")
        return self


class GeneratedFilterConfig(Section):
    """Which generated pre-grasps the evaluation keeps. The paper's protocol (§"Evaluation Protocols"): "for each
    arrangement, we generate pre-grasp poses, discarding those with significant penetration or insufficient contact
    ratio". The paper gives no thresholds; the defaults are the synthesis filter's (5 mm) and two of the three
    force-closure contacts on every object (:func:`components.generation.filter.contact_ratio`)."""

    enabled: bool = Field(
        True, description="Discard generated pre-grasps as the paper's protocol does (False: every one counts, "
        "accept_rate 1).")
    max_penetration_m: float = Field(
        0.005, gt=0.0,
        description="Discard a grasp whose PN (the metric: deepest hand-object, object-hand, hand-table or self "
        "penetration) exceeds this. Default: the synthesis filter's filter_penetration_m (the release's 5 mm).")
    contact_distance_m: float = Field(
        0.005, gt=0.0,
        description="A contact counts as touching when |signed distance| to its object is within this. Default: the "
        "synthesis filter's filter_contact_distance_m (5 mm), also Q1's contact distance.")
    min_contact_ratio: float = Field(
        2.0 / 3.0, ge=0.0, le=1.0,
        description="Discard a grasp whose contact ratio is below this. The contact ratio is the smallest, over the "
        "objects, fraction of the object's contacts_per_object force-closure contacts (each object's nearest hand "
        "candidates on distinct fingers, as the synthesis assigns them) that touch. 2/3 with 3 contacts: at least two "
        "fingers on every object.")
