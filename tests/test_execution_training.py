"""Execution training pieces: running normaliser, specialist bins, records files, PPO (train, resume after a
kill, cache, corrupt checkpoint), evaluation protocol with the scripted baseline."""

import math
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import torch

from components.errors import MultigraspError
from components.execution import GraspRecord
from components.execution.cameras import CameraConfig, preview_hand_pose
from components.execution.clustering import ClusteringConfig, assign_bins, bin_label, centre_line_angle
from components.execution.evaluation import ScriptedLift, evaluate_lift, trial_seed
from components.execution.factory import LiftEnvFactory
from components.execution.pointnet import PointNetConfig, PointNetEncoder, save_encoder
from components.execution.ppo import PPOConfig, RunningNorm, load_checkpoint, train_ppo
from components.execution.records import load_records, save_records
from components.hand import HandConfig
from components.objects import Placement, Scene

IDENTITY = (0.0, 0.0, 0.0, 1.0)
TINY_PPO = dict(frames_per_batch=100, minibatch_size=50, epochs=1, hidden=(32,), checkpoint_every=1)


def test_running_norm_matches_the_mean_and_variance_of_everything_seen():
    data = torch.randn(300, 4, dtype=torch.float64) * torch.tensor([1.0, 2.0, 3.0, 0.5]) + 5.0
    norm = RunningNorm(4).double()
    for chunk in data.split([7, 100, 193]):
        norm.update(chunk)
    assert torch.allclose(norm.mean, data.mean(0)) and torch.allclose(norm.var, data.var(0, unbiased=False))
    assert torch.allclose(norm(data).mean(0), torch.zeros(4, dtype=torch.float64), atol=1e-9)


def _record(names_positions, R=np.eye(3)) -> GraspRecord:
    scene = Scene(objects=tuple(Placement(n, pos, IDENTITY) for n, pos in names_positions))
    return GraspRecord(scene=scene, p=np.zeros(3), R=np.asarray(R, float), q=np.zeros(22))


def test_placement_bins_follow_the_centre_line_in_the_palm_plane():
    along_x = _record([("cube", (0.0, 0, 0.02)), ("sphere", (0.05, 0, 0.02))])
    along_z = _record([("cube", (0.0, 0, 0.02)), ("sphere", (0.0, 0, 0.07))])
    assert centre_line_angle(along_x) == pytest.approx(0.0, abs=1e-9)
    assert centre_line_angle(along_z) == pytest.approx(math.pi / 2)
    # a line: swapping the objects gives the same direction
    swapped = _record([("sphere", (0.05, 0, 0.02)), ("cube", (0.0, 0, 0.02))])
    assert centre_line_angle(swapped) == pytest.approx(0.0, abs=1e-9)
    # the palm frame matters: rotate the palm 90 deg about y and x becomes z
    rot_y = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    assert centre_line_angle(_record([("cube", (0.0, 0, 0.02)), ("sphere", (0.05, 0, 0.02))], rot_y)) == pytest.approx(math.pi / 2)
    cfg = ClusteringConfig()
    assert bin_label(along_x, cfg) == "cube+sphere/0" and bin_label(along_z, cfg) == "cube+sphere/3"
    assert bin_label(along_z, ClusteringConfig(mode="combination")) == "cube+sphere"
    assert bin_label(along_z, ClusteringConfig(mode="placement")) == "2obj/placement-3"
    assert bin_label(along_z, ClusteringConfig(mode="single")) == "2obj"
    single = _record([("cube", (0.0, 0, 0.02))])
    assert assign_bins([along_x, along_z, single], ClusteringConfig(mode="single")) == {"1obj": [2], "2obj": [0, 1]}


def test_records_round_trip_and_malformed_files_get_a_one_line_error(tmp_path):
    record = _record([("cube", (0.01, 0.02, 0.02))])
    record.meta["scene_id"] = "Pl/cube/0"
    path = save_records(tmp_path / "r.json", [record])
    (back,) = load_records(path)
    assert back.scene == record.scene and np.allclose(back.R, record.R) and back.meta == record.meta
    (tmp_path / "bad.json").write_text("[{]")
    with pytest.raises(MultigraspError, match="malformed"):
        load_records(tmp_path / "bad.json")
    with pytest.raises(MultigraspError, match="not found"):
        load_records(tmp_path / "missing.json")


@pytest.fixture(scope="module")
def factory(hand, library, tmp_path_factory):
    root = tmp_path_factory.mktemp("lift")
    scene = Scene(objects=(Placement("cube", (0.0, -0.03, 0.02), IDENTITY), Placement("sphere", (0.0, 0.035, 0.025), IDENTITY)))
    p, R, q = preview_hand_pose(hand, scene, CameraConfig(), library)
    save_records(root / "records.json", [GraspRecord(scene, p, R, q.astype(float))])
    enc_cfg = PointNetConfig()
    save_encoder(root / "encoder.pt", PointNetEncoder(enc_cfg), enc_cfg)
    hand.export_urdf(root / "hand.urdf")
    return LiftEnvFactory(hand_cfg=HandConfig().model_dump(mode="json"), objects_cfg=library.cfg.model_dump(mode="json"),
                          objects_cache=str(library.cache_dir), urdf=str(root / "hand.urdf"),
                          records=str(root / "records.json"), lift_cfg={"max_steps": 50}, encoder=str(root / "encoder.pt"))


def test_ppo_trains_checkpoints_resumes_and_serves_a_finished_run(factory, tmp_path):
    ckpt = tmp_path / "ppo.pt"
    first = train_ppo(factory, PPOConfig(iterations=1, **TINY_PPO), ckpt)
    assert first.resumed_from == 0 and [r["iteration"] for r in first.history] == [1]
    assert {"loss_objective", "loss_critic", "reward", "collect_s", "update_s", "frames_per_s"} <= set(first.history[0])
    assert all(row["collect_s"] >= 0 and row["update_s"] > 0 and row["frames_per_s"] > 0 for row in first.history)
    longer = train_ppo(factory, PPOConfig(iterations=2, **TINY_PPO), ckpt)
    assert longer.resumed_from == 1 and [r["iteration"] for r in longer.history] == [1, 2]
    state = load_checkpoint(ckpt)
    assert state["iteration"] == 2 and state["frames"] == 200
    served = train_ppo(factory, PPOConfig(iterations=2, **TINY_PPO), ckpt)
    assert served.resumed_from == 2 and len(served.history) == 2
    # the normaliser's statistics travel with the actor
    assert float(served.actor.module[0].module[0].count) == 200.0
    ckpt.write_bytes(b"not a checkpoint")
    with pytest.raises(MultigraspError, match="corrupt"):
        train_ppo(factory, PPOConfig(iterations=3, **TINY_PPO), ckpt)


def test_ppo_killed_mid_training_resumes_from_its_last_checkpoint(factory, tmp_path):
    ckpt = tmp_path / "ppo.pt"
    script = tmp_path / "train.py"
    script.write_text(textwrap.dedent(f"""
        import torch
        from components.execution.factory import LiftEnvFactory
        from components.execution.ppo import PPOConfig, train_ppo
        if __name__ == "__main__":
            torch.set_num_threads(1)
            factory = LiftEnvFactory(**{factory.__dict__!r})
            train_ppo(factory, PPOConfig(iterations=50, **{TINY_PPO!r}), {str(ckpt)!r})
    """))
    proc = subprocess.Popen([sys.executable, str(script)], cwd=os.getcwd(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 240
        while time.time() < deadline and not (ckpt.exists() and load_checkpoint(ckpt)["iteration"] >= 2):
            time.sleep(0.5)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    done = load_checkpoint(ckpt)["iteration"]
    assert 2 <= done < 50
    resumed = train_ppo(factory, PPOConfig(iterations=done + 1, **TINY_PPO), ckpt)
    assert resumed.resumed_from == done and [r["iteration"] for r in resumed.history] == list(range(1, done + 2))


def test_validation_keeps_the_best_actor_across_a_resume_and_load_actor_serves_it(factory, tmp_path):
    """ppo.validate_every: the untrained actor is validated first, then every k iterations; the checkpoint keeps the
    best validated actor (success first, then lift; a tie keeps the earlier one) and load_actor serves it."""
    from components.execution.ppo import load_actor

    scores = iter([(0.5, 0.01), (0.1, 0.20), (0.9, 0.00), (0.9, 0.05), (0.2, 0.30)])
    seen: list[tuple[dict, dict]] = []

    def validate(actor):
        success, lift = next(scores)
        seen.append(({k: v.clone() for k, v in actor.state_dict().items()}, {"success": success, "lift": lift}))
        return {"success": success, "lift": lift}

    ckpt = tmp_path / "ppo.pt"
    cfg = dict(TINY_PPO, validate_every=1)
    first = train_ppo(factory, PPOConfig(iterations=2, **cfg), ckpt, validate=validate)
    assert [v["iteration"] for v in first.validations] == [0, 1, 2]
    assert {k: first.best[k] for k in ("iteration", "success", "lift")} == {"iteration": 2, "success": 0.9, "lift": 0.0}
    assert [r["val_success"] for r in first.history] == [0.1, 0.9]
    # resumed: the untrained actor is not validated again, the best survives, a later tie on success wins on lift
    more = train_ppo(factory, PPOConfig(iterations=4, **cfg), ckpt, validate=validate)
    assert [v["iteration"] for v in more.validations] == [0, 1, 2, 3, 4] and more.best["iteration"] == 3
    env = factory()
    try:
        best, last = load_actor(ckpt, env).state_dict(), load_actor(ckpt, env, which="last").state_dict()
    finally:
        env.close()
    assert all(torch.equal(best[k], seen[3][0][k]) for k in best)  # the weights validated at iteration 3
    assert all(torch.equal(last[k], seen[4][0][k]) for k in last) and not all(torch.equal(best[k], last[k]) for k in best)
    # without a validate callable (or with validate_every 0) nothing is validated and the last actor is served
    plain = train_ppo(factory, PPOConfig(iterations=1, **dict(TINY_PPO, validate_every=0)), tmp_path / "p.pt",
                      validate=validate)
    assert plain.validations == [] and plain.best is None and len(seen) == 5


def test_evaluation_protocol_with_the_scripted_baseline(factory):
    env = factory()
    try:
        result = evaluate_lift(env, ScriptedLift(0.5), trials=2, seed=3)
        # the open hand above the objects flies up without them: no success, objects stay down
        assert result.n_poses == 1 and result.trials == 2 and result.succ == 0.0
        assert max(abs(x) for x in result.final_lifts) < 5e-3
        again = evaluate_lift(env, ScriptedLift(0.5), trials=2, seed=3)
        assert again.final_lifts == result.final_lifts  # seeded trials: repeatable
        chosen = evaluate_lift(env, ScriptedLift(0.5), trials=2, seed=3, poses=[0])  # records by index
        assert chosen.n_poses == 1 and chosen.final_lifts == result.final_lifts
        # seed keys: the same key gives the same perturbations whatever the pose's index in this env
        assert result.seed_keys == [0]
        keyed = evaluate_lift(env, ScriptedLift(0.5), trials=2, seed=3, seed_keys=[0])
        assert keyed.final_lifts == result.final_lifts and keyed.seed_keys == [0]
        with pytest.raises(ValueError, match="seed keys"):
            evaluate_lift(env, ScriptedLift(0.5), trials=2, seed=3, seed_keys=[0, 1])
        assert result.row("Syn-Pl") == {"setting": "Syn-Pl", "succ": 0.0, "n_poses": 1, "trials": 2}
        seeds = {trial_seed(3, pose, trial) for pose in range(100) for trial in range(5)}
        assert len(seeds) == 500
    finally:
        env.close()


def test_the_untrained_actor_starts_at_the_given_mean_action(factory):
    from components.execution.ppo import build_actor_critic
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from components.execution.evaluation import scripted_action
    from tasks.specialists import SpecialistsStageConfig, initial_action

    env = factory()
    try:
        start = scripted_action(0.2, 0.9, [1, 2, 16])
        assert start[[1, 2, 16]].tolist() == pytest.approx([0.9] * 3) and float(start[20]) == pytest.approx(0.2)
        assert float(start.abs().sum()) == pytest.approx(2.9)
        for mode in ("state", "independent"):
            actor, _, norm = build_actor_critic(env, PPOConfig(**TINY_PPO, std_mode=mode), init_action=start)
            observation = env.reset()
            with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
                mean = actor(observation)["action"]
                assert torch.allclose(mean, start, atol=2e-3)  # tanh(atanh(unit)) in float32, clamped at 0.999
                norm.update(torch.randn(64, norm.mean.shape[0]) * 5.0 + 3.0)  # statistics move, the mean does not
                assert torch.equal(actor(observation)["action"], mean)
            zero, _, _ = build_actor_critic(env, PPOConfig(**TINY_PPO, std_mode=mode))
            with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
                assert float(zero(env.reset())["action"].abs().max()) == 0.0
        hand = env.world.hand
        assert initial_action(SpecialistsStageConfig(init_policy="zero"), hand.actuated_joint_names) is None
        names = hand.actuated_joint_names
        lift = initial_action(SpecialistsStageConfig(), names)  # default: the closure squeezed, so lift only
        assert float(lift[:18].abs().max()) == 0.0 and float(lift[20]) == pytest.approx(0.2)
        squeeze = initial_action(SpecialistsStageConfig(squeeze_action=0.9), names)
        assert float(squeeze[names.index("FFJ2")]) == pytest.approx(0.9) and float(squeeze[names.index("THJ4")]) == 0.0
        with pytest.raises(MultigraspError, match="squeeze_joints: XXJ9 not among"):
            initial_action(SpecialistsStageConfig(squeeze_joints=["FFJ2", "XXJ9"]), names)
    finally:
        env.close()


def test_independent_std_starts_at_init_scale_and_is_one_learned_parameter_per_action(factory):
    from components.execution.ppo import build_actor_critic

    env = factory()
    try:
        actor, _, _ = build_actor_critic(env, PPOConfig(**TINY_PPO, std_mode="independent", init_scale=0.07))
        with torch.no_grad():
            out = actor(env.reset())
        act_dim = env.action_spec.shape[-1]
        assert out["scale"].shape[-1] == act_dim and torch.allclose(out["scale"], torch.full((act_dim,), 0.07))
        state, _, _ = build_actor_critic(env, PPOConfig(**TINY_PPO))
        n_state = sum(p.numel() for p in state.parameters())
        n_indep = sum(p.numel() for p in actor.parameters())
        # the state-dependent head has act_dim more outputs (x 32 hidden + bias); the independent one act_dim log-stds
        assert n_state - n_indep == act_dim * 33 - act_dim
    finally:
        env.close()


def test_block_scales_start_each_action_block_at_its_own_std(factory):
    """init_scale_by_block: joints / base force / base torque start at their own std, unnamed blocks at init_scale;
    a state std or a non-positive scale is refused at config time."""
    from components.execution.ppo import build_actor_critic

    env = factory()
    try:
        cfg = PPOConfig(**TINY_PPO, std_mode="independent", init_scale=0.07,
                        init_scale_by_block={"joints": 0.02, "base_force": 0.5})
        actor, _, _ = build_actor_critic(env, cfg)
        with torch.no_grad():
            scale = actor(env.reset())["scale"]
        expected = torch.tensor([0.02] * 18 + [0.5] * 3 + [0.07] * 3)
        assert torch.allclose(scale, expected)
    finally:
        env.close()
    with pytest.raises(ValueError, match="std_mode 'independent'"):
        PPOConfig(**TINY_PPO, init_scale_by_block={"joints": 0.02})
    PPOConfig(**TINY_PPO, exploration="gsde", init_scale_by_block={"joints": 0.02})  # gSDE has per-entry scales too
    with pytest.raises(ValueError, match="positive"):
        PPOConfig(**TINY_PPO, std_mode="independent", init_scale_by_block={"joints": 0.0})


def test_gsde_holds_its_noise_scores_it_as_tanh_normal_and_trains(factory, tmp_path):
    """exploration 'gsde': the untrained mean is init_action; each entry's std starts at its init scale whatever the
    state; an exploring policy repeats its perturbation on the same state until the noise is drawn again; the stored
    log-probability is TanhNormal(loc, scale)'s; deterministic calls do not explore; PPO trains and load_actor serves it."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type
    from torchrl.modules import TanhNormal

    from components.execution.ppo import GSDEHead, build_actor_critic, load_actor

    env = factory()
    try:
        init = torch.linspace(-0.5, 0.5, env.action_spec.shape[-1])
        cfg = PPOConfig(**TINY_PPO, exploration="gsde", init_scale=0.07, init_scale_by_block={"joints": 0.02},
                        gsde_resample_every=3)
        actor, _, _ = build_actor_critic(env, cfg, init_action=init)
        head = next(m for m in actor.modules() if isinstance(m, GSDEHead))
        td = env.reset()
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            out = actor(td.clone())
        assert torch.allclose(out["action"], init, atol=1e-5)
        assert torch.allclose(out["scale"], torch.tensor([0.02] * 18 + [0.07] * 6), atol=1e-6)
        assert torch.count_nonzero(out["gsde_noise"]) == 0
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            draws = [actor(td.clone()) for _ in range(4)]
        assert torch.equal(draws[0]["action"], draws[1]["action"]) and torch.equal(draws[1]["action"], draws[2]["action"])
        assert not torch.equal(draws[2]["action"], draws[3]["action"])  # a fresh noise matrix after 3 calls
        assert not torch.allclose(draws[0]["action"], init, atol=1e-4)
        first = draws[0]
        low, high = env.action_spec.space.low, env.action_spec.space.high
        expected = TanhNormal(first["loc"], first["scale"], low=low, high=high).log_prob(first["action"])
        assert torch.allclose(first["action_log_prob"], expected, atol=1e-4)
        assert head._calls == 4  # deterministic calls did not advance the noise schedule
    finally:
        env.close()
    ckpt = tmp_path / "gsde.pt"
    result = train_ppo(factory, PPOConfig(iterations=2, **{**TINY_PPO, "exploration": "gsde"}), ckpt)
    assert len(result.history) == 2 and all(math.isfinite(row["loss_objective"]) for row in result.history)
    env = factory()
    try:
        served = load_actor(ckpt, env, which="last")
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            assert served(env.reset())["action"].shape == env.action_spec.shape
    finally:
        env.close()


def test_gradient_clip_groups_are_the_parameters_the_optimiser_steps(factory):
    """grad_clip 'separate' clips the actor's and the critic's gradients apart; the groups must be the very tensors
    the loss module optimises, or the clip would act on copies."""
    from torchrl.objectives import ClipPPOLoss

    from components.execution.ppo import _clip_groups, build_actor_critic

    env = factory()
    try:
        cfg = PPOConfig(**TINY_PPO)
        actor, critic, _ = build_actor_critic(env, cfg)
        loss = ClipPPOLoss(actor_network=actor, critic_network=critic)
        optimised = {id(p) for p in loss.parameters()}
        actor_group, critic_group = _clip_groups(actor, critic, cfg)
        assert actor_group and critic_group and {id(p) for p in actor_group + critic_group} <= optimised
        assert not {id(p) for p in actor_group} & {id(p) for p in critic_group}
        assert len(_clip_groups(actor, critic, cfg.model_copy(update={"grad_clip": "joint"}))) == 1
    finally:
        env.close()


def test_critic_warmup_leaves_the_actor_alone_and_target_kl_stops_the_epochs(factory, tmp_path):
    cfg = PPOConfig(iterations=2, **dict(TINY_PPO, epochs=4), critic_warmup_iterations=1, target_kl=1e-12,
                    reward_scale=0.1, std_mode="independent")
    from components.execution.ppo import build_actor_critic

    probe = factory()
    start, start_critic, _ = build_actor_critic(probe, cfg)
    probe.close()
    result = train_ppo(factory, cfg.model_copy(update={"iterations": 1}), tmp_path / "w.pt")
    first = result.history[0]
    assert first["actor_trained"] is False and first["epochs"] == 4  # warm-up: target_kl does not cut the critic's epochs
    actor_weights = {k: v for k, v in result.actor.state_dict().items() if "mean" not in k and "var" not in k
                     and "count" not in k}
    start_weights = start.state_dict()
    assert all(torch.equal(v, start_weights[k]) for k, v in actor_weights.items())
    assert any(not torch.equal(v, start_critic.state_dict()[k]) for k, v in result.critic.state_dict().items()
               if k.endswith("weight"))
    result = train_ppo(factory, cfg, tmp_path / "w.pt")
    second = result.history[1]
    assert second["actor_trained"] is True and second["epochs"] == 1 and second["kl_approx"] > 1e-12
    assert 0.0 <= second["clip_fraction"] <= 1.0


def test_kl_adaptive_lr_steps_by_its_factor_within_its_bounds_and_needs_a_target():
    """rl_games' adaptive schedule: KL above 2 x target divides the rate by the factor, below target / 2 multiplies
    it, in between leaves it; the bounds clamp it; a config without target_kl (or lr outside the bounds) is refused."""
    from pydantic import ValidationError

    from components.execution.ppo import adapt_lr

    cfg = PPOConfig(lr=1e-3, target_kl=0.02, lr_schedule="kl_adaptive", lr_adapt_factor=2.0, lr_min=4e-4, lr_max=3e-3)
    optimizer = torch.optim.Adam([torch.nn.Parameter(torch.zeros(2))], lr=cfg.lr)
    assert adapt_lr(optimizer, 0.05, cfg) == pytest.approx(5e-4)   # 0.05 > 0.04: halved
    assert adapt_lr(optimizer, 0.05, cfg) == pytest.approx(4e-4)   # clamped at lr_min
    assert adapt_lr(optimizer, 0.02, cfg) == pytest.approx(4e-4)   # within [0.01, 0.04]: kept
    assert adapt_lr(optimizer, 0.001, cfg) == pytest.approx(8e-4)  # 0.001 < 0.01: doubled
    assert adapt_lr(optimizer, 0.0, cfg) == pytest.approx(1.6e-3)
    assert adapt_lr(optimizer, 0.0, cfg) == pytest.approx(3e-3)    # clamped at lr_max
    assert optimizer.param_groups[0]["lr"] == pytest.approx(3e-3)
    with pytest.raises(ValidationError, match="target_kl"):
        PPOConfig(lr_schedule="kl_adaptive")
    with pytest.raises(ValidationError, match="outside"):
        PPOConfig(lr_schedule="kl_adaptive", target_kl=0.02, lr=0.1)


def test_kl_adaptive_lr_lowers_an_overshooting_rate_and_a_resume_keeps_it(factory, tmp_path):
    """A target_kl no update can meet: each trained iteration's epoch divides the rate by the factor (the critic's
    warm-up does not adapt it), the history records it, and a resumed run continues from the adapted rate."""
    cfg = PPOConfig(iterations=2, **TINY_PPO, critic_warmup_iterations=1, target_kl=1e-9, lr=1e-3,
                    lr_schedule="kl_adaptive", lr_adapt_factor=2.0, lr_min=1e-5, std_mode="independent")
    first = train_ppo(factory, cfg, tmp_path / "a.pt").history
    assert first[0]["lr"] == pytest.approx(1e-3) and first[1]["lr"] == pytest.approx(5e-4)
    resumed = train_ppo(factory, cfg.model_copy(update={"iterations": 3}), tmp_path / "a.pt")
    assert resumed.resumed_from == 2 and resumed.history[2]["lr"] == pytest.approx(2.5e-4)


def test_each_update_starts_from_the_policy_that_collected_its_batch(factory, tmp_path):
    """The normaliser is the actor's first layer: with normalizer_update 'after_update' a batch's statistics enter it
    after the batch's update, so every update starts from the collecting policy (kl_start ~ 0); the legacy
    'before_update' moved the policy before the clip could bound it (kl_start > 0 once the actor has trained)."""
    rows = {}
    for mode in ("after_update", "before_update"):
        cfg = PPOConfig(iterations=3, **TINY_PPO, normalizer_update=mode)
        rows[mode] = train_ppo(factory, cfg, tmp_path / f"{mode}.pt").history
    # the first batch sets the statistics before its update (the untrained mean ignores them, the state std barely)
    assert rows["after_update"][0]["kl_start"] < 1e-3
    assert all(row["kl_start"] < 1e-6 for row in rows["after_update"][1:])
    assert all(row["kl_start"] > 1e-4 for row in rows["before_update"][1:])
    state = load_checkpoint(tmp_path / "after_update.pt")
    assert float(state["actor"]["module.0.module.0.count"]) == 300.0  # every batch still reaches the statistics


def test_frozen_normaliser_statistics_stop_after_the_given_iterations(factory, tmp_path):
    cfg = PPOConfig(iterations=3, **TINY_PPO, normalizer_frozen_after=1)
    rows = train_ppo(factory, cfg, tmp_path / "frozen.pt").history
    assert all(row["kl_start"] < 1e-5 for row in rows[1:])
    state = load_checkpoint(tmp_path / "frozen.pt")
    assert float(state["actor"]["module.0.module.0.count"]) == 100.0  # only the first batch


def test_learnability_counts_are_shared_by_the_collector_workers(factory, tmp_path):
    """Two MultiSyncCollector workers count their training episodes into one memory-mapped file that the main
    process reads: as many episodes as the batches ended, all on the bin's one record."""
    from dataclasses import replace

    from components.execution.factory import open_start_counts

    path = tmp_path / "start_counts.i64"
    counts = open_start_counts(path, 1)
    shared = replace(factory, lift_cfg={"max_steps": 10, "closure_steps": 0, "start_sampling": "learnability"},
                     start_counts=str(path))
    result = train_ppo(shared, PPOConfig(iterations=2, workers=2, **TINY_PPO), tmp_path / "ppo.pt")
    ended = sum(row["episodes"] for row in result.history)
    assert ended >= 10  # 2 x 100 frames of 10-step episodes
    assert ended <= int(counts[0, 0]) <= ended + 2  # + episodes a worker ended after its last batch was cut
    assert int(counts[0, 1]) == 0  # an open hand above the objects lifts nothing in 10 steps
    assert open_start_counts(path, 1)[0, 0] == counts[0, 0]  # reopened with the right size: kept, not zeroed
    assert open_start_counts(path, 3).sum() == 0  # another record count: a fresh file
