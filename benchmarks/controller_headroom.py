"""How much would choosing the scripted controller per pre-grasp gain? (forty-third session)

    python -m benchmarks.controller_headroom base=A.json all=B.json ... [--json OUT]

Each input is a ``benchmarks.lift_failures`` result of the same poses and trial seeds under one controller variant
(``--set lift.closure_links=all``, ``--set specialists.squeeze_force_fraction=0.4``, ...); the first is the reference.
A policy that owned the grasp closure could at best pick, for each pose, the variant that lifts it. How much that is
worth cannot be read from the best variant per pose on the same trials: with 5-10 trials per pose the maximum of
several noisy rates is biased upward. So the trials are split in two halves (even and odd trial index):

* **selected per pose (held out):** for each pose, the variant with the most successes on one half (ties go to the
  earlier variant, the reference first), scored on the other half; and the same with the halves swapped
  (cross-fitting). This is what a selector that knew each pose's outcome from a few trials would gain, an upper
  bound of what a learned selector that sees only the observation could gain.
* **best fixed variant (held out):** one variant for every pose, chosen on one half, scored on the other.
* **in-sample oracle:** the best variant per pose on all trials: biased upward, for comparison.
* **ever lifted:** the share of poses that some variant lifted in some trial, and the success if each of them
  lifted every time: the ceiling of any choice among these variants.

Paired differences against the reference come with their standard error over poses (the trials of one pose are not
independent).
"""
from __future__ import annotations

import argparse
import collections
import json
from pathlib import Path

import numpy as np

Pose = tuple[str, int]


def load(path: Path) -> dict[tuple[str, int, int], float]:
    """(combination, pose, trial) -> success of one ``lift_failures`` result."""
    try:
        rows = json.loads(Path(path).read_text())["episodes"]
        return {(e["combination"], int(e["pose"]), int(e["trial"])): float(e["success"]) for e in rows}
    except (ValueError, KeyError, TypeError):
        raise SystemExit(f"controller_headroom: {path} is not a lift_failures result (no readable 'episodes'); "
                         "make it with python -m benchmarks.lift_failures ... --json FILE") from None


def _mean_se(values: list[float]) -> tuple[float, float]:
    v = np.asarray(values, dtype=float)
    if len(v) < 2:
        return float(v.mean()) if len(v) else float("nan"), float("nan")
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v)))


def headroom(runs: dict[str, dict[tuple[str, int, int], float]]) -> dict:
    """The summary described in the module docstring; ``runs`` maps variant name -> episodes (first = reference)."""
    names = list(runs)
    if len(names) < 2:
        raise SystemExit("controller_headroom: give at least two lift_failures results (the reference first)")
    keys = set.intersection(*(set(r) for r in runs.values()))
    trials: dict[Pose, list[int]] = collections.defaultdict(list)
    for c, p, t in keys:
        trials[(c, p)].append(t)
    poses = sorted(pose for pose, ts in trials.items() if len(ts) >= 2)
    if not poses:
        raise SystemExit("controller_headroom: no pose has two trials in every file; run lift_failures with --trials >= 2")
    ref = names[0]

    def rate(name: str, pose: Pose, ts: list[int]) -> float:
        return float(np.mean([runs[name][(pose[0], pose[1], t)] for t in ts]))

    halves = {pose: (sorted(t for t in trials[pose] if t % 2 == 0), sorted(t for t in trials[pose] if t % 2 == 1))
              for pose in poses}
    chosen: collections.Counter = collections.Counter()
    selected, fixed, fixed_names = np.zeros(len(poses)), np.zeros(len(poses)), []
    for a, b in ((0, 1), (1, 0)):  # choose on half a, score on half b; each pose's two scores are averaged
        totals = {n: np.mean([rate(n, pose, halves[pose][a]) for pose in poses]) for n in names}
        best_fixed = max(names, key=lambda n: (totals[n], -names.index(n)))
        fixed_names.append(best_fixed)
        for i, pose in enumerate(poses):
            pick = max(names, key=lambda n: (rate(n, pose, halves[pose][a]), -names.index(n)))
            chosen[pick] += 1
            selected[i] += rate(pick, pose, halves[pose][b]) / 2
            fixed[i] += rate(best_fixed, pose, halves[pose][b]) / 2
    # the reference scored the same way: the mean of its two half rates (its all-trial rate when the halves are equal)
    ref_held = np.array([(rate(ref, pose, halves[pose][0]) + rate(ref, pose, halves[pose][1])) / 2 for pose in poses])
    ref_rate = [rate(ref, pose, trials[pose]) for pose in poses]
    oracle = [max(rate(n, pose, trials[pose]) for n in names) for pose in poses]
    ever = [any(runs[n][(pose[0], pose[1], t)] > 0 for n in names for t in trials[pose]) for pose in poses]
    per_variant = {}
    for n in names:
        m, _ = _mean_se([rate(n, pose, trials[pose]) for pose in poses])
        d, se = _mean_se([rate(n, pose, trials[pose]) - rate(ref, pose, trials[pose]) for pose in poses])
        per_variant[n] = {"success": m, "minus_reference": d, "minus_reference_se": se}
    sel_m, _ = _mean_se(selected)
    sel_d, sel_se = _mean_se(selected - ref_held)
    fix_m, _ = _mean_se(fixed)
    fix_d, fix_se = _mean_se(fixed - ref_held)
    return {
        "reference": ref,
        "n_poses": len(poses),
        "trials_per_pose": int(np.median([len(trials[p]) for p in poses])),
        "variants": per_variant,
        "selected_per_pose_held_out": {"success": sel_m, "minus_reference": sel_d, "minus_reference_se": sel_se,
                                       "times_chosen": dict(chosen)},
        "best_fixed_held_out": {"success": fix_m, "minus_reference": fix_d, "minus_reference_se": fix_se,
                                "chosen": fixed_names},
        "in_sample_oracle": float(np.mean(oracle)),
        "ever_lifted_poses": float(np.mean(ever)),
        "reference_success": float(np.mean(ref_rate)),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", help="NAME=lift_failures.json (or a path: its stem names it); the first is the reference")
    parser.add_argument("--json", type=Path, help="write the summary here")
    args = parser.parse_args(argv)
    runs = {}
    for item in args.runs:
        name, _, path = item.rpartition("=") if "=" in item else (Path(item).stem, "", item)
        if not Path(path).is_file():
            raise SystemExit(f"controller_headroom: {path} does not exist; give lift_failures JSON files")
        runs[name or Path(path).stem] = load(Path(path))
    out = headroom(runs)
    print(f"{out['n_poses']} poses x {out['trials_per_pose']} trials; reference {out['reference']}: "
          f"{out['reference_success']:.3f}")
    for n, v in out["variants"].items():
        print(f"  {n:12s} {v['success']:.3f}  ({v['minus_reference']:+.3f} +- {v['minus_reference_se']:.3f})")
    s, f = out["selected_per_pose_held_out"], out["best_fixed_held_out"]
    print(f"selected per pose, held out: {s['success']:.3f} ({s['minus_reference']:+.3f} +- {s['minus_reference_se']:.3f})")
    print(f"best fixed variant, held out: {f['success']:.3f} ({f['minus_reference']:+.3f} +- {f['minus_reference_se']:.3f}), "
          f"chosen {f['chosen']}")
    print(f"in-sample oracle {out['in_sample_oracle']:.3f}; poses ever lifted {out['ever_lifted_poses']:.3f}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
