"""Config of the lift environment (:class:`LiftEnvConfig`; paper §"Learning a Multi-Object Lifting Policy").

Every number the environment uses lives here with its unit and reason: physics rate and control
substeps, how actions map to the base wrench and the joint targets, the reward weights, the success
heights and the point-cloud sizes of the observation's feature blocks.
"""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import Field, model_validator

from components.config_base import Section


class LiftEnvConfig(Section):
    """The PyBullet lift environment: physics, action scaling, reward, episode, observation options."""

    # ------------------------------------------------------------------ physics
    physics_hz: int = Field(240, ge=60, description="PyBullet simulation rate (Hz); 240 is PyBullet's default and stable for the hand's small links.")
    substeps: int = Field(
        6, ge=1,
        description="Physics steps per environment step: the policy acts at physics_hz / substeps = 40 Hz.  Around "
        "the physics the env's own work (state reads, observation, features every feature_period steps, reward, "
        "TorchRL) takes ~0.5 ms per env step between PyBullet steps, against 0.4-0.7 ms per physics step, so 6 substeps "
        "give overhead_ratio ~0.78 (benchmarks/sim.py, median of 9 invocations, 0.745-0.804; 4 substeps gave 0.50-0.55 "
        "with the env of the sixth session).  Named "
        "'substeps' and not 'frame_skip': an env attribute called frame_skip makes torchrl repeat steps.")
    solver_iterations: int = Field(
        150, ge=1,
        description="PyBullet constraint solver iterations per step.  150, not PyBullet's 50: with 50 the solver does "
        "not converge on a squeezed grasp (10-20 contacts, joint motors pressing) and the held objects leak out of the "
        "fingers as the hand rises.  Grasp closure then straight lift on 60 bench training pre-grasps with Q1 >= 0.15: "
        "50 iterations 7-8 %, 100 20 %, 150 28 %, 300 28 % (joint_max_force_nm 2); the physics step costs ~1.7x the 50's "
        "(README 'Grasp closure').")
    gravity_compensation: bool = Field(
        True,
        description="Apply the hand's total weight upwards at its centre of mass every physics step, so zero base "
        "wrench holds the hand still (the hand of the paper hangs from a robot arm).")
    base_linear_damping: float = Field(
        0.5, ge=0.0, description="PyBullet linear damping of the hand base (1/s): keeps the free-floating hand from drifting.")
    base_angular_damping: float = Field(0.5, ge=0.0, description="PyBullet angular damping of the hand base (1/s).")
    hand_lateral_friction: float = Field(
        1.25, ge=0.0,
        description="Lateral friction of every hand link (rubber-like finger pads).  Bullet multiplies the two bodies' "
        "coefficients, so against the library's objects (0.8) the contact friction is 1.25 x 0.8 = 1.0: Isaac Gym's "
        "default (1.0 on both shapes, averaged), the paper's simulator; was 1.0 (0.8 at the contact).  The paper gives "
        "no friction, and lifts depend on it: the scripted squeeze-lift after the closure on the 100 bench Syn-Pl "
        "poses x 2 trials lifted 6.5 % at contact friction 0.8, 15 % at 1.0, 17 % at 1.2, 21.5 % at 1.6 "
        "(README 'Friction').")
    hand_spinning_friction: float = Field(
        0.00625, ge=0.0,
        description="Spinning (torsional) friction of every hand link (m): the torque a contact resists about its "
        "normal per newton of normal force, the soft finger pad's contact patch that a point contact lacks.  Bullet "
        "combines it as spin_hand x lateral_object + lateral_hand x spin_object, so against the library's objects "
        "(lateral 0.8, objects.spinning_friction 1e-4) a value s gives 0.8 s + 1.25e-4.  0.00625 (forty-first "
        "session; was 0, Bullet's default, no torsional friction): 0.005 m at the contact, MuJoCo's condim 4 default, "
        "which the gymnasium-robotics Shadow Hand scenes give their objects.  The scripted squeeze after the closure "
        "on the 20 bench Syn-Pl pairs (100 poses x 5 trials, paired, closure_links 'opposed'): 27.6 -> 32.4 % "
        "(docs/experiments.md 'The opposed closure and torsional friction on every bench pair').")

    # ------------------------------------------------------------------ actions (paper table: 18 joint targets + 6-D base wrench)
    max_base_force_n: float = Field(
        20.0, gt=0.0, description="Base force at action +-1 on an axis (N, world frame); the hand with its forearm weighs 4.9 kg (48 N).")
    max_base_torque_nm: float = Field(2.0, gt=0.0, description="Base torque at action +-1 on an axis (N m, world frame).")
    joint_delta_rad: float = Field(
        0.02, gt=0.0,
        description="Joint targets move by action * this per environment step (rad), starting at the pre-grasp "
        "angles (after the grasp closure: its targets) and clamped to the joint limits: zero action holds them.  J0 "
        "of FF/MF/RF/LF follows J1.  0.02 (0.8 rad/s at 40 Hz; was 0.075): the closure has closed the fingers, and "
        "PPO's exploration noise on the joint actions opens them again.  Closure then a lift at 4 N with Gaussian "
        "noise (std before the tanh) on 60 bench training pre-grasps: 0.075 -> 0/60 at std 0.5, 1/60 at 0.2; "
        "0.02 -> 1/60 at 0.5, 2/60 at 0.2; no noise 4/60 (README 'Grasp closure').")
    joint_action_mode: Literal["delta", "offset"] = Field(
        "delta",
        description="How a[:18] sets the joint targets.  'delta': they move by joint_delta_rad * a per environment step "
        "(integrating: a held action drifts the fingers, and exploration noise random-walks them).  'offset': they are "
        "anchor + joint_offset_rad * a, the anchor being the targets the episode starts from (after the grasp closure: "
        "its targets), so zero holds the grasp, a held action holds one posture and noise does not accumulate; "
        "specialists.squeeze_action then is a fixed offset, not a rate "
        "(docs/experiments.md, 'Joint offsets instead of joint rates').")
    joint_offset_rad: float = Field(
        0.3, gt=0.0, description="joint_action_mode 'offset': the joint target offset from the anchor at action +-1 (rad).")
    joint_position_gain: float = Field(0.3, gt=0.0, description="PyBullet POSITION_CONTROL position gain of every finger joint.")
    joint_velocity_gain: float = Field(1.0, ge=0.0, description="PyBullet POSITION_CONTROL velocity gain of every finger joint.")
    joint_max_force_nm: float = Field(
        2.0, gt=0.0,
        description="Largest motor torque of a finger joint (N m).  2 (was 5): with 5 a closed grasp presses 40 g objects "
        "with 50-90 N and the solver squeezes them out; on 60 bench pre-grasps with Q1 >= 0.15 (closure, then straight "
        "lift, 150 solver iterations) 5 N m lifted 18 %, 2 N m 28 %, 1 N m 17 %.")

    # ------------------------------------------------------------------ grasp closure (components/execution/closure.py)
    closure_steps: int = Field(
        10, ge=0,
        description="Grasp closure at every reset: environment steps over which the joint targets move from the "
        "pre-grasp to targets that press the links near the objects closure_depth_m into them, with the palm held "
        "(GenDexGrasp's squeeze toward the closest surface).  The episode then starts from the closed grasp.  0 = "
        "start at the pre-grasp itself, the paper's protocol (README 'Grasp closure': 100 bench Syn-Pl poses, "
        "straight lift after it 10 % against 0 % from the pre-grasp).")
    closure_settle_steps: int = Field(5, ge=0, description="Closure: environment steps the closed targets are held, palm still, before the episode starts.")
    closure_depth_m: float = Field(
        0.02, gt=0.0,
        description="Closure: how far (m) the joint targets move each near point into its object, to first order; "
        "the position-controlled joints stop at the surface and press (0.01-0.03 gave the same lifts on 100 bench Syn-Pl poses).")
    closure_radius_m: float = Field(
        0.01, gt=0.0, description="Closure: hand links closer than this (m) to an object are pressed into it (0.005 and 0.01 measured alike).")
    closure_links: Literal["all", "opposed"] = Field(
        "opposed",
        description="Closure: which near links press.  'all': every link within closure_radius_m.  'opposed' "
        "(fortieth session): per object, only the links whose push direction has an opposing partner on the same "
        "object (-d_i . d_j > closure_opposed_above); a one-sided link would push its object off the others.  An "
        "object with no opposed pair keeps all its links.  'opposed' is the default since the forty-first session "
        "(every run before pressed 'all'): the scripted squeeze on the 20 bench Syn-Pl pairs (100 poses x 5 trials, "
        "paired) lifts 27.6 % against 15.8 % with 'all' (higher on 16 of the 20 pairs, lower on none) "
        "(docs/experiments.md 'The opposed closure and torsional friction on every bench pair').")
    closure_opposed_above: float = Field(
        0.5, ge=-1.0, le=1.0,
        description="Closure, closure_links 'opposed': the opposition above which two push directions count as "
        "opposed (0.5: more than 120 degrees apart, benchmarks.lift_failures' --opposed-above).")
    closure_damping: float = Field(
        1e-3, gt=0.0, description="Closure: lambda (rad^2 per m^2 of point motion) of the damped least squares (J^T J + lambda I) dq = J^T b.")
    closure_hold_stiffness_n_per_m: float = Field(
        1000.0, gt=0.0, description="Closure: stiffness (N/m) of the PD force that holds the palm still (critically damped for the hand's mass; clipped to max_base_force_n).")
    closure_hold_stiffness_nm_per_rad: float = Field(
        20.0, gt=0.0, description="Closure: rotational stiffness (N m / rad) of the palm hold (clipped to max_base_torque_nm).")
    closure_hold_damping_nms_per_rad: float = Field(
        1.3, ge=0.0, description="Closure: rotational damping (N m s / rad) of the palm hold (~critical for the hand's ~0.02 kg m^2).")

    # ------------------------------------------------------------------ episode
    max_steps: int = Field(100, ge=1, description="Environment steps per episode (2.5 s at 40 Hz); the episode is truncated after them.")
    action_repeat: int = Field(
        1, ge=1,
        description="Environment steps each policy action is held for (1 = the policy acts at physics_hz / substeps, "
        "40 Hz).  k > 1 makes the policy act at 40 / k Hz with everything else at 40 Hz: the grasp closure, the joint "
        "target rate (joint_delta_rad per inner step), the feature period, max_steps (counted in inner steps, so an "
        "episode lasts as long) and the reward (summed over the k inner steps; a fall ends the repeat).  What it is for: "
        "PPO's Gaussian noise then holds each draw for k / 40 s, a temporally correlated exploration with exact "
        "log-probabilities.  Scale ppo.gamma to gamma**k to keep the horizon in seconds.")
    fall_height_m: float = Field(
        -0.05,
        description="An object whose centre falls below this height (m, table top = 0) ends the episode (terminated). "
        "The terminating step also gets the remaining steps times the worst reward a step can have "
        "(observations.worst_step_reward), so that knocking an object off the table never pays more than holding "
        "on: with per-step penalties and a free termination, PPO learned to end episodes that way (README 'Grasp closure').")

    # ------------------------------------------------------------------ reward (paper Eq. rl-rewards)
    w_lift: float = Field(10.0, ge=0.0, description="omega_lift: weight of r_lift = min_j (z_j - z_j(0)) (m), the lift of the lowest object.")
    lift_reward_cap_m: Optional[float] = Field(
        None, gt=0.0,
        description="r_lift counts the lowest object's lift up to this (m); None = uncapped (the paper's term).  What it "
        "is for: at w_lift 10 an object held 0.6 m up earns 6 per step, six times the success bonus, so a policy gains "
        "more by lifting the grasps it already holds higher than by holding one more (docs/experiments.md, 'State-"
        "dependent exploration, gSDE': PPO on 10 pre-grasps raised the reward 1.2 -> 4.3 and the mean final lift "
        "0.28 -> 0.62 m, and lifted fewer of them).  At success_height_m the term stops paying for height: capped at "
        "0.15 the same run's sampled success rose 22.7 -> 32.9 % and it lifted 28 % deterministically against the "
        "squeeze's 27 % (within the noise).  The evaluation's success and the env's 'lift' output are not capped.")
    w_success: float = Field(1.0, ge=0.0, description="omega_succ: bonus per step while every object is lifted above success_height_m.")
    w_rotation: float = Field(0.1, ge=0.0, description="omega_r: weight of r_r = -angle(R_goal^T R) (rad), the palm's rotation away from the pre-grasp.")
    w_joint: float = Field(0.1, ge=0.0, description="omega_q: weight of r_q = -mean_i |q_i - q_goal_i| (rad) over the 22 joints.")
    w_object: float = Field(
        1.0, ge=0.0,
        description="omega_obj: weight of r_obj = -sum_j |p_j^palm - p_j^palm,goal| (m), the objects' displacement "
        "in the palm frame from where the pre-grasp held them.")
    object_distance_clip_m: float = Field(
        0.1, gt=0.0,
        description="r_obj counts each object's displacement in the palm frame up to this (m).  Unclipped, a hand "
        "that rises without its objects costs ~1 per step (its height), ten times what a lift earns before it "
        "succeeds, and PPO learned not to lift (README 'Grasp closure': the closure then a 4 N lift, 30 bench "
        "training pairs: r_obj -1.02 per step against r_lift +0.24).")
    success_height_m: float = Field(0.15, gt=0.0, description="Lift (m) above which every object must be for the success bonus (paper: 15 cm).")
    eval_success_height_m: float = Field(0.10, gt=0.0, description="Lift (m) every object must exceed at the end of an evaluation rollout (paper: 10 cm).")

    # ------------------------------------------------------------------ evaluation trials
    trial_position_noise_m: float = Field(
        0.002, ge=0.0,
        description="Evaluation: each trial moves the pre-grasp palm by N(0, this^2) per axis (m), seeded per (pose, trial): "
        "the paper's 5 trials per pose differ by such perturbations.")
    trial_joint_noise_rad: float = Field(
        0.02, ge=0.0, description="Evaluation: ...and its 18 actuated joints by N(0, this^2) (rad), J0 coupled.")
    train_perturbation: bool = Field(
        False,
        description="Perturb every training reset's pre-grasp as an evaluation trial is perturbed (trial_position_noise_m, "
        "trial_joint_noise_rad; drawn from the env's seeded generator), so that PPO trains on the starts it is "
        "evaluated on.  False: training starts at the exact pre-grasps.  Not measured better (bench run F: "
        "Syn-Pl 13.2 % against 13.4 % without; README 'Friction, and best-policy selection').")

    start_sampling: Literal["uniform", "learnability"] = Field(
        "uniform",
        description="Which pre-grasp a training episode starts from (components/execution/start_sampling.py).  "
        "'uniform': every record alike.  'learnability': records whose training episodes sometimes lift and sometimes "
        "drop are drawn more often (prioritized level replay): on a start that always lifts, or never does, every "
        "return is alike and PPO's advantage is ~0.  Evaluation and validation pick their records themselves and "
        "are not affected.  Off by default: on the whole cube + frustum bin (234 pre-grasps, 60 iterations) Syn-Pl "
        "was 36.2 and 35.0 % (two runs) against the squeeze's 34.6 % on the same episodes, and the uniform run's "
        "35.2 % (docs/experiments.md 'Learnability start sampling').")
    learnability_prior: float = Field(
        0.5, gt=0.0, description="start_sampling 'learnability': a of the Beta(a, a) prior on each record's success rate "
        "(pseudo-episodes half lifted, half dropped; 0.5 is Jeffreys').")
    learnability_power: float = Field(
        2.0, ge=0.0,
        description="start_sampling 'learnability': k in l = (4 p (1 - p))^k; larger focuses harder on the even "
        "records (with 2, a record never lifted in 6 episodes is drawn 1/14 as often as an even one; 0 is uniform).")
    learnability_uniform_mix: float = Field(
        0.2, ge=0.0, le=1.0,
        description="start_sampling 'learnability': share of the draws that stay uniform, so that no record is "
        "dropped and a record's estimate can recover.")

    # ------------------------------------------------------------------ observation
    goal_observations: bool = Field(
        True,
        description="Include the goal blocks (joint and orientation goals/residues, object pose goals/residues). False "
        "is the paper's 'w/o Goal' ablation (their reward terms are then off too).")
    feature_dim: int = Field(256, ge=1, description="Dimension of each point-cloud feature (paper: 256, a pre-trained PointNet).")
    hand_cloud_points: int = Field(128, ge=8, description="Points of the hand cloud given to the encoder (a fixed subset of the hand surface samples).")
    hand_cloud_spacing_m: float = Field(0.01, gt=0.0, description="Spacing of the hand surface samples the hand cloud is drawn from (m).")
    object_cloud_points: int = Field(128, ge=8, description="Points of each object's cloud given to the encoder (fixed samples on its surface).")
    feature_period: int = Field(
        4, ge=1,
        description="Recompute the point-cloud features every this many environment steps (1 = every step); "
        "between updates the last features are observed.  4 (10 Hz): one update (link frames, 3 clouds of 128 points, "
        "the BatchNorm-folded encoder) costs 0.4 ms warm and ~1 ms between PyBullet steps on one CPU thread, more "
        "than a physics step (benchmarks/sim.py); features of a held grasp change slowly.")
    cloud_seed: int = Field(0, ge=0, description="Seed of the fixed hand and object cloud samples.")

    @model_validator(mode="after")
    def _heights(self) -> "LiftEnvConfig":
        if self.eval_success_height_m > self.success_height_m:
            raise ValueError("eval_success_height_m must not exceed success_height_m (the bonus would never be reached "
                             "before an evaluation counts a success)")
        return self

    @property
    def control_dt(self) -> float:
        """Seconds per environment step."""
        return self.substeps / self.physics_hz
