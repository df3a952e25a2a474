"""Stage flow ``distill``: DAgger of the specialists, as the curriculum adapted them, into one vision-based generalist
(``tasks.distill``)."""

from __future__ import annotations

import json

from prefect import flow

from components.errors import MultigraspError
from flows.config import PipelineConfig
from flows.runtime import (StageProgress, StageResult, make_console, make_task_runner, make_tracker, single_unit,
                           start_stage_run, unit_task)
from tasks.artifacts import Manifest, code_version
from tasks.distill import DISTILL_CODE_DIRS, distill_digest, distill_task
from tasks.specialist_index import read_specialist_index
from tasks.tracking import Tracker
from tasks.units import UnitSpec, make_spec

STAGE = "distill"
UPSTREAM: tuple[str, ...] = ("curriculum", "pointnet")
DESCRIPTION = "distil the specialists into one vision-based generalist by DAgger (three simulated depth cameras)"
# the config sections this stage reads, logged as its MLflow run's params (compare two runs' stage in the UI)
SETTINGS: tuple[str, ...] = ("distill", "lift", "hand", "objects")


def stage_spec(cfg: PipelineConfig, upstream: dict[str, Manifest], run_id: str | None = None,
               tracking_uri: str | None = None) -> UnitSpec:
    return make_spec(stage=STAGE, unit="stage",
                     section_digest=distill_digest(cfg.distill, cfg.lift, cfg.objects, cfg.hand),
                     upstream={"teachers": upstream["curriculum"].key[:20], "pointnet": upstream["pointnet"].key[:20]},
                     code=code_version(*DISTILL_CODE_DIRS), workdir=cfg.run.workdir, run_id=run_id,
                     tracking_uri=tracking_uri)


def planned_units(cfg: PipelineConfig, upstream: dict[str, Manifest]) -> list[UnitSpec]:
    return [stage_spec(cfg, upstream)]


@flow(name="distill", log_prints=False, validate_parameters=False)
def distill_flow(cfg: PipelineConfig, parent_run_id: str, upstream: dict[str, Manifest]) -> StageResult:
    tracker = make_tracker(cfg)
    run_id = start_stage_run(tracker, cfg, STAGE, SETTINGS, parent_run_id)
    index = read_specialist_index(upstream["curriculum"])  # the adapted specialists teach
    if not index:
        raise MultigraspError("distill: the specialists stage trained no specialist for this config (no pre-grasps "
                              "to train on: see the synthesize stage's report.md), so there is nothing to distil; "
                              "every stage before it is kept")
    dagger = cfg.distill.dagger
    console = make_console()
    console.print(f"[bold cyan]{STAGE}[/] {len(index)} specialist(s) -> one generalist: {dagger.iterations} DAgger "
                  f"iteration(s) x {dagger.episodes_per_iteration} episode(s), "
                  f"{len(cfg.distill.vision.camera_yaws_deg)} camera(s)")
    progress = StageProgress(console, STAGE, total=1)
    future = unit_task(distill_task).submit(stage_spec(cfg, upstream, run_id, tracker.tracking_uri), index,
                                            cfg.distill, cfg.lift, cfg.objects, cfg.hand,
                                            str(upstream["pointnet"].path("encoder")))
    return single_unit(STAGE, future, progress, run_id)


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: the unit's metrics; when distilled here, every iteration's row as metrics with steps and the curve."""
    tracker.log_metrics(result.run_id, result.manifest.metrics)
    if result.fully_cached:
        return
    for row in json.loads(result.manifest.path("history").read_text()):
        values = {k: float(v) for k, v in row.items() if k != "iteration"}
        tracker.log_metrics(result.run_id, values, step=int(row["iteration"]))
    tracker.log_artifact(result.run_id, result.manifest.path("learning_curve"), "distill")


def runner_flow(cfg: PipelineConfig):
    return distill_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage"]
