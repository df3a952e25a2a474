"""The reach stage end to end through the CLI: a small synthesis (filters open so there are accepted grasps), then
planned reaches to the specialists' pre-grasps executed in PyBullet; end-of-reach records, cache, resume, MLflow."""

from __future__ import annotations

from pathlib import Path

import pytest

from components.execution.records import load_records
from flows.cli import main
from tasks.artifacts import read_manifest
from tasks.units import executions
from tests.test_synthesize_stage import ACCEPT_ALL, STAGE_YAML

REACH = ["specialists.records_source=accepted", "reach.max_records=3", "reach.records_per_shard=2"]


def _final(workdir):
    manifests = [m for m in map(read_manifest, (workdir / "stages" / "reach").iterdir()) if m is not None]
    return max((m for m in manifests if m.unit == "merge"), key=lambda m: m.created_unix)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    import trimesh

    folder = tmp_path_factory.mktemp("reach-config")
    mesh = folder / "block.obj"
    trimesh.creation.box(extents=(0.04, 0.03, 0.025)).export(mesh)
    config = folder / "stage.yaml"
    config.write_text(STAGE_YAML.format(mesh=mesh))
    workdir = tmp_path_factory.mktemp("reach")
    argv = ["run", "--profile", "smoke", "--workdir", str(workdir), "--config", str(config),
            "--only", "scenes", "--only", "synthesize", "--only", "reach"]
    for item in [*ACCEPT_ALL, *REACH]:
        argv += ["--set", item]
    assert main(argv) == 0
    first = executions(workdir)
    assert main(argv) == 0
    return workdir, argv, first, executions(workdir)


def test_reach_records_the_end_state_of_each_pre_grasp(runs):
    workdir, argv, _, _ = runs
    config_path = Path(argv[argv.index("--config") + 1])
    manifest = _final(workdir)
    records = load_records(manifest.path("reached"))
    assert len(records) == 3 == manifest.metrics["reached"]
    for record in records:
        meta = record.meta
        assert meta["reached"] and len(meta["object_displacement_m"]) == len(record.scene.objects)
        assert meta["palm_error_m"] >= 0.0 and meta["penetration_planned"] <= meta["penetration_straight"] + 1e-9
        assert {"scene_id", "split", "row"} <= set(meta)  # the synthesis row it came from
    assert 0.0 <= manifest.metrics["displaced_fraction"] <= 1.0
    # the 3 are spread over the specialists' selection (first, middle, last), not its first 3
    from flows.config import load_config
    from flows.pipeline import stage_output
    from tasks.specialists import select_records

    cfg = load_config("smoke", config_path, [*ACCEPT_ALL, *REACH], workdir=workdir)
    selected = select_records(stage_output(cfg, "synthesize"), cfg.specialists, cfg.specialists.splits)
    assert len(selected) > 3
    picked = [selected[i].meta for i in (0, round((len(selected) - 1) / 2), len(selected) - 1)]
    assert [(r.meta["scene_id"], r.meta["row"]) for r in records] == [(m["scene_id"], m["row"]) for m in picked]
    assert manifest.path("displacements").is_file()


def test_reach_is_sharded_cached_and_resumes_only_what_is_missing(runs):
    import shutil

    workdir, argv, first, after = runs
    shards = sorted(label for label in first if label.startswith("reach/shard-"))
    assert len(shards) == 2 and "reach/merge" in first  # 3 pre-grasps, 2 per shard
    assert after == first  # the second run served everything from cache
    stage_dir = workdir / "stages" / "reach"
    lost = next(m for m in map(read_manifest, stage_dir.iterdir()) if m is not None and m.unit == "shard-001")
    shutil.rmtree(lost.folder)  # a crash before that shard finished
    shutil.rmtree(_final(workdir).folder)
    assert main(argv) == 0
    rerun = executions(workdir)[len(after):]
    assert sorted(rerun) == ["reach/merge", "reach/shard-001"]


def test_mlflow_has_the_reach_metrics(runs):
    import mlflow

    workdir, _, _, _ = runs
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{workdir / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("multigrasp")
    runs_ = client.search_runs([experiment.experiment_id], "tags.stage = 'reach'")
    assert runs_ and "reached" in runs_[0].data.metrics
