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
    for row in rows.values():  # one object: its own Q1 is the grasp's
        assert row["q1_object_mean"] == pytest.approx(row["q1_mean"], abs=1e-4)


def test_the_object_mean_counts_an_untouched_object_as_zero(hand, tmp_path):
    """A second object far from the hand has Q1 0: the grasp's Q1 (min over objects) is 0 and the mean over objects
    half the held sphere's."""
    table = held_sphere_table(hand, accepted=(True,))
    single = tmp_path / "single.parquet"
    pq.write_table(table, single)
    pair = tmp_path / "pair.parquet"
    pq.write_table(table.set_column(table.schema.get_field_index("object_names"), "object_names",
                                    pa.array([["sphere", "cube"]]))
                   .set_column(table.schema.get_field_index("object_positions"), "object_positions",
                               pa.array([SPHERE_AT + [0.4, 0.4, 0.03]]))
                   .set_column(table.schema.get_field_index("object_quats_xyzw"), "object_quats_xyzw",
                               pa.array([[0.0, 0.0, 0.0, 1.0] * 2])), pair)
    rows = {}
    for name, path in (("single", single), ("pair", pair)):
        out = tmp_path / f"{name}.json"
        assert main(["--grasps", str(path), "--profile", "smoke", "--workdir", str(tmp_path / "run"),
                     "--set", "objects.train=[sphere,cube]", "--set", "objects.ood=[]", "--json", str(out)]) == 0
        rows[name] = json.loads(out.read_text())["conventions"][0]
    assert rows["single"]["q1_mean"] > 0.0
    assert rows["pair"]["q1_mean"] == 0.0 and rows["pair"]["q1_positive"] == 0.0
    assert rows["pair"]["q1_object_mean"] == pytest.approx(rows["single"]["q1_mean"] / 2.0, rel=1e-6)


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
