"""How close does the trained generator come to the grasps it learnt from?  Raw samples (before refinement)
for scenes of its own training data, against those scenes' synthesised grasps.

    python -m benchmarks.generator_fidelity --profile bench --set "synthesis.splits=[train]" \
        --workdir /work/bench_run --split train --scenes 6 --per-scene 16 --json OUT \
        [--checkpoint generator.pt] [--grasps grasps.parquet] [--noise-steps 25,50]

Rows, each over the same grasps (``--scenes`` scenes of ``--split`` with at least two objects when there are
such scenes, ``--per-scene`` accepted grasps each):

* ``data``: the synthesised grasps as stored.
* ``data -> IK``: their hand representation (keypoints) taken back to (p, R, q) by the stage's IK, as a
  generated grasp is; the gap to ``data`` is the IK's.
* ``noised t -> denoised``: the grasp's representation noised to step t (``q_sample``) and denoised by the
  model with ancestral DDPM steps t .. 0 (:func:`components.generation.denoise_from`, SDEdit).  A perfect
  model returns a grasp of the data distribution near the start; how far PN, Q1 and the keypoints move
  shows how much of the truth the model keeps at that noise level.
* ``sampled``: ancestral DDPM from N(0, I) at T - 1 (the paper's sampler), for the same scenes and palm yaws.

Per row: mean PN (mm) and Q1 of the raw grasps (no refinement), the fraction with Q1 > 0, the mean wrist
height in the palm-aligned frame (mm), the IK's mean keypoint error |FK(IK(x)) - x| (mm), and for the noised rows
the mean keypoint distance (mm) between the denoised keypoints and those of the grasp they started from.  The model is the config's ``train-generator`` stage or
``--checkpoint``; the grasps are the config's ``synthesize`` stage or ``--grasps``.  ``--scenes`` x ``--per-scene``
bound the grasps measured (the shared ``--max-grasps`` option does not apply here).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import add_source_args, finish_tool, resolve_source, row_report
from components.errors import MultigraspError


def parse_steps(text: str) -> list[int]:
    """'25,50' -> [25, 50] (one-line error otherwise)."""
    try:
        steps = [int(item) for item in text.split(",") if item.strip()]
    except ValueError:
        raise MultigraspError(f"--noise-steps {text!r}: give comma-separated integers, e.g. 25,50") from None
    if not steps or min(steps) < 1:
        raise MultigraspError(f"--noise-steps {text!r}: give comma-separated integers >= 1, e.g. 25,50")
    return steps


def pick_scenes(frame, scenes: int, per_scene: int, seed: int):
    """``scenes`` scene ids (seeded, multi-object scenes first) and at most ``per_scene`` rows of each."""
    multi = frame[frame["object_names"].map(len) >= 2]
    pool = multi if len(multi) else frame
    ids = sorted(pool["scene_id"].unique())
    rng = np.random.default_rng(seed)
    chosen = rng.choice(ids, size=min(scenes, len(ids)), replace=False)
    parts = [pool[pool["scene_id"] == sid].head(per_scene) for sid in chosen]
    return [part.reset_index(drop=True) for part in parts]


def run(cfg, grasps: Path, checkpoint: Path | None, split: str | None, scenes: int, per_scene: int,
        noise_steps: list[int]) -> dict:
    import pyarrow.parquet as pq
    import torch

    from components.generation import (GraspDataset, denoise_from, from_representation, load_generator, q_sample)
    from components.generation.canonical import AlignedFrame
    from components.hand import HandModel
    from components.metrics import penetration_depth, q1_grasps
    from components.objects import ObjectLibrary, Scene
    from components.synthesis import SceneObjects
    from flows.pipeline import stage_output
    from tasks.preflight import cache_dir

    if checkpoint is None:
        manifest = stage_output(cfg, "train-generator")
        if manifest is None:
            raise MultigraspError("no trained generator for this config — run `multigrasp run --until train-generator` "
                                  "first (same --profile / --config / --set / --workdir), or pass --checkpoint")
        checkpoint = manifest.path("generator")
    elif not checkpoint.is_file():
        raise MultigraspError(f"--checkpoint {checkpoint}: no such file — give a generator.pt "
                              "(stages/train-generator/<key>/generator.pt)")
    model = load_generator(checkpoint)
    T = model.schedule.steps
    if max(noise_steps) > T:
        raise MultigraspError(f"--noise-steps: the model has T = {T} diffusion steps; give values <= {T}")
    frame = pq.read_table(grasps).to_pandas()
    frame = frame[frame["accepted"].astype(bool)] if "accepted" in frame else frame
    if split is not None:
        frame = frame[frame["split"] == split]
    frame = frame[frame["object_names"].map(len) <= model.cfg.max_objects]
    if frame.empty:
        raise MultigraspError(f"no accepted grasps{' of split ' + split if split else ''} in {grasps} — "
                              "choose another --split (the generator learns from 'train')")
    stage, metrics = cfg.generator, cfg.synthesis.metrics
    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    names = ["data", "data -> IK", *[f"noised t={t} -> denoised" for t in noise_steps], f"sampled (N(0, I) at t={T})"]
    acc = {name: {"pn": [], "q1": [], "wrist": [], "kp": [], "ik": []} for name in names}
    groups = pick_scenes(frame, scenes, per_scene, cfg.run.seed)
    for number, group in enumerate(groups):
        first = group.iloc[0]
        scene = Scene.from_arrays(first["object_names"], first["object_positions"], first["object_quats_xyzw"])
        objects = SceneObjects(library, scene, hand.device, hand.dtype)
        data = GraspDataset.from_frame(group, library, hand, model.cfg)
        x0, inputs = data.batch(torch.arange(len(data)))
        aligned = AlignedFrame(data.yaw, data.pivot)
        gen = torch.Generator().manual_seed(cfg.run.seed * 7919 + number)

        def score(name, p, R, q, wrist_height, shift=None, ik_error=None):
            with torch.no_grad():
                pn = penetration_depth(hand, objects, p, R, q, metrics).pn_mm
                q1, _ = q1_grasps(hand, objects, p, R, q, metrics)
            acc[name]["pn"] += [float(v) for v in pn]
            acc[name]["q1"] += [float(v) for v in q1]
            acc[name]["wrist"] += [1000.0 * float(v) for v in wrist_height]
            for key, values in (("kp", shift), ("ik", ik_error)):
                if values is not None:
                    acc[name][key] += [1000.0 * float(v) for v in values]

        def score_sample(name, z, paired=True):
            x = model.standardizer.denormalize(z)
            with torch.no_grad():
                p, R, q = from_representation(hand, x, model.cfg.representation, stage.ik)
                pw, Rw = aligned.pose_from_aligned(p.to(hand.dtype), R.to(hand.dtype))
                shift = ik_error = None
                if model.cfg.representation == "keypoints":
                    points = x.reshape(len(x), -1, 3).to(hand.dtype)
                    ik_error = (hand.keypoints(p, R, q) - points).norm(dim=-1).mean(-1)
                    shift = (x - x0).reshape(len(x), -1, 3).norm(dim=-1).mean(-1) if paired else None
            score(name, pw, Rw, q, p[:, 2], shift, ik_error)

        stored = [torch.as_tensor(np.stack(group[c].to_numpy()), dtype=hand.dtype) for c in ("p", "R", "q")]
        score("data", stored[0], stored[1].reshape(-1, 3, 3), stored[2], data.p[:, 2])
        score_sample("data -> IK", model.standardizer.normalize(x0))
        with torch.no_grad():
            context = model.denoiser.cache_keys_values(model.denoiser.encode(inputs))
            z0 = model.standardizer.normalize(x0)
            for t in noise_steps:
                tt = torch.full((len(z0),), t - 1, dtype=torch.long)
                z_t = q_sample(model.schedule, z0, tt, torch.randn(z0.shape, generator=gen))
                score_sample(f"noised t={t} -> denoised", denoise_from(model.denoiser, model.schedule, z_t, t - 1,
                                                                      context, gen, model.cfg.clip_sample))
            start = torch.randn(z0.shape, generator=gen)
            score_sample(names[-1], denoise_from(model.denoiser, model.schedule, start, T - 1, context, gen,
                                                 model.cfg.clip_sample), paired=False)
        print(f"generator fidelity: scene {number + 1}/{len(groups)} ({len(group)} grasps)", file=sys.stderr, flush=True)

    def mean(values):
        return round(float(np.mean(values)), 4) if values else None

    rows = [{"row": name, "pn_mm": mean(v["pn"]), "q1": mean(v["q1"]),
             "q1_positive": mean([float(x > 0) for x in v["q1"]]), "wrist_height_mm": mean(v["wrist"]),
             "keypoint_shift_mm": mean(v["kp"]), "ik_error_mm": mean(v["ik"]), "n": len(v["pn"])} for name, v in acc.items()]
    return {"checkpoint": str(checkpoint), "grasps": str(grasps), "split": split, "scenes": len(groups),
            "per_scene": per_scene, "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.generator_fidelity", description=__doc__.split("\n\n")[0])
    add_source_args(parser)
    parser.set_defaults(split="train")
    parser.add_argument("--checkpoint", type=Path, help="a generator.pt instead of the train-generator stage's")
    parser.add_argument("--scenes", type=int, default=6, help="scenes measured (default 6)")
    parser.add_argument("--per-scene", type=int, default=16, help="grasps per scene (default 16)")
    parser.add_argument("--noise-steps", default="25,50", help="noise levels t of the noised rows (default 25,50)")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)

    def compute() -> dict:
        if args.scenes < 1 or args.per_scene < 1:
            raise MultigraspError("--scenes and --per-scene must be at least 1")
        steps = parse_steps(args.noise_steps)
        if args.threads:
            import torch

            torch.set_num_threads(args.threads)
        cfg, grasps = resolve_source(args)
        return run(cfg, grasps, args.checkpoint, None if args.split == "all" else args.split, args.scenes,
                   args.per_scene, steps)

    return finish_tool(args.json, compute, row_report(
        lambda row: f"{row['row']:30s} PN {row['pn_mm']} mm  Q1 {row['q1']} (> 0: {row['q1_positive']})  "
                    f"wrist height {row['wrist_height_mm']} mm  keypoints moved {row['keypoint_shift_mm']} mm  "
                    f"IK error {row['ik_error_mm']} mm  "
                    f"n {row['n']}"))


if __name__ == "__main__":
    sys.exit(main())
