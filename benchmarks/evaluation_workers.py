"""Wall time of ``multigrasp evaluate execution`` with 1 and with N lift workers (``--max-workers``), alternated,
medians of ``--repeats`` invocations each; checks that every setting's per-pose outcomes are the same.

    python -m benchmarks.evaluation_workers --workdir W --profile smoke --set lift.max_steps=100 \\
        --set specialists.eval_poses=40 --workers 2 --repeats 3 --json OUT

The work dir must hold the config's synthesize, pointnet and specialists stages (``multigrasp run --until
specialists`` with the same ``--profile`` / ``--set``).  ``lift.max_steps=100`` on the smoke profile gives the bench
profile's episode length (the lift env's default).  The lift jobs of earlier invocations are deleted before each
timed one (``stages/evaluate-execution``, :mod:`tasks.lift_jobs`), so every pose is lifted; one more invocation at the
end, with the jobs of the last one kept, times an evaluation served from its finished jobs (``served_s``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path


def _evaluate(workdir: Path, profile: str, sets: list[str], workers: int) -> float:
    argv = [sys.executable, "-m", "flows.cli", "evaluate", "execution", "--profile", profile, "--workdir", str(workdir),
            "--max-workers", str(workers)] + sum([["--set", s] for s in sets], [])
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"evaluate execution failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return seconds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument("--profile", default="smoke")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--workers", type=int, default=2, help="the parallel setting compared with 1 (default 2)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, required=True)
    args = parser.parse_args(argv)

    times: dict[int, list[float]] = {1: [], args.workers: []}
    outcomes: dict[int, dict[str, str]] = {}
    results = args.workdir / "results" / "execution"
    for _ in range(args.repeats):
        for workers in (1, args.workers):
            shutil.rmtree(args.workdir / "stages" / "evaluate-execution", ignore_errors=True)
            times[workers].append(round(_evaluate(args.workdir, args.profile, args.sets, workers), 2))
            outcomes[workers] = {p.parent.name: p.read_text() for p in results.glob("*/outcomes.json")}
            print(f"workers {workers}: {times[workers][-1]} s", file=sys.stderr, flush=True)
    served = round(_evaluate(args.workdir, args.profile, args.sets, args.workers), 2)
    same = outcomes[1] == outcomes[args.workers] == {p.parent.name: p.read_text() for p in results.glob("*/outcomes.json")}
    medians = {w: statistics.median(t) for w, t in times.items()}
    summary = json.loads((args.workdir / "results" / "execution.json").read_text())
    result = {"times_s": {str(w): t for w, t in times.items()}, "median_s": {str(w): m for w, m in medians.items()},
              "speedup": round(medians[1] / medians[args.workers], 3), "same_outcomes": same, "served_s": served,
              "poses": {r["setting"]: r["n_poses"] for r in summary["rows"]},
              "trials": summary["rows"][0]["trials"], "profile": args.profile, "sets": args.sets,
              "cpu_count": os.cpu_count()}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
