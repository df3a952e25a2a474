"""Stage flow ``pointnet``: pre-train the frozen point-cloud encoder of the lift policies."""

from __future__ import annotations

from prefect import flow

from flows.config import PipelineConfig, section_digest
from flows.runtime import (StageProgress, StageResult, log_loss_history, make_console, make_task_runner, make_tracker,
                           single_unit, start_stage_run, unit_task)
from tasks.artifacts import Manifest, code_version
from tasks.pointnet import POINTNET_CODE_DIRS, pretrain_task
from tasks.tracking import Tracker
from tasks.units import UnitSpec, make_spec

STAGE = "pointnet"
UPSTREAM: tuple[str, ...] = ()
DESCRIPTION = "pre-train the PointNet encoder of hand / object point clouds (frozen 256-d features of the lift policies)"
# the config sections this stage reads, logged as its MLflow run's params (compare two runs' stage in the UI)
SETTINGS: tuple[str, ...] = ("pointnet", "lift", "hand", "objects")


def stage_spec(cfg: PipelineConfig, run_id: str | None = None, tracking_uri: str | None = None) -> UnitSpec:
    return make_spec(stage=STAGE, unit="stage",
                     section_digest=section_digest(cfg, "pointnet", "lift.hand_cloud_points", "lift.hand_cloud_spacing_m",
                                                   "lift.object_cloud_points", "lift.cloud_seed", "hand", "objects"),
                     upstream={}, code=code_version(*POINTNET_CODE_DIRS), workdir=cfg.run.workdir, run_id=run_id,
                     tracking_uri=tracking_uri)


def planned_units(cfg: PipelineConfig, upstream: dict[str, Manifest]) -> list[UnitSpec]:
    return [stage_spec(cfg)]


@flow(name="pointnet", log_prints=False, validate_parameters=False)
def pointnet_flow(cfg: PipelineConfig, parent_run_id: str, upstream: dict[str, Manifest]) -> StageResult:
    tracker = make_tracker(cfg)
    run_id = start_stage_run(tracker, cfg, STAGE, SETTINGS, parent_run_id)
    console = make_console()
    console.print(f"[bold cyan]{STAGE}[/] pre-training the encoder ({cfg.pointnet.encoder.steps} steps)")
    progress = StageProgress(console, STAGE, total=1)
    future = unit_task(pretrain_task).submit(stage_spec(cfg, run_id, tracker.tracking_uri), cfg.pointnet, cfg.lift,
                                             cfg.objects, cfg.hand, cfg.run.torch_threads)
    return single_unit(STAGE, future, progress, run_id)


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: final losses; the loss curve (per step) and its plot when computed here."""
    log_loss_history(tracker, result, "pointnet")


def runner_flow(cfg: PipelineConfig):
    return pointnet_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage"]
