"""``python -m benchmarks.sdf_speed``: per-object SDF cost, with the fastest object as the unit."""

from __future__ import annotations

import json

from benchmarks.sdf_speed import main


def test_times_the_chosen_objects_relative_to_the_fastest(tmp_path, capsys):
    import torch

    before = torch.get_num_threads()
    out = tmp_path / "sdf.json"
    assert main(["--profile", "smoke", "--workdir", str(tmp_path), "--objects", "sphere,cube,ellipsoid",
                 "--points", "2000", "--repeats", "2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    rows = {row["object"]: row for row in result["rows"]}
    assert set(rows) == {"sphere", "cube", "ellipsoid"} and result["points"] == 2000 and result["threads"] == 1
    assert all(row["ms"] > 0 and row["analytic"] and row["relative_to_fastest"] >= 1.0 for row in rows.values())
    assert min(row["relative_to_fastest"] for row in rows.values()) == 1.0
    assert "ns/point" in capsys.readouterr().out
    assert torch.get_num_threads() == before  # the tool's --threads does not leak into the caller


def test_unknown_object_is_one_line(tmp_path, capsys):
    assert main(["--profile", "smoke", "--workdir", str(tmp_path), "--objects", "sphere,teapot",
                 "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: unknown object 'teapot' in --objects") and "\n" not in err


def test_zero_points_is_one_line(tmp_path, capsys):
    assert main(["--points", "0", "--json", str(tmp_path / "x.json")]) == 2
    assert "--points" in capsys.readouterr().err
