"""Generated pre-grasps as a grasp table, so that every tool that reads a ``synthesize`` stage's table
(``benchmarks.scripted_lift``, ``benchmarks.lift_failures``, ``benchmarks.q1_conventions`` ... with ``--grasps
FILE``) measures generated grasps the same way:

    python -m benchmarks.generated_table --profile mini --workdir runs/mini --split Pl --scenes 3 \\
        [--checkpoint generator.pt] [--set generator.refine.fc_steps=50 ...] --out OUT.parquet --json OUT.json

For the first ``--scenes`` scenes of ``--split`` of the ``scenes`` stage, ``generator.eval_grasps_per_scene`` grasps
each, generated, IK-solved and refined exactly as ``multigrasp evaluate pregrasp --source generated`` does
(:func:`flows.evaluate_generated.generate_for_scene`, same seeds), scored by Q1 and PN, and written with the
synthesis table's columns (``scene_id``, ``split``, ``combination``, ``row``, object names / positions /
quaternions, ``p``, ``R``, ``q``, ``accepted``, ``q1``, ``pn_mm``, ``pn_before_mm``, ``contact_ratio``; no chosen
contacts; :func:`flows.evaluate_generated.generated_table`).
``accepted`` is the paper's protocol filter (``generator.eval_filter``: PN and contact ratio; ``--set
generator.eval_filter.enabled=false`` accepts every row), so the lift tools, which read accepted rows, lift what the
protocol keeps.  The JSON gives n (accepted), n_generated, mean Q1 and PN over the accepted rows and over all.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from benchmarks.grasp_tables import finish_tool
from components.errors import MultigraspError


def run(cfg, split: str, scenes: int, out: Path, checkpoint: Path | None) -> dict:
    """Generate, score and write the table (module docstring); the JSON-able summary."""
    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from flows.evaluate_generated import generated_table, load_generator_for
    from tasks.preflight import cache_dir
    from tasks.synthesize import read_scene_records

    scenes_stage, generator, model = load_generator_for(cfg, checkpoint, "benchmarks.generated_table")
    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    picked = [r for r in read_scene_records(scenes_stage)
              if r["split"] == split and len(r["objects"]) <= cfg.generator.model.max_objects][:scenes]
    if not picked:
        raise MultigraspError(f"no scenes of split {split} in this config's scenes stage — choose another --split")
    frame, _ = generated_table(cfg, model, hand, library, picked,
                               progress=lambda line: print(f"generated table: {line}", file=sys.stderr, flush=True))
    out.parent.mkdir(parents=True, exist_ok=True)
    frame.to_parquet(out)
    accepted = frame[frame["accepted"]]
    return {"grasps": str(out), "split": split, "scenes": len(picked), "n": len(accepted), "n_generated": len(frame),
            "q1": round(float(accepted["q1"].mean()), 4) if len(accepted) else None,
            "pn_mm": round(float(accepted["pn_mm"].mean()), 3) if len(accepted) else None,
            "q1_all": round(float(frame["q1"].mean()), 4), "pn_mm_all": round(float(frame["pn_mm"].mean()), 3),
            "eval_filter": cfg.generator.eval_filter.model_dump(),
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

    return finish_tool(args.json, compute, lambda r: print(f"generated table: {r['n']} of {r['n_generated']} grasps accepted, Q1 {r['q1']}, "
                                                           f"PN {r['pn_mm']} mm -> {r['grasps']}"))


if __name__ == "__main__":
    sys.exit(main())
