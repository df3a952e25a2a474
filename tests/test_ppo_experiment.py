"""``python -m benchmarks.ppo_experiment``: deterministic lift success of a PPO policy before and after training."""

from __future__ import annotations

import json

from benchmarks.ppo_experiment import curve_blocks, main
from components.execution import GraspRecord
from components.execution.cameras import CameraConfig, preview_hand_pose
from components.execution.pointnet import PointNetConfig, PointNetEncoder, save_encoder
from components.execution.records import save_records
from components.objects import Placement, Scene

IDENTITY = (0.0, 0.0, 0.0, 1.0)
TINY = ["specialists.ppo.frames_per_batch=40", "specialists.ppo.minibatch_size=20", "specialists.ppo.epochs=1",
        "specialists.ppo.hidden=[16]", "specialists.ppo.workers=1", "lift.max_steps=20",
        "objects.train=[cube,cylinder,sphere]", "objects.ood=[]"]


def test_trains_and_counts_deterministic_successes_before_and_after(hand, library, tmp_path, capsys):
    """An open hand above a sphere lifts nothing before or after one tiny PPO iteration; the JSON says so, with the
    curve and the history, and the checkpoint is kept where --checkpoint says."""
    unit = tmp_path / "unit"
    scene = Scene(objects=(Placement("sphere", (0.0, 0.0, 0.025), IDENTITY),))
    p, R, q = preview_hand_pose(hand, scene, CameraConfig(), library)
    records = save_records(unit / "records.json", [GraspRecord(scene, p, R, q.astype(float))] * 2)
    cfg = PointNetConfig()
    save_encoder(tmp_path / "encoder.pt", PointNetEncoder(cfg), cfg)
    out = tmp_path / "ppo.json"
    argv = ["--records", str(records), "--encoder", str(tmp_path / "encoder.pt"), "--profile", "smoke",
            "--workdir", str(library.cache_dir.parent), "--iterations", "1", "--eval-stride", "1",
            "--checkpoint", str(tmp_path / "policy.pt"), "--json", str(out)]
    for item in TINY:
        argv += ["--set", item]
    assert main(argv) == 0
    result = json.loads(out.read_text())
    assert result["before"] == {"wins": 0, "poses": 2} and result["after"] == {"wins": 0, "poses": 2}
    assert result["init_policy"] == "squeeze_lift" and result["frames"] == 40 and len(result["history"]) == 1
    assert result["curve"][0]["iterations"] == "1-1"
    assert (tmp_path / "policy.pt").is_file()
    assert "deterministic success 0/2 before -> 0/2 after" in capsys.readouterr().out


def test_missing_files_and_bad_arguments_are_one_line(tmp_path, capsys):
    assert main(["--records", "x", "--encoder", "y", "--iterations", "0", "--json", str(tmp_path / "o.json")]) == 2
    assert capsys.readouterr().err.strip().startswith("error: --iterations and --eval-stride")
    assert main(["--records", str(tmp_path / "records.json"), "--encoder", "y", "--profile", "smoke",
                 "--workdir", str(tmp_path), "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --records:") and "not found" in err and "\n" not in err


def test_curve_blocks_average_ten_iterations():
    history = [{"iteration": i, "frames": 10 * i, "success": float(i > 12), "reward": 1.0, "final_lift": 0.1}
               for i in range(1, 16)]
    history[10] = {"iteration": 11, "frames": 110, "reward": 1.0}  # no episode ended in iteration 11
    blocks = curve_blocks(history)
    assert [b["iterations"] for b in blocks] == ["1-10", "11-15"]
    assert blocks[0]["success"] == 0.0 and blocks[1]["success"] == 0.75 and blocks[1]["frames"] == 150
    assert curve_blocks([{"iteration": 1, "frames": 5, "reward": 0.0}])[0]["success"] is None
