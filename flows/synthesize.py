"""Stage flow ``synthesize``: multi-object pre-grasps for the settled scenes (paper §Preliminaries)."""

from __future__ import annotations

from typing import Any

from prefect import flow

from flows.config import PipelineConfig, section_digest
from flows.runtime import (StageProgress, StageResult, make_console, make_task_runner, make_tracker, merge_unit_spec,
                           planned_shards_and_merge, shards_then_merge, start_stage_run, unit_task)
from tasks.artifacts import Manifest, code_version, digest
from tasks.synthesize import SYNTHESIS_CODE_DIRS, read_scene_records, synthesize_shard_task
from tasks.synthesize_merge import MERGE_CODE_DIRS, synthesize_merge_task
from tasks.tracking import Tracker
from tasks.units import UnitSpec, make_spec

STAGE = "synthesize"
UPSTREAM: tuple[str, ...] = ("scenes",)
DESCRIPTION = "synthesise multi-object pre-grasps per scene (DFC energy, annealed MALA, refinement, filter), Q1 / PN"
# the config sections this stage reads, logged as its MLflow run's params (compare two runs' stage in the UI)
SETTINGS: tuple[str, ...] = ("synthesis", "hand", "objects", "run.seed")
#: Console lines listing combinations with 0 accepted grasps (the rest are in report.md).
MAX_ZERO_LINES = 8


def selected_scenes(cfg: PipelineConfig, scenes: Manifest) -> list[dict[str, Any]]:
    """Scene records of the configured splits, at most ``max_scenes_per_combination`` per combination."""
    stage = cfg.synthesis
    picked = []
    for record in read_scene_records(scenes):
        cap = stage.scene_cap(record["split"])
        if record["split"] in stage.splits and (cap == 0 or record["index"] < cap):
            picked.append(record)
    return picked


def shard_name(chunk: list[dict[str, Any]]) -> str:
    """A shard's unit name from the ids of the scenes it holds (``shard-Pl:cube+cylinder:0``, or
    ``shard-<first>..<last>`` for several), so that its cache key does not depend on its position in the plan:
    adding a split or a combination leaves the shards already synthesised cached."""
    ids = [str(record["id"]).replace("/", ":") for record in chunk]
    return f"shard-{ids[0]}" if len(ids) == 1 else f"shard-{ids[0]}..{ids[-1]}"


def shard_plan(cfg: PipelineConfig, scenes: Manifest, run_id: str | None = None, tracking_uri: str | None = None
               ) -> list[tuple[UnitSpec, list[dict[str, Any]]]]:
    """Unit specs of the shards and the scene records each synthesises.

    A shard's key covers the scene contents it reads (not the whole scenes manifest), the optimiser setting its
    scenes use (``synthesis.optimizer`` with the ``optimizer_by_object_count`` fields of their object counts, so
    editing the 3-object setting leaves the pair shards cached), the metrics / min_q1 / hand / objects config,
    ``run.seed`` and the component code.  Shards are named by their scenes (:func:`shard_name`), not numbered.
    """
    records = selected_scenes(cfg, scenes)
    size = cfg.synthesis.scenes_per_shard
    code = code_version(*SYNTHESIS_CODE_DIRS)
    plan = []
    for start in range(0, len(records), size):
        chunk = records[start:start + size]
        optimizers = {n: cfg.synthesis.optimizer_for(n).model_dump(mode="json")
                      for n in sorted({len(r["objects"]) for r in chunk})}
        base = section_digest(cfg, "hand", "objects", "synthesis.metrics", "synthesis.min_q1", "run.seed",
                              extra=optimizers)
        spec = make_spec(stage=STAGE, unit=shard_name(chunk), section_digest=base,
                         upstream={"scenes": digest(chunk)[:20]}, code=code, workdir=cfg.run.workdir,
                         run_id=run_id, tracking_uri=tracking_uri)
        plan.append((spec, chunk))
    return plan


def merge_spec(cfg: PipelineConfig, shards: list[Manifest], run_id: str | None = None,
               tracking_uri: str | None = None) -> UnitSpec:
    """Spec of the merge unit, keyed by the shard manifests it combines."""
    section = section_digest(cfg, "synthesis.renders_per_combination", "synthesis.camera", "synthesis.histogram_bins",
                             "hand", "objects", extra=cfg.tracking.renders)
    return merge_unit_spec(cfg, STAGE, shards, section, code_version(*MERGE_CODE_DIRS), run_id, tracking_uri)


def planned_units(cfg: PipelineConfig, upstream: dict[str, Manifest]) -> list[UnitSpec]:
    """All unit specs whose keys can be known now (for ``multigrasp status``)."""
    return planned_shards_and_merge([spec for spec, _ in shard_plan(cfg, upstream["scenes"])],
                                    lambda shards: merge_spec(cfg, shards))


@flow(name="synthesize", log_prints=False, validate_parameters=False)
def synthesize_flow(cfg: PipelineConfig, parent_run_id: str, upstream: dict[str, Manifest]) -> StageResult:
    """Shards of synthesised grasps (fanned out), then merge + statistics + renders."""
    tracker = make_tracker(cfg)
    run_id = start_stage_run(tracker, cfg, STAGE, SETTINGS, parent_run_id)
    uri = tracker.tracking_uri
    plan = shard_plan(cfg, upstream["scenes"], run_id, uri)
    console = make_console()
    scenes = sum(len(chunk) for _, chunk in plan)
    console.print(f"[bold cyan]{STAGE}[/] {scenes} scene(s) x {cfg.synthesis.optimizer.batch_size} candidates "
                  f"in {len(plan)} shard(s)")
    progress = StageProgress(console, STAGE, total=len(plan) + 1)
    shard = unit_task(synthesize_shard_task)  # named once, for every unit
    futures = [shard.submit(spec, chunk, cfg.synthesis, cfg.objects, cfg.hand, cfg.run.seed, cfg.run.device,
                            cfg.run.torch_threads)
               for spec, chunk in plan]
    result = shards_then_merge(
        STAGE, futures,
        lambda shards: unit_task(synthesize_merge_task).submit(merge_spec(cfg, shards, run_id, uri), shards,
                                                               cfg.synthesis, cfg.objects, cfg.hand,
                                                               cfg.tracking.renders),
        progress, run_id)
    print_report(console, result.manifest)
    return result


def print_report(console, manifest: Manifest) -> None:
    """Per-split lines and the combinations with 0 accepted grasps (with their rejection reasons)."""
    for line in manifest.meta.get("split_lines", []):
        console.print(f"[bold cyan]{STAGE}[/] {line}")
    zero = manifest.meta.get("zero_accepted_lines", [])
    for line in zero[:MAX_ZERO_LINES]:
        console.print(f"[bold yellow]{STAGE}[/] {line}")
    if len(zero) > MAX_ZERO_LINES:
        console.print(f"[bold yellow]{STAGE}[/] … and {len(zero) - MAX_ZERO_LINES} more combination(s) with 0 "
                      f"accepted — see {manifest.path('report')}")


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: stage metrics; stats, report, histograms and renders (only when computed here)."""
    run_id, manifest = result.run_id, result.manifest
    tracker.log_metrics(run_id, manifest.metrics)
    if result.fully_cached:
        return
    for name in ("stats", "report", "energy_terms"):
        if name in manifest.files:
            tracker.log_artifact(run_id, manifest.path(name), "synthesis")
    for name in sorted(manifest.files):
        if name.startswith("render_"):
            tracker.log_artifact(run_id, manifest.path(name), "renders")


def runner_flow(cfg: PipelineConfig):
    """The stage flow bound to the configured task runner."""
    return synthesize_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage", "selected_scenes"]
