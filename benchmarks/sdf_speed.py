"""What one signed-distance evaluation costs per object of the library: where a synthesis scene's time goes.

    python -m benchmarks.sdf_speed --profile bench --threads 1 --json OUT [--points 100000] [--repeats 5]

E_pen evaluates every object's SDF at every hand sample of every candidate, each step (B 128 x a few thousand
samples at ``synthesis.optimizer.hand_point_spacing_m`` 5 mm), so a shape whose SDF is slow slows its scenes.  For
each object of the config's library (train and ood, user meshes included) this times ``ObjectModel.sdf`` without
autograd on ``--points`` points drawn uniformly in the cube of twice the object's radius around it (seeded), the
median of ``--repeats`` runs after one warm-up (``benchmarks.timing.median_ms``), and reports ms, ns per point and
the ratio to the fastest object.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from benchmarks.grasp_tables import check_positive, finish_tool

SEED = 0


def time_objects(cfg, points: int, repeats: int, objects: list[str] | None) -> list[dict]:
    """One row per object (module docstring): ms, ns per point, whether its SDF is analytic."""
    import torch

    from benchmarks.timing import median_ms
    from components.objects import ObjectLibrary
    from tasks.preflight import cache_dir

    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    generator = torch.Generator().manual_seed(SEED)
    rows = []
    for name in objects or library.names:
        library.require(name, "--objects")
        model = library.get(name)
        x = (torch.rand(points, 3, generator=generator) * 2.0 - 1.0) * 2.0 * model.radius
        with torch.no_grad():
            ms = median_ms(lambda: model.sdf(x), repeats, lambda: None)
        rows.append({"object": name, "analytic": model.is_analytic, "ms": round(ms, 3),
                     "ns_per_point": round(ms * 1e6 / points, 2)})
    return rows


def run(cfg, points: int, repeats: int, threads: int, objects: list[str] | None = None) -> dict:
    import torch

    previous = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        rows = time_objects(cfg, points, repeats, objects)
        used = torch.get_num_threads()
    finally:
        torch.set_num_threads(previous)  # the caller's setting (a test session, a notebook) is left as it was
    fastest = min(row["ms"] for row in rows)
    for row in rows:
        row["relative_to_fastest"] = round(row["ms"] / fastest, 2)
    return {"points": points, "repeats": repeats, "threads": used, "rows": rows}


def main(argv: list[str] | None = None) -> int:
    from flows.config import load_config

    parser = argparse.ArgumentParser(prog="python -m benchmarks.sdf_speed", description=__doc__.split("\n\n")[0])
    parser.add_argument("--profile", default="bench", help="profile whose objects are timed (default: bench)")
    parser.add_argument("--config", type=Path, help="YAML config file on top of the profile")
    parser.add_argument("--set", action="append", default=[], dest="sets", help="KEY=VALUE override, as for multigrasp run")
    parser.add_argument("--workdir", type=Path, help="work dir whose object cache is used (default: the profile's)")
    parser.add_argument("--objects", help="comma-separated object names (default: every object of the library)")
    parser.add_argument("--points", type=int, default=100_000, help="points per evaluation (default 100000)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per object (default 5)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1; 0 = torch's default)")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)
    if (status := check_positive(args, "points", "repeats")) is not None:
        return status

    def compute() -> dict:
        cfg = load_config(args.profile, args.config, args.sets, **({"workdir": args.workdir} if args.workdir else {}))
        return run(cfg, args.points, args.repeats, args.threads, args.objects.split(",") if args.objects else None)

    def report(result: dict) -> None:
        for row in sorted(result["rows"], key=lambda r: r["ms"]):
            print(f"{row['object']:12s} {row['ms']:9.2f} ms  {row['ns_per_point']:8.1f} ns/point  "
                  f"x{row['relative_to_fastest']}")

    return finish_tool(args.json, compute, report)


if __name__ == "__main__":
    sys.exit(main())
