"""``python -m benchmarks.refilter``: a stage's candidates re-filtered from their stored terms, new rows scored."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from benchmarks.refilter import main
from tests.test_q1_conventions import held_sphere_table


def _shard(hand, folder):
    """Three candidates of the held sphere (in force closure): accepted; rejected by one contact 9 mm off while
    its mean is 3 mm (the every-contact rule rejects it, the official mean rule does not); rejected by fc."""
    table = held_sphere_table(hand, accepted=(True, False, False)).to_pandas()
    table["combination"] = "sphere"
    table["reason"] = ["accepted", "contact_distance", "fc"]
    table["q1"] = [0.25, np.nan, np.nan]
    table["pn_mm"] = [1.0, np.nan, np.nan]
    table["term_fc_per_object"] = [[0.1], [0.1], [0.6]]
    table["term_contact_distance_max"] = [0.002, 0.009, 0.002]
    table["term_contact_distance_per_object"] = [[0.001], [0.003], [0.001]]
    table["term_penetration_depth_max"] = [0.001, 0.001, 0.001]
    table["term_prior"] = [0.0, 0.0, 0.0]
    folder.mkdir(parents=True)
    pq.write_table(pa.Table.from_pandas(table, preserve_index=False), folder / "grasps.parquet")


def test_the_mean_rule_accepts_the_row_one_contact_kept_out_and_scores_it(hand, tmp_path, capsys):
    stage = tmp_path / "stages" / "synthesize"
    _shard(hand, stage / "shard")
    common = ["--stage-dir", str(stage), "--profile", "smoke", "--workdir", str(tmp_path)]
    out = tmp_path / "mean.json"
    assert main(common + ["--filter", "filter_contact_distance_reduce=mean", "--json", str(out)]) == 0
    group = json.loads(out.read_text())["groups"]["singles"]
    assert group["stored"]["accepted"] == 1 and group["refiltered"]["accepted"] == 2
    assert group["newly_accepted"]["accepted"] == 1 and group["newly_rejected"] == 0
    assert group["refiltered"]["reasons"] == {"fc": 1}
    # the newly accepted row is scored with the stage's metrics: the held sphere is in force closure
    assert group["refiltered"]["q1_positive"] == 1.0 and group["refiltered"]["q1"] != group["stored"]["q1"]
    assert group["newly_accepted"]["q1"] > 0.0 and group["newly_accepted"]["pn_mm"] is not None
    assert "refiltered 2/3" in capsys.readouterr().out
    # the stricter rule reproduces what the stage stored
    strict = tmp_path / "max.json"
    assert main(common + ["--filter", "filter_contact_distance_reduce=max", "--json", str(strict)]) == 0
    group = json.loads(strict.read_text())["groups"]["singles"]
    assert group["refiltered"] == group["stored"] and group["newly_accepted"]["accepted"] == 0


def test_too_many_rows_to_score_is_one_line(hand, tmp_path, capsys):
    stage = tmp_path / "stages" / "synthesize"
    _shard(hand, stage / "shard")
    assert main(["--stage-dir", str(stage), "--profile", "smoke", "--workdir", str(tmp_path), "--max-new", "0",
                 "--filter", "filter_contact_distance_reduce=mean", "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: the new filter accepts 1 rows") and "--max-new" in err and "\n" not in err


def test_no_stage_for_the_config_is_one_line(tmp_path, capsys):
    assert main(["--profile", "smoke", "--workdir", str(tmp_path), "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: no synthesize stage output") and "--stage-dir" in err and "\n" not in err


def test_min_q1_of_the_config_rejects_as_the_stage_does(hand, tmp_path):
    """A Q1 bound no grasp meets rejects the stored accepted row and the row the mean rule brings back (reason q1)."""
    stage = tmp_path / "stages" / "synthesize"
    _shard(hand, stage / "shard")
    out = tmp_path / "q1.json"
    assert main(["--stage-dir", str(stage), "--profile", "smoke", "--workdir", str(tmp_path),
                 "--set", "synthesis.min_q1=0.99", "--filter", "filter_contact_distance_reduce=mean",
                 "--json", str(out)]) == 0
    group = json.loads(out.read_text())["groups"]["singles"]
    assert group["refiltered"]["accepted"] == 0 and group["refiltered"]["reasons"] == {"fc": 1, "q1": 2}
    assert group["newly_rejected"] == 1
