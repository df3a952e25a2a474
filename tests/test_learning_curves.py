"""benchmarks.learning_curves: the per-bin summary against a hand computation, both folder layouts, the figure,
and a one-line error for a folder without histories."""

import json

import pytest

from benchmarks.learning_curves import main, summarise


def _history(successes):
    return [{"iteration": i + 1, "frames": 4000 * (i + 1), "reward": 1.0, "success": s} for i, s in enumerate(successes)]


def test_summary_slope_and_validations():
    history = _history([0.1 + 0.01 * i for i in range(10)])  # +1 point per iteration, exactly linear
    validations = [{"iteration": 0, "success": 0.2}, {"iteration": 5, "success": 0.3}, {"iteration": 10, "success": 0.25}]
    s = summarise(history, validations)
    assert s["slope_points_per_iteration"] == pytest.approx(1.0)
    assert s["correlation"] == pytest.approx(1.0)
    assert s["sampled_first"] == pytest.approx(10.5) and s["sampled_last"] == pytest.approx(18.5)
    assert (s["validation_start"], s["validation_best"], s["best_iteration"], s["validation_last"]) == (20.0, 30.0, 5, 25.0)
    assert s["iterations"] == 10 and s["frames"] == 40000


def test_both_layouts_give_a_figure_and_a_summary(tmp_path):
    copied = tmp_path / "copied"
    copied.mkdir()
    (copied / "a_0.history.json").write_text(json.dumps(_history([0.2, 0.3, 0.25, 0.35])))
    (copied / "a_0.validations.json").write_text(json.dumps({"best": None, "rows": [{"iteration": 0, "success": 0.2}]}))
    stage = tmp_path / "stage"
    unit = stage / "bin-b"
    unit.mkdir(parents=True)
    (unit / "history.json").write_text(json.dumps(_history([0.5, 0.4, 0.45])))
    (stage / "index.json").write_text(json.dumps({"b/1": {"folder": str(unit)}}))
    single = tmp_path / "single"
    single.mkdir()
    (single / "history.json").write_text(json.dumps(_history([0.1, 0.2, 0.3])))
    out, summary = tmp_path / "curves.png", tmp_path / "summary.json"
    assert main([str(copied), str(stage), str(single), "--out", str(out), "--json", str(summary)]) == 0
    assert out.stat().st_size > 1000
    data = json.loads(summary.read_text())
    assert set(data) == {"copied: a_0", "stage: b/1", "single"}
    assert data["single"]["slope_points_per_iteration"] == pytest.approx(10.0)
    assert data["copied: a_0"]["validation_start"] == 20.0 and "validation_start" not in data["stage: b/1"]


def test_a_folder_without_histories_is_a_one_line_error(tmp_path, capsys):
    assert main([str(tmp_path), "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "index.json" in err and len(err.strip().splitlines()) == 1
