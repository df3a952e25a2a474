"""``python -m benchmarks.refine_effect``: Q1 / PN of synthesised grasps before and after the paper's refinement."""

from __future__ import annotations

import json

import pyarrow.parquet as pq

from benchmarks.refine_effect import main
from tests.test_q1_conventions import held_sphere_table


def test_measures_before_and_after_the_refinement(hand, tmp_path, capsys):
    path = tmp_path / "grasps.parquet"
    pq.write_table(held_sphere_table(hand), path)
    out = tmp_path / "refine.json"
    assert main(["--grasps", str(path), "--profile", "smoke", "--workdir", str(tmp_path / "run"),
                 "--set", "objects.train=[sphere]", "--set", "objects.ood=[]",
                 "--set", "generator.refine.steps=5", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["n"] == 2 and result["refine"]["steps"] == 5
    for tag in ("before", "after"):
        assert result[tag]["q1_mean"] >= 0.0 and result[tag]["pn_mm_mean"] >= 0.0
    assert result["before"]["q1_mean"] > 0.0  # the held sphere is in force closure before refinement
    assert "before" in capsys.readouterr().out


def test_bad_max_grasps_is_one_line(tmp_path, capsys):
    assert main(["--max-grasps", "0", "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: --max-grasps must be at least 1"
