"""Q1 and its cost against ``metrics.q1_max_contacts``, on the same accepted grasps.

    python -m benchmarks.q1_contacts --profile mini --workdir runs/mini --split Pl --json OUT [--counts 32,16,8] \
        [--exact-start 32,16]

Q1's 6-D convex hull grows quickly with the number of primitive wrenches (contacts x cone edges): on
spread contacts qhull takes ~40 ms for 8 contacts, ~130 ms for 16 and ~660 ms for 32.  The synthesis
stage scores every accepted grasp, so this cap sets a good share of its time.  This tool scores the
accepted grasps of a ``synthesize`` stage (found or given as in :mod:`benchmarks.grasp_tables`) with each
cap and writes, per cap: mean Q1, the fraction with Q1 > 0, the mean absolute difference from the
reference Q1 and the seconds per grasp (``contacts``: the cap).  ``--exact-start`` adds rows of the exact Q1
over every contact (``metrics.q1_solver='exact'``, constraint generation from ``contacts`` farthest-point
contacts, ``metrics.q1_exact_start``); the reference is the first exact row, else the largest cap.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import (
    add_source_args,
    finish_tool,
    read_accepted,
    resolve_source,
    row_report,
    scene_batches,
)


def run(grasps: Path, cfg, split: str | None, max_grasps: int, counts: list[int],
        exact_starts: list[int] | None = None) -> dict:
    """Score the grasps with every cap of ``counts`` and the exact solver from every start of ``exact_starts``
    (module docstring); the JSON-able result."""
    from components.hand import HandModel
    from components.metrics import q1_grasps
    from components.objects import ObjectLibrary
    from tasks.preflight import cache_dir

    frame = read_accepted(grasps, split, max_grasps)
    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    settings = [("exact", count) for count in exact_starts or []] + [("capped", count) for count in counts]
    values = {setting: np.zeros(len(frame)) for setting in settings}
    seconds = {setting: 0.0 for setting in settings}
    for number, (rows, objects, p, R, q) in enumerate(scene_batches(frame, hand, library), 1):
        for solver, count in settings:
            size = "q1_exact_start" if solver == "exact" else "q1_max_contacts"
            metrics = cfg.synthesis.metrics.model_copy(update={size: count, "q1_solver": solver})
            start = time.perf_counter()
            values[solver, count][rows] = q1_grasps(hand, objects, p, R, q, metrics)[0].numpy()
            seconds[solver, count] += time.perf_counter() - start
        print(f"q1 contacts: scene {number} ({len(rows)} grasps)", file=sys.stderr, flush=True)
    reference = values[settings[0]] if exact_starts else values["capped", max(counts)]
    rows = [{"solver": solver, "contacts": count, "q1_mean": round(float(values[solver, count].mean()), 4),
             "q1_positive": round(float((values[solver, count] > 0).mean()), 4),
             "mean_abs_diff_from_reference": round(float(np.abs(values[solver, count] - reference).mean()), 4),
             "seconds_per_grasp": round(seconds[solver, count] / max(len(frame), 1), 4)} for solver, count in settings]
    return {"grasps": str(grasps), "split": split, "n": len(frame),
            "reference": "exact" if exact_starts else f"capped {max(counts)}", "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.q1_contacts", description=__doc__.split("\n\n")[0])
    add_source_args(parser)
    parser.add_argument("--counts", default="32,16,8", help="comma-separated q1_max_contacts values (default 32,16,8)")
    parser.add_argument("--exact-start", default="",
                        help="comma-separated starting subset sizes of the exact Q1 (q1_solver='exact'), e.g. 32")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)
    try:
        counts = [int(c) for c in args.counts.split(",") if c.strip()]
        exact_starts = [int(c) for c in args.exact_start.split(",") if c.strip()]
        if not counts or min(counts + exact_starts) < 1:
            raise ValueError
    except ValueError:
        print(f"error: --counts {args.counts!r} / --exact-start {args.exact_start!r}: give positive integers, "
              "e.g. 32,16,8", file=sys.stderr)
        return 2

    def compute() -> dict:
        cfg, grasps = resolve_source(args)
        return run(grasps, cfg, None if args.split == "all" else args.split, args.max_grasps, counts, exact_starts)

    return finish_tool(args.json, compute, row_report(
        lambda row: f"{row['solver']} {row['contacts']:3d}: Q1 {row['q1_mean']:.4f} (> 0: {row['q1_positive']:.0%}), "
                    f"|diff| {row['mean_abs_diff_from_reference']:.4f}, {row['seconds_per_grasp']:.3f} s per grasp"))


if __name__ == "__main__":
    sys.exit(main())
