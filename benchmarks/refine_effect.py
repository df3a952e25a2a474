"""What the paper's refinement does to synthesised grasps: Q1 and PN before and after it.

    python -m benchmarks.refine_effect --profile mini --workdir runs/mini --split Pl --max-grasps 32 --json OUT

The refinement is the one the pipeline applies to generated grasps (``components.generation.refine``,
paper §Refinement: minimise penetration while pulling hand points within tau of a surface onto it, tau
from 2 mm to 1 mm), with the config's ``generator.refine`` settings.  It is run on the accepted grasps
of a ``synthesize`` stage (found or given as in :mod:`benchmarks.grasp_tables`), and Q1 / PN
(``synthesis.metrics``) are measured on the same grasps before and after.  One JSON object is written:
n, mean Q1, fraction with Q1 > 0 and mean PN (mm) before and after, and the refinement settings.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import read_accepted, scene_batches, tool_main


def _summary(q1: np.ndarray, pn_mm: np.ndarray) -> dict:
    return {"q1_mean": round(float(q1.mean()), 4), "q1_positive": round(float((q1 > 0).mean()), 4),
            "pn_mm_mean": round(float(pn_mm.mean()), 3)}


def run(grasps: Path, cfg, split: str | None, max_grasps: int) -> dict:
    """Refine the grasps and measure them before and after (module docstring); the JSON-able result."""
    from components.generation import refine_grasps
    from components.hand import HandModel
    from components.metrics import penetration_depth, q1_grasps
    from components.objects import ObjectLibrary
    from tasks.preflight import cache_dir

    frame = read_accepted(grasps, split, max_grasps)
    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    metrics, refine = cfg.synthesis.metrics, cfg.generator.refine
    values = {key: np.zeros(len(frame)) for key in ("q1_before", "pn_before", "q1_after", "pn_after")}
    for number, (rows, objects, p, R, q) in enumerate(scene_batches(frame, hand, library), 1):
        out = refine_grasps(hand, objects, p, R, q, refine,
                            synthesis=cfg.synthesis.optimizer_for(objects.n_objects))
        for tag, (pp, RR, qq) in (("before", (p, R, q)), ("after", (out.p, out.R, out.q))):
            values[f"q1_{tag}"][rows] = q1_grasps(hand, objects, pp, RR, qq, metrics)[0].numpy()
            values[f"pn_{tag}"][rows] = penetration_depth(hand, objects, pp, RR, qq, metrics).pn_mm.detach().cpu().numpy()
        print(f"refine effect: scene {number} ({len(rows)} grasps, refined in {out.seconds:.1f}s)", file=sys.stderr,
              flush=True)
    return {"grasps": str(grasps), "split": split, "n": len(frame),
            "before": _summary(values["q1_before"], values["pn_before"]),
            "after": _summary(values["q1_after"], values["pn_after"]), "refine": refine.model_dump()}


def report(result: dict) -> None:
    """Before / after lines on stdout."""
    for tag in ("before", "after"):
        row = result[tag]
        print(f"{tag:6s}  Q1 {row['q1_mean']:.4f} (Q1 > 0: {row['q1_positive']:.0%})  PN {row['pn_mm_mean']:.2f} mm")


def main(argv: list[str] | None = None) -> int:
    return tool_main(argv, "python -m benchmarks.refine_effect", __doc__.split("\n\n")[0], run, report)


if __name__ == "__main__":
    sys.exit(main())
