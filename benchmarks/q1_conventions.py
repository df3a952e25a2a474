"""Q1 of the same accepted grasps under several Q1 conventions: how far the paper's "Q1 0.30" depends on them.

    python -m benchmarks.q1_conventions --profile mini --workdir runs/mini --split Pl --json OUT
    python -m benchmarks.q1_conventions --grasps runs/mini/stages/synthesize/<merge>/grasps.parquet --json OUT

The paper computes Q1 "following Liu et al." without its constants.  This project's definition
(``components.metrics.q1``; DESIGN §6) is one reading of it; the evaluation code released with DexGraspNet
and UniDexGrasp (the same line of work) is another.  This tool scores the accepted grasps of a
``synthesize`` stage (found for ``--profile`` / ``--config`` / ``--set`` / ``--workdir`` like
``multigrasp evaluate``, or read from ``--grasps``) under every convention of :data:`CONVENTIONS`
and, for scale, the same conventions' Q1 of an ideal grasp: a sphere held by six contacts along
+-x, +-y, +-z (no hand; dense conventions only).  One JSON object is written: per convention its
metric overrides, mean Q1 (min over a grasp's objects, this project's multi-object Q1), the fraction of grasps
with Q1 > 0, ``q1_object_mean`` (every object's own Q1 averaged over objects and grasps: the reading of a paper
that averages over objects rather than taking the weakest) and the ideal value.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import read_accepted, scene_batches, tool_main

#: name -> ``MetricsConfig`` overrides.  "DexGraspNet / UniDexGrasp evaluation code": the ``q1`` section of
#: their test configs (mu 1, 8 cone edges, contacts within 1 cm, one contact per link ('nms'), torque x 10 / m).
CONVENTIONS: dict[str, dict] = {
    "this project (dense, mu 0.5, 5 mm, torque / radius)": {},
    "this project with mu 1": {"friction_coefficient": 1.0},
    "DexGraspNet / UniDexGrasp evaluation code (per link, mu 1, 1 cm, torque x 10/m)": {
        "q1_contact_mode": "per_link", "friction_coefficient": 1.0, "contact_distance_m": 0.01,
        "q1_torque_scale_per_m": 10.0},
}
#: Radius (m) of the sphere of the ideal six-contact grasp.
IDEAL_SPHERE_RADIUS_M = 0.03


def ideal_six_contact_q1(metrics) -> float | None:
    """Q1 of six contacts at +-x, +-y, +-z of a sphere under ``metrics`` (None for per-link conventions,
    which need a hand)."""
    from components.metrics import q1_single_object

    if metrics.q1_contact_mode != "dense":
        return None
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    return round(q1_single_object(IDEAL_SPHERE_RADIUS_M * axes, axes, np.zeros(3), IDEAL_SPHERE_RADIUS_M, metrics), 4)


def score(frame, metrics_list, cfg) -> list[np.ndarray]:
    """Per-object Q1 (rows, most objects in a row; NaN past a row's own objects) of every row of ``frame`` under each
    ``MetricsConfig`` of ``metrics_list`` (hand and objects of the pipeline config ``cfg``)."""
    from components.hand import HandModel
    from components.metrics import q1_grasps
    from components.objects import ObjectLibrary
    from components.synthesis.hand_surface import HandSurface
    from tasks.preflight import cache_dir

    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    width = max(len(names) for names in frame["object_names"])
    out = [np.full((len(frame), width), np.nan) for _ in metrics_list]
    surfaces = {}
    for number, (rows, objects, p, R, q) in enumerate(scene_batches(frame, hand, library), 1):
        for k, metrics in enumerate(metrics_list):
            spacing = metrics.q1_hand_point_spacing_m
            surfaces.setdefault(spacing, HandSurface(hand, spacing))
            out[k][rows, : objects.n_objects] = q1_grasps(hand, objects, p, R, q, metrics, surfaces[spacing])[1].numpy()
        print(f"q1 conventions: scene {number} ({len(rows)} grasps)", file=sys.stderr, flush=True)
    return out


def run(grasps: Path, cfg, split: str | None, max_grasps: int) -> dict:
    """Score the grasps under every convention (module docstring), starting from the metric settings of the
    pipeline config ``cfg``; the JSON-able result."""
    frame = read_accepted(grasps, split, max_grasps)
    base = cfg.synthesis.metrics
    metrics_list = [type(base).model_validate({**base.model_dump(), **overrides}) for overrides in CONVENTIONS.values()]
    values = score(frame, metrics_list, cfg)
    rows = [{"convention": name, "overrides": overrides, "q1_mean": round(float(np.nanmin(v, 1).mean()), 4),
             "q1_positive": round(float((np.nanmin(v, 1) > 0).mean()), 4),
             "q1_object_mean": round(float(np.nanmean(v)), 4),
             "ideal_six_contact_sphere": ideal_six_contact_q1(m)}
            for (name, overrides), v, m in zip(CONVENTIONS.items(), values, metrics_list)]
    return {"grasps": str(grasps), "split": split, "n": len(frame), "conventions": rows}


def report(result: dict) -> None:
    """One line per convention on stdout."""
    for row in result["conventions"]:
        print(f"{row['q1_mean']:.4f}  (Q1 > 0: {row['q1_positive']:.0%}, mean over objects {row['q1_object_mean']:.4f}, "
              f"ideal {row['ideal_six_contact_sphere']})  {row['convention']}")


def main(argv: list[str] | None = None) -> int:
    return tool_main(argv, "python -m benchmarks.q1_conventions", __doc__.split("\n\n")[0], run, report)


if __name__ == "__main__":
    sys.exit(main())
