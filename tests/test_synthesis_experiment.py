"""``python -m benchmarks.synthesis_experiment``: one seeded synthesis experiment appended as a JSON line."""

from __future__ import annotations

import json

from benchmarks.synthesis_experiment import main


def test_experiment_appends_a_json_line(tmp_path, capsys):
    out = tmp_path / "runs.jsonl"
    args = ["--objects", "cube,cylinder", "--seed", "3", "--threads", "1", "--json", str(out),
            "--set", "batch_size=4", "--set", "approach_steps=2", "--set", "mala_steps=3", "--set", "refine_steps=2"]
    assert main(args) == 0 and main(args) == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(lines) == 2 and lines[0]["reasons"] == lines[1]["reasons"]  # seeded: the same run twice
    row = lines[0]
    assert row["batch"] == 4 and row["objects"] == ["cube", "cylinder"] and sum(row["reasons"].values()) == 4
    assert len(row["contact_distance_max_mm"]) == len(row["quantiles"])
    assert {"q1", "pn_mm", "div_deg", "accept_rate", "seconds"} <= set(row)


def test_bad_override_is_one_line(tmp_path, capsys):
    assert main(["--set", "mala_steps=-1", "--json", str(tmp_path / "x.jsonl")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: bad value for 'synthesis.optimizer.mala_steps'") and "\n" not in err


def test_the_experiment_uses_the_stage_setting_for_its_object_count_and_set_fields_win():
    from benchmarks.synthesis_experiment import effective_optimizer
    from flows.config import load_config

    sets = ["batch_size=16", "w_fc=7"]
    synthesis = load_config("bench", sets=[f"synthesis.optimizer.{item}" for item in sets]).synthesis
    pair, four = effective_optimizer(synthesis, 2, sets), effective_optimizer(synthesis, 4, sets)
    assert pair.contacts_per_object == 3 and four.contacts_per_object == 2  # bench: 2 contacts per object for four
    assert four.w_pen == synthesis.optimizer_by_object_count[4]["w_pen"] != pair.w_pen
    assert pair.w_fc == four.w_fc == 7 and pair.batch_size == four.batch_size == 16


def test_sibling_spread_measures_copies_against_other_chains_in_joints_and_palm():
    import math
    from types import SimpleNamespace

    import torch

    from benchmarks.synthesis_experiment import sibling_spread

    q = torch.zeros(4, 22)
    q[1] += math.radians(2.0)  # a copy of row 0, 2 degrees off
    q[2] += math.radians(20.0)  # another chain
    p = torch.tensor([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.0, 0.0]])
    result = SimpleNamespace(accepted=torch.tensor([True, True, True, False]), q=q, p=p,
                             lineage=torch.tensor([0, 0, 2, 0]))
    out = sibling_spread(result)  # row 3 is not accepted, so only (0, 1) are siblings
    assert out["siblings_joint_diff_deg_median"] == 2.0 and out["siblings_palm_mm_median"] == 1.0
    assert out["others_joint_diff_deg_median"] == 19.0 and out["others_palm_mm_median"] == 49.5
