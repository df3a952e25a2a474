"""Stage flow ``train-generator``: the diffusion pre-grasp generator on the synthesised grasps."""

from __future__ import annotations

from pathlib import Path

from prefect import flow

from flows.config import PipelineConfig, section_digest
from flows.runtime import (StageProgress, StageResult, log_loss_history, make_console, make_task_runner, make_tracker,
                           single_unit, start_stage_run, unit_task)
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
    future = unit_task(train_task).submit(stage_spec(cfg, upstream["synthesize"], run_id, tracker.tracking_uri),
                                          upstream["synthesize"], cfg.generator, cfg.objects, cfg.hand, cfg.run.device,
                                          cfg.run.torch_threads)
    result = single_unit(STAGE, future, progress, run_id)
    if not result.fully_cached and cfg.tracking.renders and cfg.tracking.generator_sample_scenes:
        try:
            log_samples(cfg, tracker, run_id, result.manifest, upstream["synthesize"], console.print)
        except Exception as exc:  # noqa: BLE001 - tracking only: the trained generator is kept and the run goes on
            console.print(f"[bold yellow]{STAGE}[/] the sample renders were not logged ({type(exc).__name__}: {exc}); "
                          "the trained generator is kept (`multigrasp generate` renders samples of any scene)")
    return result


def sample_scene_records(cfg: PipelineConfig, synthesis: Manifest) -> list[dict]:
    """Up to ``tracking.generator_sample_scenes`` scenes the generator learned from (scenes-stage records: ``id``,
    ``split``, ``scene``), those with the most objects first, then by scene id, with the rows of each in the
    training data (``rows``)."""
    from components.objects import Scene
    from tasks.generator import training_frame

    frame = training_frame(synthesis, cfg.generator)
    if not len(frame):
        return []
    counts = frame["object_names"].map(len)
    first = frame.assign(n_objects=counts).sort_values(["n_objects", "scene_id", "row"], ascending=[False, True, True])
    records = []
    for scene_id in list(dict.fromkeys(first["scene_id"]))[:cfg.tracking.generator_sample_scenes]:
        rows = first[first["scene_id"] == scene_id]
        top = rows.iloc[0]
        scene = Scene.from_arrays(top["object_names"], top["object_positions"], top["object_quats_xyzw"])
        records.append({"id": str(scene_id), "split": str(top["split"]), "scene": scene.to_dict(),
                        "rows": rows.to_dict("records")})
    return records


def log_samples(cfg: PipelineConfig, tracker: Tracker, run_id: str, generator: Manifest, synthesis: Manifest,
                say) -> None:
    """The trained generator's samples on a few of its training scenes (:func:`sample_scene_records`), generated,
    IK-solved, refined and scored as ``evaluate pregrasp --source generated`` does, rendered as one grid per scene
    beside a grid of the dataset's grasps of that scene (``generator/samples/``), with their mean Q1 / PN / kept
    fraction as ``samples/*`` metrics.  Issue 4's "sample renders in MLflow"; logged once, when the stage trains."""
    import tempfile
    import time

    from components.generation import load_generator
    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from flows.evaluate_generated import generated_table
    from tasks.preflight import cache_dir
    from tasks.synthesize_merge import render_grasp_rgb, render_grid

    started = time.perf_counter()
    records = sample_scene_records(cfg, synthesis)
    if not records:
        return
    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    model = load_generator(generator.path("generator"))
    frame, _ = generated_table(cfg, model, hand, library, records)
    with tempfile.TemporaryDirectory(prefix="generator-samples-") as tmp:
        urdf = hand.export_urdf(Path(tmp) / "hand.urdf")
        for record in records:
            name = record["id"].replace("/", ":").replace(":", "_")
            generated = frame[frame["scene_id"] == record["id"]].to_dict("records")
            for kind, rows in (("samples", generated), ("data", record["rows"])):
                tiles = [render_grasp_rgb(library, hand, urdf, row, cfg.synthesis.camera)
                         for row in rows[:cfg.synthesis.renders_per_combination]]  # the synthesis grids' size
                if tiles:
                    tracker.log_artifact(run_id, render_grid(Path(tmp) / f"{name}_{kind}.png", tiles),
                                         "generator/samples")
    tracker.log_metrics(run_id, {"samples/q1": float(frame["q1"].mean()), "samples/pn_mm": float(frame["pn_mm"].mean()),
                                 "samples/kept_fraction": float(frame["accepted"].mean()), "samples/n": len(frame)})
    say(f"[bold cyan]{STAGE}[/] {len(frame)} sample(s) of {len(records)} training scene(s) generated, scored and "
        f"rendered beside their data in MLflow (generator/samples/, {time.perf_counter() - started:.0f}s; "
        "tracking.generator_sample_scenes)")


def log_stage(tracker: Tracker, result: StageResult) -> None:
    """MLflow: dataset size and final loss; the loss curve (per step) and its plot when trained here."""
    log_loss_history(tracker, result, "generator")


def runner_flow(cfg: PipelineConfig):
    return train_generator_flow.with_options(task_runner=make_task_runner(cfg.run))


__all__ = ["STAGE", "UPSTREAM", "DESCRIPTION", "planned_units", "runner_flow", "log_stage"]
