"""Paired comparison of `benchmarks.lift_failures` results on the same poses and seeds (forty-first session).

    python benchmarks/results/fortyfirst/paired.py A.json B.json [C.json ...]

Prints each file's success, the paired difference of every later file against the first (and of the third against
the second) with its standard error over poses (the trials of one pose are not independent), and the success of each
combination under every file.
"""
import collections
import json
import sys
from pathlib import Path

import numpy as np


def episodes(path: str) -> dict[tuple, float]:
    rows = json.loads(Path(path).read_text())["episodes"]
    return {(e["combination"], e["pose"], e["trial"]): float(e["success"]) for e in rows}


def main(paths: list[str]) -> None:
    runs = {Path(p).stem: episodes(p) for p in paths}
    names = list(runs)
    keys = sorted(set.intersection(*(set(r) for r in runs.values())))
    for n in names:
        print(f"{n}: success {np.mean([runs[n][k] for k in keys]):.3f} over {len(keys)} episodes")
    pairs = [(names[0], b) for b in names[1:]] + ([(names[1], names[2])] if len(names) > 2 else [])
    for a, b in pairs:
        by_pose = collections.defaultdict(list)
        for k in keys:
            by_pose[k[:2]].append(runs[b][k] - runs[a][k])
        d = np.array([np.mean(v) for v in by_pose.values()])
        print(f"{a} -> {b}: {d.mean():+.3f} +- {d.std(ddof=1) / np.sqrt(len(d)):.3f} ({len(d)} poses)")
    by_combination = collections.defaultdict(lambda: collections.defaultdict(list))
    for n in names:
        for k in keys:
            by_combination[k[0]][n].append(runs[n][k])
    print("combination", *names)
    for c in sorted(by_combination):
        print(f"{c:24s}", " ".join(f"{np.mean(by_combination[c][n]):6.2f}" for n in names))


if __name__ == "__main__":
    main(sys.argv[1:])
