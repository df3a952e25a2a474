"""``multigrasp report`` and the paper's figures beside every evaluation table (flows/paper.py)."""

from __future__ import annotations

import datetime
import json

import pytest

from flows.cli import main
from flows.evaluate import pregrasp_markdown, with_paper
from flows.evaluate_execution import execution_markdown
from flows.paper import PAPER_PREGRASP, execution_paper
from flows.report import SOURCES, write_report


def _write(results, name, rows, profile="bench"):
    results.mkdir(parents=True, exist_ok=True)
    (results / name).write_text(json.dumps({"rows": rows, "profile": profile}))


def test_the_papers_tables_as_data():
    # Table I of the paper, as printed: Syn / Gen x Pl / Com / Geo
    assert PAPER_PREGRASP["Syn-Pl"] == {"q1": 0.30, "pn_mm": 1.64, "div_deg": 8.54}
    assert PAPER_PREGRASP["Gen-Com"]["time_256_s"] == 12.83
    assert execution_paper("Syn-Pl") == 0.6834 and execution_paper("Syn-Geo") == 0.2255
    assert execution_paper("w/o RL") == 0.0137 and execution_paper("Scripted squeeze-lift") is None


def test_each_table_row_stands_beside_the_papers_figure():
    rows = with_paper([{"setting": "Syn-Pl", "q1": 0.084, "pn_mm": 1.09, "div_deg": 14.3, "accept_rate": 0.456,
                        "n": 541},
                       {"setting": "Syn-train-pairs", "q1": None, "pn_mm": None, "div_deg": None,
                        "accept_rate": None, "n": 0}])
    assert rows[0]["paper"]["q1"] == 0.30 and rows[1]["paper"] is None
    table = pregrasp_markdown(rows, "synthetic")
    assert "| Syn-Pl | 0.084 | 1.09 | 14.30 | 45.6 % | 541 | 0.30 / 1.64 / 8.54 |" in table
    assert "| Syn-train-pairs | – | – | – | – | 0 | – |" in table
    execution = execution_markdown([{"setting": "Syn-Com", "succ": 0.302, "n_poses": 100, "trials": 5}],
                                   [{"setting": "Ours", "succ": 0.306}, {"setting": "w/o Goal", "succ": None,
                                                                         "missing": "run with --ablations"}],
                                   "accepted")
    assert "| Syn-Com | 30.2 % | 100 x 5 | 26.7 % |" in execution
    assert "| Ours | 30.6 % | 68.3 % |" in execution and "| w/o Goal | — | 16.8 % | run with --ablations |" in execution
    assert "Ours* 45.25 % on a subset of objects" in execution  # the paper's ablation base is said


def test_report_sets_every_result_beside_the_paper_and_names_what_is_missing(tmp_path, capsys):
    results = tmp_path / "results"
    _write(results, "pregrasp_synthetic.json", [{"setting": "Syn-Pl", "q1": 0.084, "pn_mm": 1.09, "div_deg": 14.3,
                                                 "accept_rate": 0.456, "n": 541}])
    _write(results, "execution.json", [{"setting": "Syn-Pl", "succ": 0.306, "n_poses": 100, "trials": 5}])
    _write(results, "ablation_execution.json", [{"setting": "Ours", "succ": 0.306},
                                                {"setting": "w/o RL", "succ": 0.004},
                                                {"setting": "Scripted squeeze-lift", "succ": 0.298}])
    assert main(["report", "--workdir", str(tmp_path)]) == 0
    text = (results / "report.md").read_text()
    assert "| Syn-Pl | 0.084 (0.30) | 1.09 (1.64) | 14.30 (8.54) |" in text and "| 30.6 % (68.3 %) |" in text
    assert "| w/o RL | 0.4 % (1.4 %) |" in text and "| Scripted squeeze-lift | 29.8 % | not in the paper |" in text
    assert "| pregrasp_synthetic.json | bench |" in text
    for name in ("pregrasp_generated.json", "ablation_generator.json", "execution_generated.json"):  # not evaluated: the command
        assert f"| {name} | – | not yet | `{SOURCES[name]}` |" in text
    report = write_report(tmp_path)
    assert report.missing == ["pregrasp_generated.json", "execution_generated.json", "ablation_generator.json",
                              "execution_generalist.json", "ablation_curriculum.json"]
    # the same figures as CSV (table, setting, metric, here, paper), both logged to an MLflow run of their own
    import csv

    rows = {(r["table"], r["setting"], r["metric"]): r for r in csv.DictReader(report.csv_path.open())}
    assert rows[("I", "Syn-Pl", "q1")]["here"] == "0.084" and rows[("I", "Syn-Pl", "q1")]["paper"] == "0.3"
    assert rows[("I", "Syn-Pl", "succ")]["here"] == "0.306" and rows[("I", "Gen-Pl", "succ")]["here"] == ""
    assert rows[("II(b,c)", "w/o RL", "succ")]["here"] == "0.004"
    from mlflow.tracking import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
    run = client.get_run(report.run_id)
    assert run.data.tags["command"] == "report" and run.data.tags["source.execution.json"] == "bench"
    assert sorted(a.path for a in client.list_artifacts(report.run_id, "results")) == ["results/report.csv",
                                                                                       "results/report.md"]


def test_report_says_when_a_table_was_evaluated_from_the_file_not_its_mtime(tmp_path):
    """A work dir copied without its files' times still shows when each table was evaluated: the ``evaluated_at``
    that ``evaluate`` writes (flows.config.results_stamp); a file without it falls back to its mtime."""
    import os

    from flows.config import load_config, results_stamp

    cfg = load_config("smoke", workdir=tmp_path)
    stamp = results_stamp(cfg, "execution.json")
    assert set(stamp) == {"config_key", "evaluated_at"}
    written = datetime.datetime.fromisoformat(stamp["evaluated_at"])
    assert written.tzinfo is not None and abs(datetime.datetime.now(datetime.timezone.utc) - written).total_seconds() < 60
    results = tmp_path / "results"
    results.mkdir()
    (results / "execution.json").write_text(json.dumps({
        "profile": "bench", "evaluated_at": "2026-01-02T03:04:00+00:00",
        "rows": [{"setting": "Syn-Pl", "succ": 0.3, "n_poses": 100, "trials": 5}]}))
    _write(results, "pregrasp_synthetic.json", [{"setting": "Syn-Pl", "q1": 0.08, "pn_mm": 1.1, "div_deg": 14.0,
                                                 "accept_rate": 0.45, "n": 10}])
    old = datetime.datetime(2025, 5, 6, 7, 8).timestamp()
    os.utime(results / "pregrasp_synthetic.json", (old, old))
    text = write_report(tmp_path).markdown
    evaluated = datetime.datetime(2026, 1, 2, 3, 4, tzinfo=datetime.timezone.utc).astimezone().strftime("%Y-%m-%d %H:%M")
    assert f"| execution.json | bench | {evaluated} |" in text  # the field, whatever the file's mtime
    assert "| pregrasp_synthetic.json | bench | 2025-05-06 07:08 |" in text  # no field: the mtime


def test_success_lifted_from_unaccepted_candidates_is_marked_as_a_plumbing_check(tmp_path):
    """The smoke profile lifts each scene's lowest-energy candidates (its synthesis accepts none): report.md marks
    those success figures and says they are no result, report.csv notes them, and accepted pre-grasps' are unmarked."""
    import csv

    results = tmp_path / "results"
    results.mkdir()
    smoke = {"profile": "smoke", "records_source": "lowest_energy"}
    (results / "execution.json").write_text(json.dumps({**smoke, "rows": [
        {"setting": "Syn-Pl", "succ": 0.0, "n_poses": 20, "trials": 5}]}))
    (results / "ablation_execution.json").write_text(json.dumps({**smoke, "rows": [
        {"setting": "Ours", "succ": 0.0}, {"setting": "w/o RL", "succ": 0.0}, {"setting": "w/o Goal", "succ": None}]}))
    _write(results, "execution_generated.json", [{"setting": "Gen-Pl", "succ": 0.1, "n_poses": 10, "trials": 5}])
    report = write_report(tmp_path)
    text = report.markdown
    assert "| 0.0 % † (68.3 %) |" in text  # Table I, Syn-Pl
    assert "| 10.0 % (40.2 %) |" in text  # Gen-Pl: kept generated pre-grasps, unmarked
    assert "| Ours | 0.0 % † (68.3 %) |" in text and "| w/o RL | 0.0 % † (1.4 %) |" in text
    assert "| w/o Goal | – (16.8 %) |" in text  # not measured: nothing to mark
    assert text.count("`records_source = lowest_energy`") == 2 and "not a result" in text
    rows = {(r["table"], r["setting"], r["metric"]): r for r in csv.DictReader(report.csv_path.open())}
    assert "lowest_energy" in rows[("I", "Syn-Pl", "succ")]["note"]
    assert "lowest_energy" in rows[("II(b,c)", "w/o RL", "succ")]["note"]
    assert rows[("I", "Gen-Pl", "succ")]["note"] == "" and rows[("II(b,c)", "w/o Goal", "succ")]["note"] == ""
    # accepted pre-grasps (the bench profile): no mark, no note
    (results / "execution.json").write_text(json.dumps({"profile": "bench", "records_source": "accepted", "rows": [
        {"setting": "Syn-Pl", "succ": 0.346, "n_poses": 100, "trials": 5}]}))
    (results / "ablation_execution.json").unlink()
    text = write_report(tmp_path).markdown
    assert "| 34.6 % (68.3 %) |" in text and "†" not in text
    # the generalist's column: lifted from the smoke profile's candidates it is marked too, with the paper's 44.13 %
    (results / "execution_generalist.json").write_text(json.dumps({**smoke, "rows": [
        {"setting": "Syn-Pl", "succ": 0.0, "n_poses": 20, "trials": 5}]}))
    report = write_report(tmp_path)
    assert "| 34.6 % (68.3 %) | 0.0 % † (44.1 %) |" in report.markdown and "not a result" in report.markdown
    rows = {(r["table"], r["setting"], r["metric"]): r for r in csv.DictReader(report.csv_path.open())}
    assert rows[("I", "Syn-Pl", "succ_generalist")]["paper"] == "0.4413"
    assert "lowest_energy" in rows[("I", "Syn-Pl", "succ_generalist")]["note"]


def test_report_errors_are_one_line(tmp_path, capsys):
    assert main(["report", "--workdir", str(tmp_path / "nowhere")]) == 2
    assert "no results in" in capsys.readouterr().err
    (tmp_path / "results").mkdir()
    assert main(["report", "--workdir", str(tmp_path)]) == 2
    assert "no evaluation results" in capsys.readouterr().err
    (tmp_path / "results" / "execution.json").write_text("{truncated")
    assert main(["report", "--workdir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "execution.json is not readable JSON" in err and "multigrasp evaluate execution" in err
    assert "\n" not in err


def test_status_tells_current_evaluations_from_stale_ones(tmp_path, monkeypatch):
    """An evaluation is current while the stage output it was made from is this config's output now (compared by
    unit key, so a moved work dir stays current); another config's or an older output makes it stale."""
    import flows.pipeline
    from flows.config import evaluation_key, load_config
    from flows.report import evaluation_status

    cfg = load_config("smoke", workdir=tmp_path)
    now = {"synthesize": tmp_path / "stages" / "synthesize" / "aaaa", "specialists": tmp_path / "stages" / "specialists" / "bbbb"}

    class Out:
        def __init__(self, folder):
            self.folder = str(folder)

    monkeypatch.setattr(flows.pipeline, "stage_output",
                        lambda c, stage: Out(now[stage]) if stage in now else None)
    results = tmp_path / "results"
    results.mkdir()
    (results / "pregrasp_synthetic.json").write_text(json.dumps(
        {"rows": [], "profile": "smoke", "synthesize_manifest": "/elsewhere/stages/synthesize/aaaa/manifest.json",
         "config_key": evaluation_key(cfg, "pregrasp_synthetic.json")}))
    (results / "execution.json").write_text(json.dumps(
        {"rows": [], "profile": "bench", "specialists_manifest": str(tmp_path / "stages/specialists/cccc/manifest.json")}))
    (results / "execution_generated.json").write_text(json.dumps(
        {"rows": [], "profile": "smoke", "specialists_manifest": str(now["specialists"] / "manifest.json"),
         "generator_manifest": "x/manifest.json"}))
    states = {r.name: (r.state, r.detail) for r in evaluation_status(cfg)}
    assert states["pregrasp_synthetic.json"][0] == "current"  # a moved work dir: same key
    written = datetime.datetime.fromtimestamp((results / "pregrasp_synthetic.json").stat().st_mtime)
    assert states["pregrasp_synthetic.json"][1] == f"profile smoke, evaluated {written:%Y-%m-%d %H:%M}"  # when, too
    assert states["execution.json"][0] == "stale" and "multigrasp evaluate execution" in states["execution.json"][1]
    assert states["execution_generated.json"][0] == "stale" and "train-generator" in states["execution_generated.json"][1]
    assert states["pregrasp_generated.json"][0] == "missing"
    # made from this config's outputs, but under other settings (or before the settings were recorded)
    other = load_config("smoke", sets=["objects.surface_points=1024"], workdir=tmp_path)
    name = "pregrasp_synthetic.json"
    assert evaluation_key(other, name) != evaluation_key(cfg, name)
    moved = load_config("smoke", sets=["run.max_workers=1", "tracking.renders=false"], workdir=tmp_path / "moved")
    assert evaluation_key(moved, name) == evaluation_key(cfg, name)  # where and how it runs: the same figures
    lifted = load_config("smoke", sets=["specialists.eval_poses=7"], workdir=tmp_path)  # lift settings: lift rows
    assert evaluation_key(lifted, name) == evaluation_key(cfg, name)
    assert evaluation_key(lifted, "execution.json") != evaluation_key(cfg, "execution.json")
    state, detail = next((r.state, r.detail) for r in evaluation_status(other) if r.name == "pregrasp_synthetic.json")
    assert state == "stale" and "other settings" in detail
    (results / "pregrasp_generated.json").write_text(json.dumps(
        {"rows": [], "profile": "smoke", "generator_manifest": "x/manifest.json"}))
    now["train-generator"] = tmp_path / "x"
    state, detail = next((r.state, r.detail) for r in evaluation_status(cfg) if r.name == "pregrasp_generated.json")
    assert state == "unknown" and "no config key" in detail
    # an older evaluation's time per 256, scaled from smaller batches: stale, though made from the same outputs
    row = {"setting": "Gen-Com", "time_256_s": 130.0}
    for timed, expected in ((row, "stale"), ({**row, "time_batch": 256}, "current")):
        (results / "pregrasp_generated.json").write_text(json.dumps(
            {"rows": [timed], "profile": "smoke", "generator_manifest": "x/manifest.json",
             "config_key": evaluation_key(cfg, "pregrasp_generated.json")}))
        state, detail = next((r.state, r.detail) for r in evaluation_status(cfg) if r.name == "pregrasp_generated.json")
        assert state == expected and (expected == "current" or "batch of 256" in detail)
    del now["train-generator"]
    (results / "pregrasp_generated.json").unlink()
    # `multigrasp status` hands over the stage outputs it has verified: the same answer without verifying again
    monkeypatch.setattr(flows.pipeline, "stage_output", lambda c, stage: pytest.fail("verified a second time"))
    finals = {"synthesize": str(now["synthesize"]), "specialists": str(now["specialists"]), "train-generator": None}
    assert {r.name: (r.state, r.detail) for r in evaluation_status(cfg, finals)} == states


def test_evaluate_pregrasp_without_a_source_names_both(tmp_path, capsys):
    assert main(["evaluate", "pregrasp", "--workdir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--source synthetic" in err and "--source generated" in err and err.count("\n") == 1


def test_status_names_the_command_that_computes_what_is_not_current(tmp_path, capsys):
    """A command to paste into a shell: values with spaces quoted, and a list such as ``[duck]`` printed (rich took
    it for a markup tag and dropped it, so the command asked for another config)."""
    import shlex

    (tmp_path / "results").mkdir()
    sets = ["--set", "run.seed=3", "--set", "objects.ood=[duck]", "--set", "objects.train=[cube, sphere]"]
    assert main(["status", "--profile", "smoke", "--workdir", str(tmp_path), *sets]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert out.endswith("computes the Table I evaluations that are not current, then the report")
    command = out.split("`")[-2]
    assert shlex.split(command) == ["multigrasp", "run", "--evaluate", "--profile", "smoke", *sets,
                                    "--workdir", str(tmp_path)]


def test_run_evaluate_keeps_its_evaluations_when_another_results_file_is_unreadable(tmp_path, monkeypatch):
    """The report at the end of ``run --evaluate`` reads every results file: a corrupt one that no evaluation of
    this run rewrites (an ablation's) costs the report, with a line naming the fix, not the run."""
    import flows.evaluations
    from flows.config import load_config

    monkeypatch.setattr(flows.evaluations, "planned_evaluations", lambda ablations: [])
    monkeypatch.setattr(flows.evaluations, "pending_evaluations", lambda cfg, ablations, finals=None, planned=None: [])
    results = tmp_path / "results"
    _write(results, "execution.json", [{"setting": "Syn-Pl", "succ": 0.3, "n_poses": 2, "trials": 1}])
    (results / "ablation_execution.json").write_text("{truncated")
    said = []
    report, computed = flows.evaluations.run_evaluations(load_config("smoke", workdir=tmp_path), False, said.append)
    assert report is None and computed == 0
    assert "report not written" in said[-1] and "evaluate execution --ablations" in said[-1]


def test_run_evaluate_plans_the_ablations_only_when_asked_and_redoes_a_partial_ablation_file(tmp_path, monkeypatch):
    """``run --evaluate --ablations`` evaluates again an ``ablation_execution.json`` written without the ablation
    specialists (what ``evaluate execution`` alone writes), and ``run --evaluate`` does not ask for ablation files."""
    import flows.report
    from flows.config import load_config
    from flows.evaluations import pending_evaluations
    from flows.report import EvaluationStatus

    names = ("pregrasp_synthetic.json", "pregrasp_generated.json", "execution.json", "execution_generated.json",
             "ablation_generator.json", "ablation_execution.json", "execution_generalist.json",
             "ablation_curriculum.json")
    states = dict.fromkeys(names, ("current", True))

    def fake_status(cfg, finals=None):
        return [EvaluationStatus(name, state, "", ablations=full) for name, (state, full) in states.items()]

    monkeypatch.setattr(flows.report, "evaluation_status", fake_status)
    cfg = load_config("smoke", workdir=tmp_path)
    assert pending_evaluations(cfg, ablations=True) == [] and pending_evaluations(cfg, ablations=False) == []
    states["ablation_execution.json"] = ("current", False)  # Ours, w/o RL and the squeeze only
    assert pending_evaluations(cfg, ablations=False) == []
    (evaluation, why), = pending_evaluations(cfg, ablations=True)
    assert evaluation.label == "evaluate execution --ablations" and "without the ablation specialists" in why
    states["ablation_generator.json"] = ("missing", False)
    assert [e.label for e, _ in pending_evaluations(cfg, ablations=False)] == []
    assert [e.label for e, _ in pending_evaluations(cfg, ablations=True)] == [
        "evaluate pregrasp --source generated --ablations", "evaluate execution --ablations"]


def test_compare_puts_work_dirs_side_by_side_with_the_papers_figures(tmp_path, capsys):
    """`multigrasp compare A B`: a row per figure either has, a column per work dir, the paper's last; rates as
    percentages; a success lifted from unaccepted candidates marked †; --out writes the same table."""
    from flows.cli import main

    a, b = tmp_path / "friction05", tmp_path / "friction02"
    _write(a / "results", "pregrasp_synthetic.json", [{"setting": "Syn-Pl", "q1": 0.085, "pn_mm": 1.13,
                                                      "div_deg": 14.4, "accept_rate": 0.447, "n": 1144}])
    _write(a / "results", "execution.json", [{"setting": "Syn-Pl", "succ": 0.346, "n_poses": 100, "trials": 5}])
    _write(b / "results", "pregrasp_synthetic.json", [{"setting": "Syn-Pl", "q1": 0.122, "pn_mm": 1.34,
                                                      "div_deg": 15.0, "accept_rate": 0.156, "n": 400}], profile="mini")
    (b / "results" / "execution.json").write_text(json.dumps({
        "rows": [{"setting": "Syn-Pl", "succ": 0.498, "n_poses": 100, "trials": 5}], "profile": "smoke",
        "records_source": "lowest_energy"}))
    out = tmp_path / "compare.md"
    assert main(["compare", str(a), str(b), "--label", "mu 0.5", "--label", "mu 0.2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| table | setting | metric | mu 0.5 | mu 0.2 | paper |" in printed
    assert "| I | Syn-Pl | q1 | 0.085 | 0.122 | 0.3 |" in printed
    assert "| I | Syn-Pl | accept_rate | 44.7 % | 15.6 % | – |" in printed
    assert "| I | Syn-Pl | succ | 34.6 % | 49.8 % † | 68.3 % |" in printed
    assert "| I | Gen-Pl |" not in printed  # measured in neither
    assert f"mu 0.2 = `{b.resolve()}` (profile mini, smoke)" in printed
    assert out.read_text() in printed


def test_compare_names_a_work_dir_without_results_and_a_wrong_label_count(tmp_path, capsys):
    from flows.cli import main

    _write(tmp_path / "a" / "results", "execution.json", [{"setting": "Syn-Pl", "succ": 0.3}])
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"no results in {tmp_path / 'nothing'}" in err
    assert main(["compare", str(tmp_path / "a"), "--label", "x", "--label", "y"]) == 2
    assert "--label was given 2 time(s) for 1 work dir(s)" in capsys.readouterr().err


def test_commands_that_read_results_start_without_importing_the_pipeline(tmp_path):
    """`multigrasp report`, `compare`, `ui` and `--version` imported torch, Prefect and every stage's code before
    doing anything (the CLI built every stage command's handler eagerly; the report's table helper came from the
    evaluation module; the provenance tags imported torch for its version): 12-20 s on a slow day before a report
    that takes a few seconds, or before the MLflow UI started."""
    import subprocess
    import sys

    _write(tmp_path / "results", "execution.json", [{"setting": "Syn-Pl", "succ": 0.3, "n_poses": 4, "trials": 5}])
    script = (
        "import sys\n"
        "from flows.cli import main\n"
        f"workdir = {str(tmp_path)!r}\n"
        "for argv in (['report', '--workdir', workdir], ['compare', workdir, workdir], ['ui', '--workdir', workdir + '/none'],"
        " ['--version']):\n"
        "    try:\n"
        "        main(argv)\n"
        "    except SystemExit:\n"
        "        pass\n"
        "print('IMPORTED', sorted(m for m in ('torch', 'prefect', 'flows.pipeline') if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "IMPORTED []" in done.stdout, done.stdout[-2000:]
    assert (tmp_path / "results" / "report.md").is_file()
