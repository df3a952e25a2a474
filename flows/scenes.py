"""Stage flow ``scenes``: settled tabletop placements for every combination of the profile."""

from __future__ import annotations

from prefect import flow

from flows.config import PipelineConfig, section_digest
from flows.runtime import (StageProgress, StageResult, make_console, make_task_runner, make_tracker, merge_unit_spec,
                           planned_shards_and_merge, shards_then_merge, start_stage_run, unit_task)
from tasks.tracking import Tracker
from tasks.artifacts import Manifest, code_version
from tasks.scenes import (RENDER_CODE_DIRS, SCENES_CODE_DIRS, SPLITS, scenes_merge_task,
                          scenes_shard_task)
from tasks.units import UnitSpec, make_spec

STAGE = "scenes"
UPSTREAM: tuple[str, ...] = ()
DESCRIPTION = "sample tabletop placements per object combination, settle them in PyBullet, render a few"
# the config sections this stage reads, logged as its MLflow run's params (compare two runs' stage in the UI)
SETTINGS: tuple[str, ...] = ("scenes", "objects", "hand", "run.seed")


def scene_jobs(cfg: PipelineConfig) -> list[tuple[str, tuple[str, ...], int]]:
    """Every (split, combination, count) job of the profile, in a deterministic order."""
    from components.objects.splits import combinations

    stage = cfg.scenes
    combos = combinations(cfg.objects, include_singles=stage.singles, include_pairs=stage.pairs,
                          include_many=stage.many)
    jobs = []
    for split in SPLITS:
        n = getattr(stage.per_combination, split)
        if n > 0:
            jobs.extend((split, tuple(combo), n) for combo in combos.get(split, []))
    return jobs


def shard_plan(cfg: PipelineConfig, run_id: str | None = None, tracking_uri: str | None = None
               ) -> list[tuple[UnitSpec, list[tuple[str, tuple[str, ...], int]]]]:
    """Unit specs (with cache keys) of the shards and the jobs each one runs."""
    jobs = scene_jobs(cfg)
    size = cfg.scenes.jobs_per_shard
    code = code_version(*SCENES_CODE_DIRS)
    base = section_digest(cfg, "objects", "scenes.sampling", "run.seed")
    plan = []
    for number, start in enumerate(range(0, len(jobs), size)):
        chunk = jobs[start:start + size]
        spec = make_spec(stage=STAGE, unit=f"shard-{number:03d}", section_digest=base + repr(chunk),
                         upstream={}, code=code, workdir=cfg.run.workdir, run_id=run_id,
                         tracking_uri=tracking_uri)
        plan.append((spec, chunk))
    return plan


def merge_spec(cfg: PipelineConfig, shards: list[Manifest], run_id: str | None = None,
               tracking_uri: str | None = None) -> UnitSpec:
    """Spec of the merge unit, keyed by the shard manifests it combines."""
    section = section_digest(cfg, "scenes.renders", "scenes.camera", "hand", extra=cfg.tracking.renders)
    return merge_unit_spec(cfg, STAGE, shards, section, code_version(*SCENES_CODE_DIRS, *RENDER_CODE_DIRS), run_id,
                           tracking_uri)


def planned_units(cfg: PipelineConfig, upstream: dict[str, Manifest]) -> list[UnitSpec]:
    """All unit specs whose keys can be known now (for ``multigrasp status``)."""
    return planned_shards_and_merge([spec for spec, _ in shard_plan(cfg)], lambda shards: merge_spec(cfg, shards))


@flow(name="scenes", log_prints=False, validate_parameters=False)
def scenes_flow(cfg: PipelineConfig, parent_run_id: str, upstream: dict[str, Manifest]) -> StageResult:
    """Shards of sampled + settled scenes (fanned out), then merge + render."""
    tracker = make_tracker(cfg)
    run_id = start_stage_run(tracker, cfg, STAGE, SETTINGS, parent_run_id)
    uri = tracker.tracking_uri
    plan = shard_plan(cfg, run_id, uri)
    progress = StageProgress(make_console(), STAGE, total=len(plan) + 1)
    shard = unit_task(scenes_shard_task)  # named once, for every unit
    futures = [shard.submit(spec, cfg.objects, cfg.scenes.sampling, jobs, cfg.run.seed)
               for spec, jobs in plan]
    return shards_then_merge(
        STAGE, futures,
        lambda shards: unit_task(scenes_merge_task).submit(merge_spec(cfg, shards, run_id, uri), shards, cfg.scenes,
                                                           cfg.objects, cfg.hand, cfg.tracking.renders),
        progress, run_id)


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: stage metrics, the scene list and the renders (only when computed here)."""
    run_id, manifest = result.run_id, result.manifest
    tracker.log_metrics(run_id, manifest.metrics)
    if result.fully_cached:
        return
    tracker.log_artifact(run_id, manifest.path("scenes"), "scenes")
    for name in sorted(manifest.files):
        if name.startswith("render_"):
            tracker.log_artifact(run_id, manifest.path(name), "renders")


def runner_flow(cfg: PipelineConfig):
    """The stage flow bound to the configured task runner."""
    return scenes_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage", "scene_jobs"]
