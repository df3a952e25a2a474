"""Stage flow ``reach``: planned, penetration-free approaches to the specialists' pre-grasps, executed in
PyBullet; the end-of-reach states are recorded (``tasks.reach``)."""

from __future__ import annotations

from prefect import flow

from components.execution.records import record_to_dict
from flows.config import PipelineConfig, section_digest
from flows.runtime import (StageProgress, StageResult, make_console, make_task_runner, make_tracker, merge_unit_spec,
                           planned_shards_and_merge, shards_then_merge, start_stage_run, unit_task)
from tasks.artifacts import Manifest, code_version, digest
from tasks.reach import REACH_CODE_DIRS, reach_merge_task, reach_shard_task
from tasks.specialists import select_records, spread_records
from tasks.tracking import Tracker
from tasks.units import UnitSpec, make_spec

STAGE = "reach"
UPSTREAM: tuple[str, ...] = ("synthesize",)
DESCRIPTION = "plan and execute the reach from an open hand to each specialist pre-grasp in PyBullet; record the end-of-reach states"
# the config sections this stage reads, logged as its MLflow run's params (compare two runs' stage in the UI)
SETTINGS: tuple[str, ...] = ("reach", "lift", "hand", "objects")


def shard_plan(cfg: PipelineConfig, upstream: dict[str, Manifest], run_id: str | None = None,
               tracking_uri: str | None = None) -> list[tuple[UnitSpec, list[dict]]]:
    """(spec, records as dicts) of every shard: the specialists' pre-grasps, at most ``reach.max_records`` of them
    evenly spread over that list (which is in scene order, so every combination keeps its share)."""
    stage = cfg.reach
    records = spread_records(select_records(upstream["synthesize"], cfg.specialists, cfg.specialists.splits),
                             stage.max_records)
    dicts = [record_to_dict(r) for r in records]
    base = section_digest(cfg, "reach.reaching", "lift", "hand", "objects")
    code = code_version(*REACH_CODE_DIRS)
    plan = []
    for number, first in enumerate(range(0, len(dicts), stage.records_per_shard)):
        chunk = dicts[first: first + stage.records_per_shard]
        spec = make_spec(stage=STAGE, unit=f"shard-{number:03d}", section_digest=base,
                         upstream={"records": digest(chunk)[:20]}, code=code, workdir=cfg.run.workdir, run_id=run_id,
                         tracking_uri=tracking_uri)
        plan.append((spec, chunk))
    return plan


def merge_spec(cfg: PipelineConfig, shards: list[Manifest], run_id: str | None = None,
               tracking_uri: str | None = None) -> UnitSpec:
    return merge_unit_spec(cfg, STAGE, shards, section_digest(cfg, "reach.displaced_threshold_m"),
                           code_version("tasks/reach.py"), run_id, tracking_uri)


def planned_units(cfg: PipelineConfig, upstream: dict[str, Manifest]) -> list[UnitSpec]:
    return planned_shards_and_merge([spec for spec, _ in shard_plan(cfg, upstream)], lambda shards: merge_spec(cfg, shards))


@flow(name="reach", log_prints=False, validate_parameters=False)
def reach_flow(cfg: PipelineConfig, parent_run_id: str, upstream: dict[str, Manifest]) -> StageResult:
    tracker = make_tracker(cfg)
    run_id = start_stage_run(tracker, cfg, STAGE, SETTINGS, parent_run_id)
    uri = tracker.tracking_uri
    plan = shard_plan(cfg, upstream, run_id, uri)
    console = make_console()
    console.print(f"[bold cyan]{STAGE}[/] {sum(len(c) for _, c in plan)} pre-grasp(s) in {len(plan)} shard(s) "
                  f"({cfg.reach.reaching.waypoints} waypoints, {cfg.reach.reaching.steps} planning steps)")
    if not plan:
        console.print(f"[bold yellow]{STAGE}[/] no pre-grasps to reach: the synthesis stage accepted none in the "
                      f"splits {cfg.specialists.splits} — see its report.md")
    progress = StageProgress(console, STAGE, total=len(plan) + 1)
    shard = unit_task(reach_shard_task)  # named once, for every unit
    futures = [shard.submit(spec, chunk, cfg.reach, cfg.lift, cfg.objects, cfg.hand)
               for spec, chunk in plan]
    threshold = cfg.reach.displaced_threshold_m
    return shards_then_merge(STAGE, futures,
                             lambda shards: unit_task(reach_merge_task).submit(merge_spec(cfg, shards, run_id, uri),
                                                                               shards, threshold),
                             progress, run_id)


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: the merged metrics, and the displacement histogram when computed here."""
    tracker.log_metrics(result.run_id, result.manifest.metrics)
    if not result.fully_cached and "displacements" in result.manifest.files:
        tracker.log_artifact(result.run_id, result.manifest.path("displacements"), "reach")


def runner_flow(cfg: PipelineConfig):
    return reach_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage"]
