"""Stage flow ``specialists``: one PPO lift policy per bin of synthesised pre-grasps (fanned out)."""

from __future__ import annotations

import re
from pathlib import Path

from prefect import flow

from components.execution.clustering import assign_bins
from components.execution.ppo_config import EXTENDABLE_FIELDS
from components.execution.records import record_to_dict
from flows.config import PipelineConfig, section_digest
from flows.runtime import (StageProgress, StageResult, make_console, make_task_runner, make_tracker, merge_unit_spec,
                           planned_shards_and_merge, shards_then_merge, start_stage_run, unit_task)
from tasks.artifacts import Manifest, code_version, digest
from tasks.specialists import SPECIALIST_CODE_DIRS, merge_task, select_records, train_bin_task, training_digest
from tasks.tracking import Tracker
from tasks.units import UnitSpec, make_spec

STAGE = "specialists"
UPSTREAM: tuple[str, ...] = ("synthesize", "pointnet")
DESCRIPTION = "bin the training pre-grasps and train one TorchRL PPO lift specialist per bin in PyBullet"
# the config sections this stage reads, logged as its MLflow run's params (compare two runs' stage in the UI)
SETTINGS: tuple[str, ...] = ("specialists", "lift", "hand", "objects", "run.seed")


def bin_unit(label: str) -> str:
    """Unit name of a bin, from its label alone (``cube+frustum/0`` -> ``bin-cube+frustum-0``), so a bin keeps its
    cache key whatever other bins are trained beside it (``max_bins`` changed, records added to another bin).
    Until the twenty-first session the name was the bin's rank among the trained bins, so raising ``max_bins``
    retrained bins that were already trained."""
    return "bin-" + re.sub(r"[^A-Za-z0-9+_.-]", "-", label)


def bin_config_digest(cfg: PipelineConfig) -> str:
    """The config part of every bin's cache key: :func:`tasks.specialists.training_digest` (specialists.ppo, the
    specialists fields that change training, :data:`tasks.specialists.TRAINING_FIELDS`, lift, hand and objects)
    plus the extendable PPO fields (``iterations``, ``checkpoint_every``), so the key and the test for continuing a
    shorter training (:func:`tasks.specialists.longest_finished_bin`) read the same definition.  Until the
    twenty-third session the key left out the training fields, so ``--set specialists.init_policy=zero`` (or another
    squeeze or validation setting) was served the specialists trained with the old value."""
    stage = cfg.specialists
    return digest({"training": training_digest(stage, cfg.lift, cfg.objects, cfg.hand),
                   "extendable": {name: getattr(stage.ppo, name) for name in sorted(EXTENDABLE_FIELDS)}})


def bin_plan(cfg: PipelineConfig, upstream: dict[str, Manifest], run_id: str | None = None,
             tracking_uri: str | None = None) -> list[tuple[UnitSpec, str, list[dict]]]:
    """(spec, bin label, records as dicts) of every trained bin, largest bins first (``max_bins``)."""
    stage = cfg.specialists
    records = select_records(upstream["synthesize"], stage, stage.splits)
    bins = [(label, idx) for label, idx in assign_bins(records, stage.clustering).items()
            if len(idx) >= stage.min_records_per_bin]
    bins.sort(key=lambda item: (-len(item[1]), item[0]))
    if stage.max_bins:
        bins = bins[: stage.max_bins]
    base = bin_config_digest(cfg)
    code = code_version(*SPECIALIST_CODE_DIRS)
    plan = []
    for label, idx in sorted(bins):
        chunk = [record_to_dict(records[i]) for i in idx]
        spec = make_spec(stage=STAGE, unit=bin_unit(label), section_digest=base,
                         upstream={"records": digest(chunk)[:20], "pointnet": upstream["pointnet"].key[:20]},
                         code=code, workdir=cfg.run.workdir, run_id=run_id, tracking_uri=tracking_uri)
        plan.append((spec, label, chunk))
    return plan


def merge_spec(cfg: PipelineConfig, bins: list[Manifest], run_id: str | None = None,
               tracking_uri: str | None = None) -> UnitSpec:
    return merge_unit_spec(cfg, STAGE, bins, section_digest(cfg, "specialists.clustering"),
                           code_version("tasks/specialists.py"), run_id, tracking_uri)


def planned_units(cfg: PipelineConfig, upstream: dict[str, Manifest]) -> list[UnitSpec]:
    return planned_shards_and_merge([spec for spec, _, _ in bin_plan(cfg, upstream)],
                                    lambda bins: merge_spec(cfg, bins))


@flow(name="specialists", log_prints=False, validate_parameters=False)
def specialists_flow(cfg: PipelineConfig, parent_run_id: str, upstream: dict[str, Manifest]) -> StageResult:
    tracker = make_tracker(cfg)
    run_id = start_stage_run(tracker, cfg, STAGE, SETTINGS, parent_run_id)
    uri = tracker.tracking_uri
    plan = bin_plan(cfg, upstream, run_id, uri)
    console = make_console()
    stage = cfg.specialists
    console.print(f"[bold cyan]{STAGE}[/] {len(plan)} bin(s), {sum(len(c) for _, _, c in plan)} pre-grasp(s) "
                  f"({stage.records_source}), {stage.ppo.iterations} x {stage.ppo.frames_per_batch} frames each")
    if not plan:
        console.print(f"[bold yellow]{STAGE}[/] no pre-grasps to train on: the synthesis stage accepted none in the "
                      f"splits {stage.splits} — see its report.md")
    encoder = str(upstream["pointnet"].path("encoder"))
    progress = StageProgress(console, STAGE, total=len(plan) + 1)
    train_bin = unit_task(train_bin_task)  # named once, for every bin
    futures = [train_bin.submit(spec, label, chunk, stage, cfg.lift, cfg.objects, cfg.hand, encoder)
               for spec, label, chunk in plan]
    return shards_then_merge(STAGE, futures,
                             lambda bins: unit_task(merge_task).submit(merge_spec(cfg, bins, run_id, uri), bins),
                             progress, run_id)


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: per-bin learning curves (metrics per iteration, prefixed by the bin) and their plots."""
    import json

    from tasks.specialist_index import read_specialist_index

    tracker.log_metrics(result.run_id, result.manifest.metrics)
    if result.fully_cached:
        return
    for label, entry in read_specialist_index(result.manifest).items():
        folder = Path(entry["folder"])
        name = label.replace("+", "-")  # MLflow metric names allow no '+'
        for row in json.loads((folder / "history.json").read_text()):
            values = {f"{name}.{k}": float(v) for k, v in row.items() if k not in ("iteration", "val_success", "val_lift")}
            tracker.log_metrics(result.run_id, values, step=int(row["iteration"]))
        validations = folder / "validations.json"
        for row in json.loads(validations.read_text())["rows"] if validations.is_file() else []:
            tracker.log_metrics(result.run_id, {f"{name}.validation_success": float(row["success"]),
                                                f"{name}.validation_lift": float(row["lift"])}, step=int(row["iteration"]))
        tracker.log_artifact(result.run_id, folder / "learning_curve.png", f"specialists/{label.replace('/', '_').replace('+', '-')}")


def runner_flow(cfg: PipelineConfig):
    return specialists_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage"]
