"""The ``distill`` stage: DAgger of every specialist into one vision-based generalist (paper §"Learning a Generalist
from Specialists"; :mod:`components.learning.dagger`, cameras :mod:`components.learning.vision`).

One unit, ``stage``: one lift env per specialist bin over the bin's training pre-grasps (the records file the bin's unit
keeps), its specialist, as the ``curriculum`` stage adapted it, as the teacher, and DAgger collecting, aggregating
and fitting in this process.  Files: ``student.pt`` (the checkpoint: a killed distillation resumes from its last finished
iteration; its data set lies beside it, ``student.pt.data/``, one file per iteration), ``history.json``, ``validations.json`` (the deterministic student, and once the teachers, on the
validation pre-grasps) and ``learning_curve.png``.

Validation: ``validation_poses`` pre-grasps spread over each bin's records, ``validation_trials`` seeded trials each,
lifted by the student in that bin's env; the teachers are validated once on the same trials, so the history shows
what the distillation keeps of them (the paper: the students lose ~30 % of their teachers' success).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task
from pydantic import Field

from components.config_base import Section
from components.execution.lift_config import LiftEnvConfig
from components.learning.dagger import DAggerConfig
from components.learning.vision import VisionConfig
from components.objects.config import ObjectsConfig
from tasks.artifacts import atomic_write_json, atomic_write_with, digest
from tasks.preflight import cache_dir
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

DISTILL_CODE_DIRS = ("components/learning", "components/execution", "components/hand", "assets/hand",
                     "components/objects", "assets/objects", "tasks/distill.py")


class DistillStageConfig(Section):
    """The distill stage: DAgger, the student's cameras and its validation."""

    dagger: DAggerConfig = Field(default_factory=DAggerConfig, description="DAgger collection and the student's fit.")
    vision: VisionConfig = Field(default_factory=VisionConfig, description="The student's three depth cameras and scene cloud.")
    validation_poses: int = Field(10, ge=1, description="Validation pre-grasps per bin, evenly spread over its training records.")
    validation_trials: int = Field(2, ge=1, description="Seeded trials per validation pre-grasp.")
    validation_seed: int = Field(1, ge=0, description="Seed of the validation trials' perturbations.")


def plot_curve(path: Path, history: list[dict], validations: list[dict], teacher: float | None) -> Path:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 3))
    ax = fig.add_subplot(1, 2, 1)
    ax.plot([h["iteration"] for h in history], [h["loss"] for h in history], "o-")
    ax.set_xlabel("DAgger iteration")
    ax.set_ylabel("imitation loss (MSE)")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.plot([v["iteration"] for v in validations], [v["success"] for v in validations], "o-", label="student")
    ax2.plot([h["iteration"] for h in history], [h["behaviour_success"] for h in history], "x--",
             label="behaviour (mixture)")
    if teacher is not None:
        ax2.axhline(teacher, color="gray", linestyle=":", label="teachers")
    ax2.set_xlabel("DAgger iteration")
    ax2.set_ylabel("success")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    return atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))


class BinValidation:
    """Validation of a policy in every bin: ``validation_poses`` spread records x ``validation_trials`` trials."""

    def __init__(self, bins, stage: DistillStageConfig):
        from tasks.specialists import spread_records

        self.bins, self.stage = bins, stage
        self.poses = [spread_records(list(range(len(b.env.records))), stage.validation_poses) for b in bins]

    def __call__(self, policy_for_env) -> dict:
        from components.execution.evaluation import evaluate_lift

        wins = trials = 0
        lifts: list[float] = []
        for b, poses in zip(self.bins, self.poses):
            result = evaluate_lift(b.env, policy_for_env(b.env), trials=self.stage.validation_trials,
                                   seed=self.stage.validation_seed, poses=poses)
            wins += sum(result.successes_per_pose)
            trials += result.n_poses * result.trials
            lifts += result.final_lifts
        return {"success": wins / max(trials, 1), "lift": float(np.mean(lifts)) if lifts else 0.0}


def distill(folder: Path, index: dict[str, dict[str, Any]], stage: DistillStageConfig, lift: LiftEnvConfig,
            objects: ObjectsConfig, hand_cfg, encoder: Path, cache: Path, unit: str) -> UnitOutput:
    from components.execution.factory import LiftEnvFactory
    from components.execution.ppo import load_actor
    from components.hand import HandModel
    from components.learning.dagger import Bin, run_dagger
    from components.learning.vision import SceneCameras

    hand = HandModel(hand_cfg)
    urdf = hand.export_urdf(folder / "hand.urdf")
    bins = []
    try:
        for label, entry in sorted(index.items()):
            factory = LiftEnvFactory(hand_cfg=hand_cfg.model_dump(mode="json"), objects_cfg=objects.model_dump(mode="json"),
                                     objects_cache=str(cache), urdf=str(urdf), records=str(entry["records"]),
                                     lift_cfg=lift.model_dump(mode="json"), encoder=str(encoder), seed=stage.dagger.seed)
            env = factory()
            bins.append(Bin(label=label, env=env, teacher=load_actor(Path(entry["policy"]), env),
                            weight=float(len(env.records))))
        cameras = SceneCameras(stage.vision)
        validation = BinValidation(bins, stage)
        teacher = validation(lambda env: next(b.teacher for b in bins if b.env is env)) if stage.dagger.validate_every else None

        def progress(iteration: int, total: int, row: dict) -> None:
            checked = f" validation {row['val_success']:.2f}" if "val_success" in row else ""
            print(f"distill {unit} iteration {iteration}/{total} beta {row['beta']:.2f} samples {row['samples']} "
                  f"loss {row['loss']:.4f}{checked} ETA {row['eta_s']:.0f}s", file=sys.stderr, flush=True)

        if teacher is not None:
            print(f"distill {unit}: {len(bins)} teacher(s) lift {teacher['success']:.2f} of the validation trials",
                  file=sys.stderr, flush=True)
        result = run_dagger(bins, cameras, stage.dagger, folder / "student.pt", progress, validation)
    finally:
        for b in bins:
            b.env.close()
    history = atomic_write_json(folder / "history.json", result.history)
    validations = atomic_write_json(folder / "validations.json",
                                    {"best": result.best, "rows": result.validations, "teachers": teacher})
    curve = plot_curve(folder / "learning_curve.png", result.history, result.validations,
                       None if teacher is None else teacher["success"])
    last = result.history[-1] if result.history else {}
    metrics = {"bins": len(bins), "iterations": len(result.history), "samples": result.samples,
               "final_loss": round(float(last.get("loss", 0.0)), 6)}
    if result.best is not None:
        metrics.update(best_iteration=int(result.best["iteration"]),
                       best_validation_success=round(float(result.best["success"]), 6))
    if teacher is not None:
        metrics["teacher_validation_success"] = round(float(teacher["success"]), 6)
    return UnitOutput(files={"student": folder / "student.pt", "history": history, "validations": validations,
                             "learning_curve": curve, "urdf": urdf},
                      metrics=metrics, meta={"bins": sorted(index), "resumed_from": result.resumed_from})


def distill_digest(stage: DistillStageConfig, lift: LiftEnvConfig, objects: ObjectsConfig, hand_cfg) -> str:
    """The config part of the unit's key: the stage's settings, the lift env, hand and objects (user meshes by
    their contents, :meth:`ObjectsConfig.key_dump`)."""
    return digest({"stage": stage.model_dump(mode="json"), "lift": lift.model_dump(mode="json"),
                   "objects": objects.key_dump(), "hand": hand_cfg.model_dump(mode="json")})


@task(name="distill-generalist", cache_policy=VerifiedUnitCache(), persist_result=True)
def distill_task(spec: UnitSpec, index: dict[str, dict[str, Any]], stage: DistillStageConfig, lift: LiftEnvConfig,
                 objects: ObjectsConfig, hand_cfg, encoder_path: str):
    """Prefect unit: the generalist (its DAgger checkpoint kept in the unit folder: a rerun after a crash resumes)."""
    return run_unit(spec, lambda folder: distill(folder, index, stage, lift, objects, hand_cfg, Path(encoder_path),
                                                 cache_dir(Path(spec.workdir)), spec.unit))
