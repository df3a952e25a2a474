"""Lift jobs of ``multigrasp evaluate generalist``: the distilled vision-based generalist lifting a chunk of poses, as
a cached unit (the generalist's counterpart of :mod:`tasks.lift_jobs`).

A job lifts up to ``specialists.eval_chunk_poses`` pre-grasps, ``specialists.eval_trials`` seeded trials each, with
the student of the distill stage (:func:`components.learning.dagger.load_student`, its best validated weights) seeing
the scene through the cameras of ``distill.vision``.  The trials are seeded by the same pose keys as the specialists'
(:func:`flows.evaluate_execution.pose_key`), so the two rows of a setting are lifted from the same perturbed starts
and compare pose by pose.  Its unit (stage folder ``evaluate-generalist``) holds ``result.json``; the key is made of
the student file, the encoder, the poses, the lift / hand / objects / cameras settings, the evaluation fields and the
code of :data:`GENERALIST_LIFT_CODE`, so a killed evaluation relifts only the jobs that had not finished.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tasks.artifacts import atomic_write_json, digest, valid_manifest
from tasks.distill import DISTILL_CODE_DIRS
from tasks.units import UnitOutput, UnitSpec, make_spec, run_unit

STAGE = "evaluate-generalist"
GENERALIST_LIFT_CODE = (*DISTILL_CODE_DIRS, "tasks/generalist_jobs.py")
RESULT_FILE = "result.json"


@dataclass
class GeneralistJob:
    """The generalist lifting some poses (picklable: a worker process builds the env from ``factory``)."""

    factory: Any
    student: str
    vision: dict
    keys: list[int]
    trials: int
    seed: int
    spec: UnitSpec | None = None


def job_spec(*, workdir: Path, first: int, setting_digest: str, student_digest: str, encoder_key: str,
             records: list[dict], keys: list[int], code: str, split: str) -> UnitSpec:
    return make_spec(stage=STAGE, unit=f"lift-{split}-{first}", section_digest=setting_digest,
                     upstream={"student": student_digest[:20], "pointnet": encoder_key[:20],
                               "poses": digest({"records": records, "keys": keys})[:20]},
                     code=code, workdir=workdir)


def lift(job: GeneralistJob) -> list[int]:
    """Successes per pose (of ``trials``) of the deterministic student on the job's poses."""
    from components.execution.evaluation import evaluate_lift
    from components.learning.dagger import StudentObserver, VisionPolicy, load_student
    from components.learning.vision import SceneCameras, VisionConfig

    env = job.factory()
    try:
        student = load_student(Path(job.student))
        policy = VisionPolicy(student, StudentObserver(env, SceneCameras(VisionConfig(**job.vision))))
        result = evaluate_lift(env, policy, trials=job.trials, seed=job.seed, seed_keys=job.keys)
        return list(result.successes_per_pose)
    finally:
        env.close()


def run_job(job: GeneralistJob) -> list[int]:
    """Lift a job into its unit (served from it when it finished before).  Runs in a worker process or here."""
    finished = valid_manifest(job.spec.folder) if job.spec is not None else None
    if finished is not None:
        return json.loads(finished.path("result").read_text())["successes"]
    if job.spec is None:
        return lift(job)

    def body(folder: Path) -> UnitOutput:
        successes = lift(job)
        path = atomic_write_json(folder / RESULT_FILE, {"successes": successes, "keys": job.keys})
        return UnitOutput(files={"result": path}, metrics={"poses": len(job.keys), "successes": sum(successes)})

    return json.loads(run_unit(job.spec, body).path("result").read_text())["successes"]
