"""``python -m benchmarks.lift_failures``: what the hand touches at the pre-grasp, after the closure, at the end."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from benchmarks.lift_failures import (by_contact_finger, by_q1_threshold, chosen_fingers, main, opposition,
                                      summarise)
from tests.test_scripted_lift import hand_above_sphere_table, sphere_argv


@pytest.mark.parametrize("normals, expected", [
    ([[0, 0, 1], [0, 0, -1]], 1.0),  # a pinch across the object
    ([[1, 0, 0], [0, 1, 0]], 0.0),  # perpendicular contacts
    ([[1, 0, 0], [-0.5, np.sqrt(3) / 2, 0], [-0.5, -np.sqrt(3) / 2, 0]], 0.5),  # three contacts 120 degrees apart
    ([[1, 0, 0], [1, 0, 0]], -1.0),  # two contacts on the same side
    ([[0, 0, 1]], -1.0),  # one contact
    (np.zeros((0, 3)), -1.0),  # none
])
def test_opposition_of_contact_normals(normals, expected):
    assert opposition(np.asarray(normals, dtype=float)) == pytest.approx(expected)


def _object(pose, opposed_before, opposed_after, lifted, force=1.0):
    return {"combination": "a+b", "pose": pose, "trial": 0, "lifted": lifted, "closure_moved_mm": 2.0,
            "pregrasp": {"links": 2, "opposition": 0.9 if opposed_before else -1.0},
            "after_closure": {"links": 2, "opposition": 0.9 if opposed_after else -1.0, "normal_force_n": force}}


def test_summary_splits_the_lift_rate_by_opposition_at_the_pregrasp():
    """Pose 0: both objects opposed, both lift (success); pose 1: one opposed and lifted, the other neither."""
    episodes = [{"combination": "a+b", "pose": 0, "trial": 0, "success": True, "objects_lifted": 2, "n_objects": 2},
                {"combination": "a+b", "pose": 1, "trial": 0, "success": False, "objects_lifted": 1, "n_objects": 2}]
    objects = [_object(0, True, True, True), _object(0, True, True, True),
               _object(1, True, False, True), _object(1, False, False, False, force=0.0)]
    s = summarise(episodes, objects, 0.5)
    assert s["outcome"] == {"all_lifted": 1, "some_lifted": 1, "none_lifted": 0} and s["success"] == 0.5
    assert s["pregrasp_opposed"] == 0.75 and s["lifted_if_pregrasp_opposed"] == 1.0
    assert s["lifted_if_not_pregrasp_opposed"] == 0.0
    assert s["episodes_every_object_opposed"] == 0.5 and s["success_if_every_object_opposed"] == 1.0
    assert s["success_otherwise"] == 0.0 and s["after_closure_opposed"] == 0.5
    assert s["episodes_every_object_opposed_after_closure"] == 0.5
    assert s["success_if_every_object_opposed_after_closure"] == 1.0
    assert s["after_closure_no_contact"] == 0.25 and s["closure_moved_mm_median"] == 2.0


def test_chosen_fingers_and_the_lift_rates_by_contact_finger():
    names = ["palm", "palm_hypothenar", "ff_distal", "mf_distal", "th_distal"]
    row = {"object_names": ["a", "b"], "contact_regions": [0, 2, 4, 1, 2, 3]}
    assert chosen_fingers(row, names) == [["ff", "palm", "th"], ["ff", "mf", "palm"]]
    assert chosen_fingers({"object_names": ["a"]}, names) is None
    # episode 0: object 0 (th) lifts, object 1 (no th) does not; episode 1: neither uses th, both lift
    episodes = [{"combination": "a+b", "pose": 0, "trial": 0, "success": False, "objects_lifted": 1, "n_objects": 2},
                {"combination": "a+b", "pose": 1, "trial": 0, "success": True, "objects_lifted": 2, "n_objects": 2}]
    objects = [{**_object(0, True, True, True), "contact_fingers": ["ff", "th"]},
               {**_object(0, True, True, False), "contact_fingers": ["ff", "mf"]},
               {**_object(1, True, True, True), "contact_fingers": ["ff", "palm"]},
               {**_object(1, True, True, True), "contact_fingers": ["mf", "palm"]}]
    rates = by_contact_finger(episodes, objects)
    assert set(rates) == {"ff", "mf", "palm", "th"}
    assert rates["th"] == {"objects_with": 1, "lifted_with": 1.0, "lifted_without": 0.6667, "episodes_with": 1,
                           "success_with": 0.0, "success_without": 1.0}
    assert rates["palm"]["objects_with"] == 2 and rates["palm"]["lifted_without"] == 0.5
    assert rates["ff"]["lifted_without"] == 1.0 and rates["ff"]["success_without"] is None
    assert summarise(episodes, objects, 0.5)["by_contact_finger"] == rates
    assert by_contact_finger(episodes, [_object(0, True, True, True)]) == {}  # tables without contact_regions


def test_a_one_sided_touch_is_not_opposed_and_lifts_nothing(hand, tmp_path, capsys):
    """The open hand of ``hand_above_sphere_table`` touches the sphere with one link only (a few mm deep): the
    sphere is not opposed at the pre-grasp (opposition -1), the closure presses that one link (the physics ran, so
    contact forces are read) and moves the sphere by at most a few mm, and nothing lifts."""
    path = tmp_path / "grasps.parquet"
    pq.write_table(hand_above_sphere_table(hand), path)
    out = tmp_path / "failures.json"
    assert main([*sphere_argv(path, tmp_path), "--trials", "2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["controller"] == "squeeze" and result["near_mm"] == 5.0 and result["closure_steps"] > 0
    s = result["summary"]
    assert s["episodes"] == 4 and s["objects"] == 4 and s["success"] == 0.0
    assert s["outcome"]["none_lifted"] == 4 and s["objects_lifted"] == 0.0 and s["pregrasp_opposed"] == 0.0
    assert s["lifted_if_pregrasp_opposed"] is None and s["lifted_if_not_pregrasp_opposed"] == 0.0
    for record in result["objects"]:
        assert record["object"] == "sphere" and not record["lifted"] and abs(record["final_lift_m"]) < 0.005
        assert record["pregrasp"]["links"] == 1 and record["pregrasp"]["opposition"] == -1.0
        assert record["after_closure"]["opposition"] == -1.0 and "normal_force_n" in record["after_closure"]
        assert record["closure_moved_mm"] < 5.0
    captured = capsys.readouterr()
    assert "pregrasp_opposed" in captured.out
    assert "lift failures: 1/2 poses" in captured.err and "lift failures: 2/2 poses" in captured.err
    assert s["by_contact_finger"] == {}  # the table has no contact_regions column
    # the straight lift has no closure: no physics before the first observation, no contact forces read
    assert main([*sphere_argv(path, tmp_path), "--trials", "1", "--max-poses", "1", "--controller", "straight",
                 "--json", str(out)]) == 0
    straight = json.loads(out.read_text())
    assert straight["closure_steps"] == 0 and straight["summary"]["after_closure_no_contact"] is None
    assert all(r["closure_moved_mm"] == 0.0 for r in straight["objects"])


def test_bad_options_are_one_line(tmp_path, capsys):
    assert main(["--near-mm", "0", "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --near-mm must be positive") and "\n" not in err
    assert main(["--trials", "0", "--json", str(tmp_path / "x.json")]) == 2
    assert capsys.readouterr().err.strip().startswith("error: --max-poses and --trials")


def test_pose_progress_prints_the_first_pose_then_every_interval_and_the_last_with_an_eta():
    """``PoseProgress`` (both lift tools): the first and the last pose always print; in between, a pose prints only
    when ``every_s`` has passed since the last line; the ETA is the mean time per pose times the poses left."""
    import io

    from benchmarks.grasp_tables import PoseProgress

    times = iter([0.0, 10.0, 20.0, 45.0, 50.0, 60.0])  # start, then after each of the 5 poses
    stream = io.StringIO()
    progress = PoseProgress("lift", 5, every_s=30.0, stream=stream, clock=lambda: next(times))
    for _ in range(5):
        progress.done()
    assert stream.getvalue().splitlines() == [
        "lift: 1/5 poses, elapsed 10s, ETA 40s",  # the first pose
        "lift: 3/5 poses, elapsed 45s, ETA 30s",  # 35 s after the last line
        "lift: 5/5 poses, elapsed 60s",  # the last pose, no ETA
    ]


def test_by_q1_threshold_keeps_the_poses_at_or_above_each_threshold():
    """Pose 0 (Q1 0.1) lifts in 1 of 2 trials, pose 1 (Q1 0.3) in 2 of 2: at 0 both poses count (3 of 4), at 0.1
    still both, at 0.2 only pose 1 (2 of 2), at 0.5 none (no rate).  No stored Q1: no rows."""
    episodes = [{"combination": "a+b", "pose": p, "trial": t, "success": s}
                for p, t, s in ((0, 0, True), (0, 1, False), (1, 0, True), (1, 1, True))]
    objects = [{"combination": "a+b", "pose": p, "trial": t, "q1": q} for p, q in ((0, 0.1), (1, 0.3)) for t in (0, 1)]
    rows = by_q1_threshold(episodes, objects, [0.0, 0.1, 0.2, 0.5])
    assert [(r["min_q1"], r["poses"], r["episodes"], r["success"]) for r in rows] == [
        (0.0, 2, 4, 0.75), (0.1, 2, 4, 0.75), (0.2, 1, 2, 1.0), (0.5, 0, 0, None)]
    assert by_q1_threshold(episodes, [dict(o, q1=None) for o in objects], [0.0]) == []


def test_contacts_opposition_of_points_on_a_sphere(library):
    """The objects' normals at the chosen contacts: a pinch across the sphere's equator is opposed (1), three
    contacts within a quarter turn are not (0: the widest pair is 90 degrees apart)."""
    import torch

    from benchmarks.lift_failures import contacts_opposition
    from components.objects import Placement, Scene
    from components.synthesis import SceneObjects

    centre, radius = np.array([0.01, -0.02, 0.025]), 0.025
    objects = SceneObjects(library, Scene(objects=(Placement("sphere", tuple(centre), (0.0, 0.0, 0.0, 1.0)),)),
                           dtype=torch.float64)

    def ring(degrees):  # (1, C, 3) points on the equator
        a = np.radians(degrees)
        return (centre + radius * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1))[None]

    points = np.stack([ring([0.0, 90.0, 180.0]), ring([0.0, 45.0, 90.0])])  # (B 2, n_obj 1, C 3, 3)
    np.testing.assert_allclose(contacts_opposition(objects, points), [[1.0], [0.0]], atol=1e-3)


def test_chosen_contact_opposition_reads_the_tables_contacts(hand, library):
    import torch

    from benchmarks.lift_failures import chosen_contact_opposition, contacts_opposition
    from components.objects import Scene
    from components.synthesis import SceneObjects

    frame = hand_above_sphere_table(hand).to_pandas()
    assert chosen_contact_opposition(frame, hand, library) is None  # no contacts column
    frame["contacts"] = [np.array([0, 50, 100]), np.array([3, 60, 120]), np.array([0, 50, 100])]
    row = frame.iloc[1]
    points, _ = hand.contact_candidates_and_normals(
        torch.tensor(np.array(row["p"]), dtype=hand.dtype).reshape(1, 3),
        torch.tensor(np.array(row["R"]), dtype=hand.dtype).reshape(1, 3, 3),
        torch.tensor(np.array(row["q"]), dtype=hand.dtype).reshape(1, -1))
    objects = SceneObjects(library, Scene.from_arrays(row["object_names"], row["object_positions"],
                                                      row["object_quats_xyzw"]), hand.device, hand.dtype)
    expected = contacts_opposition(objects, points[:, [3, 60, 120]].double().numpy()[:, None])  # (1, 1)
    result = chosen_contact_opposition(frame, hand, library)
    assert result.shape == (3, 1)
    np.testing.assert_array_equal(result[1], expected[0])
    np.testing.assert_array_equal(result[0], result[2])  # same pose and contacts
    assert np.all((-1.0 <= result) & (result <= 1.0))


def test_summary_splits_the_success_by_the_chosen_contacts_opposition():
    """Pose 0: both objects' chosen contacts opposed, success; pose 1: one of them not, failure; a table without
    the column gives no such keys."""
    episodes = [{"combination": "a+b", "pose": 0, "trial": 0, "success": True, "objects_lifted": 2, "n_objects": 2},
                {"combination": "a+b", "pose": 1, "trial": 0, "success": False, "objects_lifted": 0, "n_objects": 2}]
    objects = [{**_object(0, True, True, True), "contact_opposition": 0.9},
               {**_object(0, True, True, True), "contact_opposition": 0.6},
               {**_object(1, True, True, False), "contact_opposition": 0.9},
               {**_object(1, True, True, False), "contact_opposition": 0.2}]
    s = summarise(episodes, objects, 0.5)
    assert s["episodes_every_object_contacts_opposed"] == 0.5
    assert s["success_if_every_object_contacts_opposed"] == 1.0
    assert s["success_if_not_every_object_contacts_opposed"] == 0.0
    plain = summarise(episodes, [_object(0, True, True, True)] * 2 + [_object(1, True, True, False)] * 2, 0.5)
    assert "episodes_every_object_contacts_opposed" not in plain
