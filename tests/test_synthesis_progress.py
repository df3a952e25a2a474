"""``python -m benchmarks.synthesis_progress``: a synthesize stage's shard tables summarised, merge skipped."""

from __future__ import annotations

import json

import pandas as pd

from benchmarks.synthesis_progress import main


def _shard(folder, combination, accepted, reasons, q1):
    folder.mkdir(parents=True)
    rows = [{"combination": combination, "accepted": a, "reason": r, "q1": q, "pn_mm": 1.0 if a else float("nan"),
             "q": [0.1 * i] * 22} for i, (a, r, q) in enumerate(zip(accepted, reasons, q1))]
    pd.DataFrame(rows).to_parquet(folder / "grasps.parquet")


def test_summarises_shards_and_skips_the_merge(tmp_path, capsys):
    stage = tmp_path / "synthesize"
    _shard(stage / "a", "cube", [True, True, False], ["accepted", "accepted", "fc"], [0.2, 0.0, float("nan")])
    _shard(stage / "b", "cube+sphere", [True, False, False, False], ["accepted", "fc", "fc", "penetration"],
           [0.1, float("nan"), float("nan"), float("nan")])
    _shard(stage / "merge", "cube", [True] * 5, ["accepted"] * 5, [0.9] * 5)  # the merge: repeats accepted rows
    (stage / "merge" / "rejected.parquet").write_bytes(b"")
    out = tmp_path / "p.json"
    assert main(["--stage-dir", str(stage), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["shards"] == 2
    singles, pairs = result["groups"]["singles"], result["groups"]["pairs"]
    assert (singles["accepted"], singles["candidates"], singles["q1"], singles["q1_positive"]) == (2, 3, 0.1, 0.5)
    assert singles["div_deg"] > 0.0 and singles["reasons"] == {"fc": 1}
    assert (pairs["accepted"], pairs["candidates"], pairs["reasons"]) == (1, 4, {"fc": 2, "penetration": 1})
    assert "cube+sphere" in capsys.readouterr().out


def test_empty_stage_dir_is_one_line(tmp_path, capsys):
    assert main(["--stage-dir", str(tmp_path), "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: no shard tables") and "\n" not in err


def test_split_filter_and_newest_table_per_candidate(tmp_path):
    import os

    stage = tmp_path / "synthesize"
    for name, split, accepted in (("old", "Pl", False), ("new", "Pl", True), ("t", "train", True)):
        folder = stage / name
        folder.mkdir(parents=True)
        rows = [{"combination": "cube+sphere", "accepted": accepted, "reason": "accepted" if accepted else "fc",
                 "q1": 0.1 if accepted else float("nan"), "pn_mm": 1.0, "q": [0.1 * i] * 22, "split": split,
                 "scene_id": f"{split}/cube+sphere/0", "row": i} for i in range(2)]
        pd.DataFrame(rows).to_parquet(folder / "grasps.parquet")
    os.utime(stage / "old" / "grasps.parquet", (1, 1))  # an earlier run's shard of the same scene
    out = tmp_path / "p.json"
    assert main(["--stage-dir", str(stage), "--json", str(out), "--split", "Pl"]) == 0
    result = json.loads(out.read_text())
    assert result["superseded_rows"] == 2 and result["splits"] == ["Pl"]
    assert (result["groups"]["pairs"]["accepted"], result["groups"]["pairs"]["candidates"]) == (2, 2)
    assert main(["--stage-dir", str(stage), "--json", str(out)]) == 0
    assert json.loads(out.read_text())["groups"]["pairs"]["candidates"] == 4


def test_sibling_spread_separates_copies_of_one_chain_from_other_chains():
    import numpy as np
    import pandas as pd

    from benchmarks.synthesis_progress import quality_summary

    q = [np.zeros(22), np.full(22, np.radians(1.0)), np.full(22, np.radians(10.0)), np.zeros(22)]
    frame = pd.DataFrame({"combination": ["a+b"] * 4, "accepted": [True] * 4, "reason": ["accepted"] * 4,
                          "q1": [0.1] * 4, "pn_mm": [1.0] * 4, "q": q, "scene_id": ["s0", "s0", "s0", "s1"],
                          "lineage": [3, 3, 5, 3]})
    out = quality_summary(frame)
    # scene s0: rows 0 and 1 share lineage 3 (1 degree apart); row 2 is another chain (10 and 9 degrees away);
    # row 3 is alone in its scene, so lineage 3 there is another chain
    assert out["lineages"] == 3 and out["sibling_pairs"] == 1
    assert out["siblings_joint_diff_deg_median"] == 1.0 and out["others_joint_diff_deg_median"] == 9.5
