"""The pointnet and specialists stages end to end through the CLI: a small synthesis (filters open so
there are accepted grasps), the encoder pre-training, one PPO specialist per bin, MLflow curves, cache."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from flows.cli import main
from tasks.artifacts import read_manifest
from tasks.units import executions
from tests.test_synthesize_stage import ACCEPT_ALL, STAGE_YAML

TINY = ["specialists.records_source=accepted", "specialists.max_bins=2",
        "specialists.ppo.iterations=2", "specialists.ppo.frames_per_batch=50", "specialists.ppo.minibatch_size=25",
        "lift.max_steps=20"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    import trimesh

    folder = tmp_path_factory.mktemp("exec-config")
    mesh = folder / "block.obj"
    trimesh.creation.box(extents=(0.04, 0.03, 0.025)).export(mesh)
    config = folder / "stage.yaml"
    config.write_text(STAGE_YAML.format(mesh=mesh))
    workdir = tmp_path_factory.mktemp("exec")
    argv = ["run", "--profile", "smoke", "--workdir", str(workdir), "--config", str(config), "--until", "specialists"]
    for item in [*ACCEPT_ALL, *TINY]:
        argv += ["--set", item]
    assert main(argv) == 0
    first = executions(workdir)
    assert main(argv) == 0
    return workdir, first, executions(workdir)


def _rerun_argv(workdir, *sets: str) -> list[str]:
    """The fixture's ``multigrasp run --until specialists`` with more ``--set``s."""
    config = next((workdir.parent).glob("exec-config*/stage.yaml"))
    argv = ["run", "--profile", "smoke", "--workdir", str(workdir), "--config", str(config), "--until", "specialists"]
    for item in [*ACCEPT_ALL, *TINY, *sets]:
        argv += ["--set", item]
    return argv


def _evaluate_argv(workdir, config, *sets: str, ablations: bool = False) -> list[str]:
    """``multigrasp evaluate execution`` on ``workdir`` with the fixture's settings and more ``--set``s, lifting in
    the test's process (monkeypatched spies see it; tests/test_flows.py checks the worker processes)."""
    argv = ["evaluate", "execution", *(["--ablations"] if ablations else []), "--profile", "smoke",
            "--workdir", str(workdir), "--config", str(config), "--max-workers", "1"]
    for item in [*ACCEPT_ALL, *TINY, *sets]:
        argv += ["--set", item]
    return argv


def _final(workdir, stage):
    manifests = [m for m in map(read_manifest, (workdir / "stages" / stage).iterdir()) if m is not None]
    return max((m for m in manifests if m.unit in ("merge", "stage")), key=lambda m: m.created_unix)


def test_pointnet_stage_writes_a_loadable_frozen_encoder(runs):
    from components.execution.pointnet import load_encoder

    workdir, _, _ = runs
    manifest = _final(workdir, "pointnet")
    encoder, cfg = load_encoder(manifest.path("encoder"))
    assert not any(p.requires_grad for p in encoder.parameters())
    assert manifest.metrics["loss_last"] < manifest.metrics["loss_first"]
    history = json.loads(manifest.path("history").read_text())
    assert history[-1]["step"] == cfg.steps


def test_specialists_stage_trains_one_policy_per_bin(runs):
    from components.execution.ppo import load_checkpoint

    workdir, _, _ = runs
    index = json.loads(_final(workdir, "specialists").path("index").read_text())
    assert 1 <= len(index) <= 2
    for label, entry in index.items():
        state = load_checkpoint(entry["policy"])
        assert state["iteration"] == 2 and entry["metrics"]["records"] >= 1
        # the smoke profile validates before training and after each iteration; the best validated actor is kept
        validations = json.loads((Path(entry["folder"]) / "validations.json").read_text())
        assert [v["iteration"] for v in validations["rows"]] == [0, 1, 2]
        assert state["best"]["iteration"] == validations["best"]["iteration"] == entry["metrics"]["best_iteration"]
        assert entry["metrics"]["best_validation_success"] == max(v["success"] for v in validations["rows"])
        records = json.loads(open(entry["records"]).read())
        assert all(len(r["scene"]["objects"]) <= 2 for r in records)
        assert "/" in label or "+" in label or label  # labels name the combination and the placement sector


def test_second_run_serves_the_execution_stages_from_cache(runs):
    _, first, after = runs
    assert any(label.startswith("specialists/bin-") for label in first)
    assert any(label.startswith("pointnet/") for label in first)
    assert after == first  # nothing executed on the second run


def test_fewer_bins_reuse_the_trained_specialists(runs):
    """A bin's unit is named by its label, not its rank: changing max_bins retrains no bin already trained."""
    from flows.specialists import bin_unit

    assert bin_unit("cube+frustum/0") == "bin-cube+frustum-0"
    workdir, _, after = runs
    assert main(_rerun_argv(workdir, "specialists.max_bins=1")) == 0
    new = executions(workdir)[len(after):]
    assert not [e for e in new if e.startswith("specialists/bin-")], new
    index = json.loads(_final(workdir, "specialists").path("index").read_text())
    assert len(index) == 1


def test_learnability_starts_write_their_counts_and_metrics_per_bin(runs):
    """lift.start_sampling=learnability: the bin trains anew (the lift config is part of its key) and its unit keeps
    the shared counts file, start_counts.json and the never / always / mixed metrics, which add up to its records."""
    workdir, _, _ = runs
    assert main(_rerun_argv(workdir, "specialists.max_bins=1", "lift.start_sampling=learnability")) == 0
    index = json.loads(_final(workdir, "specialists").path("index").read_text())
    (entry,) = index.values()
    counts = json.loads((Path(entry["folder"]) / "start_counts.json").read_text())
    assert (Path(entry["folder"]) / "start_counts.i64").stat().st_size == 16 * entry["metrics"]["records"]
    assert len(counts["records"]) == entry["metrics"]["records"] and sum(e for e, _ in counts["records"]) >= 1
    kinds = ("untried", "never_lifted", "always_lifted", "mixed")
    assert sum(entry["metrics"][f"start_records_{k}"] for k in kinds) == entry["metrics"]["records"]
    assert sum(entry["metrics"][f"start_episode_share_{k}"] for k in kinds) == pytest.approx(1.0, abs=1e-3)


def test_mlflow_has_the_learning_curves(runs):
    import mlflow

    workdir, _, _ = runs
    client = mlflow.tracking.MlflowClient(f"sqlite:///{workdir / 'mlflow.db'}")
    experiment = client.search_experiments()[0]
    runs_ = client.search_runs([experiment.experiment_id], "tags.stage = 'specialists'")
    computed = [r for r in runs_ if any(k.endswith(".reward") for k in r.data.metrics)]
    assert computed, "the specialists run that trained logs per-bin reward curves"
    key = next(k for k in computed[0].data.metrics if k.endswith(".reward"))
    assert len(client.get_metric_history(computed[0].info.run_id, key)) == 2


def test_evaluate_execution_writes_the_success_tables(runs, tmp_path, capsys):
    workdir, _, _ = runs
    config = next((workdir.parent).glob("exec-config*/stage.yaml"))
    argv = _evaluate_argv(workdir, config, "specialists.eval_poses=1", "specialists.eval_trials=2",
                          "specialists.eval_progress_every=1")
    assert main(argv) == 0
    rows = json.loads((workdir / "results" / "execution.json").read_text())["rows"]
    assert [r["setting"] for r in rows] == ["Syn-Pl", "Syn-Com", "Syn-Geo"]
    for row in rows:
        assert set(row) >= {"setting", "succ", "n_poses", "trials"} and row["trials"] == 2
        assert row["succ"] is None or 0.0 <= row["succ"] <= 1.0
    assert rows[1]["n_poses"] + rows[1]["unmatched_poses"] >= 1  # the Com pair is evaluated (or said unmatched)
    assert all(sum(row["matched_by"].values()) == row["n_poses"] for row in rows)
    ablation = json.loads((workdir / "results" / "ablation_execution.json").read_text())["rows"]
    assert [r["setting"] for r in ablation] == ["Ours", "w/o RL", "Scripted squeeze-lift", "w/o Goal", "w/o Spe-Pl",
                                                 "w/o Spe-Com", "w/o Spe"]
    # the squeeze-and-lift runs on the same poses as the w/o RL lift (none here when Syn-Pl is unmatched)
    assert (ablation[2]["succ"] is None) == (ablation[1]["succ"] is None) and "not in the paper" in ablation[2]["note"]
    assert ablation[2]["n_poses"] == ablation[1]["n_poses"]
    assert all(r["succ"] is None and "--ablations" in r["missing"] for r in ablation[3:])
    # each row beside the paper's figure: Table I's specialists, Table II's ablations (none for the squeeze)
    assert [r["paper"] for r in rows] == [0.6834, 0.2673, 0.2255]
    assert [r["paper"] for r in ablation[:4]] == [0.6834, 0.0137, None, 0.1679]
    for setting, row in zip(("Syn-Pl", "Syn-Com", "Syn-Geo"), rows):  # per-pose outcomes, for paired comparisons
        outcomes = json.loads((workdir / "results" / "execution" / setting / "outcomes.json").read_text())
        assert outcomes["trials"] == 2 and len(outcomes["poses"]) == row["n_poses"]
        if row["n_poses"]:
            assert sum(p["policy"] for p in outcomes["poses"]) == round(row["succ"] * 2 * row["n_poses"])
            assert all(set(p) >= {"specialist", "combination", "pose_key", "policy"} for p in outcomes["poses"])
        if setting == "Syn-Pl" and row["n_poses"]:
            assert sum(p["squeeze"] for p in outcomes["poses"]) == round(ablation[2]["succ"] * 2 * row["n_poses"])
    captured = capsys.readouterr()
    assert "per-pose outcomes:" in captured.out and "benchmarks.paired_execution" in captured.out
    err = captured.err  # progress: one line per split, then counts per specialist
    assert "evaluate execution Syn-Pl:" in err and "evaluate execution Syn-Geo:" in err
    if rows[0]["n_poses"]:
        assert "lifted " in err and "w/o RL " in err
        assert "policy: 1/1 poses" in err and "squeeze: 1/1 poses" in err  # a line per pose of each pass here


def test_evaluate_execution_of_generated_pre_grasps_writes_the_gen_rows(runs, capsys):
    """The paper's Gen succ rows: the generator's kept pre-grasps lifted by the same specialists; the report reads
    them."""
    workdir, _, _ = runs
    config = next((workdir.parent).glob("exec-config*/stage.yaml"))
    argv = _evaluate_argv(workdir, config, "specialists.eval_poses=1", "specialists.eval_trials=2",
                          "generator.eval_scenes=1", "generator.eval_grasps_per_scene=2", "generator.refine.fc_steps=2",
                          "generator.eval_filter.enabled=false")
    assert main([*argv, "--source", "generated"]) == 0
    rows = {r["setting"]: r for r in json.loads((workdir / "results" / "execution_generated.json").read_text())["rows"]}
    assert list(rows) == ["Gen-Pl", "Gen-Com", "Gen-Geo"]
    assert rows["Gen-Pl"]["generated"] == 0  # this config has no Pl scenes
    com = rows["Gen-Com"]  # one Com pair scene, 2 generated grasps, the filter open: both kept, one lifted
    assert com["generated"] == com["kept"] == 2 and com["n_poses"] + com["unmatched_poses"] == 1
    assert com["succ"] is None or 0.0 <= com["succ"] <= 1.0
    assert com["paper"] == 0.2332 and rows["Gen-Pl"]["paper"] == 0.4020
    outcomes = json.loads((workdir / "results" / "execution_generated" / "Gen-Com" / "outcomes.json").read_text())
    assert len(outcomes["poses"]) == com["n_poses"]
    assert "| Gen-Com |" in capsys.readouterr().out
    assert main([*argv, "--source", "generated", "--ablations"]) == 2
    assert "--ablations applies to" in capsys.readouterr().err
    assert main(["report", "--workdir", str(workdir)]) == 0
    assert "| execution_generated.json | smoke |" in (workdir / "results" / "report.md").read_text()


def test_pose_chunks_split_a_specialists_poses_into_jobs_of_at_most_the_chunk_size():
    from flows.evaluate_execution import pose_chunks

    assert pose_chunks(5, 3) in ([(0, 2), (2, 5)], [(0, 3), (3, 5)])
    assert pose_chunks(1, 4) == [(0, 1)] and pose_chunks(7, 7) == [(0, 7)] and pose_chunks(0, 2) == [(0, 0)]
    assert [b - a for a, b in pose_chunks(100, 10)] == [10] * 10
    assert [b - a for a, b in pose_chunks(21, 10)] == [7, 7, 7]  # three jobs, as equal as they can be
    assert [b - a for a, b in pose_chunks(3, 1)] == [1, 1, 1]


def test_evaluation_progress_says_a_line_every_k_poses_of_each_pass_with_an_eta():
    from flows.evaluate_execution import _Progress

    lines = []
    progress = _Progress(lines.append, "Syn-Pl", poses=4, trials=2, specialists=1, passes=3, every=2)
    for phase in ("policy", "w/o RL"):
        seen = progress.on_rollout("cube+frustum/0", phase, 4)
        for pose in range(4):
            for trial in range(2):
                seen(pose, trial, None)
    said = [line for line in lines if "poses, elapsed" in line]
    assert len(said) == 4 and "cube+frustum/0, policy: 2/4 poses" in said[0] and "w/o RL: 4/4 poses" in said[-1]
    assert all("ETA" in line for line in said)  # 8 of the 12 pose-passes are done after the second pass


def test_evaluate_execution_after_the_reach_lifts_from_the_end_of_reach_states(runs, monkeypatch):
    import flows.evaluate_execution as ev
    import tasks.reach

    workdir, _, _ = runs
    config = next((workdir.parent).glob("exec-config*/stage.yaml"))
    reached = []
    real = tasks.reach.reach_records

    def spy(records, *args, **kwargs):
        out = real(records, *args, **kwargs)
        reached.extend(out)
        return out

    monkeypatch.setattr(tasks.reach, "reach_records", spy)
    # at this size the specialists are single-object ones and no evaluation pair matches them: evaluate the splits'
    # singles instead, each with the first specialist
    monkeypatch.setattr(ev, "EVALUATED_OBJECTS", 1)
    monkeypatch.setattr(ev, "matching_specialist", lambda label, index: next(iter(index)))
    argv = _evaluate_argv(workdir, config, "specialists.eval_poses=3", "specialists.eval_trials=1",
                          "specialists.eval_after_reach=true", "specialists.gifs_per_outcome=0")
    assert main(argv) == 0
    rows = json.loads((workdir / "results" / "execution.json").read_text())["rows"]
    assert all(r["after_reach"] for r in rows)
    assert sum(r["reached_poses"] for r in rows) == sum(r["n_poses"] for r in rows) == len(reached) >= 1
    assert all(r.meta["reached"] and "object_displacement_m" in r.meta for r in reached)



def test_a_moved_work_dir_keeps_its_specialists_and_evaluates_them_from_where_it_is(runs, tmp_path, monkeypatch):
    """Trained on a cluster, evaluated on a laptop: the copied work dir serves every unit from its own cache and
    lifts with its own policies and this installation's URDF, with the original work dir out of reach."""
    import shutil

    import components.execution.factory
    import components.execution.ppo
    import flows.evaluate_execution as ev

    workdir, _, _ = runs
    moved = tmp_path / "laptop-runs"
    shutil.copytree(workdir, moved)
    argv = _rerun_argv(workdir)
    argv[argv.index("--workdir") + 1] = str(moved)
    parked = workdir.with_name(workdir.name + "-parked")
    workdir.rename(parked)
    try:
        done = executions(moved)
        assert main(argv) == 0
        assert executions(moved) == done, "the moved work dir recomputed finished units"
        urdfs, policies = [], []
        factory, load_actor = components.execution.factory.LiftEnvFactory, components.execution.ppo.load_actor

        def spy_factory(**kwargs):
            urdfs.append(kwargs["urdf"])
            return factory(**kwargs)

        def spy_load(path, env):
            policies.append(str(path))
            return load_actor(path, env)

        monkeypatch.setattr(components.execution.factory, "LiftEnvFactory", spy_factory)
        monkeypatch.setattr(components.execution.ppo, "load_actor", spy_load)
        monkeypatch.setattr(ev, "EVALUATED_OBJECTS", 1)  # single-object specialists at this size (test above)
        monkeypatch.setattr(ev, "matching_specialist", lambda label, index: next(iter(index)))
        config = next((parked.parent).glob("exec-config*/stage.yaml"))
        argv = _evaluate_argv(moved, config, "specialists.eval_poses=2", "specialists.eval_trials=1",
                              "specialists.gifs_per_outcome=0")
        assert main(argv) == 0
        rows = json.loads((moved / "results" / "execution.json").read_text())["rows"]
        assert sum(r["n_poses"] for r in rows) >= 1 and policies and urdfs
        assert all(p.startswith(str(moved / "stages" / "specialists")) for p in policies)
        assert all(u == str(moved / "cache" / "hand" / "shadow_hand.urdf") for u in urdfs)
    finally:
        parked.rename(workdir)


def test_a_finished_job_that_lifted_more_serves_a_narrower_one(runs, tmp_path, monkeypatch):
    """The policy is lifted first in every job, so a finished job with GIFs or the scripted baselines serves the
    same poses' policy-only job (``evaluate curriculum``'s ``w/o Adpt`` row after ``evaluate execution --source
    generated``) instead of lifting them again."""
    import flows.evaluate_execution as ev
    from flows.config import load_config
    from flows.evaluate_execution import _stage_outputs, evaluate_split, lift_setting, wider_settings

    workdir, _, _ = runs
    # at this size the specialists are single-object ones: lift the Geo split's single, with the first specialist
    monkeypatch.setattr(ev, "EVALUATED_OBJECTS", 1)
    monkeypatch.setattr(ev, "matching_specialist", lambda label, index: next(iter(index)))
    config = next((workdir.parent).glob("exec-config*/stage.yaml"))
    sets = [*ACCEPT_ALL, *TINY, "specialists.eval_poses=1", "specialists.eval_trials=1", "specialists.eval_seed=7"]
    cfg = load_config("smoke", config_file=config, sets=sets, workdir=workdir)
    assert wider_settings(cfg, False, False) == [lift_setting(cfg, *w) for w in ((False, True), (True, False),
                                                                                  (True, True))]
    assert wider_settings(cfg, True, False) == [lift_setting(cfg, True, True)] and not wider_settings(cfg, True, True)
    outputs = _stage_outputs(cfg)
    wide = evaluate_split(cfg, outputs, "Geo", tmp_path / "wide", scripted=True, gifs=False)
    assert wide.poses == 1 and wide.scripted_total == 1
    before = executions(workdir)
    narrow = evaluate_split(cfg, outputs, "Geo", tmp_path / "narrow", scripted=False, gifs=False)
    assert executions(workdir) == before  # served by the scripted job's unit, not lifted again
    assert narrow.outcomes == [{k: v for k, v in row.items() if k not in ("w/o RL", "squeeze")} for row in wide.outcomes]
    assert narrow.scripted_total == 0  # no baseline counts where none were asked for
    # the other way round there is nothing to serve: the scripted baselines are lifted
    other = load_config("smoke", config_file=config, sets=[*sets[:-1], "specialists.eval_seed=8"], workdir=workdir)
    evaluate_split(other, outputs, "Geo", tmp_path / "first", scripted=False, gifs=False)
    before = executions(workdir)
    evaluate_split(other, outputs, "Geo", tmp_path / "second", scripted=True, gifs=False)
    assert len(executions(workdir)) == len(before) + 1


def test_the_wo_rl_row_lifts_from_the_pre_grasp_without_the_grasp_closure():
    from components.execution.factory import LiftEnvFactory
    from tasks.lift_jobs import without_closure

    factory = LiftEnvFactory(hand_cfg={}, objects_cfg={}, objects_cache="c", urdf="u", records="r",
                             lift_cfg={"closure_steps": 10, "max_steps": 25}, encoder="e")
    plain = without_closure(factory)
    assert plain.lift_cfg == {"closure_steps": 0, "max_steps": 25} and factory.lift_cfg["closure_steps"] == 10
    assert without_closure(plain) is plain  # already the paper's start: the same env serves both rows
    assert without_closure(dataclasses.replace(factory, lift_cfg={})).lift_cfg == {"closure_steps": 0}  # default: on


def test_each_pose_is_reached_once_per_reach_setting(monkeypatch):
    """evaluate execution's ablations lift the same Syn-Pl poses again: their reaches are reused, and only a change
    of the reach / lift / hand / objects setting (or another pose) reaches again."""
    import numpy as np

    import tasks.reach
    from components.execution.records import GraspRecord
    from components.objects import Placement, Scene
    from flows.config import load_config, with_overrides
    from flows.evaluate_execution import reached_once

    calls = []

    def fake_reach(records, *args, **kwargs):
        calls.append(len(records))
        return [GraspRecord(scene=r.scene, p=r.p + 0.01, R=r.R, q=r.q, meta={**r.meta, "reached": True}) for r in records]

    monkeypatch.setattr(tasks.reach, "reach_records", fake_reach)
    scene = Scene(objects=(Placement(name="cube", position=(0.0, 0.0, 0.55), quat_xyzw=(0.0, 0.0, 0.0, 1.0)),))
    poses = [GraspRecord(scene=scene, p=np.array([0.0, 0.0, 0.6 + k / 100]), R=np.eye(3), q=np.zeros(22),
                         meta={"row": k}) for k in range(3)]
    cfg, memo = load_config("smoke"), {}
    first = reached_once(poses[:2], cfg, None, None, None, memo)
    again = reached_once(poses, cfg, None, None, None, memo)  # two known poses, one new
    assert calls == [2, 1]
    assert all(a is b for a, b in zip(again[:2], first)) and [r.meta["row"] for r in again] == [0, 1, 2]
    assert np.allclose(again[2].p, poses[2].p + 0.01)
    reached_once(poses, with_overrides(cfg, {"reach.reaching.waypoints": 7}), None, None, None, memo)
    assert calls == [2, 1, 3]  # another reach setting: reached again


def test_evaluate_execution_without_the_stages_names_the_command(tmp_path, capsys):
    assert main(["evaluate", "execution", "--profile", "smoke", "--workdir", str(tmp_path)]) == 2
    assert "multigrasp run --until specialists" in capsys.readouterr().err


def test_matching_specialist_prefers_the_own_bin_then_the_sector_then_the_object_count():
    from flows.evaluate_execution import matching_specialist

    index = {"cube+sphere/3": {"metrics": {"records": 5}}, "cube+cylinder/3": {"metrics": {"records": 9}},
             "cube+cylinder/0": {"metrics": {"records": 20}}, "cube/0": {"metrics": {"records": 4}}}
    assert matching_specialist("cube+sphere/3", index) == "cube+sphere/3"
    assert matching_specialist("duck+sphere/3", index) == "cube+cylinder/3"  # same sector, largest
    assert matching_specialist("duck+sphere/5", index) == "cube+cylinder/0"  # same object count, largest
    assert matching_specialist("duck/2", index) == "cube/0"
    assert matching_specialist("a+b+c/1", index) is None
    from flows.evaluate_execution import match_kind

    assert [match_kind(lab, matching_specialist(lab, index)) for lab in ("cube+sphere/3", "duck+sphere/3",
                                                                         "duck+sphere/5")] == \
        ["own bin", "same sector", "same object count"]
    assert match_kind("2obj", "2obj") == "own bin"


def test_pose_key_follows_the_pre_grasp_not_its_place_in_a_group():
    """The ablation rows are paired: a pose's trial seeds come from its scene id and row, not its group index."""
    from types import SimpleNamespace

    from flows.evaluate_execution import pose_key

    a = SimpleNamespace(meta={"scene_id": "Pl/cube+sphere/0", "row": 7})
    b = SimpleNamespace(meta={"scene_id": "Pl/cube+sphere/0", "row": 8})
    assert pose_key(a, 0) == pose_key(a, 5) != pose_key(b, 0)
    assert pose_key(SimpleNamespace(meta={}), 3) == 3


def test_evaluated_poses_are_spread_over_every_combination():
    """eval_poses (and reach.max_records) take poses across the scene-ordered list, not its head."""
    from tasks.specialists import spread_records

    records = [f"{combo}-{i}" for combo in ("a+b", "a+c", "b+c", "c+d") for i in range(25)]
    picked = spread_records(records, 8)
    assert len(picked) == 8 and picked[0] == "a+b-0" and picked[-1] == "c+d-24"
    assert {r.split("-")[0] for r in picked} == {"a+b", "a+c", "b+c", "c+d"}
    assert [r.split("-")[0] for r in picked].count("a+b") == 2
    assert spread_records(records[:5], 8) == records[:5] and spread_records(records, 0) == records


def test_evaluate_execution_with_ablations_trains_and_evaluates_the_variants(runs, monkeypatch):
    import flows.evaluate_execution as ev

    monkeypatch.setattr(ev, "ABLATIONS", {"w/o Goal": {"lift.goal_observations": False}})
    workdir, _, _ = runs
    config = next((workdir.parent).glob("exec-config*/stage.yaml"))
    argv = _evaluate_argv(workdir, config, "specialists.eval_poses=1", "specialists.eval_trials=1",
                          "specialists.gifs_per_outcome=0", ablations=True)
    before = len(executions(workdir))
    assert main(argv) == 0  # this small config has no Pl scenes: the rows have 0 poses, the training still runs
    ablation = json.loads((workdir / "results" / "ablation_execution.json").read_text())["rows"]
    goal = next(r for r in ablation if r["setting"] == "w/o Goal")
    assert goal["overrides"] == {"lift.goal_observations": False}
    trained = [e for e in executions(workdir)[before:] if e.startswith("specialists/bin-")]
    assert trained, "the w/o Goal specialists are trained by the ablation run"


@pytest.mark.parametrize("override, changes", [
    ("specialists.init_policy=zero", True),
    ("specialists.squeeze_action=0.3", True),
    ("specialists.squeeze_force_fraction=0.3", True),
    ("specialists.validation_poses=7", True),
    ("specialists.validation_seed=9", True),
    ("specialists.ppo.lr=0.001", True),
    ("specialists.ppo.iterations=7", True),
    ("lift.w_object=0.5", True),
    ("specialists.eval_poses=7", False),
    ("specialists.max_bins=1", False),
    ("specialists.gifs_per_outcome=0", False),
])
def test_a_bins_cache_key_follows_every_setting_that_changes_its_training(tmp_path, override, changes):
    """The specialists fields outside ppo that change a bin's start or its best-policy selection are in its key
    (init_policy was not, so an ablation with another start was served the cached specialists); evaluation-only
    fields are not, so evaluating differently retrains nothing."""
    from flows.config import load_config
    from flows.specialists import bin_config_digest

    base = bin_config_digest(load_config("smoke", workdir=tmp_path))
    assert (bin_config_digest(load_config("smoke", sets=[override], workdir=tmp_path)) != base) is changes


def test_raising_the_iterations_continues_the_finished_specialists(runs, capsys):
    """Training longer: ppo.iterations 2 -> 3 retrains no iteration already done; each bin continues from its
    finished 2-iteration checkpoint (history and validations go on from there)."""
    from components.execution.ppo import load_checkpoint

    workdir, _, _ = runs
    assert main(_rerun_argv(workdir, "specialists.ppo.iterations=3")) == 0
    assert "continuing the finished 2-iteration training" in capsys.readouterr().err
    index = json.loads(_final(workdir, "specialists").path("index").read_text())
    for entry in index.values():
        manifest = read_manifest(Path(entry["folder"]))
        assert manifest.meta["resumed_from"] == 2 and manifest.meta["extended_from"]
        assert load_checkpoint(entry["policy"])["iteration"] == 3
        history = json.loads(manifest.path("history").read_text())
        assert [h["iteration"] for h in history] == [1, 2, 3]
        validations = json.loads(manifest.path("validations").read_text())["rows"]
        assert [v["iteration"] for v in validations] == [0, 1, 2, 3]


def test_a_lift_jobs_setting_counts_the_gif_quota_only_for_the_jobs_that_make_gifs():
    """Lift-job keys (tasks/lift_jobs.py): the evaluation fields count, the GIF quota only where the job makes
    GIFs, how jobs are cut and how many workers lift them never (nor do they count in the results' config key)."""
    from flows.config import evaluation_key, load_config, with_overrides
    from flows.evaluate_execution import lift_setting

    cfg = load_config("smoke")
    quota = with_overrides(cfg, {"specialists.gifs_per_outcome": 5})
    assert lift_setting(quota, True, False) == lift_setting(cfg, True, False)
    assert lift_setting(quota, True, True) != lift_setting(cfg, True, True)
    assert lift_setting(cfg, True, True) != lift_setting(cfg, True, False) != lift_setting(cfg, False, False)
    for override in ({"specialists.eval_trials": 2}, {"specialists.squeeze_action": 0.3}, {"lift.max_steps": 30}):
        assert lift_setting(with_overrides(cfg, override), True, False) != lift_setting(cfg, True, False)
    for override in ({"specialists.eval_chunk_poses": 3}, {"run.max_workers": 1}, {"run.malloc_trim_threshold_mb": 0}):
        other = with_overrides(cfg, override)
        assert lift_setting(other, True, True) == lift_setting(cfg, True, True)
        assert evaluation_key(other, "execution.json") == evaluation_key(cfg, "execution.json")


# --------------------------------------------------------------------------- curriculum, distill, the generalist

#: Two generated starts per bin (unfiltered, the default), one PPO iteration per phase; a two-iteration DAgger.
ADAPT = ["curriculum.generated_per_scene=2", "curriculum.phase_iterations=[1,1,1]",
         "distill.dagger.iterations=2", "distill.dagger.episodes_per_iteration=2"]


def _adapt_argv(command: list[str], workdir, *sets: str) -> list[str]:
    config = next((workdir.parent).glob("exec-config*/stage.yaml"))
    argv = [*command, "--profile", "smoke", "--workdir", str(workdir), "--config", str(config)]
    for item in [*ACCEPT_ALL, *TINY, *ADAPT, *sets]:
        argv += ["--set", item]
    return argv


def test_the_curriculum_adapts_each_specialist_then_dagger_distils_them_and_the_generalist_is_evaluated(runs, capsys):
    from components.execution.ppo import load_checkpoint
    from components.execution.records import load_records
    from components.learning.dagger import load_student

    workdir, _, _ = runs
    assert main(_adapt_argv(["distill"], workdir)) == 0  # with its upstream: train-generator, reach, curriculum
    specialists, curriculum = _final(workdir, "specialists"), _final(workdir, "curriculum")
    index = json.loads(curriculum.path("index").read_text())
    assert sorted(index) == sorted(json.loads(specialists.path("index").read_text()))  # one adapted per specialist
    for label, entry in index.items():
        unit = read_manifest(Path(entry["folder"]))
        base = unit.metrics["specialist_iterations"]
        assert base == 2 and unit.metrics["iterations"] == base + 3  # continued from the specialist, 3 phases
        assert load_checkpoint(unit.path("policy"))["iteration"] == base + 3
        generated = load_records(unit.path("generated"))
        assert unit.metrics["generated_starts"] == len(generated) > 0
        assert all("object_displacement_m" in r.meta for r in generated)  # reached from an open hand
        assert {p.name for p in generated[0].scene.objects} == set(label.split("/")[0].split("+"))
        phase3 = load_records(unit.path("phase3"))
        assert sum(r.meta.get("source") == "generated" for r in phase3) >= 0.7 * len(phase3)
    distill = _final(workdir, "distill")
    assert distill.metrics["bins"] == len(index) and distill.metrics["iterations"] == 2
    assert distill.metrics["samples"] > 0 and "teacher_validation_success" in distill.metrics
    history = json.loads(distill.path("history").read_text())
    assert [h["beta"] for h in history] == [1.0, 0.5]
    assert load_student(distill.path("student")).mean.shape[0] == 438 + 256
    err = capsys.readouterr().err
    assert "curriculum" in err and "distill" in err and "ETA" in err
    before = executions(workdir)
    assert main(_adapt_argv(["distill"], workdir)) == 0
    assert executions(workdir) == before  # served from cache
    # the generalist lifts the evaluation poses of `evaluate execution`, in cached jobs
    evaluate = _adapt_argv(["evaluate", "generalist", "--max-workers", "1"], workdir, "specialists.eval_poses=2",
                           "specialists.eval_trials=1", "generator.eval_scenes=1", "generator.eval_grasps_per_scene=4")
    assert main(evaluate) == 0
    data = json.loads((workdir / "results" / "execution_generalist.json").read_text())
    assert [r["setting"] for r in data["rows"]] == ["Syn-Pl", "Syn-Com", "Syn-Geo", "Gen-Pl", "Gen-Com", "Gen-Geo"]
    assert [r["paper"] for r in data["rows"]] == [0.4413, None, None, 0.3024, None, None]
    assert all(0.0 <= (r["succ"] or 0.0) <= 1.0 for r in data["rows"])
    # the fixture's Syn-Pl scenes are singles (the table lifts pairs): its Syn-Com pair is lifted
    assert sum(r["n_poses"] for r in data["rows"][:3]) >= 1 and all(r["n_poses"] <= 2 for r in data["rows"])
    assert data["distill_manifest"].endswith("manifest.json")
    # per pose, in evaluate execution's layout: the paired comparison with the specialists reads it
    from benchmarks.paired_execution import load_outcomes

    for row in data["rows"]:
        trials, poses = load_outcomes(workdir / "results" / "generalist" / row["setting"] / "outcomes.json")
        assert trials == 1 and len(poses) == row["n_poses"]
        assert all(p["specialist"] == "generalist" and p["policy"] in (0, 1) for p in poses.values())
    jobs = executions(workdir)
    assert main(evaluate) == 0
    assert executions(workdir) == jobs  # every lift job served from its unit
    assert "evaluate generalist Syn-Pl" in capsys.readouterr().err
    # lifted after the planned reach, as the specialists are with the same setting: other jobs, reached poses
    assert main([*evaluate, "--set", "specialists.eval_after_reach=true"]) == 0
    data = json.loads((workdir / "results" / "execution_generalist.json").read_text())
    assert data["after_reach"] is True and executions(workdir) != jobs
    lifted = [r for f in (workdir / "results" / "generalist").glob("Syn-*.json") for r in load_records(f)]
    assert lifted and all("object_displacement_m" in r.meta for r in lifted)


@pytest.mark.parametrize("filtered", [False, True])
def test_the_protocol_filter_keys_the_curriculum_only_where_it_filters_the_generated_starts(filtered):
    """Unfiltered (the default), the filter decides nothing in the curriculum, so ``generate --lift --set
    generator.eval_filter.enabled=false`` finds the adapted specialists and the generalist of the same config."""
    from flows.config import load_config, with_overrides
    from flows.curriculum import config_digest

    cfg = with_overrides(load_config("smoke"), {"curriculum.filter_generated": filtered})
    for override in ({"generator.eval_filter.enabled": False}, {"generator.eval_filter.max_penetration_m": 0.009}):
        assert (config_digest(with_overrides(cfg, override)) != config_digest(cfg)) is filtered
    assert config_digest(with_overrides(cfg, {"generator.refine.steps": 7})) != config_digest(cfg)


def test_evaluate_generalist_without_the_distill_stage_names_the_command(tmp_path, capsys):
    assert main(["evaluate", "generalist", "--profile", "smoke", "--workdir", str(tmp_path)]) == 2
    assert "run --until distill" in capsys.readouterr().err


@pytest.mark.parametrize("target, option", [("generalist", "--ablations"), ("generalist", "--source=generated"),
                                            ("curriculum", "--source=synthetic"), ("curriculum", "--ablations")])
def test_evaluate_generalist_and_curriculum_name_the_options_they_do_not_take(tmp_path, capsys, target, option):
    assert main(["evaluate", target, option, "--profile", "smoke", "--workdir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"evaluate {target} " in err and "drop --source / --ablations" in err and "Traceback" not in err


def test_a_curriculum_killed_in_phase_two_resumes_there_and_keeps_its_generated_starts(runs, monkeypatch):
    import components.execution.ppo as ppo
    import tasks.curriculum

    workdir, _, _ = runs
    argv = _adapt_argv(["curriculum"], workdir, "curriculum.seed=7")  # a key of its own: not the test above's units
    real_train, real_generated = ppo.train_ppo, tasks.curriculum.generated_starts
    calls: dict[str, int] = {}
    generated: list[str] = []

    def killed_in_phase_two(factory, cfg, checkpoint, *args, **kwargs):
        calls[str(checkpoint)] = calls.get(str(checkpoint), 0) + 1
        if calls[str(checkpoint)] == 2:
            raise RuntimeError("simulated kill in phase 2")
        return real_train(factory, cfg, checkpoint, *args, **kwargs)

    def counted(label, *args, **kwargs):
        generated.append(label)
        return real_generated(label, *args, **kwargs)

    monkeypatch.setattr(ppo, "train_ppo", killed_in_phase_two)
    monkeypatch.setattr(tasks.curriculum, "generated_starts", counted)
    with pytest.raises(RuntimeError, match="simulated kill"):
        main(argv)
    before = sorted(generated)
    assert before  # the killed bins made their generated starts
    monkeypatch.setattr(ppo, "train_ppo", real_train)
    assert main(argv) == 0
    assert sorted(generated) == before  # ...and kept them: none made again
    for entry in json.loads(_final(workdir, "curriculum").path("index").read_text()).values():
        history = json.loads((Path(entry["folder"]) / "history.json").read_text())
        assert [h["iteration"] for h in history] == [1, 2, 3, 4, 5]  # phase 1 not redone, phases 2 and 3 once
