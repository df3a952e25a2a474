"""``multigrasp generate``: pre-grasps for any objects from the trained generator (paper §"Multi-object
Grasp Generation" + §"Refinement").

    multigrasp generate --objects cube,cylinder --n 16 [--palm-direction DEG] [--placement FILE] [--seed S]

The scene is read from ``--placement`` (JSON of ``Scene.to_dict``: ``{"objects": [{"name", "position",
"quat_xyzw"}, ...]}``) or sampled like the pipeline's scenes.  The generator samples ``n`` grasps (all
with the palm facing ``--palm-direction`` degrees about z, else each a random direction), IK turns
keypoints into (p, R, q), the refinement removes penetration, and the result goes to
``<workdir>/results/generated/<objects>-<seed>/``: ``grasps.json`` (p, R, q, penetration before/after, Q1, PN,
contact ratio, and ``kept``: whether the paper's protocol filter keeps the grasp, ``generator.eval_filter``),
``scene.json`` and a render grid ``grasps.png``.  Any library object or user mesh works, seen in
training or not; without a trained generator the error names the command that trains it.

With ``--lift`` (two objects) the grasps the protocol filter keeps are then lifted in PyBullet as ``evaluate
execution`` lifts the Gen rows' (:func:`lift_generated`): the matching specialist (by the bin of the pair and its
centre line; a pair no specialist was trained on falls back to the nearest sector, then to any pair), seeded
perturbed trials (after the planned reach with ``specialists.eval_after_reach``), and ``w/o RL`` and the scripted
squeeze on the same trials; where the ``distill`` stage has run for the config, the vision-based generalist on the
same trials too, as ``evaluate generalist`` lifts (it needs no matching specialist).  Results: ``lift.json`` (success
rates, specialists used, GIFs) and ``lift/outcomes.json`` (per pose) in the same folder.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from components.errors import MultigraspError
from flows.config import PipelineConfig
from tasks.artifacts import atomic_write_json


@dataclass
class LiftReport:
    """``generate --lift``: the specialists (and the scripted rows) lifting the kept grasps."""

    path: Path
    kept: int
    poses: int
    trials: int
    succ: float | None
    without_rl: float | None
    squeeze: float | None
    specialists: tuple[str, ...]
    gifs: tuple[Path, ...]
    generalist: float | None = None
    """The distilled generalist's success on the same trials (``None`` without a ``distill`` stage for the config)."""


@dataclass
class GenerateReport:
    folder: Path
    n: int
    seconds: dict
    depth_before_mm: float
    depth_after_mm: float
    kept: int = 0
    lift: LiftReport | None = None
    run_id: str | None = None
    """The MLflow run holding the grasps, their render and the lift's results and GIFs."""


def generate(cfg: PipelineConfig, objects: list[str], n: int, palm_direction_deg: float | None = None,
             placement: Path | None = None, seed: int = 0, lift: bool = False, say=None) -> GenerateReport:
    """Generate, IK-solve, refine, score and render ``n`` grasps (module docstring); with ``lift`` lift the kept
    ones (:func:`lift_generated`), ``say`` receiving its progress lines."""
    import torch

    from components.generation import generate_grasps, load_generator, posed_clouds, refine_grasps
    from components.hand import HandModel
    from components.objects import ObjectLibrary, Scene, sample_scene
    from components.synthesis import SceneObjects
    from flows.evaluate_generated import score_generated
    from flows.pipeline import stage_output
    from tasks.preflight import cache_dir
    from tasks.synthesize_merge import render_grasp_rgb, render_grid

    if n < 1:
        raise MultigraspError(f"--n must be at least 1 (got {n})")
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    if placement is not None:
        if not Path(placement).is_file():
            raise MultigraspError(f"--placement {placement} does not exist; fix the path")
        try:
            scene = Scene.from_dict(json.loads(Path(placement).read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise MultigraspError(f"--placement {placement} is not a readable scene JSON ({type(exc).__name__}); write "
                                  '{"objects": [{"name": ..., "position": [x, y, z], "quat_xyzw": [...]}]}') from None
    else:
        if not objects:
            raise MultigraspError("give --objects (e.g. --objects cube,cylinder) or --placement FILE")
        scene = sample_scene(library, objects, np.random.default_rng(seed), cfg.scenes.sampling)
    for name in scene.names:
        library.get(name)  # unknown names / bad meshes: the library's one-line error (before the generator check)
    manifest = stage_output(cfg, "train-generator")
    if manifest is None:
        raise MultigraspError("no trained generator for this config — run `multigrasp run --until train-generator` "
                              "first (same --profile / --config / --set)")
    stage = cfg.generator
    lift_outputs = _lift_outputs(cfg, scene) if lift else None  # before any work: what the lift needs is there
    if len(scene.objects) > stage.model.max_objects:
        raise MultigraspError(
            f"the generator of this config takes at most {stage.model.max_objects} objects per scene "
            f"(generator.model.max_objects) and the scene has {len(scene.objects)} ({'+'.join(scene.names)}); ask for "
            f"at most {stage.model.max_objects}, or train a generator with a larger generator.model.max_objects")
    hand = HandModel(cfg.hand)
    model = load_generator(manifest.path("generator"))
    positions = np.array([pl.position for pl in scene.objects])
    quats = np.array([pl.quat_xyzw for pl in scene.objects])
    clouds, mask = posed_clouds(library, scene.names, positions, quats, stage.model.points_per_object,
                                stage.model.max_objects)
    gen = torch.Generator().manual_seed(seed)
    if palm_direction_deg is None:
        yaws = torch.rand(n, generator=gen, dtype=torch.float32) * 2.0 * math.pi
    else:
        yaws = torch.full((n,), math.radians(palm_direction_deg))
    clouds_t = torch.as_tensor(clouds, dtype=torch.float32).unsqueeze(0).expand(n, -1, -1, -1)
    mask_t = torch.as_tensor(mask).unsqueeze(0).expand(n, -1)
    scene_objects = SceneObjects(library, scene, hand.device, hand.dtype)
    t0 = time.perf_counter()
    with torch.no_grad():
        p, R, q = generate_grasps(model, hand, clouds_t, yaws, stage.ik, mask_t, per_scene=1, generator=gen,
                                  sampler=stage.sampler, distance=lambda x: scene_objects.sdf(x).amin(-1),
                                  table_height=scene_objects.table_height)
    t1 = time.perf_counter()
    refined = refine_grasps(hand, scene_objects, p.detach(), R.detach(), q.detach(), stage.refine,
                           synthesis=cfg.synthesis.optimizer_for(len(scene.objects)))
    t2 = time.perf_counter()
    folder = cfg.run.workdir / "results" / "generated" / f"{'+'.join(scene.names)}-{seed}"
    atomic_write_json(folder / "scene.json", scene.to_dict())
    q1, pn, ratio, kept = score_generated(cfg, hand, scene_objects, refined)
    rows = [{"p": refined.p[i].tolist(), "R": refined.R[i].reshape(-1).tolist(), "q": refined.q[i].tolist(),
             "penetration_before_mm": float(refined.depth_before[i]) * 1000.0,
             "penetration_after_mm": float(refined.depth_after[i]) * 1000.0,
             "q1": float(q1[i]), "pn_mm": float(pn[i]), "contact_ratio": float(ratio[i]), "kept": bool(kept[i])}
            for i in range(n)]
    seconds = {"sample_and_ik_s": round(t1 - t0, 3), "refine_s": round(t2 - t1, 3)}
    atomic_write_json(folder / "grasps.json", {"grasps": rows, "palm_direction_deg": palm_direction_deg, "seed": seed,
                                               "generator": str(manifest.path("generator")), **seconds})
    urdf = hand.export_urdf(folder / "hand.urdf")
    flat = scene.to_dict()["objects"]
    tiles = [render_grasp_rgb(library, hand, urdf, {"object_names": list(scene.names),
                                                     "object_positions": [v for o in flat for v in o["position"]],
                                                     "object_quats_xyzw": [v for o in flat for v in o["quat_xyzw"]],
                                                     "p": r["p"], "R": r["R"], "q": r["q"]}, cfg.synthesis.camera)
             for r in rows[:16]]
    render_grid(folder / "grasps.png", tiles)
    lifted = lift_generated(cfg, lift_outputs, folder, scene, rows, seed, say) if lift else None
    report = GenerateReport(folder=folder, n=n, seconds=seconds,
                            depth_before_mm=float(refined.depth_before.mean()) * 1000.0,
                            depth_after_mm=float(refined.depth_after.mean()) * 1000.0,
                            kept=sum(r["kept"] for r in rows), lift=lifted)
    report.run_id = _log_generate(cfg, report, scene, seed, manifest)
    return report


def _log_generate(cfg: PipelineConfig, report: GenerateReport, scene, seed: int, generator) -> str:
    """An MLflow run ``generate:<objects>`` with the grasps, their render and, with ``--lift``, the lift's rates
    and GIFs, as ``evaluate`` logs its tables."""
    from flows.config import evaluation_settings
    from flows.runtime import make_tracker
    from tasks.tracking import flatten

    tracker = make_tracker(cfg)
    run_id = tracker.start_run(f"generate:{'+'.join(scene.names)}",
                               tags={"command": "generate", "objects": "+".join(scene.names), "seed": str(seed),
                                     "profile": cfg.profile, "generator_run": generator.producer_run_id or ""})
    # the settings of the generated and lifted grasps (all but where and how it runs), to compare two generate runs
    tracker.log_params(run_id, flatten(evaluation_settings(cfg, "execution_generated.json")))
    metrics = {"generated": report.n, "kept": report.kept, "depth_before_mm": report.depth_before_mm,
               "depth_after_mm": report.depth_after_mm, **report.seconds}
    if report.lift is not None:
        metrics.update({f"lift/{k}": v for k, v in (("succ", report.lift.succ), ("w/o RL", report.lift.without_rl),
                                                    ("squeeze", report.lift.squeeze), ("poses", report.lift.poses),
                                                    ("generalist", report.lift.generalist))
                        if v is not None})
    tracker.log_metrics(run_id, metrics)
    for name in ("grasps.json", "scene.json", "grasps.png", "lift.json"):
        if (report.folder / name).is_file():
            tracker.log_artifact(run_id, report.folder / name, "generated")
    for path in report.lift.gifs if report.lift is not None else ():
        tracker.log_artifact(run_id, path, "rollouts")
    tracker.end_run(run_id)
    return run_id


def _lift_outputs(cfg: PipelineConfig, scene) -> dict:
    """The stage outputs ``--lift`` needs, checked before anything is generated (one-line errors)."""
    from flows.evaluate_execution import EVALUATED_OBJECTS, _stage_outputs

    if len(scene.objects) != EVALUATED_OBJECTS:
        raise MultigraspError(f"--lift lifts {EVALUATED_OBJECTS}-object pre-grasps (the specialists are trained on "
                              f"pairs) and the scene has {len(scene.objects)} ({'+'.join(scene.names)}) — give two "
                              "--objects, or drop --lift")
    from flows.pipeline import stage_output

    # the generalist lifts them too where the distill stage has run for this config (its absence is no error)
    return {**_stage_outputs(cfg, "generate --lift"), "distill": stage_output(cfg, "distill")}


def lift_generated(cfg: PipelineConfig, outputs: dict, folder: Path, scene, rows: list[dict], seed: int,
                   say=None) -> LiftReport:
    """Lift the kept grasps of ``rows`` (one scene's, as ``generate`` wrote them) with the matching specialists,
    and the same trials with ``w/o RL`` and the scripted squeeze (:func:`flows.evaluate_execution.evaluate_split`:
    at most ``specialists.eval_poses`` of them, ``eval_trials`` seeded trials each, after the planned reach with
    ``eval_after_reach``).  Writes ``folder/lift.json`` and ``folder/lift/outcomes.json``."""
    from components.execution.lift_sim import GraspRecord
    from flows.evaluate_execution import evaluate_split, lift_pool, write_outcomes

    stage = cfg.specialists
    combination = "+".join(scene.names)
    records = [GraspRecord(scene=scene, p=np.asarray(r["p"], float), R=np.asarray(r["R"], float).reshape(3, 3),
                           q=np.asarray(r["q"], float),
                           meta={"scene_id": f"generated/{combination}-{seed}", "split": "generated", "row": i,
                                 "combination": combination, "accepted": True})
               for i, r in enumerate(rows) if r["kept"]]
    scratch = folder / "lift"
    generalist: list[int] = []  # the generalist's successes per pose
    if records:
        reach_memo: dict = {}  # with eval_after_reach: each pose reached once for the specialists and the generalist
        with lift_pool(cfg.run) as pool:
            res = evaluate_split(cfg, outputs, "generated", scratch, scripted=True, records=records, say=say,
                                 title=f"lift {combination}", pool=pool, cached=False,  # a one-off, in its own folder
                                 reach_memo=reach_memo)
            if outputs.get("distill") is not None:
                from flows.evaluate_generalist import plan_jobs, run_jobs

                jobs = plan_jobs(cfg, outputs, "generated", scratch, records, "generalist", cached=False,
                                 reach_memo=reach_memo)
                per_job = run_jobs(jobs, pool, say or (lambda line: None), f"lift {combination}")
                generalist = [s for successes in per_job for s in successes]  # one per pose, as the specialist's
                by_key = {key: s for job, successes in zip(jobs, per_job) for key, s in zip(job.keys, successes)}
                for row in res.outcomes:  # outcomes.json: the generalist's column beside the specialist's, per pose
                    row["generalist"] = by_key.get(row["pose_key"])
        write_outcomes(scratch / "outcomes.json", res, stage.eval_trials)
    else:
        from flows.evaluate_execution import SplitResult

        res = SplitResult()
    report = LiftReport(path=folder / "lift.json", kept=len(records), poses=res.poses, trials=stage.eval_trials,
                        succ=res.rate(res.wins, res.total), without_rl=res.rate(res.scripted_wins, res.scripted_total),
                        squeeze=res.rate(res.squeeze_wins, res.squeeze_total), specialists=res.used, gifs=res.gifs,
                        generalist=(sum(generalist) / (len(generalist) * stage.eval_trials) if generalist else None))
    atomic_write_json(report.path, {
        "kept": report.kept, "generated": len(rows), "n_poses": report.poses, "trials": report.trials,
        "succ": report.succ, "w/o RL": report.without_rl, "squeeze": report.squeeze,
        "generalist": report.generalist, "generalist_poses": len(generalist),
        "distill_manifest": (str(Path(outputs["distill"].folder) / "manifest.json")
                             if outputs.get("distill") is not None else None),
        "specialists_used": list(res.used), "matched_by": res.matched_by, "unmatched_poses": res.unmatched,
        "after_reach": stage.eval_after_reach, "gifs": [str(p) for p in res.gifs],
        "specialists_manifest": str(Path(outputs["specialists"].folder) / "manifest.json"),
        "note": "the generated grasps kept by the paper's protocol filter (generator.eval_filter), lifted as "
                "`evaluate execution --source generated` lifts them" if records else
                "no generated grasp passed the paper's protocol filter (generator.eval_filter): nothing was lifted"})
    return report
