"""Stage flow ``train-generator``: the diffusion pre-grasp generator on the synthesised grasps."""

from __future__ import annotations

from prefect import flow

from flows.config import PipelineConfig, section_digest
from flows.runtime import (start_stage_run, StageProgress, StageResult, log_loss_history, make_console, make_task_runner,
                           make_tracker, single_unit)
from tasks.artifacts import Manifest, code_version, upstream_hashes
from tasks.generator import GENERATOR_CODE_DIRS, train_task
from tasks.tracking import Tracker
from tasks.units import UnitSpec, make_spec

STAGE = "train-generator"
UPSTREAM: tuple[str, ...] = ("synthesize",)
DESCRIPTION = "train the diffusion pre-grasp generator (31 palm-aligned keypoints, PointNet++ objects, DDPM)"
# the config sections this stage reads, logged as its MLflow run's params (compare two runs' stage in the UI)
SETTINGS: tuple[str, ...] = ("generator", "hand", "objects", "run.seed")


def stage_spec(cfg: PipelineConfig, synthesis: Manifest, run_id: str | None = None,
               tracking_uri: str | None = None) -> UnitSpec:
    """Keyed by the model / data config and the synthesis output (training steps included: a longer
    training is another unit, which starts from the longest finished one on the same data, code and model --
    ``tasks.generator.longest_finished_training`` -- rather than from step 0)."""
    return make_spec(stage=STAGE, unit="stage",
                     section_digest=section_digest(cfg, "generator.model", "generator.splits", "generator.records_source",
                                                   "generator.lowest_energy_per_scene", "hand", "objects"),
                     upstream=upstream_hashes([("synthesize", synthesis)]), code=code_version(*GENERATOR_CODE_DIRS),
                     workdir=cfg.run.workdir, run_id=run_id, tracking_uri=tracking_uri)


def planned_units(cfg: PipelineConfig, upstream: dict[str, Manifest]) -> list[UnitSpec]:
    return [stage_spec(cfg, upstream["synthesize"])]


@flow(name="train-generator", log_prints=False, validate_parameters=False)
def train_generator_flow(cfg: PipelineConfig, parent_run_id: str, upstream: dict[str, Manifest]) -> StageResult:
    tracker = make_tracker(cfg)
    run_id = start_stage_run(tracker, cfg, STAGE, SETTINGS, parent_run_id)
    console = make_console()
    console.print(f"[bold cyan]{STAGE}[/] {cfg.generator.model.train_steps} steps, batch {cfg.generator.model.batch_size} "
                  f"({cfg.generator.records_source} grasps of {cfg.generator.splits})")
    progress = StageProgress(console, STAGE, total=1)
    future = train_task.submit(stage_spec(cfg, upstream["synthesize"], run_id, tracker.tracking_uri), upstream["synthesize"],
                               cfg.generator, cfg.objects, cfg.hand, cfg.run.device, cfg.run.torch_threads)
    return single_unit(STAGE, future, progress, run_id)


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: dataset size and final loss; the loss curve (per step) and its plot when trained here."""
    log_loss_history(tracker, result, "generator")


def runner_flow(cfg: PipelineConfig):
    return train_generator_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage"]
