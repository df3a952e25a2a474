"""``python -m benchmarks.scripted_lift``: the "w/o RL" lift on a synthesize stage's grasps, per combination."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from benchmarks.scripted_lift import main

#: A sphere of the library (radius 2.5 cm) resting on the table, and an open hand 30 cm above it.
SPHERE_ON_TABLE = [0.0, 0.0, 0.025]


def hand_above_sphere_table(hand, accepted=(True, True, False)):
    n = len(accepted)
    q = hand.open_pose().double().numpy().tolist()
    return pa.table({
        "scene_id": ["s0"] * n, "split": ["train"] * n, "combination": ["sphere"] * n, "accepted": list(accepted),
        "row": list(range(n)), "object_names": [["sphere"]] * n, "object_positions": [SPHERE_ON_TABLE] * n,
        "object_quats_xyzw": [[0.0, 0.0, 0.0, 1.0]] * n,
        "p": [[0.0, 0.0, 0.3]] * n, "R": [np.eye(3).ravel().tolist()] * n, "q": [q] * n,
    })


def sphere_argv(path, tmp_path) -> list[str]:
    """Options that read the sphere table at ``path`` (written by :func:`hand_above_sphere_table`) in a smoke work
    dir whose library holds only the sphere."""
    return ["--grasps", str(path), "--profile", "smoke", "--workdir", str(tmp_path / "run"), "--split", "train",
            "--set", "objects.train=[sphere]", "--set", "objects.ood=[]"]


def test_a_hand_that_does_not_hold_the_object_lifts_nothing(hand, tmp_path, capsys):
    """The scripted force raises the hand; the sphere it touches with one link only (``benchmarks.lift_failures``
    finds that link a few mm deep) stays on the table: success 0, and the final lift (of the object, not the hand)
    is ~0.  The rejected row is not run."""
    path = tmp_path / "grasps.parquet"
    pq.write_table(hand_above_sphere_table(hand), path)
    out = tmp_path / "lift.json"
    assert main([*sphere_argv(path, tmp_path), "--trials", "2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    (row,) = result["rows"]
    assert row["combination"] == "sphere" and row["n_poses"] == 2 and row["trials"] == 2
    assert row["succ"] == 0.0 and result["succ_all"] == 0.0
    assert abs(row["median_final_lift_m"]) < 0.005 and abs(row["p90_final_lift_m"]) < 0.005
    captured = capsys.readouterr()
    assert "sphere" in captured.out
    assert "scripted lift: 1/2 poses" in captured.err and "scripted lift: 2/2 poses, elapsed" in captured.err
    assert result["controller"] == "straight" and result["force_fraction"] == 0.5
    assert result["closure_steps"] == 0  # the paper's w/o RL: from the pre-grasp itself, no grasp closure
    # the squeeze-and-lift closes a hand that holds nothing: still no success
    assert main([*sphere_argv(path, tmp_path), "--trials", "1", "--max-poses", "1", "--controller", "squeeze",
                 "--json", str(out)]) == 0
    squeezed = json.loads(out.read_text())
    assert squeezed["controller"] == "squeeze" and squeezed["squeeze_action"] == 0.0 and squeezed["succ_all"] == 0.0
    assert squeezed["closure_steps"] == 10  # the env's grasp closure first


def test_q1_bounds_select_grasps_and_an_empty_range_is_one_line(hand, tmp_path, capsys):
    table = hand_above_sphere_table(hand, accepted=(True, True, True))
    path = tmp_path / "grasps.parquet"
    pq.write_table(table.append_column("q1", pa.array([0.0, 0.25, 0.4])), path)
    out = tmp_path / "lift.json"
    base = [*sphere_argv(path, tmp_path), "--trials", "1", "--json", str(out)]
    assert main([*base, "--min-q1", "0.2", "--max-q1", "0.3"]) == 0
    result = json.loads(out.read_text())
    assert result["rows"][0]["n_poses"] == 1 and result["q1_mean"] == 0.25
    assert result["min_q1"] == 0.2 and result["max_q1"] == 0.3
    capsys.readouterr()
    assert main([*base, "--min-q1", "0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: no accepted grasps with Q1 in [0.5, inf]") and "\n" not in err
    pq.write_table(hand_above_sphere_table(hand), path)  # no q1 column
    assert main([*base, "--min-q1", "0.1"]) == 2
    assert "no q1 column" in capsys.readouterr().err


def test_bad_trials_and_missing_split_are_one_line(hand, tmp_path, capsys):
    assert main(["--trials", "0", "--json", str(tmp_path / "x.json")]) == 2
    assert capsys.readouterr().err.strip().startswith("error: --max-poses and --trials")
    path = tmp_path / "grasps.parquet"
    pq.write_table(hand_above_sphere_table(hand), path)
    assert main(["--grasps", str(path), "--profile", "smoke", "--workdir", str(tmp_path / "run"), "--split", "Geo",
                 "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: no accepted grasps of split Geo") and "\n" not in err


def test_n_objects_selects_scenes_by_object_count_and_a_bad_count_is_one_line(hand, tmp_path, capsys):
    """``--n-objects 1`` keeps the single-sphere scenes and drops an accepted two-object row (never simulated);
    ``--n-objects 3`` finds nothing: one line."""
    table = hand_above_sphere_table(hand).to_pylist()
    pair = dict(table[0], scene_id="s1", combination="sphere+sphere", object_names=["sphere", "sphere"],
                object_positions=[0.0, 0.0, 0.025, 0.1, 0.0, 0.025], object_quats_xyzw=[0.0, 0.0, 0.0, 1.0] * 2)
    path = tmp_path / "grasps.parquet"
    pq.write_table(pa.Table.from_pylist([*table, pair]), path)
    out = tmp_path / "lift.json"
    base = [*sphere_argv(path, tmp_path), "--trials", "1", "--max-poses", "1", "--json", str(out)]
    assert main([*base, "--n-objects", "1"]) == 0
    result = json.loads(out.read_text())
    assert result["n_objects"] == 1
    assert [(row["combination"], row["n_poses"]) for row in result["rows"]] == [("sphere", 1)]
    capsys.readouterr()
    assert main([*base, "--n-objects", "3"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: no accepted grasps of 3-object scenes") and "\n" not in err
    assert main([*base, "--n-objects", "0"]) == 2
    assert capsys.readouterr().err.strip() == "error: --n-objects must be at least 1 (2: the pairs)"
