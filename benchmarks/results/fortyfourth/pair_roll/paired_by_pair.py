"""Squeeze success of two `benchmarks.lift_failures` results on the same pairs but different pre-grasps (forty-fourth
session, docs/experiments.md "Fingers along the object line"): each file's success over its first TRIALS trials, and
the per-pair difference B - A with its standard error over the pairs (the pre-grasps differ, so poses are not paired).

    .venv/bin/python benchmarks/results/fortyfourth/pair_roll/paired_by_pair.py A.json B.json [TRIALS=5]
"""
import collections
import json
import sys

import numpy as np


def rates(path: str, trials: int) -> tuple[dict[str, float], float]:
    """(success per combination, overall success) over the trials below ``trials``."""
    rows = [e for e in json.load(open(path))["episodes"] if e["trial"] < trials]
    by_pair = collections.defaultdict(list)
    for e in rows:
        by_pair[e["combination"]].append(e["success"])
    return {k: float(np.mean(v)) for k, v in by_pair.items()}, float(np.mean([e["success"] for e in rows]))


def main(a_path: str, b_path: str, trials: int = 5) -> None:
    a, total_a = rates(a_path, trials)
    b, total_b = rates(b_path, trials)
    common = sorted(set(a) & set(b))
    diff = np.array([b[k] - a[k] for k in common])
    print(f"A {total_a:.3f}  B {total_b:.3f} (first {trials} trials)  per-pair B - A {diff.mean():+.3f} +- "
          f"{diff.std(ddof=1) / np.sqrt(len(diff)):.3f} over {len(diff)} pairs (B higher in {(diff > 0).sum()}, "
          f"lower in {(diff < 0).sum()})")
    for k in common:
        print(f"  {k:22s} {a[k]:.2f} {b[k]:.2f}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], *(int(x) for x in sys.argv[3:4]))
