"""benchmarks.paired_execution: the paired difference and its standard error against a hand computation, and clear
errors for a missing file or mismatched trials."""

import json
import math

from benchmarks.paired_execution import main


def _write(path, trials, rows):
    path.write_text(json.dumps({"trials": trials, "poses": rows}))
    return path


def test_paired_difference_and_standard_error_over_poses(tmp_path, capsys):
    a = _write(tmp_path / "a.json", 5, [{"pose_key": k, "policy": s, "squeeze": q}
                                        for k, s, q in ((1, 0, 0), (2, 5, 4), (3, 2, 1), (4, 1, 1))])
    b = _write(tmp_path / "b.json", 5, [{"pose_key": k, "policy": s} for k, s in ((1, 1), (2, 5), (3, 4), (4, 1), (9, 5))])
    out = tmp_path / "r.json"
    assert main([str(a), str(b), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    d = [0.2, 0.0, 0.4, 0.0]  # pose 9 is only in B: left out
    mean = sum(d) / 4
    se = math.sqrt(sum((x - mean) ** 2 for x in d) / 3 / 4)
    assert result["poses"] == 4 and result["difference"] == round(mean, 4)
    assert result["standard_error"] == round(se, 4)
    assert (result["poses_higher"], result["poses_level"], result["poses_lower"]) == (2, 2, 0)
    assert result["a"] == round(8 / 20, 4) and result["b"] == round(11 / 20, 4)
    assert "B - A: +15.0" in capsys.readouterr().out
    # one file: its squeeze against its policy
    assert main([str(a), "--column", "squeeze", "--column-b", "policy", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["difference"] == round((0 + 1 + 1 + 0) / 5 / 4, 4)


def test_missing_file_and_mismatched_trials_give_one_line_errors(tmp_path, capsys):
    a = _write(tmp_path / "a.json", 5, [{"pose_key": 1, "policy": 1}, {"pose_key": 2, "policy": 0}])
    b = _write(tmp_path / "b.json", 2, [{"pose_key": 1, "policy": 1}, {"pose_key": 2, "policy": 0}])
    assert main([str(a), str(tmp_path / "none.json")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main([str(a), str(b)]) == 2
    err = capsys.readouterr().err
    assert "trials" in err and len(err.strip().splitlines()) == 1
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert main([str(bad), str(a)]) == 2
    assert "not an evaluate-execution outcomes.json" in capsys.readouterr().err


def test_paired_or_none_gives_the_difference_of_two_evaluations_and_its_standard_error():
    from flows.paired import paired_cell, paired_or_none

    ours = [{"pose_key": k, "policy": s} for k, s in ((1, 2), (2, 0), (3, 1))]
    other = [{"pose_key": k, "policy": s} for k, s in ((3, 1), (1, 0), (2, 0), (9, 2))]  # pose 9: only here
    result = paired_or_none(ours, other, trials=2)
    # per shared pose (b - a): -1, 0, 0 -> mean -1/3, sample sd 0.577, standard error 0.333
    assert result["poses"] == 3 and result["difference"] == round(-1 / 3, 4)
    assert result["standard_error"] == round(0.5773503 / 3 ** 0.5, 4)
    assert (result["poses_higher"], result["poses_level"], result["poses_lower"]) == (0, 2, 1)
    assert paired_cell(result) == "-33.3 ± 33.3" and paired_cell(None) == "–"
    assert paired_or_none(ours[:1], other, trials=2) is None  # one shared pose: no standard error
