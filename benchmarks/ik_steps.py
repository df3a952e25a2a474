"""How many Adam steps the keypoint IK needs: time and keypoint error against ``IKConfig.steps``.

    python -m benchmarks.ik_steps --threads 2 --json OUT [--batch 256] [--steps 300,150,100] [--noise-mm 3]

Workload: ``batch`` random hand poses (joint angles uniform in the limits, palm within 5 cm of the origin,
uniform random rotations; ``torch`` seed :data:`SEED`); their 31 keypoints are the IK targets, once exact
(reachable) and once with N(0, noise^2) added to every coordinate, standing in for generated keypoints
that no hand pose fits exactly.  For each step count (other settings: the ``IKConfig`` defaults): wall
time of :func:`components.generation.ik.solve_ik` and the median keypoint error of the solution (mm);
for the noisy targets also the error to the clean pose the noise was added to.  One run per setting
(the sweep's point is the error; the time is the order of magnitude).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

SEED = 0


def run_ik_steps(steps: list[int], batch: int = 256, noise_m: float = 0.003, threads: int = 0) -> dict:
    import torch

    from components.generation import IKConfig
    from components.generation.ik import solve_ik
    from components.hand import HandConfig, HandModel

    if threads:
        torch.set_num_threads(threads)
    hand = HandModel(HandConfig())
    gen = torch.Generator().manual_seed(SEED)
    q = hand.sample_joint_angles(batch, gen)
    p = 0.05 * torch.randn(batch, 3, generator=gen)
    rot, _ = torch.linalg.qr(torch.randn(batch, 3, 3, generator=gen))
    rot = rot * torch.sign(torch.det(rot)).view(-1, 1, 1)  # proper rotations
    clean = hand.keypoints(p, rot, q)
    noisy = clean + noise_m * torch.randn(clean.shape, generator=gen)
    rows = []
    for n in steps:
        row: dict = {"steps": n}
        for name, target in (("exact", clean), ("noisy", noisy)):
            start = time.perf_counter()
            result = solve_ik(hand, target, IKConfig(steps=n))
            seconds = time.perf_counter() - start
            reached = hand.keypoints(result.p, result.R, result.q)
            row[f"{name}_s"] = round(seconds, 2)
            row[f"{name}_median_error_mm"] = round(float((reached - target).norm(dim=-1).median()) * 1e3, 4)
            if name == "noisy":
                row["noisy_median_error_to_clean_mm"] = round(float((reached - clean).norm(dim=-1).median()) * 1e3, 4)
        rows.append(row)
    return {"rows": rows, "threads": torch.get_num_threads(),
            "workload": {"batch": batch, "seed": SEED, "noise_mm": noise_m * 1e3, "ik": IKConfig().model_dump(mode="json")}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.ik_steps", description=__doc__.splitlines()[0])
    parser.add_argument("--steps", default="300,150,100", help="comma-separated IK step counts")
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--noise-mm", type=float, default=3.0)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch's default)")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)
    try:
        steps = [int(s) for s in args.steps.split(",") if s.strip()]
    except ValueError:
        parser.error(f"--steps must be comma-separated integers, got '{args.steps}'")
    result = run_ik_steps(steps, args.batch, args.noise_mm / 1e3, args.threads)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    for row in result["rows"]:
        print(row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
