"""The train-generator stage and ``multigrasp generate`` through the CLI: a small synthesis (filters open),
a tiny generator, generation for an object it never saw (a user mesh), clear errors, cache."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from flows.cli import main
from tasks.artifacts import read_manifest
from tasks.units import executions
from tests.test_synthesize_stage import ACCEPT_ALL, STAGE_YAML

TINY = ["generator.model.train_steps=6", "generator.model.batch_size=4", "generator.model.model_dim=16",
        "generator.model.heads=2", "generator.model.blocks=1", "generator.model.points_per_object=64",
        "generator.model.log_every=2", "generator.model.checkpoint_every=3", "generator.ik.steps=5",
        "generator.refine.steps=3", "generator.records_source=accepted"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    import trimesh

    folder = tmp_path_factory.mktemp("gen-config")
    mesh = folder / "block.obj"
    trimesh.creation.box(extents=(0.04, 0.03, 0.025)).export(mesh)
    config = folder / "stage.yaml"
    config.write_text(STAGE_YAML.format(mesh=mesh))
    workdir = tmp_path_factory.mktemp("gen")
    base = ["--profile", "smoke", "--workdir", str(workdir), "--config", str(config)]
    for item in [*ACCEPT_ALL, *TINY]:
        base += ["--set", item]
    assert main(["run", *base, "--until", "train-generator"]) == 0
    first = executions(workdir)
    assert main(["run", *base, "--until", "train-generator"]) == 0
    return workdir, base, first, executions(workdir)


def _fixture_units(workdir: Path) -> list:
    """The fixture's 6-step train-generator unit(s), not the longer ones a test below adds."""
    units = [m for m in map(read_manifest, (workdir / "stages" / "train-generator").iterdir()) if m is not None]
    return [m for m in units if json.loads(m.path("history").read_text())[-1]["step"] == 6]


def test_train_generator_stage_writes_a_checkpoint_and_a_loss_curve(trained):
    workdir, _, first, again = trained
    (manifest,) = _fixture_units(workdir)
    history = json.loads(manifest.path("history").read_text())
    assert history[-1]["step"] == 6 and manifest.metrics["grasps"] >= 1
    assert manifest.path("loss_plot").is_file()
    assert "train-generator/stage" in first and again == first  # the second run is served from cache


def test_generate_for_an_object_the_generator_never_saw(trained):
    workdir, base, _, _ = trained
    # 'block' is the user mesh of the Geo split: the generator trained on the train split only
    # with the force-closure refinement on (a generation-time setting: the training is served from cache)
    assert main(["generate", "--objects", "cube,block", "--n", "2", "--palm-direction", "90", *base,
                 "--set", "generator.refine.fc_steps=2"]) == 0
    (folder,) = (workdir / "results" / "generated").iterdir()
    grasps = json.loads((folder / "grasps.json").read_text())
    assert len(grasps["grasps"]) == 2 and len(grasps["grasps"][0]["q"]) == 22
    first = grasps["grasps"][0]
    assert first["q1"] >= 0.0 and 0.0 <= first["contact_ratio"] <= 1.0 and isinstance(first["kept"], bool)
    assert (folder / "grasps.png").is_file()
    assert json.loads((folder / "scene.json").read_text())["objects"][1]["name"] == "block"
    from mlflow.tracking import MlflowClient  # its MLflow run holds the settings it generated under

    client = MlflowClient(f"sqlite:///{workdir / 'mlflow.db'}")
    run = client.search_runs([client.get_experiment_by_name("multigrasp").experiment_id],
                             filter_string="tags.command = 'generate'", order_by=["attributes.start_time DESC"])[0]
    assert run.data.params["generator.refine.fc_steps"] == "2" and "run.workdir" not in run.data.params
    # --placement: the same scene again, from the scene.json that generate wrote
    assert main(["generate", "--placement", str(folder / "scene.json"), "--n", "1", "--seed", "1", *base]) == 0
    again = [f for f in (workdir / "results" / "generated").iterdir() if f != folder]
    assert len(again) == 1 and json.loads((again[0] / "scene.json").read_text()) == json.loads(
        (folder / "scene.json").read_text())


def test_generate_placement_that_is_missing_or_unreadable_is_one_line(tmp_path, capsys):
    base = ["--profile", "smoke", "--workdir", str(tmp_path / "runs")]
    assert main(["generate", "--placement", str(tmp_path / "none.json"), *base]) == 2
    assert "does not exist; fix the path" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("{bad")
    assert main(["generate", "--placement", str(tmp_path / "bad.json"), *base]) == 2
    err = capsys.readouterr().err
    assert "is not a readable scene JSON" in err and err.count("\n") == 1


def test_generate_without_a_trained_generator_names_the_command(tmp_path, capsys):
    assert main(["generate", "--objects", "cube", "--profile", "smoke", "--workdir", str(tmp_path)]) == 2
    assert "multigrasp run --until train-generator" in capsys.readouterr().err


def test_generate_names_an_unknown_object_before_asking_for_a_training(tmp_path, capsys):
    """A typo in --objects is reported as such, not as a missing generator (which training would not fix)."""
    assert main(["generate", "--objects", "cube,banana", "--profile", "smoke", "--workdir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "unknown object 'banana'" in err and "train-generator" not in err


def test_generate_with_an_unknown_object_is_a_one_line_error(trained, capsys):
    _, base, _, _ = trained
    assert main(["generate", "--objects", "cube,banana", *base]) == 2
    err = capsys.readouterr().err
    assert "banana" in err and "Traceback" not in err


def test_generate_for_more_objects_than_the_generator_takes_names_its_limit(trained, capsys):
    _, base, _, _ = trained
    assert main(["generate", "--objects", "cube,cylinder,sphere,bar", "--n", "1", *base]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: the generator of this config takes at most 3 objects per scene "
                          "(generator.model.max_objects) and the scene has 4 (cube+cylinder+sphere+bar)")


def test_bench_generation_reports_its_timings():
    from benchmarks.generation import run_generation_benchmark

    result = run_generation_benchmark(repeats=1, threads=1, batch=2)
    assert result["time_256_s"] is None and result["workload"]["batch"] == 2  # only a 256 batch is the paper's figure
    assert result["time_s"] == pytest.approx(result["sample_s"] + result["ik_s"] + result["refine_s"], abs=2e-3)
    assert result["threads"] == 1
    assert result["workload"]["sampler"] == "ddim" and result["workload"]["denoiser_calls"] == 25  # bench profile
    paper = run_generation_benchmark(repeats=1, threads=1, batch=2, profile="paper", sets=("refine.steps=5",))
    assert paper["workload"]["sampler"] == "ddpm" and paper["workload"]["denoiser_calls"] == 100
    assert paper["workload"]["refine_steps"] == 5 and paper["workload"]["profile"] == "paper"


def test_evaluate_pregrasp_generated_writes_the_gen_rows(trained):
    workdir, base, _, _ = trained
    argv = ["evaluate", "pregrasp", "--source", "generated", *base,
            "--set", "generator.eval_scenes=1", "--set", "generator.eval_grasps_per_scene=2"]
    assert main(argv) == 0
    report = json.loads((workdir / "results" / "pregrasp_generated.json").read_text())
    rows = {r["setting"]: r for r in report["rows"]}
    assert set(rows) == {"Gen-Pl", "Gen-Com", "Gen-Geo"}
    assert rows["Gen-Pl"]["n"] == 0 and rows["Gen-Pl"]["q1"] is None  # this small config has no Pl scenes
    for name in ("Gen-Com", "Gen-Geo"):  # Geo: a user mesh the generator never trained on
        row = rows[name]
        assert row["n_generated"] == 2 and row["q1_all"] >= 0.0 and row["pn_mm_all"] >= 0.0
        assert row["time_s"] > 0 and row["div_deg_all"] is not None and 0.0 <= row["contact_ratio"] <= 1.0
        # the paper's protocol filter: n kept of the 2, Q1 / PN over the kept ones
        assert 0 <= row["n"] <= 2 and row["accept_rate"] == row["n"] / 2
        assert (row["q1"] is None) == (row["n"] == 0)
        assert row["time_256_s"] > 0 and row["time_batch"] == 256  # one timed batch of 256 (the paper's "Time"), not time_s scaled from 2 grasps
    assert rows["Gen-Pl"]["time_256_s"] is None  # no scene to time
    markdown = (workdir / "results" / "pregrasp_generated.md").read_text()
    assert "| Gen-Com |" in markdown and "0.25 / 2.65 / 8.45 / 12.83 s |" in markdown and "all generated" in markdown
    assert rows["Gen-Pl"]["paper"] == {"q1": 0.29, "pn_mm": 1.67, "div_deg": 9.24, "time_256_s": 12.28}


def test_the_timed_batch_is_the_settings_own_when_its_scenes_get_256_grasps(trained, monkeypatch):
    """With eval_grasps_per_scene 256 the setting's batches are the paper's: time_256_s is their mean time, and no
    extra batch is generated (Q1 is skipped here to keep the test short)."""
    import flows.evaluate_generated as eg
    from flows.config import load_config

    workdir, base, _, _ = trained
    config, sets = Path(base[base.index("--config") + 1]), base[base.index("--set") + 1::2]
    cfg = load_config("smoke", config_file=config, workdir=workdir,
                      sets=[*sets, "generator.eval_scenes=1", "generator.eval_grasps_per_scene=256"])
    batches, generate, score = [], eg.generate_for_scene, eg.score_generated

    def counted(*args, **kwargs):
        batches.append(kwargs.get("n"))
        return generate(*args, **kwargs)

    monkeypatch.setattr(eg, "generate_for_scene", counted)
    monkeypatch.setattr(eg, "score_generated", lambda *a, **k: score(*a, **{**k, "with_q1": False}))
    (row,), _ = eg.generated_rows(cfg, settings=(("Gen-Com", "Com"),), progress=None)
    assert batches == [None] and row["n_generated"] == 256  # the scene's own batch, no timed one beside it
    # one scene: the batch's time is time_s, rounded to 2 places from the unrounded seconds (time_s keeps 3: rounding
    # time_s again could land a cent away, as 3.935 -> 3.94 against 3.93)
    assert row["time_batch"] == 256 and row["time_256_s"] == pytest.approx(row["time_s"], abs=0.0051)


def test_generator_ablations_file_has_the_papers_rows(trained, monkeypatch):
    import flows.evaluate_generated as eg

    # keep the test short: the refinement ablation (no retraining) and Ours
    monkeypatch.setattr(eg, "GENERATOR_ABLATIONS", {"Ours": {}, "w/o Refinement": eg.GENERATOR_ABLATIONS["w/o Refinement"]})
    workdir, base, _, _ = trained
    argv = ["evaluate", "pregrasp", "--source", "generated", "--ablations", *base,
            "--set", "generator.eval_scenes=1", "--set", "generator.eval_grasps_per_scene=2"]
    assert main(argv) == 0
    rows = json.loads((workdir / "results" / "ablation_generator.json").read_text())["rows"]
    assert [r["setting"] for r in rows] == ["Ours", "w/o Refinement"]
    assert all(set(r) >= {"q1", "pn_mm", "n", "accept_rate", "q1_all", "pn_mm_all"} for r in rows)


def test_generator_ablations_list_the_papers_variants():
    import flows.evaluate_generated as eg

    assert list(eg.GENERATOR_ABLATIONS) == ["Ours", "Joint Angles", "w/o Obj Embd", "w/o Refinement"]


def _tool_source_args(trained) -> list[str]:
    """--profile / --workdir / --config / --set options of a benchmarks tool for the fixture's run."""
    workdir, base, _, _ = trained
    config = [base[i + 1] for i in range(len(base) - 1) if base[i] == "--config"]
    argv = ["--profile", "smoke", "--workdir", str(workdir), "--config", config[0]]
    for i in range(len(base) - 1):
        if base[i] == "--set":
            argv += ["--set", base[i + 1]]
    return argv


def test_sampler_quality_tool_compares_settings_on_the_same_scenes(trained, tmp_path, capsys):
    from benchmarks import sampler_quality

    out = tmp_path / "sq.json"
    argv = [*_tool_source_args(trained), "--split", "Com",
            "--variant", "paper=", "--variant", "fast=sampler.method=ddim,sampler.steps=5,refine.steps=2",
            "--set", "generator.eval_scenes=1", "--set", "generator.eval_grasps_per_scene=2", "--json", str(out)]
    assert sampler_quality.main(argv) == 0
    rows = {r["variant"]: r for r in json.loads(out.read_text())["rows"]}
    assert set(rows) == {"paper", "fast"} and rows["paper"]["n_generated"] == rows["fast"]["n_generated"] == 2
    assert all(r["n"] <= 2 and r["accept_rate"] == r["n"] / 2 and r["q1_all"] >= 0.0 for r in rows.values())
    assert rows["fast"]["overrides"] == ["sampler.method=ddim", "sampler.steps=5", "refine.steps=2"]
    assert rows["fast"]["pn_before_refine_mm"] >= 0.0
    assert sampler_quality.main([*argv, "--variant", "oops"]) == 2
    assert "NAME=KEY=VALUE" in capsys.readouterr().err


def test_generator_fidelity_tool_compares_samples_with_their_training_grasps(trained, tmp_path, capsys):
    from benchmarks import generator_fidelity

    out = tmp_path / "fidelity.json"
    argv = [*_tool_source_args(trained), "--scenes", "1", "--per-scene", "2", "--noise-steps", "3", "--json", str(out)]
    assert generator_fidelity.main(argv) == 0
    rows = {r["row"]: r for r in json.loads(out.read_text())["rows"]}
    T = 100  # the smoke profile's diffusion steps (GeneratorConfig default)
    assert list(rows) == ["data", "data -> IK", "noised t=3 -> denoised", f"sampled (N(0, I) at t={T})"]
    assert all(r["n"] == rows["data"]["n"] >= 1 and r["pn_mm"] >= 0.0 for r in rows.values())
    assert rows["data -> IK"]["keypoint_shift_mm"] < 1e-3  # the representation round trip itself moves nothing
    assert rows["noised t=3 -> denoised"]["keypoint_shift_mm"] > 0.0 and rows["data"]["ik_error_mm"] is None
    assert rows[f"sampled (N(0, I) at t={T})"]["keypoint_shift_mm"] is None
    assert generator_fidelity.main([*argv, "--noise-steps", "x"]) == 2
    assert "comma-separated integers" in capsys.readouterr().err


def test_a_longer_training_continues_the_finished_shorter_one(trained):
    workdir, base, first, _ = trained
    stage_dir = workdir / "stages" / "train-generator"
    (short,) = _fixture_units(workdir)
    longer = [*base, "--set", "generator.model.train_steps=8"]
    assert main(["run", *longer, "--until", "train-generator"]) == 0
    (extended,) = [m for m in map(read_manifest, stage_dir.iterdir()) if m is not None and m.key != short.key]
    assert extended.meta["extended_from"] == short.key and extended.meta["resumed_from"] == 6
    history = json.loads(extended.path("history").read_text())
    assert [row["step"] for row in history][-1] == 8 and history[:3] == json.loads(short.path("history").read_text())
    assert read_manifest(Path(short.folder)).hash == short.hash  # the shorter unit is left as it was
    done = executions(workdir)
    assert main(["run", *longer, "--until", "train-generator"]) == 0 and executions(workdir) == done  # cached
    # other training data (another split set), same model: trained from scratch, not continued
    other = [*longer, "--set", "generator.splits=[train,Pl]"]
    assert main(["run", *other, "--until", "train-generator"]) == 0
    (fresh,) = [m for m in map(read_manifest, stage_dir.iterdir())
                if m is not None and m.key not in (short.key, extended.key)]
    assert fresh.meta["extended_from"] == "" and fresh.meta["resumed_from"] == 0
    assert fresh.meta["data"] != extended.meta["data"] == short.meta["data"]


def test_generated_table_reads_like_a_synthesis_table(trained, tmp_path, capsys):
    """benchmarks.generated_table writes generated, refined grasps with the synthesis table's columns, so the lift
    tools read them (records_from_table) and the grasp-table reader serves them."""
    from benchmarks.generated_table import main as table_main
    from benchmarks.grasp_tables import read_accepted
    from tasks.specialists import records_from_table

    _, base, _, _ = trained
    out, summary = tmp_path / "gen.parquet", tmp_path / "gen.json"
    argv = [*base, "--set", "generator.eval_grasps_per_scene=2", "--set", "generator.refine.fc_steps=2",
            "--split", "Geo", "--scenes", "1", "--out", str(out), "--json", str(summary)]
    assert table_main([*argv, "--set", "generator.eval_filter.enabled=false"]) == 0  # every row accepted
    frame = read_accepted(out, "Geo", 10)
    assert len(frame) == 2 and json.loads(summary.read_text())["n"] == 2
    records = records_from_table(frame)
    assert records[0].R.shape == (3, 3) and records[0].q.shape == (22,)
    assert [o.name for o in records[0].scene.objects] == list(frame.iloc[0]["object_names"])
    assert table_main(argv) == 0  # the paper's protocol filter: `accepted` is the kept rows
    import pandas as pd

    written, result = pd.read_parquet(out), json.loads(summary.read_text())
    assert result["n_generated"] == 2 and result["n"] == int(written["accepted"].sum())
    assert written["contact_ratio"].between(0.0, 1.0).all()
    assert table_main([*argv, "--checkpoint", str(tmp_path / "missing.pt")]) == 2
    assert "is not a file" in capsys.readouterr().err


def test_a_generator_trained_elsewhere_is_adopted_by_its_unit(trained, tmp_path, capsys):
    """benchmarks.gpu_check.generator_job: export the stage's training data, train it (here on the CPU, in the
    README on a GPU machine), copy the checkpoint into the unit folder the export names: the stage adopts it
    (resumed at its last step, nothing left to train) and then serves it from cache."""
    import shutil

    from benchmarks.gpu_check import generator_job

    workdir, base, _, _ = trained
    sets = [*_tool_source_args(trained), "--set", "generator.model.train_steps=4"]
    assert generator_job.main(["export", *sets, "--out", str(tmp_path / "job")]) == 0
    folder = Path(capsys.readouterr().out.strip().splitlines()[-1].split("train-generator unit: ")[1])
    assert not folder.exists()
    assert generator_job.main(["train", "--data", str(tmp_path / "job" / "dataset.pt"), "--out", str(tmp_path / "gpu"),
                               "--device", "cpu"]) == 0
    folder.mkdir(parents=True)
    shutil.copyfile(tmp_path / "gpu" / "generator.pt", folder / "generator.pt")
    run = [*base, "--set", "generator.model.train_steps=4"]
    assert main(["run", *run, "--only", "train-generator"]) == 0
    manifest = read_manifest(folder)
    assert manifest.meta["resumed_from"] == 4 and manifest.meta["extended_from"] == ""
    done = executions(workdir)
    assert main(["run", *run, "--only", "train-generator"]) == 0 and executions(workdir) == done


def test_sample_renders_that_fail_cost_a_warning_not_the_trained_generator(trained, capsys, monkeypatch):
    """The samples logged after a training (tracking.generator_sample_scenes) are tracking only: if they fail, the
    run says so in one line and goes on, and the trained unit is kept and served from then on."""
    import flows.train_generator

    def broken(*_args, **_kwargs):
        raise RuntimeError("renderer unavailable")

    monkeypatch.setattr(flows.train_generator, "log_samples", broken)
    workdir, base, _, _ = trained
    run = [*base, "--set", "generator.model.train_steps=7"]
    capsys.readouterr()
    assert main(["run", *run, "--until", "train-generator"]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "the sample renders were not logged (RuntimeError: renderer unavailable); the trained generator is kept" in err
    done = executions(workdir)
    assert main(["run", *run, "--until", "train-generator"]) == 0 and executions(workdir) == done  # served
