"""The ``reach`` stage: bring an open hand to every pre-grasp the specialists train on, in PyBullet, and record
where everything ends up (paper §"Multi-object Grasp Execution": a planned reach precedes the lift; the end-of-reach
states, objects possibly pushed, are what §"Learning from Imprecise Poses" adapts the policies to).

Units: shards of ``records_per_shard`` pre-grasps (the specialists' selection: ``specialists.splits``,
``records_source``, ``max_objects``; at most ``reach.max_records``, evenly spread), fanned out through the task runner, then a
merge.  Per pre-grasp (:mod:`components.execution.reaching`): plan the path from the open hand
``reaching.retreat_m`` behind it (linear, then optimised against penetration with a smoothness term), execute it
with a PD-driven base and joint targets, and keep the end-of-reach record (``meta``: ``object_displacement_m``
per object, ``palm_error_m``, the path's penetration before and after planning, and the pre-grasp's synthesis
row).  Shard files: ``reached.json`` (:func:`components.execution.records.save_records` format) and
``stats.json``; merge: all records in one ``reached.json``, ``stats.json`` and a histogram of the largest object
displacement per reach.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task
from pydantic import Field

from components.config_base import Section
from components.execution.lift_config import LiftEnvConfig
from components.execution.reaching import ReachingConfig
from components.objects.config import ObjectsConfig
from tasks.artifacts import Manifest, atomic_write_json, atomic_write_with
from tasks.preflight import cache_dir
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

REACH_CODE_DIRS = ("components/execution/reaching.py", "components/execution/lift_sim.py",
                   "components/execution/lift_config.py", "components/execution/records.py", "components/synthesis",
                   "components/hand", "assets/hand", "components/objects", "assets/objects", "tasks/reach.py")


class ReachStageConfig(Section):
    """The reach stage: which pre-grasps (the specialists' selection, capped) and how the reach is planned / run."""

    reaching: ReachingConfig = Field(default_factory=ReachingConfig, description="Path planning and its execution.")
    max_records: int = Field(
        0, ge=0, description="Reach at most this many of the specialists' pre-grasps, evenly spread over them (0 = all). "
        "A reach costs ~2.5 s on one core with the default reaching (40 bench pairs, README).")
    records_per_shard: int = Field(16, ge=1, description="Pre-grasps per cached unit (a crash loses at most one shard).")
    displaced_threshold_m: float = Field(
        0.01, gt=0.0, description="A reach 'displaces' its objects when one of them moved more than this (m); the "
        "stage reports the fraction.")


def reach_summary(records: list[dict[str, Any]], threshold: float) -> dict[str, Any]:
    """Metrics of end-of-reach records: count, median / p90 of the largest object displacement (m), the fraction
    above ``threshold``, median palm error (m), mean path penetration before / after planning."""
    if not records:
        return {"reached": 0}
    moved = np.array([max(r["meta"]["object_displacement_m"]) for r in records])
    palm = np.array([r["meta"]["palm_error_m"] for r in records])
    straight = np.array([r["meta"]["penetration_straight"] for r in records])
    planned = np.array([r["meta"]["penetration_planned"] for r in records])
    return {"reached": len(records), "displacement_median_m": round(float(np.median(moved)), 6),
            "displacement_p90_m": round(float(np.quantile(moved, 0.9)), 6),
            "displaced_fraction": round(float(np.mean(moved > threshold)), 6),
            "palm_error_median_m": round(float(np.median(palm)), 6),
            "path_penetration_straight": round(float(straight.mean()), 6),
            "path_penetration_planned": round(float(planned.mean()), 6)}


def reach_records(records: list, reaching: ReachingConfig, lift: LiftEnvConfig, hand, library, urdf: Path,
                  progress=None) -> list:
    """End-of-reach records (GraspRecords) of pre-grasp records: plan and execute each reach in one LiftWorld
    (module docstring); ``meta`` gains the plan's path penetration before / after planning.  ``progress(k, n, end)``
    after each."""
    from components.execution.lift_sim import LiftWorld
    from components.execution.reaching import execute_reach, plan_reach
    from components.synthesis import SceneObjects

    world = LiftWorld(hand, library, urdf, lift)
    reached = []
    try:
        for number, record in enumerate(records):
            waypoints, plan = plan_reach(hand, SceneObjects(library, record.scene), record, reaching)
            end = execute_reach(world, record, waypoints, reaching)
            end.meta.update({k: round(float(v), 9) for k, v in plan.items()})
            reached.append(end)
            if progress is not None:
                progress(number + 1, len(records), end)
    finally:
        world.close()
    return reached


def reach_shard(folder: Path, records: list[dict[str, Any]], stage: ReachStageConfig, lift: LiftEnvConfig,
                objects: ObjectsConfig, hand_cfg, cache: Path, unit: str) -> UnitOutput:
    """Plan and execute the reach of each record (module docstring); write ``reached.json`` and ``stats.json``."""
    from components.execution.records import record_from_dict, record_to_dict, save_records
    from components.hand import HandModel
    from components.objects import ObjectLibrary

    hand = HandModel(hand_cfg)
    start = time.perf_counter()

    def progress(done: int, total: int, end) -> None:
        elapsed = time.perf_counter() - start
        print(f"reach {unit} {done}/{total}: largest object displacement "
              f"{max(end.meta['object_displacement_m']) * 1000:.1f} mm, palm error {end.meta['palm_error_m'] * 1000:.1f} mm, "
              f"ETA {elapsed / done * (total - done):.0f}s", file=sys.stderr, flush=True)

    reached = reach_records([record_from_dict(r) for r in records], stage.reaching, lift, hand,
                            ObjectLibrary(objects, cache_dir=cache), hand.export_urdf(folder / "hand.urdf"), progress)
    path = save_records(folder / "reached.json", reached)
    metrics = reach_summary([record_to_dict(r) for r in reached], stage.displaced_threshold_m)
    stats = atomic_write_json(folder / "stats.json", metrics)
    return UnitOutput(files={"reached": path, "stats": stats}, metrics=metrics)


def plot_displacements(path: Path, records: list, threshold: float) -> Path:
    """Histogram of the largest object displacement per reach (mm) as a PNG."""
    from matplotlib.figure import Figure  # no pyplot: no global state

    moved = [1000.0 * max(r.meta["object_displacement_m"]) for r in records]
    fig = Figure(figsize=(5, 3))
    ax = fig.add_subplot()
    ax.hist(moved, bins=30)
    ax.axvline(1000.0 * threshold, color="red", linestyle="--")
    ax.set_xlabel("largest object displacement during the reach (mm)")
    ax.set_ylabel("reaches")
    fig.tight_layout()
    return atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))


@task(name="reach-shard", cache_policy=VerifiedUnitCache(), persist_result=True)
def reach_shard_task(spec: UnitSpec, records: list[dict[str, Any]], stage: ReachStageConfig, lift: LiftEnvConfig,
                     objects: ObjectsConfig, hand_cfg) -> Manifest:
    """Prefect unit: one shard of reaches."""
    return run_unit(spec, lambda folder: reach_shard(folder, records, stage, lift, objects, hand_cfg,
                                                     cache_dir(Path(spec.workdir)), spec.unit))


@task(name="reach-merge", cache_policy=VerifiedUnitCache(), persist_result=True)
def reach_merge_task(spec: UnitSpec, shards: list[Manifest], threshold: float) -> Manifest:
    """Prefect unit: every shard's end-of-reach records in one ``reached.json``, ``stats.json``, the histogram."""
    from components.execution.records import load_records, record_to_dict, save_records

    def body(folder: Path) -> UnitOutput:
        records = [r for m in shards for r in load_records(m.path("reached"))]
        path = save_records(folder / "reached.json", records)
        metrics = reach_summary([record_to_dict(r) for r in records], threshold)
        stats = atomic_write_json(folder / "stats.json", metrics)
        files = {"reached": path, "stats": stats}
        if records:
            files["displacements"] = plot_displacements(folder / "displacements.png", records, threshold)
        return UnitOutput(files=files, metrics=metrics)

    return run_unit(spec, body)
