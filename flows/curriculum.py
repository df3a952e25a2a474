"""Stage flow ``curriculum``: each specialist adapted to imprecise pre-grasps in three phases (``tasks.curriculum``)."""

from __future__ import annotations

from pathlib import Path

from prefect import flow

from flows.config import PipelineConfig, section_digest
from flows.runtime import (StageProgress, StageResult, make_console, make_task_runner, make_tracker, merge_unit_spec,
                           planned_shards_and_merge, shards_then_merge, start_stage_run, unit_task)
from flows.specialists import bin_config_digest, bin_unit
from tasks.artifacts import Manifest, code_version, digest
from tasks.curriculum import CURRICULUM_CODE_DIRS, adapt_bin_task
from tasks.specialist_index import read_specialist_index
from tasks.specialists import merge_task
from tasks.tracking import Tracker
from tasks.units import UnitSpec, make_spec

STAGE = "curriculum"
UPSTREAM: tuple[str, ...] = ("specialists", "reach", "train-generator", "pointnet")
DESCRIPTION = ("adapt each specialist to imprecise pre-grasps: reached and generated starts, three phases of PPO "
               "from its checkpoint")
# the config sections this stage reads, logged as its MLflow run's params (compare two runs' stage in the UI)
SETTINGS: tuple[str, ...] = ("curriculum", "specialists", "generator", "synthesis", "scenes.sampling", "reach.reaching",
                             "lift", "hand", "objects")


def config_digest(cfg: PipelineConfig) -> str:
    """The config part of every adapted bin's key: the curriculum, what shapes a specialist's training
    (:func:`flows.specialists.bin_config_digest`) and what makes the generated starts (the generator's sampling, IK,
    refinement, the protocol filter where ``curriculum.filter_generated`` applies it, the synthesis settings the
    refinement and PN use, the placements' sampling, the reach).  Without ``filter_generated`` the filter decides
    nothing here, so ``generate --lift --set generator.eval_filter.enabled=false`` still finds the adapted specialists
    and the generalist distilled from them."""
    filtered = ("generator.eval_filter",) if cfg.curriculum.filter_generated else ()
    return digest({"specialist": bin_config_digest(cfg),
                   "sections": section_digest(cfg, "curriculum", "specialists.clustering", "generator.sampler",
                                              "generator.ik", "generator.refine", *filtered,
                                              "generator.model.points_per_object", "generator.model.max_objects",
                                              "synthesis.optimizer", "synthesis.optimizer_by_object_count",
                                              "synthesis.metrics", "scenes.sampling", "reach.reaching")})


def bin_plan(cfg: PipelineConfig, upstream: dict[str, Manifest], run_id: str | None = None,
             tracking_uri: str | None = None) -> list[tuple[UnitSpec, str, dict]]:
    """(spec, bin label, specialists index entry) of every specialist."""
    index = read_specialist_index(upstream["specialists"])
    base, code = config_digest(cfg), code_version(*CURRICULUM_CODE_DIRS)
    plan = []
    for label, entry in sorted(index.items()):
        spec = make_spec(stage=STAGE, unit=bin_unit(label), section_digest=base,
                         upstream={"specialist": Path(entry["folder"]).name[:20], "reach": upstream["reach"].key[:20],
                                   "generator": upstream["train-generator"].key[:20],
                                   "pointnet": upstream["pointnet"].key[:20]},
                         code=code, workdir=cfg.run.workdir, run_id=run_id, tracking_uri=tracking_uri)
        plan.append((spec, label, entry))
    return plan


def merge_spec(cfg: PipelineConfig, bins: list[Manifest], run_id: str | None = None,
               tracking_uri: str | None = None) -> UnitSpec:
    return merge_unit_spec(cfg, STAGE, bins, section_digest(cfg, "curriculum"), code_version("tasks/specialists.py"),
                           run_id, tracking_uri)


def planned_units(cfg: PipelineConfig, upstream: dict[str, Manifest]) -> list[UnitSpec]:
    return planned_shards_and_merge([spec for spec, _, _ in bin_plan(cfg, upstream)], lambda bins: merge_spec(cfg, bins))


@flow(name="curriculum", log_prints=False, validate_parameters=False)
def curriculum_flow(cfg: PipelineConfig, parent_run_id: str, upstream: dict[str, Manifest]) -> StageResult:
    from components.execution.records import load_records, record_to_dict

    tracker = make_tracker(cfg)
    run_id = start_stage_run(tracker, cfg, STAGE, SETTINGS, parent_run_id)
    uri = tracker.tracking_uri
    plan = bin_plan(cfg, upstream, run_id, uri)
    stage = cfg.curriculum
    console = make_console()
    console.print(f"[bold cyan]{STAGE}[/] {len(plan)} specialist(s), phases of {stage.phase_iterations} iterations, "
                  f"{stage.generated_scenes} x {stage.generated_per_scene} generated pre-grasps per bin")
    reached = [record_to_dict(r) for r in load_records(upstream["reach"].path("reached"))]
    progress = StageProgress(console, STAGE, total=len(plan) + 1)
    adapt = unit_task(adapt_bin_task)  # named once, for every bin
    generator = str(upstream["train-generator"].path("generator"))
    encoder = str(upstream["pointnet"].path("encoder"))
    futures = [adapt.submit(spec, label, entry, reached, stage, cfg.specialists, cfg.generator, cfg.synthesis,
                            cfg.scenes.sampling, cfg.reach.reaching, cfg.lift, cfg.objects, cfg.hand, generator, encoder)
               for spec, label, entry in plan]
    return shards_then_merge(STAGE, futures,
                             lambda bins: unit_task(merge_task).submit(merge_spec(cfg, bins, run_id, uri), bins),
                             progress, run_id)


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: per-bin curves of the adaptation (as the specialists stage logs its own)."""
    from flows.specialists import log_stage as log_bins

    log_bins(tracker, result)


def runner_flow(cfg: PipelineConfig):
    return curriculum_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage"]
