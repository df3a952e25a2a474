"""benchmarks.controller_headroom: held-out per-pose selection among controller variants."""
import json

import numpy as np
import pytest

from benchmarks.controller_headroom import headroom, main


def _episodes(success):  # success[pose][trial] -> lift_failures-like episodes
    return {("a+b", p, t): float(s) for p, row in enumerate(success) for t, s in enumerate(row)}


def test_a_variant_that_always_lifts_some_poses_is_selected_and_its_gain_is_held_out():
    n_poses, n_trials = 40, 10
    ref = np.zeros((n_poses, n_trials))
    ref[:10] = 1.0                      # the reference lifts poses 0-9 always
    better = ref.copy()
    better[10:20] = 1.0                 # the variant also lifts poses 10-19
    out = headroom({"ref": _episodes(ref), "better": _episodes(better)})
    assert out["n_poses"] == n_poses and out["trials_per_pose"] == n_trials
    assert out["reference_success"] == pytest.approx(0.25)
    assert out["variants"]["better"]["minus_reference"] == pytest.approx(0.25)
    sel = out["selected_per_pose_held_out"]
    assert sel["success"] == pytest.approx(0.5) and sel["minus_reference"] == pytest.approx(0.25)
    assert out["best_fixed_held_out"]["chosen"] == ["better", "better"]
    assert out["in_sample_oracle"] == pytest.approx(0.5)
    assert out["ever_lifted_poses"] == pytest.approx(0.5)


def test_noise_variants_have_in_sample_but_no_held_out_headroom():
    rng = np.random.default_rng(0)
    n_poses, n_trials = 400, 10
    runs = {f"v{i}": _episodes(rng.random((n_poses, n_trials)) < 0.3) for i in range(5)}   # all alike: 30 %
    out = headroom(runs)
    sel = out["selected_per_pose_held_out"]
    assert abs(sel["minus_reference"]) < 3 * sel["minus_reference_se"] + 0.01
    assert out["in_sample_oracle"] > out["reference_success"] + 0.1     # picking the max of noise looks like a gain


def test_ties_keep_the_reference_and_cli_writes_json(tmp_path):
    ref = np.array([[1, 0, 1, 0]] * 3)
    same = ref.copy()
    paths = []
    for name, arr in (("ref", ref), ("same", same)):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps({"episodes": [{"combination": c, "pose": p, "trial": t, "success": bool(s)}
                                                 for (c, p, t), s in _episodes(arr).items()]}))
        paths.append(f"{name}={path}")
    out = main(paths + ["--json", str(tmp_path / "out.json")])
    assert out["selected_per_pose_held_out"]["times_chosen"] == {"ref": 6}
    assert json.loads((tmp_path / "out.json").read_text())["reference"] == "ref"
    with pytest.raises(SystemExit, match="at least two"):
        main(paths[:1])
    with pytest.raises(SystemExit, match="does not exist"):
        main(paths[:1] + [f"x={tmp_path / 'missing.json'}"])
    (tmp_path / "foreign.json").write_text(json.dumps({"rows": []}))
    with pytest.raises(SystemExit, match="not a lift_failures result"):
        main(paths[:1] + [f"x={tmp_path / 'foreign.json'}"])
