"""Generated pre-grasps as a grasp table, so that every tool that reads a ``synthesize`` stage's table
(``benchmarks.scripted_lift``, ``benchmarks.lift_failures``, ``benchmarks.q1_conventions`` ... with ``--grasps
FILE``) measures generated grasps the same way:

    python -m benchmarks.generated_table --profile mini --workdir runs/mini --split Pl --scenes 3 \\
        [--checkpoint generator.pt] [--set generator.refine.fc_steps=50 ...] --out OUT.parquet --json OUT.json

For the first ``--scenes`` scenes of ``--split`` of the ``scenes`` stage, ``generator.eval_grasps_per_scene`` grasps
each, generated, IK-solved and refined exactly as ``multigrasp evaluate pregrasp --source generated`` does
(:func:`flows.evaluate_generated.generate_for_scene`, same seeds), scored by Q1 and PN, and written with the
synthesis table's columns (``scene_id``, ``split``, ``combination``, ``row``, object names / positions /
quaternions, ``p``, ``R``, ``q``, ``accepted`` = True for every row: generated grasps are not filtered, ``q1``,
``pn_mm``; no chosen contacts).  The JSON gives n, mean Q1 and PN.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import finish_tool
from components.errors import MultigraspError


def run(cfg, split: str, scenes: int, out: Path, checkpoint: Path | None) -> dict:
    """Generate, score and write the table (module docstring); the JSON-able summary."""
    import pandas as pd

    from components.generation import load_generator
    from components.hand import HandModel
    from components.metrics import penetration_depth, q1_grasps
    from components.objects import ObjectLibrary
    from flows.evaluate_generated import generate_for_scene
    from flows.pipeline import stage_output
    from tasks.preflight import cache_dir
    from tasks.synthesize import read_scene_records

    scenes_stage = stage_output(cfg, "scenes")
    generator = stage_output(cfg, "train-generator") if checkpoint is None else None
    if scenes_stage is None:
        raise MultigraspError("no scenes stage for this config — run `multigrasp run --until scenes` first")
    if checkpoint is None and generator is None:
        raise MultigraspError("no trained generator for this config — run `multigrasp run --until train-generator` "
                              "first, or pass --checkpoint")
    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    model = load_generator(generator.path("generator") if checkpoint is None else checkpoint)
    picked = [r for r in read_scene_records(scenes_stage)
              if r["split"] == split and len(r["objects"]) <= cfg.generator.model.max_objects][:scenes]
    if not picked:
        raise MultigraspError(f"no scenes of split {split} in this config's scenes stage — choose another --split")
    rows = []
    for number, record in enumerate(picked):
        objects, refined, seconds = generate_for_scene(cfg, model, hand, library, record, number)
        q1, _ = q1_grasps(hand, objects, refined.p, refined.R, refined.q, cfg.synthesis.metrics)
        pn = penetration_depth(hand, objects, refined.p, refined.R, refined.q, cfg.synthesis.metrics).pn_mm
        scene = objects.scene
        for i in range(refined.p.shape[0]):
            rows.append({"scene_id": record["id"], "split": split, "combination": "+".join(scene.names), "row": i,
                         "object_names": list(scene.names),
                         "object_positions": np.concatenate([pl.position for pl in scene.objects]).tolist(),
                         "object_quats_xyzw": np.concatenate([pl.quat_xyzw for pl in scene.objects]).tolist(),
                         "p": refined.p[i].tolist(), "R": refined.R[i].reshape(-1).tolist(),
                         "q": refined.q[i].tolist(), "accepted": True, "q1": float(q1[i]), "pn_mm": float(pn[i])})
        print(f"generated table: scene {number + 1}/{len(picked)} ({refined.p.shape[0]} grasps in {seconds:.1f}s)",
              file=sys.stderr, flush=True)
    frame = pd.DataFrame(rows)
    out.parent.mkdir(parents=True, exist_ok=True)
    frame.to_parquet(out)
    return {"grasps": str(out), "split": split, "scenes": len(picked), "n": len(frame),
            "q1": round(float(frame["q1"].mean()), 4), "pn_mm": round(float(frame["pn_mm"].mean()), 3),
            "refine": cfg.generator.refine.model_dump(),
            "checkpoint": str(checkpoint) if checkpoint else str(Path(generator.folder) / "manifest.json")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--profile", default="mini")
    parser.add_argument("--config", type=Path)
    parser.add_argument("--set", action="append", default=[], dest="sets", help="KEY=VALUE override, as for multigrasp run")
    parser.add_argument("--workdir", type=Path)
    parser.add_argument("--checkpoint", type=Path, help="a generator.pt to use instead of the train-generator stage's")
    parser.add_argument("--split", default="Pl")
    parser.add_argument("--scenes", type=int, default=3, help="the first this many scenes of the split")
    parser.add_argument("--out", type=Path, required=True, help="the table to write (.parquet)")
    parser.add_argument("--json", type=Path, required=True, help="the summary to write")
    args = parser.parse_args(argv)

    def compute() -> dict:
        from flows.config import load_config

        if args.scenes < 1:
            raise MultigraspError("--scenes must be at least 1")
        if args.checkpoint is not None and not args.checkpoint.is_file():
            raise MultigraspError(f"--checkpoint {args.checkpoint} is not a file — pass a train-generator unit's generator.pt")
        cfg = load_config(args.profile, args.config, args.sets, **({"workdir": args.workdir} if args.workdir else {}))
        return run(cfg, args.split, args.scenes, args.out, args.checkpoint)

    return finish_tool(args.json, compute, lambda r: print(f"generated table: {r['n']} grasps, Q1 {r['q1']}, "
                                                           f"PN {r['pn_mm']} mm -> {r['grasps']}"))


if __name__ == "__main__":
    sys.exit(main())
