"""``multigrasp evaluate pregrasp --source generated``: pre-grasp quality of the trained generator on the
evaluation scenes (paper Table "pre-grasp quality", Gen rows).

For each setting ``Gen-Pl`` / ``Gen-Com`` / ``Gen-Geo``, the first ``generator.eval_scenes`` scenes of that
split (the ``scenes`` stage's, the same ones synthesis saw) each get ``generator.eval_grasps_per_scene``
grasps -- random palm directions, sampling (``generator.sampler``), IK, refinement -- whose Q1, PN and Div are measured as
for the synthetic rows (``synthesis.metrics``).  ``time_s`` is the wall time of sampling + IK + refinement
of the setting's grasps (in batches of ``eval_grasps_per_scene``).  ``time_256_s`` is the paper's "Time": the wall
time of sampling + IK + refinement of one batch of :data:`TIME_BATCH` (256) grasps for the setting's first scene,
generated after its scenes (warm) and not scored; with ``eval_grasps_per_scene`` 256 the mean time of the setting's
own batches instead (no extra batch).  Until the fifty-second session it was ``time_s`` scaled to 256
grasps, which on a CPU overstated it at the bench profile's batches of 16 (~24 s for 16 batches of 16 against
9.3 s for one of 256: a step of sampling or refinement costs nearly the same for 16 grasps as for 256).

The paper's protocol discards generated pre-grasps "with significant penetration or insufficient contact ratio"
(``generator.eval_filter``, :mod:`components.generation.filter`). A row's ``q1`` / ``pn_mm`` / ``div_deg`` are
over the kept grasps, ``accept_rate`` = kept / generated, and ``q1_all`` / ``pn_mm_all`` / ``div_deg_all`` are over
every generated grasp (the rows' only figures until the thirty-fourth session), with ``contact_ratio`` their mean
contact ratio. With ``eval_filter.enabled: false`` every grasp is kept.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from components.errors import MultigraspError
from flows.config import PipelineConfig, with_overrides

GENERATED_SETTINGS = (("Gen-Pl", "Pl"), ("Gen-Com", "Com"), ("Gen-Geo", "Geo"))
#: Grasps of the batch that ``time_256_s`` times: the paper's Table I gives the seconds to produce 256 pre-grasps.
TIME_BATCH = 256


#: The generator ablations of the paper (Table "ablations", generation): config overrides of each variant.
GENERATOR_ABLATIONS: dict[str, dict[str, Any]] = {
    "Ours": {},
    "Joint Angles": {"generator.model.representation": "joints"},
    "w/o Obj Embd": {"generator.model.use_object_embedding": False},
    "w/o Refinement": {"generator.refine.steps": 0, "generator.refine.fc_steps": 0},
}


#: What an ablation row keeps of its Gen-Pl row: Q1 / PN over the kept grasps (the paper's protocol), the kept
#: fraction, and Q1 / PN over every generated grasp.
ABLATION_FIELDS = ("q1", "pn_mm", "n", "accept_rate", "q1_all", "pn_mm_all")


def generator_ablation_rows(cfg: PipelineConfig, ours: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """Q1 / PN on the Pl scenes of every :data:`GENERATOR_ABLATIONS` variant; variants that change the model
    are trained first (the train-generator stage with the overrides: cached units).  ``ours``: the Gen-Pl row
    already measured for ``cfg`` (reused for "Ours" instead of generating it again)."""
    from flows import train_generator
    from flows.pipeline import run_pipeline

    rows = []
    for name, overrides in GENERATOR_ABLATIONS.items():
        if not overrides and ours is not None:
            rows.append({"setting": name, **{k: ours.get(k) for k in ABLATION_FIELDS}, "overrides": {}})
            continue
        variant = with_overrides(cfg, overrides)
        if any(key.startswith("generator.model") for key in overrides):
            run_pipeline(variant, [train_generator], command=f"ablation:{name}")
        pl = generated_rows(variant, settings=(("Gen-Pl", "Pl"),), timed=False)[0][0]
        rows.append({"setting": name, **{k: pl.get(k) for k in ABLATION_FIELDS}, "overrides": overrides})
    return rows


def _progress_line(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def generate_for_scene(cfg: PipelineConfig, model, hand, library, record: dict[str, Any], number: int,
                       n: int | None = None):
    """``n`` (default ``generator.eval_grasps_per_scene``) grasps for one scene record of the ``scenes`` stage: palm yaws and noise
    seeded by (``run.seed``, ``number``), sampling, IK and the refinement of ``cfg.generator`` (with the run's
    synthesis settings for the force-closure stage).  -> (SceneObjects, RefineResult, seconds of generation, IK and
    refinement)."""
    import torch

    from components.generation import generate_grasps, posed_clouds, refine_grasps
    from components.objects import Scene
    from components.synthesis import SceneObjects

    stage = cfg.generator
    scene = Scene.from_dict(record["scene"])
    positions = np.array([pl.position for pl in scene.objects])
    quats = np.array([pl.quat_xyzw for pl in scene.objects])
    clouds, mask = posed_clouds(library, scene.names, positions, quats, stage.model.points_per_object,
                                stage.model.max_objects)
    n = stage.eval_grasps_per_scene if n is None else n
    gen = torch.Generator().manual_seed(cfg.run.seed * 7919 + number)
    yaws = torch.rand(n, generator=gen) * 2.0 * math.pi
    objects = SceneObjects(library, scene, hand.device, hand.dtype)
    start = time.perf_counter()
    with torch.no_grad():
        p, R, q = generate_grasps(model, hand, torch.as_tensor(clouds, dtype=torch.float32)[None].expand(n, -1, -1, -1),
                                  yaws, stage.ik, torch.as_tensor(mask)[None].expand(n, -1), generator=gen,
                                  sampler=stage.sampler, distance=lambda x: objects.sdf(x).amin(-1),
                                  table_height=objects.table_height)
    refined = refine_grasps(hand, objects, p.detach(), R.detach(), q.detach(), stage.refine,
                            synthesis=cfg.synthesis.optimizer_for(len(scene.objects)))
    return objects, refined, time.perf_counter() - start


#: Columns of :func:`generated_table` (also of an empty one).
GENERATED_COLUMNS = ["scene_id", "split", "combination", "row", "object_names", "object_positions",
                     "object_quats_xyzw", "p", "R", "q", "accepted", "q1", "pn_mm", "pn_before_mm", "contact_ratio"]


def generated_table(cfg: PipelineConfig, model, hand, library, scene_records: list[dict[str, Any]],
                    progress: Callable[[str], None] | None = None, with_q1: bool = True):
    """Generated, refined and scored grasps of ``scene_records`` (scenes-stage records; the ``number`` of
    :func:`generate_for_scene` is each record's index here) as a frame in the synthesis table's layout
    (``scene_id``, ``split``, ``combination``, ``row``, object names / positions / quaternions, ``p``, ``R``, ``q``,
    ``accepted`` = kept by ``generator.eval_filter``, ``q1``, ``pn_mm``, ``contact_ratio``; no chosen contacts) plus
    ``pn_before_mm``, the raw sample's deepest penetration (after IK, before refinement), so that what reads a
    synthesis table's rows (:func:`tasks.specialists.records_from_table`, the grasp-table tools) reads generated
    grasps the same way.  ``with_q1=False`` leaves ``q1`` NaN (the filter does not need it; Q1 is the costly
    metric).  ``progress`` gets one line per scene.  -> (frame, seconds of generation, IK and refinement)."""
    import pandas as pd

    rows, seconds = [], 0.0
    for number, record in enumerate(scene_records):
        objects, refined, elapsed = generate_for_scene(cfg, model, hand, library, record, number)
        seconds += elapsed
        q1, pn, ratio, kept = score_generated(cfg, hand, objects, refined, with_q1=with_q1)
        scene = objects.scene
        for i in range(refined.p.shape[0]):
            rows.append({"scene_id": record["id"], "split": record["split"], "combination": "+".join(scene.names),
                         "row": i, "object_names": list(scene.names),
                         "object_positions": np.concatenate([pl.position for pl in scene.objects]).tolist(),
                         "object_quats_xyzw": np.concatenate([pl.quat_xyzw for pl in scene.objects]).tolist(),
                         "p": refined.p[i].tolist(), "R": refined.R[i].reshape(-1).tolist(),
                         "q": refined.q[i].tolist(), "accepted": bool(kept[i]), "q1": float(q1[i]),
                         "pn_mm": float(pn[i]), "pn_before_mm": float(refined.depth_before[i]) * 1000.0,
                         "contact_ratio": float(ratio[i])})
        if progress is not None:
            progress(f"scene {number + 1}/{len(scene_records)} ({refined.p.shape[0]} grasps, {int(kept.sum())} kept; "
                     f"generation, IK, refinement{', Q1' if with_q1 else ''}, PN {elapsed:.1f}s)")
    return pd.DataFrame(rows, columns=GENERATED_COLUMNS), seconds


def load_generator_for(cfg: PipelineConfig, checkpoint: Path | None = None, purpose: str = "this command"):
    """The scenes stage's manifest and the generator (the config's train-generator stage, or ``checkpoint``), with
    one-line errors naming the command that makes what is missing."""
    from components.generation import load_generator
    from flows.pipeline import stage_output

    scenes = stage_output(cfg, "scenes")
    if scenes is None:
        raise MultigraspError(f"{purpose} needs the scenes stage for this config — run `multigrasp run --until scenes` "
                              "first (same --profile / --config / --set)")
    generator = stage_output(cfg, "train-generator") if checkpoint is None else None
    if checkpoint is None and generator is None:
        raise MultigraspError(f"{purpose} needs a trained generator for this config — run `multigrasp run --until "
                              "train-generator` first (same --profile / --config / --set)")
    model = load_generator(generator.path("generator") if checkpoint is None else checkpoint)
    return scenes, generator, model


def score_generated(cfg: PipelineConfig, hand, objects, refined, with_q1: bool = True):
    """Q1, PN (mm), contact ratio and the paper's protocol filter (``generator.eval_filter``) of one scene's refined
    grasps (:func:`generate_for_scene`). -> q1, pn_mm, contact_ratio (B,) float tensors and kept (B,) bool.
    ``with_q1=False``: Q1 is NaN (not computed)."""
    import torch

    from components.generation import contact_ratio, keep_generated
    from components.metrics import penetration_depth, q1_grasps

    metrics, keep = cfg.synthesis.metrics, cfg.generator.eval_filter
    pn = penetration_depth(hand, objects, refined.p, refined.R, refined.q, metrics).pn_mm
    ratio = contact_ratio(hand, objects, refined.p, refined.R, refined.q,
                          cfg.synthesis.optimizer_for(objects.n_objects), keep.contact_distance_m)
    pn = torch.as_tensor(pn, dtype=ratio.dtype)
    if with_q1:
        q1 = torch.as_tensor(q1_grasps(hand, objects, refined.p, refined.R, refined.q, metrics)[0], dtype=ratio.dtype)
    else:
        q1 = torch.full_like(ratio, float("nan"))
    return q1, pn, ratio, keep_generated(pn, ratio, keep)


def generated_rows(cfg: PipelineConfig, settings=GENERATED_SETTINGS, checkpoint: Path | None = None,
                   progress: Callable[[str], None] | None = _progress_line, timed: bool = True,
                   ) -> tuple[list[dict[str, Any]], dict[str, str]]:
    """The Gen rows of ``settings`` (module docstring) and where the model came from: the config's
    ``train-generator`` stage, or ``checkpoint`` (a ``generator.pt``) when given.  Each row also has
    ``pn_before_refine_mm``, the mean deepest penetration of the raw samples (after IK, before refinement).
    ``progress`` gets one line per scene (setting, scene k/n, elapsed, ETA; stderr by default).  ``timed=False``
    skips the timed batch (``time_256_s`` is then None; the ablation rows do not report time)."""
    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from flows.evaluate import Setting, setting_row
    from tasks.preflight import cache_dir
    from tasks.synthesize import read_scene_records

    scenes, generator, model = load_generator_for(cfg, checkpoint, "evaluate pregrasp --source generated")
    stage = cfg.generator
    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    records = read_scene_records(scenes)
    rows = []
    plan = [(name, split, [r for r in records if r["split"] == split
                           and len(r["objects"]) <= stage.model.max_objects][: stage.eval_scenes])
            for name, split in settings]
    total, done, begin = sum(len(picked) for _, _, picked in plan), [0], time.perf_counter()
    for name, split, picked in plan:
        def scene_done(line: str, name: str = name) -> None:
            done[0] += 1
            if progress is not None:
                elapsed = time.perf_counter() - begin
                progress(f"generated {name} {line} elapsed {elapsed:.0f}s ETA {elapsed / done[0] * (total - done[0]):.0f}s")

        frame, seconds = generated_table(cfg, model, hand, library, picked, progress=scene_done)
        row = setting_row(Setting(name, split), frame[frame["accepted"].astype(bool)], len(frame))
        every = setting_row(Setting(name, split), frame, len(frame))
        row.update({"q1_all": every["q1"], "pn_mm_all": every["pn_mm"], "div_deg_all": every["div_deg"],
                    "n_generated": len(frame),
                    "contact_ratio": round(float(frame["contact_ratio"].mean()), 4) if len(frame) else None})
        row["pn_before_refine_mm"] = round(float(frame["pn_before_mm"].mean()), 3) if len(frame) else None
        row["time_s"] = round(seconds, 3)
        row["time_256_s"] = None
        if timed and picked:
            if stage.eval_grasps_per_scene == TIME_BATCH:  # the setting's own batches are of 256: their mean time
                batch_seconds = seconds / len(picked)
            else:
                if progress is not None:
                    progress(f"timing {name}: one batch of {TIME_BATCH} grasps for its first scene (sampling, IK, "
                             "refinement)")
                *_, batch_seconds = generate_for_scene(cfg, model, hand, library, picked[0], len(picked), n=TIME_BATCH)
            row["time_256_s"] = round(batch_seconds, 2)
            row["time_batch"] = TIME_BATCH
        rows.append(row)
    if checkpoint is not None:
        return rows, {"generator_checkpoint": str(checkpoint)}
    return rows, {"generator_manifest": str(Path(generator.folder) / "manifest.json"),
                  "generator_run": generator.producer_run_id or ""}
