"""The ``scenes`` stage: tabletop placements for every object combination of the profile.

Units:
- ``shard-NNN`` — sample placements for a few (split, combination) jobs and settle each
  scene in PyBullet; keep only scenes where every object moves less than the settle
  tolerance.  Output ``scenes.json``.
- ``merge`` — concatenate the shards into ``scenes.json`` (one id per scene), render a
  few scenes to PNG (open hand above the objects) and compute the stage's statistics.
"""

from __future__ import annotations

import json
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task
from pydantic import Field

from components.config_base import Section
from components.execution.cameras import CameraConfig
from components.objects.config import ObjectsConfig, ScenesConfig
from tasks.artifacts import Manifest, atomic_write_json
from tasks.preflight import cache_dir
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

SCENES_CODE_DIRS = ("components/objects", "assets/objects", "tasks/scenes.py")
RENDER_CODE_DIRS = ("components/hand", "assets/hand", "components/execution/cameras.py")  # what the renders run
SPLITS = ("train", "Pl", "Com", "Geo", "many")


class SceneCounts(Section):
    """How many settled scenes to make per object combination, by split."""

    train: int = Field(4, ge=0, le=100_000, description="Training placements per seen combination.")
    Pl: int = Field(2, ge=0, le=100_000, description="Unseen placements per seen combination (-Pl).")
    Com: int = Field(2, ge=0, le=100_000, description="Placements per held-out pair (-Com).")
    Geo: int = Field(2, ge=0, le=100_000, description="Placements per out-of-domain combination (-Geo).")
    many: int = Field(1, ge=0, le=100_000, description="Placements per 3–5 small-cylinder set.")


class ScenesStageConfig(Section):
    """The scenes stage: what to sample, how to shard it and how many to render."""

    sampling: ScenesConfig = Field(default_factory=ScenesConfig, description="Placement sampling and settling.")
    per_combination: SceneCounts = Field(default_factory=SceneCounts, description="Scenes per combination, by split.")
    singles: bool = Field(True, description="Include single-object combinations of the training objects.")
    pairs: bool = Field(True, description="Include pairs (dual-object grasping, the paper's focus).")
    many: bool = Field(True, description="Include the 3-, 4- and 5-object small-cylinder sets.")
    jobs_per_shard: int = Field(8, ge=1, le=10_000, description="(split, combination) jobs per cached shard.")
    renders: int = Field(4, ge=0, le=64, description="Scenes rendered to PNG and logged to MLflow.")
    camera: CameraConfig = Field(default_factory=CameraConfig, description="Render camera.")


def job_seed(base_seed: int, split: str, combo: tuple[str, ...]) -> list[int]:
    """A deterministic, order-independent seed for one (split, combination) job."""
    return [base_seed, zlib.crc32(f"{split}|{'+'.join(combo)}".encode())]


# --------------------------------------------------------------------------- units


def sample_shard(folder: Path, objects: ObjectsConfig, sampling: ScenesConfig,
                 jobs: list[tuple[str, tuple[str, ...], int]], base_seed: int, cache: Path) -> UnitOutput:
    """Sample and settle the scenes of one shard into ``folder/scenes.json``."""
    from components.objects import ObjectLibrary, sample_settled_scenes

    library = ObjectLibrary(objects, cache_dir=cache)
    records: list[dict[str, Any]] = []
    attempted = 0
    for split, combo, n in jobs:
        rng = np.random.default_rng(job_seed(base_seed, split, combo))
        results = sample_settled_scenes(library, list(combo), n, rng, sampling)
        for index, (scene, settle) in enumerate(results):
            records.append({"split": split, "objects": list(combo), "index": index,
                            "scene": scene.to_dict(), "max_displacement_m": settle.max_displacement_m,
                            "stable": bool(settle.stable)})
        attempted += n
    path = atomic_write_json(folder / "scenes.json", {"scenes": records})
    kept = sum(r["stable"] for r in records)
    return UnitOutput(files={"scenes": path}, metrics={"scenes": kept, "requested": attempted},
                      meta={"jobs": len(jobs)})


@task(name="scenes-shard", cache_policy=VerifiedUnitCache(), persist_result=True)
def scenes_shard_task(spec: UnitSpec, objects: ObjectsConfig, sampling: ScenesConfig,
                      jobs: list[tuple[str, tuple[str, ...], int]], base_seed: int) -> Manifest:
    """Prefect unit: one shard of settled scenes."""
    return run_unit(spec, lambda folder: sample_shard(folder, objects, sampling, jobs, base_seed,
                                                      cache_dir(Path(spec.workdir))))


def merge_and_render(folder: Path, shards: list[Manifest], stage: ScenesStageConfig, objects: ObjectsConfig,
                     hand_cfg, cache: Path, render: bool) -> UnitOutput:
    """Concatenate shard scenes, give each an id, render a few, compute statistics."""
    scenes: list[dict[str, Any]] = []
    for shard in shards:
        scenes.extend(json.loads(shard.path("scenes").read_text())["scenes"])
    scenes.sort(key=lambda r: (SPLITS.index(r["split"]), r["objects"], r["index"]))
    for record in scenes:
        record["id"] = f"{record['split']}/{'+'.join(record['objects'])}/{record['index']}"
    files: dict[str, Path] = {"scenes": atomic_write_json(folder / "scenes.json", {"scenes": scenes})}

    by_split = {s: sum(r["split"] == s for r in scenes) for s in SPLITS}
    displacement_mm = np.array([r["max_displacement_m"] * 1000.0 for r in scenes]) if scenes else np.zeros(1)
    metrics = {"scenes": len(scenes), "max_displacement_mm": float(displacement_mm.max()),
               "median_displacement_mm": float(np.median(displacement_mm)),
               **{f"scenes_{s}": float(n) for s, n in by_split.items()}}
    metrics["requested"] = float(sum(s.metrics.get("requested", 0.0) for s in shards))
    metrics["kept_fraction"] = metrics["scenes"] / max(metrics["requested"], 1.0)

    if render and stage.renders and scenes:
        from components.execution.cameras import render_scene_png
        from components.hand import HandModel
        from components.objects import ObjectLibrary, Scene

        library = ObjectLibrary(objects, cache_dir=cache)
        hand = HandModel(hand_cfg)
        urdf = hand.export_urdf(cache / "hand" / "shadow_hand.urdf")
        step = max(1, len(scenes) // stage.renders)
        for i, record in enumerate(scenes[::step][: stage.renders]):
            path = folder / f"render_{i:02d}.png"
            render_scene_png(path, library, Scene.from_dict(record["scene"]), hand, urdf, stage.camera)
            files[f"render_{i:02d}"] = path
    return UnitOutput(files=files, metrics=metrics, meta={"by_split": by_split})


@task(name="scenes-merge", cache_policy=VerifiedUnitCache(), persist_result=True)
def scenes_merge_task(spec: UnitSpec, shards: list[Manifest], stage: ScenesStageConfig, objects: ObjectsConfig,
                      hand_cfg, render: bool) -> Manifest:
    """Prefect unit: merge shards, render PNGs, stage statistics."""
    return run_unit(spec, lambda folder: merge_and_render(folder, shards, stage, objects, hand_cfg,
                                                          cache_dir(Path(spec.workdir)), render))
