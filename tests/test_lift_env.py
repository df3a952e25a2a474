"""Lift environment: TorchRL specs, the paper's observation blocks, zero-action stability, wrench actions,
palm-frame bookkeeping, reward terms at the goal, clear errors."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from torchrl.envs.utils import check_env_specs

from components.errors import MultigraspError
from components.execution import GraspRecord, LiftEnv, LiftEnvConfig, observation_blocks, observation_dim
from components.execution.cameras import CameraConfig, preview_hand_pose
from components.execution.observations import Goal, euler_xyz, reward_terms
from components.execution.pointnet import PointNetConfig, PointNetEncoder
from components.objects import Placement, Scene

IDENTITY = (0.0, 0.0, 0.0, 1.0)
#: The paper's observation table (state-based policy), per block.
PAPER_BLOCKS = {"joint_angles": 22, "joint_velocities": 22, "joint_forces": 22, "fingertip_wrenches": 30,
                "base_state": 12, "last_actions": 24, "joint_goals": 22, "joint_residues": 22,
                "orientation_goal": 3, "orientation_residue": 3, "hand_feature": 256}
PAPER_OBJECT_BLOCKS = {"state": 12, "pose_goal": 6, "pose_residue": 6, "feature": 256}


@pytest.fixture(scope="module")
def record(hand, library):
    scene = Scene(objects=(Placement("cube", (0.0, -0.03, 0.02), IDENTITY),  # resting: 4 cm cube, 2.5 cm sphere
                           Placement("sphere", (0.0, 0.035, 0.025), IDENTITY)))
    p, R, q = preview_hand_pose(hand, scene, CameraConfig(), library)  # open hand above the objects, no contact
    return GraspRecord(scene=scene, p=p, R=R, q=q.astype(np.float64))


@pytest.fixture(scope="module")
def env(hand, library, record, tmp_path_factory):
    urdf = hand.export_urdf(tmp_path_factory.mktemp("urdf"))
    encoder = PointNetEncoder(PointNetConfig()).eval()
    environment = LiftEnv(hand, library, urdf, [record], LiftEnvConfig(), encoder)
    yield environment
    environment.close()


def test_observation_blocks_are_the_papers_table():
    blocks = dict(observation_blocks(LiftEnvConfig(), 2))
    for name, dim in PAPER_BLOCKS.items():
        assert blocks[name] == dim, name
    for j in range(2):
        for name, dim in PAPER_OBJECT_BLOCKS.items():
            assert blocks[f"object_{j}_{name}"] == dim
    assert observation_dim(LiftEnvConfig(), 2) == sum(PAPER_BLOCKS.values()) + 2 * sum(PAPER_OBJECT_BLOCKS.values()) == 998
    # w/o Goal drops the goal and residue blocks
    no_goal = LiftEnvConfig(goal_observations=False)
    assert observation_dim(no_goal, 2) == 998 - (22 + 22 + 3 + 3) - 2 * (6 + 6)
    assert not any("goal" in n or "residue" in n for n, _ in observation_blocks(no_goal, 2))


def test_env_passes_torchrl_spec_checks(env):
    check_env_specs(env)
    assert env.observation_spec["observation"].shape == (998,)
    assert env.action_spec.shape == (24,)


def _block(obs: torch.Tensor, name: str) -> np.ndarray:
    start = 0
    for block, dim in observation_blocks(LiftEnvConfig(), 2):
        if block == name:
            return obs[start:start + dim].numpy()
        start += dim
    raise KeyError(name)


def test_reset_puts_the_palm_frame_and_joints_at_the_pre_grasp(env, record):
    td = env.reset()
    p, R = env.world.palm_pose()
    assert np.allclose(p, record.p, atol=1e-6) and np.allclose(R, record.R, atol=1e-6)
    obs = td["observation"]
    assert np.allclose(_block(obs, "joint_angles"), record.q, atol=1e-6)
    assert np.allclose(_block(obs, "joint_goals"), record.q, atol=1e-6)
    assert np.allclose(_block(obs, "joint_residues"), 0.0, atol=1e-6)
    assert np.allclose(_block(obs, "base_state")[:3], record.p, atol=1e-6)
    assert np.allclose(_block(obs, "object_0_pose_residue"), 0.0, atol=1e-6)
    assert float(td["lift"]) == pytest.approx(0.0, abs=1e-9)


def test_zero_actions_hold_the_hand_and_leave_the_objects_on_the_table(env, record):
    env.reset()
    rollout = env.rollout(env.cfg.max_steps, policy=lambda td: td.set("action", torch.zeros(24)),
                          break_when_any_done=False)
    assert rollout.shape == (env.cfg.max_steps,)
    assert bool(rollout["next", "truncated"][-1]) and not rollout["next", "terminated"].any()
    state = env.world.read()
    start = np.array([pl.position for pl in record.scene.objects])
    assert np.abs(state.obj_pos - start).max() < 2e-3  # objects stay where they were put
    assert np.abs(state.palm_pos - record.p).max() < 5e-3  # gravity compensation holds the hand
    assert float(rollout["next", "lift"].abs().max()) < 2e-3
    assert not rollout["next", "success"].any()


def test_an_upward_base_force_lifts_the_hand(env, record):
    env.reset()
    up = torch.zeros(24)
    up[20] = 0.5  # +z force
    td = env.reset()
    for _ in range(10):
        td["action"] = up
        td = env.step(td)["next"]
    p, _ = env.world.palm_pose()
    assert p[2] > record.p[2] + 0.01
    assert np.allclose(_block(td["observation"], "last_actions"), up.numpy())


def test_actions_are_clipped_and_a_nan_action_is_refused(env, record):
    env.reset()
    targets = env.world.targets
    with pytest.raises(ValueError, match="NaN entries"):
        env.world.set_action(np.full(24, np.nan, dtype=np.float32))
    np.testing.assert_array_equal(env.world.targets, targets)  # nothing applied
    force, torque = env.world.set_action(np.array([0.0] * 18 + [3.0, -3.0, 0.5, 0.0, 0.0, 0.0]))  # 18 joints, wrench
    assert env.world.last_action[18:] == [1.0, -1.0, 0.5, 0.0, 0.0, 0.0]
    assert force == [env.cfg.max_base_force_n, -env.cfg.max_base_force_n, 0.5 * env.cfg.max_base_force_n]
    assert torque == [0.0, 0.0, 0.0]


def test_reward_terms_vanish_at_the_goal(env, record):
    env.reset()
    state = env.world.read()
    terms = reward_terms(env.cfg, state, Goal.from_state(state), state.obj_pos[:, 2].copy())
    for name in ("r_lift", "r_rot", "r_joint", "r_object", "reward"):
        assert terms[name] == pytest.approx(0.0, abs=1e-6), name


def test_lift_reward_cap_stops_paying_for_height_above_it(env, record):
    """lift_reward_cap_m: r_lift = min(lift, cap); the success bonus and the reported lift stay uncapped."""
    env.reset()
    state = env.world.read()
    start = state.obj_pos[:, 2].copy() - 0.4  # as if every object had been lifted 0.4 m
    goal = Goal.from_state(state)
    free = reward_terms(env.cfg, state, goal, start)
    capped = reward_terms(env.cfg.model_copy(update={"lift_reward_cap_m": 0.15}), state, goal, start)
    assert free["r_lift"] == pytest.approx(0.4) and capped["r_lift"] == pytest.approx(0.15)
    assert capped["lift"] == pytest.approx(0.4) and capped["r_success"] == free["r_success"] == 1.0
    assert free["reward"] - capped["reward"] == pytest.approx(env.cfg.w_lift * 0.25)


def test_observation_blocks_hold_the_state_after_steps(env, record):
    """The preallocated observation buffer is rewritten every step: each block equals its definition."""
    from components.execution.observations import wrap_angle

    td = env.reset()
    push = torch.zeros(24)
    push[0], push[18] = 0.5, 0.3  # a finger joint and a sideways base force
    for _ in range(3):
        td["action"] = push
        td = env.step(td)["next"]
    state, goal = env.world.read(), env.episode.goal
    obs = td["observation"]
    assert np.allclose(_block(obs, "joint_angles"), state.q, atol=1e-5)
    assert np.allclose(_block(obs, "joint_residues"), state.q - goal.q, atol=1e-5)
    assert np.allclose(_block(obs, "base_state"), np.concatenate([state.palm_pos, euler_xyz(state.palm_rot),
                                                                   state.palm_lin_vel, state.palm_ang_vel]), atol=1e-5)
    assert np.allclose(_block(obs, "orientation_residue"),
                       wrap_angle(euler_xyz(state.palm_rot) - euler_xyz(goal.palm_rot)), atol=1e-5)
    pos_palm, rot_palm = state.objects_in_palm
    for j in range(2):
        assert np.allclose(_block(obs, f"object_{j}_state")[:3], state.obj_pos[j], atol=1e-6)
        assert np.allclose(_block(obs, f"object_{j}_pose_residue")[:3], pos_palm[j] - goal.obj_pos_palm[j], atol=1e-6)
    assert not np.allclose(_block(obs, "joint_residues"), 0.0)  # the step moved something
    # the returned observation is a copy: the next step does not change it
    before = obs.clone()
    td["action"] = push
    env.step(td)
    assert torch.equal(obs, before)


def test_quaternion_matrices_match_scipy():
    from components.execution.lift_sim import quat_matrices

    R = Rotation.random(7, random_state=1)
    assert np.allclose(quat_matrices(R.as_quat()), R.as_matrix(), atol=1e-9)


def test_euler_xyz_matches_scipy_extrinsic_xyz():
    R = Rotation.random(64, random_state=0)
    assert np.allclose(euler_xyz(R.as_matrix()), R.as_euler("xyz"), atol=1e-9)


def test_records_with_different_object_counts_are_refused_with_a_clear_error(hand, library, record, tmp_path):
    single = GraspRecord(scene=Scene(objects=record.scene.objects[:1]), p=record.p, R=record.R, q=record.q)
    with pytest.raises(MultigraspError, match="one object count"):
        LiftEnv(hand, library, tmp_path / "x.urdf", [record, single], LiftEnvConfig(), lambda x: x)
    with pytest.raises(MultigraspError, match="no grasp records"):
        LiftEnv(hand, library, tmp_path / "x.urdf", [], LiftEnvConfig(), lambda x: x)


def test_trial_perturbations_are_seeded_small_and_keep_the_coupling(env, record):
    starts = []
    for seed in (1, 1, 2):
        env.set_next_record(0, seed)
        env.reset()
        starts.append(env.world.read())
    assert np.allclose(starts[0].palm_pos, starts[1].palm_pos) and not np.allclose(starts[0].palm_pos, starts[2].palm_pos)
    assert np.abs(starts[0].palm_pos - record.p).max() < 5 * env.cfg.trial_position_noise_m
    q = starts[2].q
    assert np.allclose(env.world.coupled(q), q, atol=1e-6)  # J0 follows J1, within limits


def test_training_resets_are_perturbed_like_trials_only_when_asked(hand, library, record, tmp_path):
    urdf = hand.export_urdf(tmp_path)
    encoder = PointNetEncoder(PointNetConfig()).eval()
    for perturb in (False, True):
        env = LiftEnv(hand, library, urdf, [record], LiftEnvConfig(train_perturbation=perturb), encoder, seed=3)
        starts = []
        try:
            for _ in range(2):
                env.reset()
                starts.append(env.world.read().palm_pos)
        finally:
            env.close()
        same = np.allclose(starts[0], starts[1], atol=1e-6)
        assert same != perturb
        if perturb:
            assert np.abs(starts[0] - record.p).max() < 5 * LiftEnvConfig().trial_position_noise_m


def test_bench_sim_writes_rates_ratio_and_physics_share(tmp_path):
    import json

    from flows.cli import main

    out = tmp_path / "sim.json"
    assert main(["bench", "sim", "--repeats", "1", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    for key in ("env_steps_per_s", "env_steps_per_s_2workers", "raw_physics_steps_per_s"):
        assert result[key] > 0
    assert result["substeps"] == 6 and result["overhead_ratio"] > 0
    assert 0.0 < result["physics_share"] < 1.0 and len(result["physics_share_runs"]) == 1
    assert len(result["overhead_ratio_runs"]) == 1 and result["workload"]["chunk"] == 10  # interleaved chunks
    import os
    import platform

    trim = str(1024 * 2**20)  # RunConfig's default, applied unless the user's environment sets another value
    if platform.libc_ver()[0] == "glibc" and os.environ.get("MALLOC_TRIM_THRESHOLD_", trim) == trim:
        assert result["allocator"]["MALLOC_TRIM_THRESHOLD_"] == int(trim)


def test_quaternion_helpers_match_the_matrix_definitions():
    """The env's per-step Euler angles and rotation angles come from quaternions; they equal the matrix formulas."""
    from components.execution.observations import euler_of_quat, quaternion_angle, rotation_angle

    R = Rotation.random(256, random_state=2)
    quats = R.as_quat()
    assert np.allclose([euler_of_quat(q) for q in quats], euler_xyz(R.as_matrix()), atol=1e-12)
    # also 1e-4 rad from pitch -90 deg, where PyBullet's getEulerFromQuaternion would snap the roll to 0
    near = Rotation.from_euler("xyz", [0.7, -np.pi / 2 + 1e-4, 0.3])
    assert np.allclose(euler_of_quat(near.as_quat()), [0.7, -np.pi / 2 + 1e-4, 0.3], atol=1e-9)
    mats = R.as_matrix()
    for k in range(0, 256, 2):
        assert quaternion_angle(quats[k], quats[k + 1]) == pytest.approx(rotation_angle(mats[k], mats[k + 1]), abs=1e-7)
    assert quaternion_angle(quats[0], quats[0]) == 0.0


def test_joint_targets_follow_the_coupling_rule(env, record):
    """set_action's plain-Python arithmetic equals ``coupled(targets + joint_delta_rad * clip(a))``."""
    world = env.world
    world.reset(record)
    rng = np.random.default_rng(3)
    for _ in range(5):
        before = world.targets.copy()
        action = rng.uniform(-1.5, 1.5, 24).astype(np.float32)
        force, torque = world.set_action(action)
        clipped = np.clip(action.astype(np.float64), -1.0, 1.0)
        expected = before.copy()
        expected[world._actuated] += env.cfg.joint_delta_rad * clipped[:18]
        assert np.array_equal(world.targets, world.coupled(expected))
        assert np.allclose(force, env.cfg.max_base_force_n * clipped[18:21])
        assert np.allclose(torque, env.cfg.max_base_torque_nm * clipped[21:])
        assert np.array_equal(world.last_action, clipped)


def test_physics_does_not_depend_on_when_features_are_computed(hand, library, record, tmp_path):
    """Asking PyBullet for link frames with forward kinematics rewrites its cached link transforms, which the next
    physics step uses: the world recomputes them on every read, so the point-cloud feature period (when the env asks
    for link frames) leaves the motion unchanged."""
    urdf = hand.export_urdf(tmp_path / "urdf")
    trajectories = []
    for period in (1, 3):
        environment = LiftEnv(hand, library, urdf, [record], LiftEnvConfig(feature_period=period),
                              PointNetEncoder(PointNetConfig()).eval())
        generator = torch.Generator().manual_seed(0)
        td, run = environment.reset(), []
        for _ in range(12):
            td["action"] = torch.rand(24, generator=generator) * 2.0 - 1.0
            td = environment.step(td)["next"]
            run.append(environment.world.read().q.copy())
        environment.close()
        trajectories.append(np.array(run))
    assert np.array_equal(trajectories[0], trajectories[1])


def test_world_state_arrays_match_pybullet(env, record):
    """WorldState keeps PyBullet's tuples and builds its arrays on demand; they hold the same numbers."""
    import pybullet as pb

    env.reset()
    state = env.world.read()
    c = env.world.client
    for j, body in enumerate(env.world.objects):
        pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=c)
        lin, ang = pb.getBaseVelocity(body, physicsClientId=c)
        assert np.allclose(state.obj_pos[j], pos) and np.allclose(state.obj_rot[j], Rotation.from_quat(quat).as_matrix())
        assert np.allclose(state.obj_lin_vel[j], lin) and np.allclose(state.obj_ang_vel[j], ang)
    p, R = env.world.palm_pose()
    assert np.allclose(state.palm_pos, p) and np.allclose(state.palm_rot, R)
    pos_palm, rot_palm = state.objects_in_palm
    assert np.allclose(pos_palm, (state.obj_pos - state.palm_pos) @ state.palm_rot, atol=1e-12)
    assert np.allclose(rot_palm, state.palm_rot.T @ state.obj_rot, atol=1e-12)
    assert np.array_equal(state.q, np.array(state.q_tuple))


def test_a_goal_built_from_arrays_gives_the_same_reward(env):
    """Goal's tuple and quaternion fields are derived from its arrays when not given."""
    env.reset()
    td = env.step(env.reset().set("action", torch.full((24,), 0.3)))["next"]
    state = env.world.read()
    goal = env.episode.goal
    plain = Goal(q=goal.q, palm_rot=goal.palm_rot, obj_pos_palm=goal.obj_pos_palm, obj_rot_palm=goal.obj_rot_palm)
    a = reward_terms(env.cfg, state, goal, env.episode.start_heights)
    b = reward_terms(env.cfg, state, plain, env.episode.start_heights)
    for name in ("r_rot", "r_joint", "r_object", "reward"):
        assert a[name] == pytest.approx(b[name], abs=1e-9), name
    assert td["reward"].shape == (1,)


def test_object_displacement_is_clipped_and_a_fall_costs_the_rest_of_the_episode(env, record):
    """r_obj counts each object's displacement up to object_distance_clip_m; the step on which an object falls gets
    the remaining steps times worst_step_reward, which bounds every step's reward before a fall from below."""
    import pybullet as pb

    from components.execution.observations import worst_step_reward

    cfg = env.cfg
    env.reset()
    world = env.world
    sphere = world.objects[1]
    pos, orn = pb.getBasePositionAndOrientation(sphere, physicsClientId=world.client)
    pb.resetBasePositionAndOrientation(sphere, (pos[0] + 0.5, pos[1], pos[2]), orn, physicsClientId=world.client)
    state = world.read()
    terms = reward_terms(cfg, state, env.episode.goal, env.episode.start_heights)
    assert terms["r_object"] == pytest.approx(-cfg.object_distance_clip_m, abs=1e-3)  # 0.5 m away, counted 0.1
    ranges = (world.upper - world.lower).tolist()
    heights = env.episode.start_heights.tolist()
    worst = worst_step_reward(cfg, 2, ranges, heights)
    sink = max(heights) - cfg.fall_height_m  # the highest-starting object just above the fall height
    assert worst == pytest.approx(-(cfg.w_lift * sink + cfg.w_rotation * np.pi + cfg.w_joint * np.mean(ranges)
                                    + cfg.w_object * 2 * cfg.object_distance_clip_m))
    assert terms["reward"] >= worst
    assert env.episode.worst_step == pytest.approx(worst)
    # the sphere below the table's edge: the next step terminates and pays for the steps it skips
    pb.resetBasePositionAndOrientation(sphere, (pos[0], pos[1], -0.2), orn, physicsClientId=world.client)
    td = env.step(env.reset().set("action", torch.zeros(24)))["next"]
    assert not bool(td["terminated"])  # reset put the sphere back
    pb.resetBasePositionAndOrientation(sphere, (pos[0], pos[1], -0.2), orn, physicsClientId=world.client)
    td = env.step(td.set("action", torch.zeros(24)))["next"]
    assert bool(td["terminated"]) and env.episode.t == 2
    after = reward_terms(cfg, world.read(), env.episode.goal, env.episode.start_heights)
    worst = env.episode.worst_step  # this episode's start heights
    assert worst == pytest.approx(worst_step_reward(cfg, 2, ranges, env.episode.start_heights.tolist()))
    assert float(td["reward"]) == pytest.approx(after["reward"] + (cfg.max_steps - 2) * worst, rel=1e-5)
    # without goal observations only the lift term can go below zero
    no_goal = cfg.model_copy(update={"goal_observations": False})
    assert worst_step_reward(no_goal, 2, ranges, heights) == pytest.approx(-cfg.w_lift * sink)


def test_an_episode_does_not_depend_on_the_episodes_before_it(hand, library, record, tmp_path):
    """The same record, seed and actions give the same trajectory whether the world is fresh or has run other
    episodes (with other objects, re-created) before: Bullet's contact pairs are solved in a sorted order
    (deterministicOverlappingPairs), not in an order that depends on the bodies' history."""
    scene = Scene(objects=(Placement("cylinder", (0.01, -0.04, 0.03), IDENTITY), Placement("cube", (0.0, 0.03, 0.02), IDENTITY)))
    p, R, q = preview_hand_pose(hand, scene, CameraConfig(), library)
    other = GraspRecord(scene=scene, p=p, R=R, q=q.astype(np.float64))
    urdf = hand.export_urdf(tmp_path / "urdf")
    encoder = PointNetEncoder(PointNetConfig()).eval()
    actions = torch.rand(25, 24, generator=torch.Generator().manual_seed(0)) * 2.0 - 1.0
    actions[:, 18 + 2] = -1.0  # push the hand down into the objects: contacts between hand, objects and table

    def episode(environment, pose: int) -> np.ndarray:
        environment.set_next_record(pose, 7)
        td, states = environment.reset(), []
        for action in actions:
            td["action"] = action
            td = environment.step(td)["next"]
            state = environment.world.read()
            states.append(np.concatenate([state.q, state.palm_pos, np.ravel(state.obj_pos)]))
        return np.array(states)

    runs = []
    for history in ([], [1, 0, 1]):
        environment = LiftEnv(hand, library, urdf, [record, other], LiftEnvConfig(), encoder)
        try:
            for pose in history:
                episode(environment, pose)
            runs.append(episode(environment, 0))
        finally:
            environment.close()
    assert np.array_equal(runs[0], runs[1])


def test_action_repeat_holds_the_action_and_sums_the_reward(hand, library, record, tmp_path):
    """action_repeat k: one policy step is k inner steps of the same action (same physics as k steps at 40 Hz), the
    reward is their sum, and max_steps still counts inner steps, so the episode lasts as long."""
    urdf = hand.export_urdf(tmp_path / "urdf")
    action = torch.zeros(24)
    action[20], action[3] = 0.3, 0.5  # lift a little, flex a joint
    runs = {}
    for repeat in (1, 4):
        environment = LiftEnv(hand, library, urdf, [record], LiftEnvConfig(action_repeat=repeat, max_steps=8),
                              PointNetEncoder(PointNetConfig()).eval())
        td, rewards, states, dones = environment.reset(), [], [], []
        for _ in range(8 // repeat):
            td["action"] = action
            td = environment.step(td)["next"]
            rewards.append(float(td["reward"]))
            states.append(environment.world.read().q.copy())
            dones.append(bool(td["truncated"]))
        environment.close()
        runs[repeat] = (rewards, states, dones)
    r1, s1, d1 = runs[1]
    r4, s4, d4 = runs[4]
    assert np.allclose(r4, [sum(r1[:4]), sum(r1[4:])], rtol=1e-5, atol=1e-6)
    assert np.array_equal(s4[0], s1[3]) and np.array_equal(s4[1], s1[7])
    assert d4 == [False, True] and d1[-1] and not any(d1[:-1])


def test_joint_offset_mode_sets_targets_from_the_anchor_and_does_not_drift(hand, library, record, tmp_path):
    """joint_action_mode 'offset': targets = coupled(anchor + joint_offset_rad * clip(a)), the anchor being the
    targets the episode started from; holding an action holds the targets (no drift, unlike 'delta'), and a zero
    action returns them to the anchor."""
    cfg = LiftEnvConfig(joint_action_mode="offset", joint_offset_rad=0.25, closure_steps=0)
    environment = LiftEnv(hand, library, hand.export_urdf(tmp_path / "urdf"), [record], cfg,
                          PointNetEncoder(PointNetConfig()).eval())
    try:
        world = environment.world
        world.reset(record)
        anchor = world.targets.copy()
        action = np.zeros(24, dtype=np.float32)
        action[3], action[7], action[12] = 0.4, -0.8, 1.7  # the last is clipped to 1
        expected = anchor.copy()
        expected[world._actuated] += 0.25 * np.clip(action[:18].astype(np.float64), -1.0, 1.0)
        for _ in range(3):  # held: the same targets every step
            world.set_action(action)
            assert np.array_equal(world.targets, world.coupled(expected))
        world.set_action(np.zeros(24, dtype=np.float32))
        assert np.array_equal(world.targets, world.coupled(anchor))
        # targets set from outside (the grasp closure, reaching) become the new anchor
        moved = anchor.copy()
        moved[world._actuated[0]] += 0.1
        world.set_joint_targets(moved)
        world.set_action(np.zeros(24, dtype=np.float32))
        assert np.allclose(world.targets, np.clip(moved, world.lower, world.upper))
    finally:
        environment.close()


def test_hand_links_carry_the_configured_lateral_and_spinning_friction(hand, library, record, tmp_path):
    """``lift.hand_lateral_friction`` / ``hand_spinning_friction`` reach every hand link that can touch an object
    (PyBullet's dynamics info: index 1 lateral, 7 spinning); the default spinning friction is 0.00625 (0.005 m at a
    contact with a library object, MuJoCo's condim 4 default), and 0 gives Bullet's own (none)."""
    import pybullet as pb

    urdf = hand.export_urdf(tmp_path / "urdf")
    for spin in (None, 0.0):
        cfg = LiftEnvConfig() if spin is None else LiftEnvConfig(hand_spinning_friction=spin)
        environment = LiftEnv(hand, library, urdf, [record], cfg, PointNetEncoder(PointNetConfig()).eval())
        world = environment.world
        for link in [-1, *world._child_links]:
            info = pb.getDynamicsInfo(world.body, link, physicsClientId=world.client)
            assert info[1] == pytest.approx(cfg.hand_lateral_friction)
            assert info[7] == pytest.approx(0.00625 if spin is None else spin)
        environment.close()



def test_an_object_cloud_has_its_size_and_the_cli_holds_back_the_shortfall_warning(hand, tmp_path, caplog):
    """trimesh's even surface sampling returns fewer points than asked on some meshes (a thin-walled cup in
    millimetres: 89 of 128) and warns, once per env; the featurizer tops the cloud up to its size, so the CLI and the
    evaluation's worker processes hold that warning back (``flows.library_logs``)."""
    import logging

    import trimesh

    from components.execution.clouds import CloudFeaturizer
    from components.objects import ObjectLibrary, ObjectsConfig, UserMesh
    from flows.cli import main
    from flows.evaluate_execution import _worker_init

    cup = trimesh.creation.revolve(np.array([[0, 0], [25, 0], [25, 60], [22, 60], [22, 4], [0, 4]], float), sections=48)
    cup.export(tmp_path / "cup.obj")
    library = ObjectLibrary(ObjectsConfig(user=[UserMesh(name="cup", mesh=tmp_path / "cup.obj", scale=0.001,
                                                         mass_kg=0.1)]), tmp_path / "cache")
    cfg = LiftEnvConfig()
    import signal

    sampler = logging.getLogger("trimesh.sample")
    level, threads, on_sigint = sampler.level, torch.get_num_threads(), signal.getsignal(signal.SIGINT)
    try:
        sampler.setLevel(logging.NOTSET)  # as in a process that never ran the CLI (an earlier test may have)
        with caplog.at_level(logging.WARNING):
            short, _ = trimesh.sample.sample_surface_even(library.get("cup").mesh, cfg.object_cloud_points,
                                                          seed=cfg.cloud_seed)
            assert len(short) < cfg.object_cloud_points and "only got" in caplog.text  # the case of this test
            cloud = CloudFeaturizer(hand, library, cfg, PointNetEncoder(PointNetConfig()).eval()).object_local("cup")
            assert cloud.shape == (cfg.object_cloud_points, 3)
        for quiet in (lambda: main(["stages"]), _worker_init):
            sampler.setLevel(logging.NOTSET)
            quiet()
            assert sampler.level == logging.ERROR
    finally:  # _worker_init also sets the worker's threads and SIGINT: this process's are given back
        sampler.setLevel(level)
        torch.set_num_threads(threads)
        signal.signal(signal.SIGINT, on_sigint)
