"""Wall time of short ``multigrasp`` commands (those that read results or fail fast), medians of several runs.

    python -m benchmarks.cli_start --workdir W --repeats 3 --json OUT [--repo CHECKOUT]

Each command runs as ``python -m flows.cli ...`` in ``--repo`` (default: this checkout), so another checkout's code
(an older commit in a ``git worktree``) is timed with the same interpreter and packages. ``W`` must hold results
(``multigrasp report`` writes a report and an MLflow run there at each repeat: use a copy). The commands: ``report
--workdir W``, ``compare W W``, ``ui`` on a folder without a store (its one-line error), ``--version``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def commands(workdir: Path) -> dict[str, list[str]]:
    return {"report": ["report", "--workdir", str(workdir)], "compare": ["compare", str(workdir), str(workdir)],
            "ui (no store)": ["ui", "--workdir", str(workdir / "no-store-here")], "--version": ["--version"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", type=Path, required=True, help="a work dir with results/ (a copy: it is written)")
    parser.add_argument("--repo", type=Path, default=REPO, help="the checkout whose code is timed")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, required=True)
    args = parser.parse_args(argv)
    rows = {}
    for name, cli in commands(args.workdir.resolve()).items():
        times, codes = [], set()
        for _ in range(args.repeats):
            start = time.perf_counter()
            done = subprocess.run([sys.executable, "-m", "flows.cli", *cli], cwd=args.repo, capture_output=True)
            times.append(round(time.perf_counter() - start, 2))
            codes.add(done.returncode)
        rows[name] = {"median_s": statistics.median(times), "runs_s": times, "exit_codes": sorted(codes)}
        print(f"{name}: {rows[name]['median_s']} s (median of {args.repeats}; exit {sorted(codes)})", flush=True)
    commit = subprocess.run(["git", "-C", str(args.repo), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"commit": commit, "repeats": args.repeats, "commands": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
