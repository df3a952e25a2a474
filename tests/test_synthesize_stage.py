"""The synthesize stage end to end: Parquet tables, statistics, MLflow, cache / resume, user meshes,
zero accepted grasps, ``evaluate pregrasp --source synthetic`` and ``bench synthesis``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import tasks.synthesize
import tasks.synthesize_merge
from flows.cli import main
from tasks.artifacts import read_manifest
from tasks.units import executions

# 7 scenes (train: 3 singles + 2 pairs; Com: cube+sphere; Geo: a user mesh), 4 candidates each, 3 shards.
STAGE_YAML = """
objects:
  train: [cube, cylinder, sphere]
  ood: [block]
  user:
    - {{name: block, mesh: {mesh}, mass_kg: 0.05}}
  sdf_grid_resolution: 32
scenes:
  many: false
  per_combination: {{train: 1, Pl: 0, Com: 1, Geo: 1, many: 0}}
  renders: 0
synthesis:
  optimizer: {{batch_size: 4, mala_steps: 8, refine_steps: 2, object_surface_points: 32}}
  metrics: {{pn_object_points: 256, q1_max_contacts: 8}}
  scenes_per_shard: 3
  renders_per_combination: 4
"""
# Filters wide open: every candidate is accepted, so Q1 / PN and the renders run on real rows.
ACCEPT_ALL = ["synthesis.optimizer.filter_fc=1.0e9", "synthesis.optimizer.filter_contact_distance_m=10.0",
              "synthesis.optimizer.filter_penetration_m=10.0", "synthesis.optimizer.filter_prior=1.0e9"]
# No optimisation and a force-closure threshold no grasp can meet (E_fc >= 0): nothing is accepted.
ACCEPT_NONE = ["synthesis.optimizer.mala_steps=0", "synthesis.optimizer.refine_steps=0",
               "synthesis.optimizer.filter_fc=0.0"]
SCENES, BATCH = 7, 4


def _args(workdir, config, sets) -> list[str]:
    argv = ["--profile", "smoke", "--workdir", str(workdir), "--config", str(config)]
    for item in sets:
        argv += ["--set", item]
    return argv


def _run(workdir, config, *sets: str) -> int:
    return main(["run", *_args(workdir, config, sets), "--until", "synthesize"])


def _merge_manifest(workdir, run_id: str | None = None):
    folders = (workdir / "stages" / "synthesize").iterdir()
    merges = [m for m in map(read_manifest, folders) if m is not None and m.unit == "merge"]
    if run_id is not None:
        merges = [m for m in merges if m.producer_run_id == run_id]
    return max(merges, key=lambda m: m.created_unix)


@pytest.fixture(scope="module")
def stage_config(tmp_path_factory):
    import trimesh

    folder = tmp_path_factory.mktemp("stage-config")
    mesh = folder / "block.obj"
    trimesh.creation.box(extents=(0.04, 0.03, 0.025)).export(mesh)
    path = folder / "stage.yaml"
    path.write_text(STAGE_YAML.format(mesh=mesh))
    return path


@pytest.fixture(scope="module")
def stage_runs(tmp_path_factory, stage_config):
    """The small stage run twice through the CLI in one work dir (the second must be all cache)."""
    workdir = tmp_path_factory.mktemp("synthesize")
    assert _run(workdir, stage_config, *ACCEPT_ALL) == 0
    first = executions(workdir)
    assert _run(workdir, stage_config, *ACCEPT_ALL) == 0
    return workdir, first, executions(workdir)


# --------------------------------------------------------------------------- fast: table layout, report


def test_every_result_array_becomes_a_column_and_new_keys_are_kept():
    record = {"id": "Pl/cube+cylinder/0", "split": "Pl", "objects": ["cube", "cylinder"], "index": 0,
              "scene": {"objects": [{"name": "cube", "position": [0, 0, 0.02], "quat_xyzw": [0, 0, 0, 1]},
                                    {"name": "cylinder", "position": [0.05, 0, 0.03], "quat_xyzw": [0, 0, 0, 1]}]}}
    arrays = {"p": np.zeros((3, 3)), "R": np.tile(np.eye(3), (3, 1, 1)), "accepted": np.array([True, False, True]),
              "term_fc_per_object": np.ones((3, 2)), "contact_points": np.zeros((3, 2, 3, 3)),
              "reasons": np.array(["accepted", "fc", "accepted"])}
    table = tasks.synthesize._table(tasks.synthesize._row_columns(record, arrays, 7, np.full(3, np.nan),
                                                                  np.full(3, np.nan)))
    assert table.num_rows == 3
    assert {"p", "R", "accepted", "term_fc_per_object", "contact_points", "reason", "q1", "pn_mm",
            "object_names", "object_positions"} <= set(table.column_names)
    assert len(table.column("contact_points")[0].as_py()) == 2 * 3 * 3  # flattened per row
    assert table.column("combination")[0].as_py() == "cube+cylinder"


def test_zero_accepted_combination_gives_a_report_line_with_reasons():
    import pandas as pd

    frame = pd.DataFrame({"scene_id": ["a", "a", "b"], "split": ["Pl"] * 3, "combination": ["cube+sphere"] * 3,
                          "accepted": [False] * 3, "reason": ["fc", "fc", "penetration"], "q1": [np.nan] * 3,
                          "pn_mm": [np.nan] * 3})
    stats = tasks.synthesize_merge.grasp_statistics(frame)
    summary = stats["combinations"]["Pl/cube+sphere"]
    assert summary["accepted"] == 0 and summary["reasons"] == {"fc": 2, "penetration": 1}
    assert summary["mean_q1"] is None and "q1_group_rows" not in summary  # no group rows: no group fields
    line = tasks.synthesize_merge.report_line("Pl/cube+sphere", summary)
    assert line.startswith("Pl/cube+sphere: 0/3 accepted") and "fc 2" in line and "penetration 1" in line


def test_bad_synthesis_split_is_a_one_line_error(tmp_path, capsys):
    assert main(["run", "--profile", "smoke", "--workdir", str(tmp_path), "--set", "synthesis.splits=[Foo]"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "synthesis.splits" in err[0]


def test_evaluate_without_the_synthesize_stage_names_the_command(tmp_path, capsys):
    assert main(["evaluate", "pregrasp", "--source", "synthetic", "--profile", "smoke",
                 "--workdir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "multigrasp run --until synthesize" in err[0]


# --------------------------------------------------------------------------- slow: the stage end to end


@pytest.mark.slow
def test_stage_writes_every_candidate_with_metrics_stats_and_renders(stage_runs):
    import pyarrow.parquet as pq

    workdir, _, _ = stage_runs
    merge = _merge_manifest(workdir)
    accepted = pq.read_table(merge.path("grasps"))
    rejected = pq.read_table(merge.path("rejected"))
    assert accepted.num_rows + rejected.num_rows == SCENES * BATCH
    assert accepted.num_rows == SCENES * BATCH  # filters wide open
    names = set(accepted.column_names)
    assert {"scene_id", "split", "object_names", "object_positions", "object_quats_xyzw", "p", "R", "q",
            "contact_regions", "energy", "accepted", "reason", "q1", "pn_mm"} <= names
    assert any(n.startswith("term_") for n in names)
    frame = accepted.select(["q1", "pn_mm", "R", "q"]).to_pandas()
    q1 = frame["q1"].to_numpy()
    assert np.isfinite(q1).all() and (q1 >= 0).all()  # measured for every accepted grasp
    assert np.isfinite(frame["pn_mm"]).all() and (frame["pn_mm"] >= 0).all()
    assert len(frame["R"][0]) == 9 and len(frame["q"][0]) == 22

    stats = json.loads(merge.path("stats").read_text())
    assert stats["overall"]["candidates"] == SCENES * BATCH
    assert set(stats["splits"]) == {"train", "Com", "Geo"}
    assert merge.path("energy_terms").is_file()
    renders = [name for name in merge.files if name.startswith("render_")]
    assert len(renders) == len(stats["combinations"])  # one 2 x 2 grid per combination
    assert merge.metrics["accepted"] == SCENES * BATCH


@pytest.mark.slow
def test_user_mesh_scene_is_synthesised(stage_runs):
    workdir, _, _ = stage_runs
    stats = json.loads(_merge_manifest(workdir).path("stats").read_text())
    assert stats["combinations"]["Geo/block"]["candidates"] == BATCH


@pytest.mark.slow
def test_second_run_serves_every_unit_from_cache(stage_runs):
    _, first, after_second = stage_runs
    units = sorted(set(first))
    assert units[:2] == ["scenes/merge", "scenes/shard-000"] and units[2] == "synthesize/merge"
    assert len(units) == 6 and all(u.startswith("synthesize/shard-") for u in units[3:])  # 7 scenes, 3 per shard
    assert after_second == first


@pytest.mark.slow
def test_mlflow_synthesize_run_has_stats_metrics_and_pngs(stage_runs):
    from mlflow.tracking import MlflowClient

    workdir, _, _ = stage_runs
    client = MlflowClient(f"sqlite:///{workdir / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("multigrasp")
    runs = client.search_runs([experiment.experiment_id], max_results=1000)
    computed = [r for r in runs if r.data.tags.get("stage") == "synthesize" and r.data.tags.get("cached") == "false"]
    assert len(computed) == 1
    run = computed[0]
    assert run.data.metrics["candidates"] == SCENES * BATCH
    assert run.data.metrics["Geo.accepted"] == BATCH
    stats_files = [a.path for a in client.list_artifacts(run.info.run_id, "synthesis")]
    assert {"synthesis/stats.json", "synthesis/energy_terms.png", "synthesis/report.md"} <= set(stats_files)
    pngs = [a.path for a in client.list_artifacts(run.info.run_id, "renders")]
    assert pngs and all(p.endswith(".png") for p in pngs)


@pytest.mark.slow
def test_evaluate_pregrasp_synthetic_writes_the_syn_rows(stage_runs, stage_config):
    workdir, _, _ = stage_runs
    assert main(["evaluate", "pregrasp", "--source", "synthetic", *_args(workdir, stage_config, ACCEPT_ALL)]) == 0
    rows = {r["setting"]: r for r in json.loads((workdir / "results" / "pregrasp_synthetic.json").read_text())["rows"]}
    assert {"Syn-Pl", "Syn-Com", "Syn-Geo", "Syn-train-pairs", "Syn-Pl-singles", "Syn-Geo-singles"} <= set(rows)
    assert rows["Syn-Pl"]["n"] == 0 and rows["Syn-Pl"]["q1"] is None  # no Pl scenes in this config
    assert rows["Syn-Com"]["n"] == BATCH and rows["Syn-Com"]["accept_rate"] == 1.0
    assert rows["Syn-train-pairs"]["n"] == 2 * BATCH and rows["Syn-train-pairs"]["div_deg"] > 0
    # Syn-* rows are dual-object as the paper's table: this config's Geo has one single (the user mesh), no pair
    assert rows["Syn-Geo"]["n"] == 0 and rows["Syn-Geo-singles"]["n"] == BATCH
    assert rows["Syn-Geo-singles"]["pn_mm"] >= 0
    table = (workdir / "results" / "pregrasp_synthetic.md").read_text()
    # every row beside the paper's figures for the same setting (Table I); rows the paper does not have: '–'
    assert "| 0.31 / 1.78 / 8.58 |" in table.split("| Syn-Com |")[1].splitlines()[0]
    assert table.split("| Syn-Pl-singles |")[1].splitlines()[0].endswith("| – |")
    assert rows["Syn-Pl"]["paper"] == {"q1": 0.30, "pn_mm": 1.64, "div_deg": 8.54} and rows["Syn-train-pairs"]["paper"] is None


@pytest.mark.slow
def test_zero_accepted_grasps_are_reported_not_a_crash(stage_runs, stage_config, capsys):
    workdir, _, _ = stage_runs
    assert _run(workdir, stage_config, *ACCEPT_NONE) == 0
    err = capsys.readouterr().err
    assert "Geo/block: 0/4 accepted" in err and "rejected: fc 4" in err
    merge = _merge_manifest(workdir)
    stats = json.loads(merge.path("stats").read_text())
    assert stats["overall"]["accepted"] == 0
    assert sum(stats["overall"]["reasons"].values()) == SCENES * BATCH
    assert not [name for name in merge.files if name.startswith("render_")]
    assert "0 accepted" in merge.path("report").read_text() or "0/4 accepted" in merge.path("report").read_text()

    assert main(["evaluate", "pregrasp", "--source", "synthetic", *_args(workdir, stage_config, ACCEPT_NONE)]) == 0
    rows = json.loads((workdir / "results" / "pregrasp_synthetic.json").read_text())["rows"]
    assert all(r["n"] == 0 and r["q1"] is None and r["div_deg"] is None for r in rows)


@pytest.mark.slow
def test_min_q1_above_any_q1_rejects_every_grasp_with_reason_q1(stage_runs, stage_config):
    workdir, _, _ = stage_runs
    assert _run(workdir, stage_config, *ACCEPT_ALL, "synthesis.min_q1=100.0") == 0  # a new shard key: recomputed
    stats = json.loads(_merge_manifest(workdir).path("stats").read_text())
    assert stats["overall"]["accepted"] == 0
    assert stats["overall"]["reasons"] == {"q1": SCENES * BATCH}


@pytest.mark.slow
def test_rerun_after_a_crashed_shard_recomputes_only_unfinished_units(stage_runs, stage_config, monkeypatch):
    workdir, _, _ = stage_runs
    variant = [*ACCEPT_ALL, "synthesis.optimizer.mala_steps=4"]  # new shard keys, same scenes
    real = tasks.synthesize.synthesize_shard

    def crash_on_geo(folder, records, *args, **kwargs):
        if any(r["split"] == "Geo" for r in records):
            raise RuntimeError("simulated crash in a synthesize shard")
        return real(folder, records, *args, **kwargs)

    monkeypatch.setattr(tasks.synthesize, "synthesize_shard", crash_on_geo)
    before = len(executions(workdir))
    with pytest.raises(RuntimeError, match="simulated crash"):
        _run(workdir, stage_config, *variant)
    first = executions(workdir)[before:]
    assert len(first) == 3 and all(u.startswith("synthesize/shard-") for u in first)
    crashed = [u for u in first if "Geo:" in u]
    assert len(crashed) == 1

    monkeypatch.setattr(tasks.synthesize, "synthesize_shard", real)
    assert _run(workdir, stage_config, *variant) == 0
    assert executions(workdir)[before + len(first):] == [*crashed, "synthesize/merge"]


@pytest.mark.slow
def test_bench_synthesis_writes_its_json(tmp_path):
    out = tmp_path / "synthesis.json"
    assert main(["bench", "synthesis", "--json", str(out), "--steps-scale", "0.01", "--repeats", "2",
                 "--threads", "1"]) == 0
    result = json.loads(out.read_text())
    assert {"accepted_per_s", "accept_rate", "step_ms", "fk_ms", "threads", "workload", "q1", "pn_mm", "div_deg",
            "quality_n"} <= set(result)
    assert result["workload"]["batch"] == 256 and result["workload"]["objects"] == ["cube", "cylinder"]
    assert result["step_ms"] > 0 and result["fk_ms"] > 0
    if result["quality_n"]:  # the min over objects is at most each object's mean
        assert len(result["q1_per_object"]) == 2 and result["q1"] <= min(result["q1_per_object"]) + 1e-4
    else:
        assert result["q1_per_object"] is None


def test_merge_code_is_outside_the_shard_cache_keys():
    """Editing reports or renders must recompute only the merge, never the (expensive) shards."""
    from tasks.synthesize import SYNTHESIS_CODE_DIRS
    from tasks.synthesize_merge import MERGE_CODE_DIRS

    assert "tasks/synthesize_merge.py" in MERGE_CODE_DIRS
    assert not any(d.startswith("tasks/synthesize_merge") for d in SYNTHESIS_CODE_DIRS)


def test_adding_a_split_keeps_the_shards_already_synthesised(monkeypatch):
    """Shards are named by their scenes, so a plan that gains the train split keeps the Pl shards' keys."""
    import flows.synthesize
    from flows.config import load_config

    def records(split, combos):
        return [{"id": f"{split}/{c}/0", "split": split, "objects": c.split("+"), "index": 0, "scene": {"c": c}}
                for c in combos]

    scenes = records("train", ["cube", "cube+sphere"]) + records("Pl", ["cube+cylinder", "cylinder+sphere"])
    monkeypatch.setattr(flows.synthesize, "read_scene_records", lambda manifest: scenes)

    def keys(*sets):
        cfg = load_config("smoke", None, ["synthesis.scenes_per_shard=1", *sets])
        return {spec.unit: spec.key for spec, _ in flows.synthesize.shard_plan(cfg, None)}

    pl_only, both = keys("synthesis.splits=[Pl]"), keys("synthesis.splits=[train,Pl]")
    assert sorted(pl_only) == ["shard-Pl:cube+cylinder:0", "shard-Pl:cylinder+sphere:0"]
    assert len(both) == 4 and all(both[unit] == key for unit, key in pl_only.items())
    assert flows.synthesize.shard_name(scenes[:2]) == "shard-train:cube:0..train:cube+sphere:0"


def test_min_q1_rejects_accepted_rows_that_are_not_above_it():
    from tasks.synthesize import reject_weak

    arrays = {"accepted": np.array([True, True, True, False]),
              "reasons": np.array(["accepted", "accepted", "accepted", "fc"])}
    q1 = np.array([0.2, 0.0, np.nan, np.nan])  # measured for accepted rows only
    unchanged = reject_weak({k: v.copy() for k, v in arrays.items()}, q1, None)
    assert unchanged["accepted"].tolist() == arrays["accepted"].tolist()
    out = reject_weak(arrays, q1, 0.0)  # 0: keep only grasps in force closure under the metric
    assert out["accepted"].tolist() == [True, False, False, False]
    assert out["reasons"].tolist() == ["accepted", "q1", "q1", "fc"]


def test_scene_cap_per_split():
    from components.errors import MultigraspError
    from flows.config import load_config
    from tasks.synthesize import SynthesisStageConfig

    assert SynthesisStageConfig(max_scenes_per_combination=3).scene_cap("Geo") == 3
    mapping = SynthesisStageConfig(max_scenes_per_combination={"train": 2, "Pl": 1})
    assert (mapping.scene_cap("train"), mapping.scene_cap("Pl"), mapping.scene_cap("Geo")) == (2, 1, 0)
    with pytest.raises(MultigraspError, match="max_scenes_per_combination"):
        load_config("smoke", None, ["synthesis.max_scenes_per_combination={trian: 2}"])


def test_optimizer_by_object_count_overrides_only_scenes_of_that_count():
    from components.errors import MultigraspError
    from flows.config import load_config
    from tasks.synthesize import SynthesisStageConfig

    stage = SynthesisStageConfig(optimizer_by_object_count={3: {"w_pen": 1000.0, "contacts_per_object": 2}})
    assert stage.optimizer_for(2) is stage.optimizer
    three = stage.optimizer_for(3)
    assert (three.w_pen, three.contacts_per_object) == (1000.0, 2)
    assert three.batch_size == stage.optimizer.batch_size  # the rest is the base setting
    with pytest.raises(MultigraspError, match="optimizer_by_object_count") as info:
        load_config("smoke", None, ["synthesis.optimizer_by_object_count={3: {w_pne: 1000}}"])
    assert "w_pne" in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(MultigraspError, match="optimizer_by_object_count"):
        load_config("smoke", None, ["synthesis.optimizer_by_object_count={3: {w_pen: -1}}"])


def test_stage_uses_the_override_for_scenes_of_that_count(stage_runs, stage_config):
    import pandas as pd

    workdir, _, _ = stage_runs
    before = executions(workdir)
    assert _run(workdir, stage_config, *ACCEPT_ALL, "synthesis.optimizer_by_object_count={3: {w_pen: 500}}") == 0
    assert executions(workdir) == before  # no 3-object scene here: every shard (and the merge) served from cache
    assert _run(workdir, stage_config, *ACCEPT_ALL, "synthesis.optimizer_by_object_count={2: {batch_size: 2}}") == 0
    frame = pd.read_parquet(_merge_manifest(workdir).path("grasps"))
    sizes = frame.groupby("scene_id").size()
    pairs = frame.groupby("scene_id").object_names.first().map(len) == 2
    assert set(sizes[pairs]) == {2} and set(sizes[~pairs]) == {BATCH}


def test_group_force_closure_for_pairs_writes_group_q1_and_the_hand_alone_q1(stage_runs, stage_config):
    import pandas as pd

    workdir, _, _ = stage_runs
    assert _run(workdir, stage_config, *ACCEPT_ALL, "synthesis.optimizer_by_object_count={2: {fc_mode: group}}") == 0
    merge = _merge_manifest(workdir)
    frame = pd.read_parquet(merge.path("grasps"))
    pairs = frame.object_names.map(len) == 2
    assert frame.loc[pairs, "q1_group"].all() and not frame.loc[~pairs, "q1_group"].any()
    singles = frame[~pairs]
    assert np.allclose(singles.q1, singles.q1_objects, equal_nan=True)  # one object: Q1 is the object's
    assert frame.loc[pairs, "q1_objects"].notna().all() and frame.loc[pairs, "q1"].notna().all()
    stats = json.loads(merge.path("stats").read_text())
    assert stats["overall"]["q1_group_rows"] == int(pairs.sum())
    assert "the hand alone" in merge.path("report").read_text()


def _refilter_args(workdir, config, *extra: str) -> list[str]:
    argv = ["--profile", "smoke", "--workdir", str(workdir), "--config", str(config)]
    for item in ACCEPT_ALL:
        argv += ["--set", item]
    return argv + list(extra)


def test_refilter_rescores_every_candidate_of_the_configs_stage_and_writes_them(stage_runs, stage_config, tmp_path):
    """``benchmarks.refilter`` finds the stage from the config; ``--rescore`` recomputes the terms (an E_fc margin no
    grasp exceeds zeroes every E_fc, so a force-closure threshold only 0 meets accepts every row again), and
    ``--write-grasps`` writes the accepted rows as a grasps table."""
    import pandas as pd

    from benchmarks.refilter import main as refilter

    workdir = stage_runs[0]
    strict = ["--filter", "filter_fc=1e-12"]
    out, written = tmp_path / "strict.json", tmp_path / "strict.parquet"
    assert refilter(_refilter_args(workdir, stage_config, *strict, "--json", str(out), "--write-grasps", str(written))) == 0
    groups = json.loads(out.read_text())["groups"]
    candidates = sum(g["stored"]["candidates"] for g in groups.values())
    assert candidates == SCENES * BATCH and sum(g["stored"]["accepted"] for g in groups.values()) == candidates
    rejected_fc = sum(g["refiltered"]["reasons"].get("fc", 0) for g in groups.values())
    assert rejected_fc > 0  # the stored E_fc of the barely optimised candidates are above 1e-12
    assert len(pd.read_parquet(written)) == candidates - rejected_fc
    out, written = tmp_path / "rescored.json", tmp_path / "rescored.parquet"
    assert refilter(_refilter_args(workdir, stage_config, *strict, "--rescore", "fc_margin=1e9", "--json", str(out),
                                   "--write-grasps", str(written))) == 0
    result = json.loads(out.read_text())
    assert result["rescore"] == ["fc_margin=1e9"]
    assert all(g["refiltered"]["accepted"] == g["stored"]["accepted"] for g in result["groups"].values())
    table = pd.read_parquet(written)
    assert len(table) == candidates and {"p", "R", "q", "contacts", "q1"} <= set(table.columns)
    assert np.all(np.concatenate(table["term_fc_per_object"].to_numpy()) == 0.0)


def test_refilter_rescore_under_another_config_than_the_stages_is_one_line(stage_runs, stage_config, tmp_path, capsys):
    from benchmarks.refilter import main as refilter

    workdir = stage_runs[0]
    merge = _merge_manifest(workdir).folder
    argv = _refilter_args(workdir, stage_config, "--stage-dir", str(merge), "--set", "synthesis.optimizer.fc_friction=0",
                          "--rescore", "fc_margin=1e9", "--json", str(tmp_path / "x.json"))
    assert refilter(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "does not reproduce the stored term_fc_per_object" in err and "--set" in err and "\n" not in err
