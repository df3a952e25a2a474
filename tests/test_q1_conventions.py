"""``python -m benchmarks.q1_conventions``: the same grasps scored under several Q1 conventions."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from benchmarks.q1_conventions import CONVENTIONS, main

SPHERE_AT = [0.0, -0.035, 0.38]


def held_sphere_table(hand, accepted=(True, True, False)):
    """Grasps of a sphere by the curled fingers and the palm, in the columns of a synthesize grasps.parquet."""
    q = hand.open_pose().double().numpy().copy()
    q[[1, 2, 5, 6, 9, 10, 14, 15]] = 1.2
    n = len(accepted)
    return pa.table({
        "scene_id": ["s0"] * n, "split": ["Pl"] * n, "accepted": list(accepted),
        "object_names": [["sphere"]] * n, "object_positions": [SPHERE_AT] * n,
        "object_quats_xyzw": [[0.0, 0.0, 0.0, 1.0]] * n,
        "p": [[0.0, 0.0, 0.3]] * n, "R": [np.eye(3).ravel().tolist()] * n, "q": [q.tolist()] * n,
    })


def test_scores_every_convention(hand, tmp_path, capsys):
    path = tmp_path / "grasps.parquet"
    pq.write_table(held_sphere_table(hand), path)
    out = tmp_path / "q1.json"
    assert main(["--grasps", str(path), "--profile", "smoke", "--workdir", str(tmp_path / "run"),
                 "--set", "objects.train=[sphere]", "--set", "objects.ood=[]", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["n"] == 2  # the rejected row is not scored
    rows = {row["convention"]: row for row in result["conventions"]}
    assert set(rows) == set(CONVENTIONS)
    for row in rows.values():
        assert row["q1_mean"] > 0.0 and row["q1_positive"] == 1.0  # the held sphere is in force closure
    mine, mu1 = (rows[name] for name in list(CONVENTIONS)[:2])
    assert mu1["q1_mean"] > mine["q1_mean"]  # wider friction cones, larger hull
    assert mine["ideal_six_contact_sphere"] == pytest.approx(0.5 * np.sqrt(2.0 / 3.0), rel=1e-3)  # mu sqrt(2/3)
    assert "DexGraspNet" in capsys.readouterr().out


def test_missing_grasps_file_is_one_line(tmp_path, capsys):
    assert main(["--grasps", str(tmp_path / "nope.parquet"), "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --grasps") and "\n" not in err


def test_no_accepted_grasp_of_the_split_is_one_line(hand, tmp_path, capsys):
    path = tmp_path / "grasps.parquet"
    pq.write_table(held_sphere_table(hand), path)
    assert main(["--grasps", str(path), "--split", "Geo", "--workdir", str(tmp_path / "run"),
                 "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "no accepted grasps of split Geo" in err and "\n" not in err
