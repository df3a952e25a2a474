"""Train a stage's generator on a GPU machine that lacks the pipeline's packages (benchmarks/gpu_check/README.md).

Here, after the ``synthesize`` stage:

    python -m benchmarks.gpu_check.generator_job export --profile bench --workdir W [--set ...] --out .gpu_job

writes the generator's training data (``tasks.generator.training_frame`` -> ``GraspDataset``, as tensors) and the
stage's model config to ``.gpu_job/dataset.pt``, and prints the ``train-generator`` unit folder of that config.
On the GPU machine (``.gpu`` and ``.gpu_job`` carried, packages as in ``check.sh``):

    python3 -m benchmarks.gpu_check.generator_job train --data .gpu_job/dataset.pt --out $OUT

runs ``components.generation.train_generator`` on cuda with that config and writes ``$OUT/generator.pt``.  Copied
into the unit folder here, the stage's own training resumes from it at its last step -- nothing left to train --
and writes the unit's manifest, so ``multigrasp run`` serves it from cache like a generator trained here.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import fields
from pathlib import Path


def export(args) -> int:
    import torch

    from components.generation import GraspDataset
    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from flows.config import load_config
    from flows.pipeline import stage_output
    from flows.train_generator import stage_spec
    from tasks.generator import training_frame
    from tasks.preflight import cache_dir

    cfg = load_config(args.profile, args.config, args.sets, workdir=args.workdir)
    synthesis = stage_output(cfg, "synthesize")
    if synthesis is None:
        print("error: the synthesize stage has not finished for this config — run `multigrasp run --until synthesize` "
              "with the same options first", file=sys.stderr)
        return 2
    dataset = GraspDataset.from_frame(training_frame(synthesis, cfg.generator), ObjectLibrary(
        cfg.objects, cache_dir=cache_dir(Path(cfg.run.workdir))), HandModel(cfg.hand), cfg.generator.model)
    tensors = {f.name: getattr(dataset, f.name) for f in fields(dataset) if f.name != "cfg"}
    args.out.mkdir(parents=True, exist_ok=True)
    torch.save({"tensors": tensors, "config": cfg.generator.model.model_dump(mode="json")}, args.out / "dataset.pt")
    print(f"{len(dataset)} grasps, {dataset.scenes} scenes -> {args.out / 'dataset.pt'}")
    print(f"train-generator unit: {stage_spec(cfg, synthesis).folder}")
    return 0


def train(args) -> int:
    import torch

    from components.generation import GeneratorConfig, GraspDataset, train_generator

    saved = torch.load(args.data, map_location="cpu", weights_only=True)
    cfg = GeneratorConfig(**saved["config"])
    dataset = GraspDataset(**saved["tensors"], cfg=cfg)
    start = time.perf_counter()

    def progress(step: int, total: int, info: dict) -> None:
        print(f"step {step}/{total} loss {info['loss']:.4f} ETA {info['eta_s']:.0f}s", flush=True)

    args.out.mkdir(parents=True, exist_ok=True)
    train_generator(dataset, cfg, args.out / "generator.pt", progress, device=args.device)
    print(f"{cfg.train_steps} steps x {cfg.batch_size} on {len(dataset)} grasps in {time.perf_counter() - start:.0f} s "
          f"({torch.cuda.get_device_name() if args.device == 'cuda' else args.device})")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.gpu_check.generator_job", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ex = sub.add_parser("export", help="write the generator's training data of a finished synthesize stage")
    ex.add_argument("--profile", default="bench")
    ex.add_argument("--config", type=Path)
    ex.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    ex.add_argument("--workdir", type=Path)
    ex.add_argument("--out", type=Path, default=Path(".gpu_job"))
    tr = sub.add_parser("train", help="train on the exported data (on the GPU machine)")
    tr.add_argument("--data", type=Path, default=Path(".gpu_job/dataset.pt"))
    tr.add_argument("--out", type=Path, required=True)
    tr.add_argument("--device", default="cuda")
    args = parser.parse_args(argv)
    return export(args) if args.command == "export" else train(args)


if __name__ == "__main__":
    sys.exit(main())
