"""``python -m benchmarks.q1_contacts``: Q1 of the same grasps under several contact caps."""

from __future__ import annotations

import json

import pyarrow.parquet as pq
import pytest

from benchmarks.q1_contacts import main
from tests.test_q1_conventions import held_sphere_table


def test_fewer_contacts_never_raise_q1(hand, tmp_path, capsys):
    path = tmp_path / "grasps.parquet"
    pq.write_table(held_sphere_table(hand), path)
    out = tmp_path / "q1.json"
    assert main(["--grasps", str(path), "--profile", "smoke", "--workdir", str(tmp_path / "run"),
                 "--set", "objects.train=[sphere]", "--set", "objects.ood=[]", "--counts", "32,6",
                 "--json", str(out)]) == 0
    rows = {row["contacts"]: row for row in json.loads(out.read_text())["rows"]}
    assert rows[32]["q1_mean"] > 0.0 and rows[32]["mean_abs_diff_from_reference"] == 0.0
    # the 6 farthest-point contacts are the first 6 of the 32: a sub-hull, so Q1 can only drop
    assert rows[6]["q1_mean"] <= rows[32]["q1_mean"] + 1e-12
    assert rows[6]["seconds_per_grasp"] >= 0.0 and "capped" in capsys.readouterr().out


def test_the_exact_solver_bounds_every_cap_from_above_whatever_its_start(hand, tmp_path):
    path = tmp_path / "grasps.parquet"
    pq.write_table(held_sphere_table(hand), path)
    out = tmp_path / "q1.json"
    assert main(["--grasps", str(path), "--profile", "smoke", "--workdir", str(tmp_path / "run"),
                 "--set", "objects.train=[sphere]", "--set", "objects.ood=[]", "--counts", "16,6",
                 "--exact-start", "6,16", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    rows = {(row["solver"], row["contacts"]): row for row in result["rows"]}
    assert result["reference"] == "exact"
    # the same exact value from either start; every capped value a lower bound of it
    assert rows["exact", 16]["q1_mean"] == pytest.approx(rows["exact", 6]["q1_mean"], abs=1e-9)
    assert rows["capped", 16]["q1_mean"] <= rows["exact", 6]["q1_mean"] + 1e-12


def test_bad_counts_are_one_line(tmp_path, capsys):
    assert main(["--counts", "16,zero", "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --counts") and "\n" not in err
