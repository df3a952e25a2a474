"""End-to-end flow tests under the smoke profile: one smoke run shared by the tests that read it (caching, the
evaluations, MLflow, the UI), status, CLI errors.  Fresh-work-dir flows (resume, moves, signals) are in
``test_resume.py``."""

from __future__ import annotations

import os
import re
import sys
import types
from pathlib import Path
from typing import NamedTuple

import pytest

import tasks.scenes
from flows.cli import main
from flows.config import load_config
from flows.pipeline import status
from tasks.units import executions
from tests.standins import FakeRay

pytestmark = pytest.mark.slow

# A small scenes stage: 8 single-object jobs in 2 shards, 1 render.
SMALL = ["scenes.pairs=false", "scenes.many=false", "scenes.jobs_per_shard=4", "scenes.renders=1",
         "scenes.per_combination={train: 1, Pl: 0, Com: 0, Geo: 0, many: 0}"]


def run_smoke(workdir, *extra: str) -> int:
    """``multigrasp run --profile smoke`` in ``workdir`` with each of ``extra`` as a ``--set`` item."""
    argv = ["run", "--profile", "smoke", "--workdir", str(workdir)]
    for item in extra:
        argv += ["--set", item]
    return main(argv)


class SmokeRuns(NamedTuple):
    """The shared smoke work dir, the units its first run computed, those after its second run, and what each run
    printed on the console (stderr)."""

    workdir: Path
    first: list[str]
    after_second: list[str]
    consoles: list[str]


def _run_smoke_printing(workdir: Path) -> tuple[int, str]:
    """:func:`run_smoke`, returning its exit status and its console output (which is also printed, so a failure
    shows it)."""
    import contextlib
    import io

    buffer = io.StringIO()
    try:
        with contextlib.redirect_stderr(buffer):
            code = run_smoke(workdir)
    finally:
        sys.stderr.write(buffer.getvalue())
    return code, buffer.getvalue()


@pytest.fixture(scope="module")
def smoke_runs(tmp_path_factory) -> SmokeRuns:
    """The smoke pipeline run twice in one work dir (second run must be all cache)."""
    workdir = tmp_path_factory.mktemp("smoke")
    code, console = _run_smoke_printing(workdir)
    assert code == 0
    first = executions(workdir)
    code, again = _run_smoke_printing(workdir)
    assert code == 0
    return SmokeRuns(workdir, first, executions(workdir), [console, again])


def test_second_smoke_run_serves_every_stage_from_cache(smoke_runs):
    assert smoke_runs.first, "the first run computed nothing"
    assert smoke_runs.after_second == smoke_runs.first, "the second run recomputed units"


def test_smoke_run_prints_its_wall_time(smoke_runs):
    assert all(len(re.findall(r"done in [0-9.]+s wall time", console)) == 1 for console in smoke_runs.consoles)
    assert "every stage served from cache" not in smoke_runs.consoles[0]
    assert "every stage served from cache" in smoke_runs.consoles[1]
    assert all("multigrasp ui --workdir" in console for console in smoke_runs.consoles)


def test_deleted_artifact_is_recomputed_not_trusted(smoke_runs, tmp_path):
    import shutil

    from tasks.artifacts import read_manifest

    workdir = tmp_path / "runs"  # a copy: the shared smoke work dir stays whole for the other tests
    shutil.copytree(smoke_runs.workdir, workdir)
    cfg = load_config("smoke", workdir=workdir)
    shard = next(p for p in (workdir / "stages" / "scenes").iterdir() if read_manifest(p).unit == "shard-000")
    (shard / "scenes.json").unlink()
    states = {r.name: r.state for r in status(cfg)}
    assert states["scenes"] == "corrupt" and states["synthesize"] == "blocked" and states["specialists"] == "blocked"
    before = len(executions(workdir))
    assert run_smoke(workdir) == 0
    assert executions(workdir)[before:] == ["scenes/shard-000"]
    assert (shard / "scenes.json").is_file()
    assert all(r.state == "done" for r in status(cfg))


def _lift_job_keys(workdir: Path) -> list[str]:
    """Keys of the lift jobs executed in ``workdir`` (not served from their units), in order."""
    log = workdir / "executions.log"
    return [line.split()[1] for line in log.read_text().splitlines() if line.startswith("evaluate-execution/")]


def test_an_evaluation_killed_halfway_relifts_only_its_unfinished_jobs_and_workers_give_the_same_outcomes(
        smoke_runs, tmp_path, monkeypatch):
    """Each specialist's poses are lifted in cached jobs (tasks/lift_jobs.py): an evaluation interrupted after two
    jobs, run again, serves those two and lifts the rest; a rerun lifts nothing.  --max-workers 2 lifts the jobs
    in two spawned processes; every trial is seeded by its pose and an episode does not depend on the ones before
    it, so every pose's outcome is the one lifted in-process."""
    import json
    import shutil

    import tasks.lift_jobs
    from flows.cli import EXIT_INTERRUPTED

    workdir = tmp_path / "runs"  # a copy: the shared smoke work dir's MLflow store is counted by another test
    shutil.copytree(smoke_runs[0], workdir)
    argv = ["evaluate", "execution", "--profile", "smoke", "--workdir", str(workdir)]
    for item in ("specialists.eval_poses=4", "specialists.eval_trials=1", "specialists.gifs_per_outcome=0",
                 "specialists.eval_chunk_poses=1"):
        argv += ["--set", item]

    def outcomes() -> dict:
        return {setting: json.loads((workdir / "results" / "execution" / setting / "outcomes.json")
                                    .read_text())["poses"] for setting in ("Syn-Pl", "Syn-Com", "Syn-Geo")}

    real, lifted = tasks.lift_jobs.lift_job, []

    def dies_on_the_third(job, progress=None):
        if len(lifted) == 2:
            raise KeyboardInterrupt  # as Ctrl-C in the middle of the third job
        lifted.append(job.keys)
        return real(job, progress)

    monkeypatch.setattr(tasks.lift_jobs, "lift_job", dies_on_the_third)
    assert main([*argv, "--max-workers", "1"]) == EXIT_INTERRUPTED
    monkeypatch.setattr(tasks.lift_jobs, "lift_job", real)
    first = _lift_job_keys(workdir)
    assert len(first) == 3 and not (workdir / "results" / "execution.json").exists()
    from flows.report import evaluation_status  # status says how far the killed evaluation got

    sets = [item for item in argv[argv.index("--set"):] if item != "--set"]
    row = next(r for r in evaluation_status(load_config("smoke", sets=sets, workdir=workdir))
               if r.name == "execution.json")
    assert row.state == "missing" and "2 lift job(s) of this config finished" in row.detail
    assert main([*argv, "--max-workers", "1"]) == 0
    second = _lift_job_keys(workdir)[3:]
    assert first[2] in second and not {first[0], first[1]} & set(second)  # the two finished jobs were served
    resumed = outcomes()
    assert len(resumed["Syn-Pl"]) == 4 and len({p["specialist"] for p in resumed["Syn-Pl"]}) >= 1
    assert len(second) + 2 == sum(len(poses) for poses in resumed.values())  # one job per pose here
    assert main([*argv, "--max-workers", "1"]) == 0 and len(_lift_job_keys(workdir)) == 3 + len(second)

    shutil.rmtree(workdir / "stages" / "evaluate-execution")  # lift every job again, now in two processes
    assert main([*argv, "--max-workers", "2"]) == 0
    assert len(_lift_job_keys(workdir)) == 3 + len(second) + (len(second) + 2)
    assert outcomes() == resumed

    # --runner ray: the jobs are Ray tasks of the invocation's Ray (a stand-in here: CI installs no Ray)
    shutil.rmtree(workdir / "stages" / "evaluate-execution")
    ray = FakeRay()
    monkeypatch.setitem(sys.modules, "ray", ray)
    monkeypatch.setitem(sys.modules, "prefect_ray", types.ModuleType("prefect_ray"))
    assert main([*argv, "--runner", "ray"]) == 0
    assert [name for name, _ in ray.calls][0] == "init" and [name for name, _ in ray.calls][-1] == "shutdown"
    tasks_run = [options for name, options in ray.calls if name == "task"]
    assert len(tasks_run) >= 2 and all(options == {"num_cpus": 1} for options in tasks_run)
    assert outcomes() == resumed


def test_run_evaluate_computes_each_missing_evaluation_once_then_serves_them(smoke_runs, tmp_path, capsys):
    """``run --evaluate`` ends the pipeline with every evaluation of Table I and the report; a rerun computes none of
    them; an evaluation whose results file is gone (a crash before it wrote it) is the only one computed again."""
    import json
    import shutil

    from flows.report import evaluation_status

    workdir = tmp_path / "runs"  # a copy: the shared smoke work dir's MLflow store is counted by another test
    shutil.copytree(smoke_runs[0], workdir)
    argv = ["run", "--evaluate", "--profile", "smoke", "--workdir", str(workdir)]
    sets = ("specialists.eval_poses=2", "specialists.eval_trials=1", "specialists.gifs_per_outcome=0",
            "generator.eval_scenes=1", "generator.eval_grasps_per_scene=4")
    for item in sets:
        argv += ["--set", item]
    results = workdir / "results"
    names = ("pregrasp_synthetic.json", "pregrasp_generated.json", "execution.json", "execution_generated.json",
             "execution_generalist.json")

    assert main(argv) == 0
    first = capsys.readouterr().err
    assert "5 evaluation(s) computed" in first and "every stage served from cache" in first
    assert (results / "report.md").is_file() and "| Syn-Pl |" in (results / "report.md").read_text()
    cfg = load_config("smoke", sets=list(sets), workdir=workdir)
    assert {r.name: r.state for r in evaluation_status(cfg) if r.name in names} == dict.fromkeys(names, "current")
    written = {name: (results / name).stat().st_mtime_ns for name in names}
    assert all(json.loads((results / name).read_text())["config_key"] for name in names)
    assert all(json.loads((results / name).read_text())["evaluated_at"] for name in names)  # the report shows it
    from mlflow.tracking import MlflowClient  # the evaluations' runs and the report's are the pipeline run's children

    client = MlflowClient(f"sqlite:///{workdir / 'mlflow.db'}")
    runs = client.search_runs(client.get_experiment_by_name("multigrasp").experiment_id)
    nested = [r for r in runs if r.info.run_name.startswith("evaluate:") or r.info.run_name == "report"]
    parents = {r.data.tags.get("mlflow.parentRunId") for r in nested}
    assert len(nested) == 6 and len(parents) == 1 and client.get_run(parents.pop()).info.run_name == "run:smoke"
    # the closing lines link this invocation's run in the UI that `multigrasp ui` starts
    import re

    (experiment_id, run_id), = re.findall(r"http://127\.0\.0\.1:5000/#/experiments/(\w+)/runs/(\w+)   \(this run\)",
                                          first)
    linked = client.get_run(run_id)
    assert linked.info.run_name == "run:smoke" and linked.info.experiment_id == experiment_id
    from flows.cli import run_url

    assert run_url("http://mlflow:5000/", "3", "abc") == "http://mlflow:5000/#/experiments/3/runs/abc"
    # each evaluation's run: the settings its figures depend on as params, their digest as its results file's key
    files = {"evaluate:pregrasp:synthetic": "pregrasp_synthetic.json", "evaluate:pregrasp:generated":
             "pregrasp_generated.json", "evaluate:execution": "execution.json",
             "evaluate:execution:generated": "execution_generated.json", "evaluate:generalist": "execution_generalist.json"}
    for run in nested:
        if run.info.run_name in files:
            written_key = json.loads((results / files[run.info.run_name]).read_text())["config_key"]
            assert run.data.tags["config_key"] == written_key
            assert run.data.params["objects.train"] and "run.workdir" not in run.data.params
            assert ("specialists.eval_trials" in run.data.params) == run.info.run_name.startswith(("evaluate:execution", "evaluate:generalist"))

    assert main(argv) == 0
    assert "0 evaluation(s) computed" in capsys.readouterr().err
    assert {name: (results / name).stat().st_mtime_ns for name in names} == written

    (results / "execution_generated.json").unlink()
    assert main(argv) == 0
    third = capsys.readouterr().err
    assert "1 evaluation(s) computed" in third and "execution --source generated (execution_generated.json missing)" in third
    assert all((results / name).stat().st_mtime_ns == written[name] for name in names[:3])
    # another evaluation setting of the lift makes the lift evaluations stale, not the pre-grasp ones
    other = load_config("smoke", sets=[*sets, "specialists.eval_trials=2"], workdir=workdir)
    states = {r.name: r for r in evaluation_status(other) if r.name in names}
    assert [states[name].state for name in names] == ["current", "current", "stale", "stale", "stale"]
    assert "other settings" in states["execution.json"].detail


def test_generate_lift_lifts_the_kept_grasps_of_a_pair_with_the_matching_specialists(smoke_runs, tmp_path, capsys):
    """``generate --lift``: a user's own mesh, added to the config of a trained pipeline (``objects.user`` only: no
    stage key changes), paired with a cube from generation to lifted outcomes in one command, as ``evaluate execution
    --source generated`` lifts the Gen rows."""
    import json
    import shutil

    import trimesh

    workdir = tmp_path / "runs"  # a copy: the shared smoke work dir's MLflow store is counted by another test
    shutil.copytree(smoke_runs[0], workdir)
    mesh = tmp_path / "mug.obj"
    trimesh.creation.cylinder(radius=0.02, height=0.05).export(mesh)
    argv = ["generate", "--objects", "cube,mug", "--n", "3", "--seed", "1", "--lift", "--profile", "smoke",
            "--workdir", str(workdir), "--max-workers", "1"]
    for item in (f"objects.user=[{{name: mug, mesh: {mesh}}}]", "specialists.eval_poses=2",
                 "specialists.eval_trials=1", "specialists.gifs_per_outcome=1", "generator.eval_filter.enabled=false"):
        argv += ["--set", item]
    assert main(argv) == 0
    out, err = capsys.readouterr()
    assert "evaluate execution lift cube+mug" in err and "[/]" not in err  # progress rendered, not raw rich markup
    folder = workdir / "results" / "generated" / "cube+mug-1"
    lift = json.loads((folder / "lift.json").read_text())
    assert lift["generated"] == lift["kept"] == 3  # the filter open: every grasp kept, eval_poses of them lifted
    assert lift["n_poses"] == 2 and lift["unmatched_poses"] == 0 and lift["trials"] == 1  # a pair specialist matches
    assert lift["specialists_used"] and all(0.0 <= lift[k] <= 1.0 for k in ("succ", "w/o RL", "squeeze", "generalist"))
    # the smoke pipeline distilled a generalist: it lifts the same poses (it needs no matching specialist)
    assert lift["generalist_poses"] == 2 and lift["distill_manifest"].endswith("manifest.json")
    assert len(json.loads((folder / "lift" / "outcomes.json").read_text())["poses"]) == 2
    assert all(p["generalist"] in (0, 1) for p in json.loads((folder / "lift" / "outcomes.json").read_text())["poses"])
    assert lift["gifs"] and all(Path(p).is_file() for p in lift["gifs"])
    assert "the protocol filter off: every grasp kept" in out and "lift: 2 pose(s) x 1 trial(s)" in out
    assert ", generalist " in out
    from mlflow.tracking import MlflowClient  # the grasps, their render, the lift and its GIFs: one MLflow run

    client = MlflowClient(f"sqlite:///{workdir / 'mlflow.db'}")
    run, = [r for r in client.search_runs(client.get_experiment_by_name("multigrasp").experiment_id)
            if r.info.run_name == "generate:cube+mug"]
    assert run.data.metrics["kept"] == 3 and run.data.metrics["lift/poses"] == 2 and "lift/generalist" in run.data.metrics
    assert {a.path for a in client.list_artifacts(run.info.run_id, "generated")} >= {
        "generated/grasps.png", "generated/grasps.json", "generated/lift.json"}
    assert client.list_artifacts(run.info.run_id, "rollouts")
    # three objects: one line before anything is generated
    three = [*argv[:2], "cube,mug,sphere", *argv[3:]]
    assert main(three) == 2
    assert "--lift lifts 2-object pre-grasps" in capsys.readouterr().err
    assert not (workdir / "results" / "generated" / "cube+mug+sphere-1").exists()


def test_run_evaluate_needs_every_stage(tmp_path, capsys):
    assert main(["run", "--evaluate", "--until", "scenes", "--workdir", str(tmp_path)]) == 2
    assert main(["run", "--ablations", "--workdir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "--evaluate needs every stage" in err[0] and "--ablations belongs to --evaluate" in err[1]
    assert not (tmp_path / "stages").exists()


def test_mlflow_store_has_one_parent_with_a_child_per_stage_and_pngs(smoke_runs):
    from mlflow.tracking import MlflowClient

    from flows.pipeline import stage_names

    workdir = smoke_runs.workdir
    client = MlflowClient(f"sqlite:///{workdir / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("multigrasp")
    runs = client.search_runs([experiment.experiment_id], max_results=1000)
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    assert len(parents) == 2  # one per invocation
    first_parent = min(parents, key=lambda r: r.info.start_time)
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == first_parent.info.run_id]
    assert sorted(r.data.tags["stage"] for r in children) == sorted(stage_names())
    assert first_parent.data.params["profile"] == "smoke"
    from tasks.tracking import provenance_tags

    expected = provenance_tags()  # the package version, torch, Python, and the checkout's commit where there is one
    assert all(first_parent.data.tags[k] == v for k, v in expected.items() if k != "multigrasp.git_dirty")
    assert not any(k.startswith("multigrasp.") for c in children for k in c.data.tags)  # on the parent only
    scenes_run = next(r for r in children if r.data.tags["stage"] == "scenes")
    pngs = [a.path for a in client.list_artifacts(scenes_run.info.run_id, "renders")]
    assert pngs and all(p.endswith(".png") for p in pngs)
    assert scenes_run.data.metrics["scenes"] > 0
    # each stage run holds the settings it reads as params (MLflow compares runs by their own params)
    cfg = load_config("smoke", workdir=workdir)
    synthesize_run = next(r for r in children if r.data.tags["stage"] == "synthesize")
    assert synthesize_run.data.params["synthesis.optimizer.batch_size"] == str(cfg.synthesis.optimizer.batch_size)
    assert synthesize_run.data.params["run.seed"] == str(cfg.run.seed)
    assert not any(k.startswith(("specialists.", "generator.")) for k in synthesize_run.data.params)
    specialists_run = next(r for r in children if r.data.tags["stage"] == "specialists")
    assert specialists_run.data.params["specialists.ppo.lr"] == str(cfg.specialists.ppo.lr)
    assert all(child.data.params for child in children)
    # the trained generator's samples on a training scene, rendered beside the dataset's grasps of that scene
    generator_run = next(r for r in children if r.data.tags["stage"] == "train-generator")
    samples = sorted(a.path for a in client.list_artifacts(generator_run.info.run_id, "generator/samples"))
    assert len(samples) == 2 * cfg.tracking.generator_sample_scenes
    assert samples[0].endswith("_data.png") and samples[1].endswith("_samples.png")
    assert generator_run.data.metrics["samples/n"] == cfg.generator.eval_grasps_per_scene
    assert 0.0 <= generator_run.data.metrics["samples/kept_fraction"] <= 1.0

    second_parent = max(parents, key=lambda r: r.info.start_time)
    cached = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == second_parent.info.run_id]
    assert cached and all(r.data.tags["cached"] == "true" for r in cached)
    assert all(r.data.tags["cached_from_run"] in {c.info.run_id for c in children} for r in cached)
    cached_generator = next(r for r in cached if r.data.tags["stage"] == "train-generator")
    assert not client.list_artifacts(cached_generator.info.run_id, "generator/samples")  # logged where it trained


def test_status_lists_missing_then_done(tmp_path, capsys):
    cfg = load_config("smoke", sets=SMALL, workdir=tmp_path)
    states = {r.name: r.state for r in status(cfg)}
    assert states == {"scenes": "missing", "synthesize": "blocked", "train-generator": "blocked", "pointnet": "missing",
                      "specialists": "blocked", "reach": "blocked", "curriculum": "blocked", "distill": "blocked"}
    assert main(["status", "--profile", "smoke", "--workdir", str(tmp_path)] + sum([["--set", s] for s in SMALL], [])) == 0
    assert "missing" in capsys.readouterr().out
    # --json: the same states for scripts, and the command that computes the evaluations
    import json
    import shlex

    sets = sum([["--set", s] for s in SMALL], [])
    assert main(["status", "--profile", "smoke", "--workdir", str(tmp_path), *sets, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert {row["name"]: row["state"] for row in report["stages"]} == states
    assert report["workdir"] == str(tmp_path) and report["evaluations"] == []
    assert shlex.split(report["evaluate_command"]) == ["multigrasp", "run", "--evaluate", "--profile", "smoke", *sets,
                                                       "--workdir", str(tmp_path)]
    assert not any(tmp_path.iterdir())  # status wrote nothing


def test_status_shows_each_done_stage_folder_whole_on_an_80_column_terminal(smoke_runs, capsys, monkeypatch):
    """The output column holds each stage's folder relative to the work dir (named in the title), folded over lines
    where it is long: rich cut the absolute path to "/tmp/…/st…" on an 80-column terminal."""
    workdir = smoke_runs[0]
    monkeypatch.setenv("COLUMNS", "80")
    capsys.readouterr()
    assert main(["status", "--profile", "smoke", "--workdir", str(workdir)]) == 0
    out = capsys.readouterr().out
    assert max(len(line) for line in out.splitlines()) <= 80
    cells: dict[str, str] = {}
    stage = None
    for line in out.split("evaluations in")[0].splitlines():
        parts = [part.strip() for part in line.split("│")]
        if len(parts) < 6:
            continue
        stage = parts[1] or stage  # a folded row continues the stage above it
        cells[stage] = cells.get(stage, "") + parts[4]
    cfg = load_config("smoke", workdir=workdir)
    rows = status(cfg)
    assert rows and all(row.state == "done" for row in rows)
    for row in rows:
        assert cells[row.name] == str(Path(row.folder).relative_to(workdir))
        assert (workdir / cells[row.name] / "manifest.json").is_file()
    import json

    assert main(["status", "--profile", "smoke", "--workdir", str(workdir), "--json"]) == 0
    stages = json.loads(capsys.readouterr().out)["stages"]
    assert [(s["name"], s["state"], s["folder"]) for s in stages] == [(r.name, "done", r.folder) for r in rows]


def test_the_readme_block_that_reads_a_work_dirs_grasps_runs_on_the_smoke_run(smoke_runs):
    """README "Reading a work dir's outputs in Python", run as written with the smoke run's work dir for ``runs``."""
    workdir = smoke_runs[0]
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = readme.split("```python\n# reading a work dir's grasps\n", 1)[1].split("```", 1)[0]
    assert 'Path("runs")' in block
    namespace: dict = {}
    exec(compile(block.replace('Path("runs")', f"Path({str(workdir)!r})"), "README.md", "exec"), namespace)
    assert tuple(namespace["keypoints"].shape) == (4, 31, 3)
    assert len(namespace["accepted"]) + len(namespace["rejected"]) > 0
    assert "reason" in namespace["rejected"].columns


def test_status_tells_a_started_unit_from_another_configs_outputs(tmp_path):
    """A unit folder without a manifest (a training running now, or interrupted with its checkpoint) is 'partial',
    not 'stale' ('outputs exist only for another config'), which it was reported as before; the unit's lock tells
    running from interrupted."""
    import flows.scenes

    cfg = load_config("smoke", sets=SMALL, workdir=tmp_path)
    other = tmp_path / "stages" / "scenes" / "0123456789abcdef0123"
    other.mkdir(parents=True)
    assert {r.name: r.state for r in status(cfg)}["scenes"] == "stale"
    first = flows.scenes.planned_units(cfg, {})[0]
    first.folder.mkdir(parents=True)
    (first.folder / "checkpoint.pt").write_bytes(b"x")
    row = next(r for r in status(cfg) if r.name == "scenes")
    assert row.state == "partial" and "1 unit(s) interrupted" in row.detail and "running" not in row.detail
    import os

    from tasks.artifacts import file_lock, lock_path

    with file_lock(lock_path(tmp_path, first.key)):  # an invocation computing it now holds its lock
        row = next(r for r in status(cfg) if r.name == "scenes")
    assert row.state == "partial" and f"1 unit(s) running now (pid {os.getpid()} (" in row.detail
    assert "interrupted" not in row.detail
    row = next(r for r in status(cfg) if r.name == "scenes")  # the lock is released with its holder
    assert "1 unit(s) interrupted" in row.detail


@pytest.mark.parametrize("override, expected", [
    ("objects.train=[cube,banana]", "banana"),
    ("scenes.bogus=1", "unknown config key 'scenes.bogus'"),
    ("scenes.renders=-4", "scenes.renders"),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, override, expected):
    assert main(["run", "--profile", "smoke", "--workdir", str(tmp_path), "--set", override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and expected in err[0]


def test_user_error_inside_a_unit_is_one_line_without_traceback(tmp_path, capsys, monkeypatch):
    from components.errors import MultigraspError

    def impossible(*args, **kwargs):
        raise MultigraspError("could not place cube, sphere without overlap in 2000 tries — enlarge xy_half_range_m")

    monkeypatch.setattr(tasks.scenes, "sample_shard", impossible)
    assert run_smoke(tmp_path, *SMALL) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("error: could not place cube, sphere")


def test_prefect_server_start_timeout_is_one_line_and_other_runtime_errors_are_not_hidden(tmp_path, capsys,
                                                                                       monkeypatch):
    import flows.cli

    def slow_server(args, **kwargs):
        raise RuntimeError("Timed out while attempting to connect to ephemeral Prefect API server.")

    monkeypatch.setattr(flows.cli, "_cmd_run", slow_server)
    assert flows.cli.main(["run", "--profile", "smoke", "--workdir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS" in err[0]
    assert os.environ["PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS"] == "120"  # the project's default

    def bug(args, **kwargs):
        raise RuntimeError("something else")

    monkeypatch.setattr(flows.cli, "_cmd_run", bug)
    with pytest.raises(RuntimeError, match="something else"):
        flows.cli.main(["run", "--profile", "smoke", "--workdir", str(tmp_path)])


def test_ui_serves_the_workdir_store_on_localhost(smoke_runs):
    import subprocess
    import sys
    import time
    import urllib.request

    workdir = smoke_runs.workdir
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "flows.cli", "ui", "--workdir", str(workdir), "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        body = b""
        while time.monotonic() < deadline:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/2.0/mlflow/experiments/search?max_results=5",
                                            timeout=2) as response:
                    body = response.read()
                break
            except OSError:
                assert proc.poll() is None, proc.stdout.read().decode()
                time.sleep(1)
        assert b"multigrasp" in body
    finally:
        import os
        import signal

        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
    out = proc.stdout.read().decode()
    assert "MLflow UI on" in out and "DeprecationWarning" not in out, out  # Starlette's, per server process: held back


def test_ui_without_a_store_says_what_to_run(tmp_path, capsys):
    assert main(["ui", "--workdir", str(tmp_path)]) == 2
    assert "run `multigrasp run` first" in capsys.readouterr().err


def test_ui_starts_one_server_worker_per_core_up_to_four_or_those_asked(tmp_path, capsys, monkeypatch):
    """MLflow's server starts 4 workers; on 2 cores each extra one only slows the start (docs/benchmarks.md)."""
    import flows.cli

    (tmp_path / "mlflow.db").touch()
    started = []
    monkeypatch.setattr(flows.cli.subprocess, "call", lambda cmd, env: started.append(cmd) or 0)
    monkeypatch.setattr(flows.cli.os, "cpu_count", lambda: 2)
    for argv, workers in (([], "2"), (["--workers", "3"], "3")):
        assert main(["ui", "--workdir", str(tmp_path), "--port", str(_free_port())] + argv) == 0
        assert started[-1][started[-1].index("--workers") + 1] == workers
    monkeypatch.setattr(flows.cli.os, "cpu_count", lambda: 16)
    assert main(["ui", "--workdir", str(tmp_path), "--port", str(_free_port())]) == 0
    assert started[-1][started[-1].index("--workers") + 1] == "4"
    assert len(started) == 3
    assert main(["ui", "--workdir", str(tmp_path), "--workers", "0"]) == 2
    assert capsys.readouterr().err.strip() == "error: --workers must be at least 1 (got 0) — e.g. --workers 2"


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_ui_on_a_port_in_use_says_so_and_names_a_free_one(tmp_path, capsys):
    """MLflow's server logged 'Address already in use' and exited 0; the CLI now checks the port first."""
    import socket

    (tmp_path / "mlflow.db").touch()
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["ui", "--workdir", str(tmp_path), "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: port {port} on 127.0.0.1 is in use (another `multigrasp ui` or MLflow server?) — open that "
                   f"one, stop it, or pass --port {port + 1}")
    assert main(["ui", "--workdir", str(tmp_path), "--port", "70000"]) == 2
    assert "--port must be between 1 and 65535" in capsys.readouterr().err


def test_prefect_shutdown_cancellations_and_user_errors_are_filtered_but_other_records_kept():
    """The in-process server's 'Error flushing events' at interpreter exit (a CancelledError) printed a traceback
    after a finished run; the handler filter drops it, and drops MultigraspError tracebacks, nothing else."""
    import asyncio
    import logging
    import sys

    from components.errors import MultigraspError
    from flows.runtime import HideUserErrorTracebacks

    def record(name, exc):
        try:
            raise exc
        except BaseException:
            return logging.LogRecord(name, logging.ERROR, __file__, 1, "msg", None, sys.exc_info())

    keep = HideUserErrorTracebacks().filter
    assert not keep(record("prefect.server.services.task_run_recorder", asyncio.CancelledError()))
    assert not keep(record("prefect.task_runs", MultigraspError("bad mesh")))
    assert keep(record("prefect.task_runs", asyncio.CancelledError()))  # a cancelled task outside the server: kept
    assert keep(record("prefect.server.api", RuntimeError("real failure")))
    assert keep(logging.LogRecord("prefect.server", logging.WARNING, __file__, 1, "plain", None, None))



def test_unit_task_runs_are_named_after_their_unit_and_the_console_lines_say_which_run():
    """Prefect's task runs of a unit are named ``stage/unit`` (they were ``<task>-3e1``), and the console's log lines
    carry the run's name, which the plain format dropped ("INFO prefect.task_runs: Finished in state Completed()")."""
    import logging

    from prefect import flow, task

    from flows.library_logs import RunNameFormatter
    from flows.runtime import unit_task
    from tasks.units import make_spec

    @task
    def named(spec, value):
        from prefect.runtime import task_run

        return task_run.name, value

    @flow
    def one_unit(spec):
        return unit_task(named).submit(spec, 3).result()

    spec = make_spec(stage="synthesize", unit="shard-Pl:cube+mug:0", section_digest="s", upstream={}, code="c",
                     workdir=Path("/tmp/unused"))
    assert one_unit(spec) == ("synthesize/shard-Pl:cube+mug:0", 3)

    line = logging.LogRecord("prefect.task_runs", logging.INFO, __file__, 1, "Finished in state Completed()", None, None)
    line.task_run_name = spec.label
    assert RunNameFormatter().format(line) == ("INFO prefect.task_runs (synthesize/shard-Pl:cube+mug:0): Finished in "
                                               "state Completed()")
    plain = logging.LogRecord("flows.cli", logging.WARNING, __file__, 1, "a warning", None, None)
    assert RunNameFormatter().format(plain) == "WARNING flows.cli: a warning"


def test_evaluate_curriculum_lifts_the_same_poses_with_the_adapted_the_plain_and_the_unphased_specialists(
        smoke_runs, monkeypatch):
    """Table II(c): the curriculum's specialists, the plain ones (w/o Adpt) and those adapted without phases (w/o
    Curr, trained here) lift the same Gen-Pl poses.  The smoke generator's pre-grasps all fail the protocol filter,
    so the smoke Syn-Pl pre-grasps stand in for them here."""
    import json

    import flows.evaluate_generalist
    from flows.evaluate_curriculum import OURS
    from flows.pipeline import stage_output
    from tasks.artifacts import read_manifest
    from tasks.specialists import select_records

    workdir = smoke_runs.workdir

    def stand_in(cfg, say, settings=()):
        return {"Gen-Pl": select_records(stage_output(cfg, "synthesize"), cfg.specialists, ["Pl"])}

    monkeypatch.setattr(flows.evaluate_generalist, "_generated_records", stand_in)
    argv = ["evaluate", "curriculum", "--profile", "smoke", "--workdir", str(workdir), "--max-workers", "1",
            "--set", "specialists.eval_poses=2", "--set", "specialists.eval_trials=1"]
    assert main(argv) == 0
    data = json.loads((workdir / "results" / "ablation_curriculum.json").read_text())
    rows = data["rows"]
    assert [r["setting"] for r in rows] == [OURS, "w/o Adpt", "w/o Curr"]
    assert [r["paper"] for r in rows] == [0.4525, 0.2505, 0.2488]
    assert rows[0]["n_poses"] == rows[1]["n_poses"] == rows[2]["n_poses"] == 2
    # each ablation row against Ours, paired by pose: the difference of the rates, with a standard error
    assert rows[0]["vs_ours"] is None
    for row in rows[1:]:
        assert row["vs_ours"]["poses"] == 2 and row["vs_ours"]["a"] == rows[0]["succ"] and row["vs_ours"]["b"] == row["succ"]
        assert row["vs_ours"]["difference"] == round(row["succ"] - rows[0]["succ"], 4) and row["vs_ours"]["standard_error"] >= 0
    assert "vs Ours, paired" in (workdir / "results" / "ablation_curriculum.md").read_text()
    stages = [Path(r["specialists_manifest"]).parent for r in rows]
    assert [s.parent.name for s in stages] == ["curriculum", "specialists", "curriculum"] and stages[0] != stages[2]
    # w/o Curr: every phase starts from all of the bin's starts alike
    index = json.loads(read_manifest(stages[2]).path("index").read_text())
    unit = Path(next(iter(index.values()))["folder"])
    assert all((unit / f"phase{k}.json").read_text() == (unit / "phase1.json").read_text() for k in (2, 3))
    assert main(["report", "--workdir", str(workdir)]) == 0
    report = (workdir / "results" / "report.md").read_text()
    assert "(c) Adaptation" in report and "| w/o Curr |" in report and "vs Ours, paired" in report
