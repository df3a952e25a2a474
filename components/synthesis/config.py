"""Config section of multi-object grasp synthesis (:class:`SynthesisConfig`, DESIGN §5.1).

Defaults are the official MultiGrasp values where the release has them (energy weights 1 / 10 / 10 / 10,
batch 1024, 6500 MALA steps with step 0.01 * 0.95^floor(t/100) and temperature 8 * 0.95^floor(t/50),
contact switch probability 0.25, 1500 Adam refinement steps, filter FC < 0.25, contact distance < 5 mm,
penetration < 5 mm, prior < 0.1).  Every other number is a documented choice of this project; three defaults
differ from the release on purpose and their fields say so: ``fc_friction`` 0.5 (the release: frictionless),
``fc_normalize_by_radius`` True (raw lever arms in metres) and ``w_align`` 1 (computed, never added); and the MALA
step is DexGraspNet's RMSProp step unless ``mala_step_rule='release'``.
"""

from typing import Literal, Optional

from pydantic import Field, model_validator

from components.config_base import Section


class SynthesisConfig(Section):
    """Multi-object DFC synthesis: energy weights, MALA schedule, Adam refinement, filter, initialisation."""

    # ------------------------------------------------------------------ batch / contacts
    batch_size: int = Field(1024, ge=1, description="Candidate grasps optimised in parallel for one scene (official: 1024).")
    contacts_per_object: int = Field(3, ge=1, description="Hand contact points assigned to each object (official: 3).")

    # ------------------------------------------------------------------ energy weights (paper Eq. multi-dfc-energy)
    w_fc: float = Field(1.0, ge=0.0, description="Weight of the force-closure error E_fc (official: 1).")
    w_dist: float = Field(10.0, ge=0.0, description="Weight of the contact-distance energy E_dist during MALA (official: 10).")
    w_pen: float = Field(10.0, ge=0.0, description="Weight of the penetration energy E_pen (official: 10).")
    w_prior: float = Field(10.0, ge=0.0, description="Weight of the joint-limit prior E_prior (official: 10).")
    w_align: float = Field(
        1.0, ge=0.0,
        description="Weight of the contact alignment energy E_align (energy.contact_alignment_energy): the hand patch at "
        "a contact must face the object.  The official release computes this term but leaves it out of E (= 0).")
    w_surround: float = Field(
        0.0, ge=0.0,
        description="Weight of the surround energy E_sur (energy.surround_energy): force balance of the unit pushes of "
        "every hand surface sample within surround_band_m of an object, i.e. the hand must touch each object from "
        "around it, not from one side (Q1 counts every touching sample; E_fc only the chosen contacts).  Added in "
        "MALA and refinement, not in the approach stage.  0 = off (not in the official release).  Measured (bench "
        "setting, cube + cylinder, seed 0, B = 32, 1 thread): off 14/32 accepted, Q1 0.045, PN 2.94 mm; 10: 12/32, "
        "Q1 0.058, PN 3.21; 50: 7/32, Q1 0.049, PN 4.01; 200: 0/32 -- the hand backs off (max contact distance "
        "median 5.2 -> 6.2 -> 9.0 mm): no touching sample is the cheapest balance, and extra one-sided contacts "
        "do not lower Q1 anyway (the wrench hull only grows); off by default.")
    surround_band_m: float = Field(
        0.005, gt=0.0,
        description="Band (m) of E_sur: a hand sample at |d| from an object's surface weighs relu(1 - |d| / band) "
        "(default: the Q1 contact distance, 5 mm).")
    w_q1: float = Field(
        0.0, ge=0.0,
        description="Weight of E_q1 (energy.q1_surrogate_energy) = sum_j relu(q1_target - Q1~_j): Q1~ a smooth Ferrari-Canny "
        "Q1 of object j over the hand samples within q1_band_m of it (the metric's contacts: every touching sample, "
        "circular friction cones of q1_friction), so the grasp is pushed towards what Q1 measures, not only towards "
        "force closure of the 3 chosen contacts.  Added in the stages of q1_stages, never in the approach stage.  "
        "0 = off (not in the official release).")
    q1_target: float = Field(
        0.4, gt=0.0,
        description="E_q1 stops pulling an object once its Q1~ reaches this (the ideal six-contact sphere scores 0.41 under "
        "the default metric).")
    q1_band_m: float = Field(
        0.005, gt=0.0, description="Contact band of E_q1 (m): a hand sample at distance d from the surface, outside or "
        "inside, weighs relu(1 - |d| / band) (default: the Q1 metric's contact distance).")
    q1_friction: float = Field(
        0.5, ge=0.0, description="Friction coefficient of E_q1's cones (default: the Q1 metric's).")
    q1_directions: int = Field(
        64, ge=12, description="Fixed unit wrench directions at which E_q1 probes the hull's support (seeded by "
        "seed_surface_points); the minimum over them stands in for the minimum over the 6-D sphere.")
    q1_samples: int = Field(
        64, ge=1, description="Hand samples per object that E_q1 considers: the nearest ones (bounds its cost).")
    q1_weakest: int = Field(
        8, ge=0, description="E_q1 also probes the hull at its q1_weakest weakest fixed directions after q1_weakest_steps "
        "gradient steps down the smoothed support (energy.weakest_directions): random directions alone miss narrow gaps "
        "(two opposing contacts, which resist no torque about their axis, read 0.08 with 4,096 of them).")
    q1_weakest_steps: int = Field(15, ge=0, description="Gradient steps of each of E_q1's weakest directions.")
    q1_search_smoothing: float = Field(
        0.02, gt=0.0, description="Temperature of the smoothed support (log-sum-exp over the samples) that the weakest "
        "directions descend.  Six contacts on a ball, 64 fixed directions: 0.418 with 15 smoothed steps, 0.47 with 15 "
        "steps down the plain max, 0.408 exact (the metric with 64-edge cones).")
    q1_search_rate: float = Field(0.5, gt=0.0, description="First step size of the weakest-direction search (on the unit sphere).")
    q1_search_decay: float = Field(0.85, gt=0.0, le=1.0, description="Step size factor after each weakest-direction step.")
    q1_stages: Literal["refine", "mala_refine"] = Field(
        "refine", description="Where E_q1 acts: only in the refinement (default) or in MALA as well.  Its cost: one "
        "energy call with gradient took 143 ms with E_q1 against 64 ms without (cube + cylinder, B 64, one thread); "
        "refinement-only synthesis of the bench Syn-Pl pairs took 1.4-1.8x as long per scene.")
    q1_temperature: float = Field(
        0.01, gt=0.0, description="Softness T of E_q1's minimum over directions, -T log sum_u exp(-S(u) / T) (a lower "
        "bound of the minimum).")
    w_contact_excess: float = Field(
        0.0, ge=0.0,
        description="Weight of the contact-distance hinge E_excess = sum_i (relu(|d_i| - h) / h)^2 "
        "(energy.contact_excess_energy, h = contact_excess_m) added to E in every stage and to the contact "
        "reassignment score. 0 = off (official). Reason: with E_dist linear (a 1 cm hover costs 0.1 at w_dist 10) "
        "MALA and Adam meet E_fc with contacts hovering 1-4 cm off the surface through the SDF normal there. "
        "Measured (cube + cylinder, seed 0, with the approach pipeline of approach_steps): adding 1 (h 3 mm) holds "
        "the max contact distance at median 4.5 mm (vs 18 mm) but drives the hand into the objects (penetration "
        "median 11 mm) unless w_pen is raised to 100; off by default.")
    contact_excess_m: float = Field(
        0.003, gt=0.0, description="Tolerance h (m) of E_excess: contacts within it of the surface are not penalised.")
    w_pen_object_points: float = Field(
        1.0, ge=0.0, description="Sub-weight in E_pen of object surface points inside the hand (sum of depths, m).")
    w_pen_hand_points: float = Field(
        1.0, ge=0.0, description="Sub-weight in E_pen of hand surface points inside the objects (sum of depths, m).")
    w_pen_self: float = Field(1.0, ge=0.0, description="Sub-weight in E_pen of hand self-penetration (sum over geom pairs, m).")
    w_pen_table: float = Field(
        10.0, ge=0.0,
        description="Sub-weight in E_pen of the hand below the table (sum over the hand's geoms of the depth of their lowest "
        "point, m). 10: the official release sums the depth of every hand surface vertex below the table, which weighs a "
        "finger below the table about ten times more than its single lowest point does here.")
    fc_margin: float = Field(
        0.2, ge=0.0,
        description="E_fc per object = relu(|G n|^2 - fc_margin): force-closure errors below this are not penalised (official: 0.2).")
    fc_friction: float = Field(
        0.5, ge=0.0,
        description="Friction coefficient of E_fc: each unit contact force may tilt inside its Coulomb cone to cancel the "
        "net force (energy.friction_tilted_forces).  0 = the official frictionless form, under which three contacts "
        "on a box's faces can never reach force closure; 0.5 matches the Q1 metric's metrics.friction_coefficient.")
    w_opposition: float = Field(
        0.0, ge=0.0,
        description="Weight of the contact opposition energy E_opp (energy.contact_opposition_energy) = sum_j relu("
        "opposition_min - max_{i<k} -m_i . m_k) over each object's chosen contacts: at least one pair of an object's "
        "contacts must push from opposite sides (m: the normals of opposition_normals).  E_fc with friction cones "
        "(fc_friction 0.5) and its margin balances contacts ~90 deg apart; the scripted squeeze lifts an object that "
        "has opposing contacts at the pre-grasp 64 % of the time and one without 18 % (docs/experiments.md 'Why the "
        "pre-grasps drop').  Scaled like E_fc in each stage (w_opposition x the stage's w_fc / w_fc: off in the "
        "approach) and added to the contact reassignment's score.  0 = off (not in the official release).  Measured "
        "(forty-sixth session, docs/experiments.md 'Opposed contacts in the energy'; 20 bench Syn-Pl pair scenes x 64, "
        "50, object normals): poses with both objects' contacts opposed 81 % against 57 %, accepted 41.6 % against "
        "42.3 %, Q1 0.087 against 0.084, PN 1.19 against 1.07 mm, squeeze success 31.2 % against 32.0 % (100 poses x "
        "5): the opposed grasps that the term adds do not lift more; off by default.")
    opposition_min: float = Field(
        0.5, ge=-1.0, le=1.0,
        description="E_opp's threshold on max_{i<k} -m_i . m_k: 0.5 = two contacts more than 120 deg apart (the "
        "'opposed' of benchmarks.lift_failures); 1 = exactly opposite.")
    opposition_normals: Literal["object", "hand"] = Field(
        "object",
        description="Normals m of E_opp: 'object' = the objects' outward normals at the contacts (what the lift's "
        "opposition measures; piecewise constant on a box face, so on boxes only the reassignment acts on it), "
        "'hand' = the hand patches' outward normals at the contacts (smooth in the pose and the joints, so the "
        "gradient turns the fingers to face each other).")
    fc_friction_iterations: int = Field(
        1, ge=1,
        description="Projection steps of the friction tilt in E_fc (energy.friction_tilted_forces): each step hands the "
        "residual force on to the contacts' tangent planes within their cones.  1 = the one-step tilt used so far; "
        "more steps let E_fc reach 0 where Coulomb cones of coefficient fc_friction can balance the contacts.  "
        "Measured with fc_margin 0 (bench setting, B = 32, 1 thread; off in brackets): cube + cylinder seed 0 "
        "14/32 accepted, Q1 0.071 (14/32, 0.045); seed 1 17/32, Q1 0.025 (24/32, 0.047); capsule + bar seed 1 "
        "2/32, Q1 0.050 (4/32, 0.043): no gain beyond the scene-to-scene noise; 1 by default.")
    fc_mode: Literal["per_object", "group"] = Field(
        "per_object",
        description="What must be in force closure.  'per_object' (the paper's Eq. multi-dfc-energy, the official code): "
        "E_fc of each object over its own contacts_per_object contacts, and the filter's fc test on the worst object.  "
        "'group': the objects held as one rigid body -- one E_fc over every object's contacts, lever arms from the "
        "objects' centroid (normalised by the group's bounding radius when fc_normalize_by_radius), and the filter's "
        "fc test on it; Q1 is then measured for the group too (metrics.q1_grasps(group=True)).  It assumes the "
        "objects' contacts with each other hold them together, which the paper says four and five small cylinders "
        "need ('inter-object contact becomes essential'): per object, four cylinders with 2 contacts each never "
        "reached force closure here (E_fc stalls at 0.30; README 'Synthesis settings').  Meant for the 'many' split "
        "through optimizer_by_object_count; a weaker test than 'per_object' (an upper bound on what the hand alone holds).")
    fc_normalize_by_radius: bool = Field(
        True,
        description="Lever arms x in G = [I; [x]x] are measured from the object's centre and divided by its radius, so "
        "the torque rows are scale-free like Q1's (the official code used raw world coordinates in metres, where the "
        "torque rows are ~100x smaller than the force rows).")
    fc_contact_gate_m: float = Field(
        0.0, ge=0.0,
        description="Distance scale s (m) of the proximity weights of the contact forces in E_fc "
        "(energy.contact_gate_weights: w_i = C exp(-|d_i|/s) / sum_j exp(-|d_j|/s)): a contact hovering off the "
        "surface carries little force, so E_fc cannot be met through the SDF normal of a hovering contact. 0 = off "
        "(official: every contact counts fully wherever it is). Measured (cube + cylinder, seed 0): with 0.01 (and "
        "pair init, reassignment, fc ramp) the max contact distance median falls from 29 to 18 mm but max E_fc "
        "median rises from 0.14 to 1.0 (1/32 accepted, Q1 0); undetached weights (tried, removed) pushed contacts off "
        "the surface. Off by default.")
    couple_distal_joints: bool = Field(
        True,
        description="Evaluate the energy at q with the J0 of FF/MF/RF/LF recomputed from J1 by the Shadow Hand's "
        "tendon coupling, so every synthesised pose is reachable by the 18 actuators.")
    object_surface_points: int = Field(
        256, ge=1, description="Surface samples per object tested against the hand's signed distance in E_pen (official: 256).")
    hand_point_spacing_m: float = Field(
        0.01, gt=0.0,
        description="Spacing (m) of the samples on the hand's collision geometry tested against the object SDFs in E_pen.")

    # ------------------------------------------------------------------ MALA (annealed Langevin with Metropolis test)
    mala_steps: int = Field(6500, ge=0, description="Annealed MALA steps with contact switching (official: 6500).")
    step_size: float = Field(0.01, gt=0.0, description="Initial step size s_0 of the preconditioned gradient step (official: 0.01).")
    step_size_decay: float = Field(0.95, gt=0.0, le=1.0, description="s_t = s_0 * decay^floor(t / step_size_period) (official: 0.95).")
    step_size_period: int = Field(100, ge=1, description="Steps between step-size decays at the reference schedule (official: 100).")
    temperature: float = Field(8.0, gt=0.0, description="Initial Metropolis temperature T_0 (official: 8).")
    temperature_decay: float = Field(0.95, gt=0.0, le=1.0, description="T_t = T_0 * decay^floor(t / temperature_period) (official: 0.95).")
    temperature_period: int = Field(50, ge=1, description="Steps between temperature decays at the reference schedule (official: 50).")
    schedule_reference_steps: int = Field(
        6500, ge=1,
        description="MALA length the periods above are written for. With compress_schedule, both periods are scaled by "
        "mala_steps / schedule_reference_steps so shorter runs anneal over the same range.")
    compress_schedule: bool = Field(
        True, description="Scale the decay periods to the run length (see schedule_reference_steps); no effect at 6500 steps.")
    contact_assignment: Literal["switch", "region", "nearest"] = Field(
        "switch",
        description="How the contacts of each object are chosen. 'switch' (official): contacts are chain variables "
        "changed by stochastic switches and the Metropolis test. 'region': the switches choose each contact's hand "
        "region and the energy uses the region's candidate with the lowest assignment score (below) -- standing in "
        "for the official release's continuous contact weights over a region's patch, which E_dist drives to the "
        "patch point nearest the object. 'nearest': at every energy evaluation each object "
        "takes, on each of its ``contacts_per_object`` best fingers, the candidate with the lowest assignment score "
        "|d_O| + assign_align_scale_m * (1 + n_H . n_O) / 2 (energy.nearest_contacts) -- the conditional mode of the "
        "contacts given the pose, so the energy is a function of the pose alone and no switch is proposed.")
    contact_reassign_every: int = Field(
        0, ge=0,
        description="Every this many MALA steps (0 = never), each object's contacts are reassigned for the current "
        "pose by energy.best_contacts: every finger offers its candidate of lowest assignment score, every set of "
        "contacts_per_object fingers is scored by the contact-dependent energy w_fc E_fc + w_dist E_dist + w_align "
        "E_align, and the best set replaces the current contacts if it scores lower (a greedy Gibbs-like move; the "
        "row's energy never rises). Also applied before, and with contact_reassign_refine during, refinement. "
        "Measured (cube + cylinder, B = 32, 1000 MALA + 200 refine, seed 0): every 50 steps 0/32 accepted, max "
        "contact distance median 32 mm (default 0/32, 32 mm) -- the poses, not the assignment, keep contacts off the "
        "surface; off by default.")
    contact_reassign_refine: bool = Field(
        False,
        description="With contact_reassign_every > 0, also reassign every contact_reassign_every refinement steps "
        "(otherwise only once, before refinement).")
    w_fc_ramp_fraction: float = Field(
        0.0, ge=0.0, le=1.0,
        description="Staged objective: during the first fraction of the MALA steps the E_fc weight ramps linearly "
        "from 0 to w_fc (in 10 piecewise-constant levels; the state is re-evaluated at each level), so the hand first "
        "approaches the objects under E_dist / E_pen / E_align and force closure is enforced afterwards. 0 = off. "
        "Measured only in combination (init_mode='pair', w_align 0, reassignment every 10): 0/32 on cube + cylinder "
        "seed 0; even with w_fc = 0 throughout, 500 MALA steps leave the max contact distance at median 27 mm.")
    assign_align_scale_m: float = Field(
        0.02, ge=0.0,
        description="With contact_assignment='nearest': distance (m) added to the score of a candidate whose hand "
        "patch faces straight away from the object (half of it when perpendicular).")
    contact_regions_excluded: list[str] = Field(
        default_factory=list,
        description="Hand contact regions (names of assets/hand/contact_regions.yaml, e.g. [palm, palm_hypothenar]) "
        "that may never be a chosen contact: the initial draw, the contact switches and every reassignment skip "
        "their candidates (GraspProblem.candidate_allowed).  The hand may still touch the objects there; only E_fc "
        "and E_dist stop asking for it.  Empty = every region (the official release).  Reason to exclude the palm: "
        "for an object resting on the table under a downward-facing palm, a palm contact can only be opposed from "
        "below, where the fingers cannot reach.  Measured on the 20 bench Syn-Pl pairs (B 64) with the palm's two regions "
        "excluded: 45.6 % accepted against 30.1 %, Q1 0.084 against 0.078, PN 1.09 against 1.38 mm, Div 14.3 against "
        "16.8 deg, scripted squeeze lift 16.0 % against 11.3 %: README 'Palm contacts'.")
    contact_switch_probability: float = Field(
        0.25, ge=0.0, le=1.0,
        description="Probability of a contact switch (official: 0.25); what it applies to is set by contact_switch_mode.")
    contact_switch_mode: Literal["per_step", "per_contact"] = Field(
        "per_step",
        description="'per_step' (official MultiGrasp): with the probability, one random contact of every object of the row "
        "moves to a new candidate; 'per_contact' (DexGraspNet): every contact moves independently with the probability. "
        "Either way the new candidate is one no contact of the row uses.")
    contact_switch_local_probability: float = Field(
        0.5, ge=0.0, le=1.0,
        description="Fraction of switches that stay within the contact's hand region (slide along the link); the others "
        "jump to any region. The official release instead optimises continuous weights of each contact over its region's "
        "patch; this discrete slide plays that role for point candidates.")
    contact_distinct_fingers: bool = Field(
        True,
        description="The contacts of one object sit on different fingers (the palm counts as one): contacts on one "
        "link push along nearly the same normal and cannot make force closure, so such assignments are never "
        "proposed.  Fingers may still touch several objects.")
    contact_switch_guided_probability: float = Field(
        0.5, ge=0.0, le=1.0,
        description="Fraction of the non-local switches drawn with probability proportional to "
        "exp(-|d_O(candidate)| / contact_switch_guide_scale_m), favouring hand points already near the object "
        "(a data-driven proposal; 0 = the official uniform draw).")
    contact_switch_guide_scale_m: float = Field(
        0.01, gt=0.0, description="Distance scale (m) of the guided contact switches (see above).")
    rmsprop_decay: float = Field(
        0.98, ge=0.0, lt=1.0,
        description="EMA decay of the squared gradient (per parameter, averaged over the batch) that preconditions the step, as in DexGraspNet.")
    rmsprop_per_row: bool = Field(
        False,
        description="Keep the squared-gradient EMA per candidate (B, D) instead of averaged over the batch (D,) as in "
        "DexGraspNet: every candidate then moves at the step size whatever the scale of its own gradient.")
    rmsprop_epsilon: float = Field(1e-6, gt=0.0, description="Added to sqrt(EMA of grad^2) before dividing the gradient.")
    mala_step_rule: Literal["rmsprop", "release"] = Field(
        "rmsprop",
        description="How a MALA proposal moves the pose (optimizer module docstring).  'rmsprop': DexGraspNet's "
        "preconditioned step of size s_t per coordinate, x' = x - s k g / (sqrt(v) + eps) + s k sigma xi, whatever "
        "the gradient's scale.  'release': the official MultiGrasp run.py's step, x' = x - s^2 / 2 m g~ + s sigma xi: "
        "plain gradient steps that shrink with the gradient near a minimum, the rotation gradient times "
        "release_rotation_gradient_scale, the joint gradient divided by the EMA (decay rmsprop_decay) of its "
        "batch-mean |g| and times a weight falling linearly from release_joint_weight_start to "
        "release_joint_weight_end over the first release_joint_weight_fraction of the chain (official 85 -> 25 over "
        "0.8; the release's noise is sigma = 0.01).  step_scale_* do not apply to it.")
    release_rotation_gradient_scale: float = Field(
        10.0, gt=0.0, description="'release' step rule: multiplier of the 6-D rotation gradient (official: 10).")
    release_joint_weight_start: float = Field(
        85.0, gt=0.0, description="'release' step rule: joint-gradient weight at the chain's start (official: 85).")
    release_joint_weight_end: float = Field(
        25.0, gt=0.0, description="'release' step rule: joint-gradient weight from release_joint_weight_fraction of the "
        "chain on (official: 25).")
    release_joint_weight_fraction: float = Field(
        0.8, gt=0.0, le=1.0, description="'release' step rule: fraction of the MALA chain over which the joint weight "
        "falls (official: 0.8).")
    langevin_noise: float = Field(
        0.1, ge=0.0,
        description="Standard deviation of the Gaussian noise of a proposal, as a fraction of the current step size.")
    step_scale_translation: float = Field(1.0, gt=0.0, description="Step multiplier of the palm position p (m).")
    step_scale_rotation: float = Field(1.0, gt=0.0, description="Step multiplier of the 6-D rotation parameters.")
    step_scale_joints: float = Field(1.0, gt=0.0, description="Step multiplier of the joint angles (rad).")
    resample_at: list[float] = Field(
        default_factory=list,
        description="Population resampling (not in the paper; off when empty): after these fractions of the MALA chain "
        "(each in (0, 1), e.g. [0.5]) the resample_fraction worst candidates, ranked by resample score, continue from "
        "copies of the best ones (optimizer.resample_sources), so the rest of the chain is spent on the basins that "
        "are closest to acceptance.  Measured on the 20 bench Syn-Pl pairs at [0.5]: 48.1 % accepted against 30.1 %, "
        "but 321 distinct chains accepted against 385, the copies 0.3 deg from their source (near-duplicates; with "
        "the jitter below 3.2 deg, 348 chains) and Q1, PN, Div and the scripted lift unchanged: README 'Population "
        "resampling'.  SynthesisResult.stats['lineages_accepted'] and the table's lineage column count the chains.")
    resample_fraction: float = Field(
        0.5, gt=0.0, lt=1.0,
        description="Share of the batch replaced at each resampling; each survivor is copied at most "
        "ceil(f / (1 - f)) times (once at 0.5), best first.")
    resample_jitter_translation_m: float = Field(
        0.0, ge=0.0,
        description="Standard deviation (m) of Gaussian noise added to the palm position of every copy made by resample_at, "
        "so that copies leave their source's basin (without it, siblings ended 0.4 mm / 0.3 deg apart: README "
        "'Population resampling').")
    resample_jitter_joints_rad: float = Field(
        0.0, ge=0.0, description="Standard deviation (rad) of Gaussian noise added to the joint angles of every copy (see above).")
    resample_w_q1: float = Field(
        0.0, ge=0.0,
        description="Resample score = the chain's energy E (MALA weights) + resample_w_q1 * sum_j relu(q1_target - "
        "Q1~_j) (the smooth Q1 of w_q1, computed only at the resampling steps, so it costs a few energy calls, "
        "not one per step); 0 ranks by E alone.")

    # ------------------------------------------------------------------ approach stage (before MALA)
    approach_steps: int = Field(
        0, ge=0,
        description="Adam steps of the approach stage run between the initialisation and MALA "
        "(optimizer.approach): E_dist + E_pen + E_prior only (no force closure, alignment weighted by "
        "approach_w_align), contacts reassigned every approach_reassign_every steps. 0 = off (the official "
        "pipeline). Measured (B = 32, 1 thread, init_mode='pair', w_align 0, 400 approach + 400 MALA + 400 "
        "refine): the approach alone brings all 6 contacts within 5 mm in 15/32 rows (approach_w_dist 20) but "
        "any MALA with the default weights, even cold (step 0.002, T 0.05), undoes it (max contact distance "
        "median 14 -> 36 mm: force closure is cheaper with hovering contacts); with w_dist 100, w_fc 5, w_pen 100, "
        "w_contact_excess 1 (h 2 mm), MALA step 0.005, T 0.5, reassignment every 10: cube + cylinder 5/32 "
        "(seed 0, Q1 of accepted 0.06, PN 2.9 mm), 0/32 (seed 1); cube + sphere 1/32 (seed 0) -- failures are "
        "now force closure with contacts on the surface (max E_fc median ~1); single cube (seed 0) 19/32 vs 7/32 with "
        "the defaults, but accepted Q1 mean 0.11 vs 0.13 (one seed only). Off by default.")
    approach_lr: float = Field(
        3e-3, gt=0.0, description="Adam learning rate of the approach stage (about 3 mm / 3 mrad per step).")
    approach_reassign_every: int = Field(
        10, ge=0,
        description="Approach stage: every this many steps each object's contacts are reassigned to its best "
        "fingers by distance (energy.best_contacts with w_fc = 0); 0 = keep the initial random contacts.")
    approach_w_dist: Optional[float] = Field(
        None, ge=0.0, description="Weight of E_dist during the approach stage (None = w_dist).")
    approach_w_align: float = Field(
        0.0, ge=0.0,
        description="Weight of E_align during the approach stage. 0: measured, the alignment gradient through "
        "the SDF normal of off-surface points is 1-50x the E_dist gradient and opposes it.")

    # ------------------------------------------------------------------ Adam refinement
    refine_steps: int = Field(1500, ge=0, description="Adam refinement steps after MALA, contacts fixed (official: 1500).")
    refine_lr: float = Field(
        1e-3, gt=0.0,
        description="Adam learning rate of the refinement (Adam moves every parameter by about lr per step: 1 mm, 1 mrad). "
        "The official 1e-2 made the energy oscillate here (1 cm steps of the palm near contact).")
    refine_w_dist: float = Field(20.0, ge=0.0, description="Weight of E_dist during refinement (official raises it from 10 to 20).")
    keep_best: bool = Field(True, description="Return, per candidate, the lowest-energy pose seen during refinement.")

    # ------------------------------------------------------------------ filter
    filter_fc: float = Field(0.25, ge=0.0, description="Accept if the largest per-object E_fc is below this (official: 0.25).")
    filter_contact_distance_m: float = Field(
        0.005, gt=0.0, description="Accept if every contact point is within this distance of its object's surface (official: 5 mm).")
    filter_contact_distance_reduce: Literal["max", "mean"] = Field(
        "mean",
        description="How the contact distances enter the contact-distance criterion: 'mean' (default) = each "
        "object's mean contact distance within filter_contact_distance_m (the official release: "
        "surf_dist.mean(-1).max(-1)); 'max' = every contact within it (stricter; the default before 2026-11-22). "
        "On the bench profile's first pass (20 training pairs x 128 candidates) 'mean' accepts 898 (35.1 %, Q1 "
        "0.054, PN 3.02 mm) where 'max' accepts 540 (21.1 %, Q1 0.062, PN 2.75 mm) (python -m benchmarks.refilter).")
    filter_penetration_m: float = Field(
        0.005, gt=0.0,
        description="Accept if the deepest sampled penetration (hand-object both ways, hand-table, self) is below this (official: 5 mm).")
    filter_prior: float = Field(0.1, ge=0.0, description="Accept if E_prior (rad of joint-limit violation) is below this (official: 0.1).")

    # ------------------------------------------------------------------ initialisation
    init_mode: Literal["sphere", "pair"] = Field(
        "sphere",
        description="'sphere': palm on a spherical cap around the objects' bounding sphere, aimed at the centroid "
        "(initializations module docstring). 'pair' (scenes of >= 2 objects; one object falls back to 'sphere'): "
        "palm centre above the centroid, init_pair_height_m above the highest object top, palm facing down within "
        "init_max_polar_deg / init_jitter_deg, fingers (+z) across the line joining the two objects farthest apart "
        "(random sign), so ff/mf reach one object and rf/lf the other. Measured (cube + cylinder, seed 0, 400 Adam "
        "steps on E_dist + E_pen only, w_align 0): rows with all 6 contacts within 5 mm 15/32 with 'pair' vs 2/32 "
        "with 'sphere' ('along' roll: 2/32); but the full MALA (step 1 cm, T 8 at the start) leaves that start: "
        "with the default energy 0/32 accepted either way, so 'sphere' stays the default.")
    init_pair_height_m: tuple[float, float] = Field(
        (0.01, 0.03),
        description="With init_mode='pair': range (m) of the palm centre's height above the highest object point.")
    init_pair_roll: Literal["across", "along", "uniform"] = Field(
        "across",
        description="With init_mode='pair': fingers across the object line, along it, or at a uniform roll.")
    init_max_polar_deg: float = Field(
        60.0, ge=0.0, le=90.0,
        description="Approach directions are uniform on the spherical cap above the objects within this angle of +z.")
    init_distance_min_m: float = Field(
        0.01, ge=-0.1,
        description="Palm centre starts this far (at least) outside the objects' bounding sphere (negative: inside it, "
        "which the bounding sphere of several objects leaves room for).")
    init_distance_max_m: float = Field(0.04, ge=-0.1, description="...and at most this far.")
    init_jitter_deg: float = Field(
        10.0, ge=0.0, description="Standard deviation of a random rotation applied to the palm after aiming it at the objects.")
    init_joint_fraction: float = Field(
        0.5, ge=0.0, le=1.0,
        description="Initial actuated joint angles: open pose + fraction * (uniform sample in the limits - open pose).")
    seed_surface_points: int = Field(0, ge=0, description="Seed of the object and hand surface samples (fixed samples, not the optimisation seed).")

    # ------------------------------------------------------------------ logging
    progress_every: int = Field(50, ge=1, description="Steps between calls of the progress callback (MALA and refinement).")

    @model_validator(mode="after")
    def _ranges(self) -> "SynthesisConfig":
        if self.init_distance_max_m < self.init_distance_min_m:
            raise ValueError("init_distance_max_m must be >= init_distance_min_m")
        bad = [f for f in self.resample_at if not 0.0 < f < 1.0]
        if bad:
            raise ValueError(f"resample_at: every fraction must lie in (0, 1) (a copy made at the end of MALA would "
                             f"be refined into a duplicate); got {bad}")
        return self

    def schedule_periods(self) -> tuple[int, int]:
        """(step-size period, temperature period) of this run (scaled when ``compress_schedule``)."""
        if not self.compress_schedule:
            return self.step_size_period, self.temperature_period
        scale = self.mala_steps / self.schedule_reference_steps
        return max(1, round(self.step_size_period * scale)), max(1, round(self.temperature_period * scale))
