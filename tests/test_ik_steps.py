"""The IK step-count sweep (benchmarks.ik_steps) on a tiny workload: its JSON has a row per step count, and
more steps never leave a larger error on exact targets."""

import json

from benchmarks.ik_steps import main


def test_ik_steps_sweep_writes_rows(tmp_path):
    out = tmp_path / "ik.json"
    assert main(["--steps", "40,5", "--batch", "6", "--threads", "1", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    rows = {row["steps"]: row for row in result["rows"]}
    assert set(rows) == {40, 5}
    for row in rows.values():
        assert {"exact_s", "exact_median_error_mm", "noisy_s", "noisy_median_error_mm",
                "noisy_median_error_to_clean_mm"} <= set(row)
    assert rows[40]["exact_median_error_mm"] <= rows[5]["exact_median_error_mm"]
    assert result["workload"]["batch"] == 6
