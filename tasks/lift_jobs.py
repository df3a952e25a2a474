"""Lift jobs of ``multigrasp evaluate execution``: one specialist lifting a chunk of its poses, as a cached unit.

A *lift job* lifts up to ``specialists.eval_chunk_poses`` pre-grasps with one specialist, ``eval_trials`` seeded
trials each, and on the Syn-Pl poses also with the paper's ``w/o RL`` and the scripted squeeze on the same trials.
Every trial is seeded by its pose (:func:`flows.evaluate_execution.pose_key`) and an episode does not depend on the
ones before it, so a job's outcomes do not depend on which process lifts it or on the jobs beside it.

Each job is a unit (:func:`tasks.units.run_unit`) of the ``evaluate-execution`` stage folder
(``<workdir>/stages/evaluate-execution/<key>``): ``result.json`` (successes per pose of each controller) and the
job's GIFs, under a manifest that verifies them.  The key (:func:`lift_unit_spec`) is made of what the outcomes
depend on: the specialist's policy file, the point-cloud encoder, the poses (and with ``eval_after_reach`` the
reach setting), the lift / hand / objects settings, the evaluation fields of :data:`EVALUATION_FIELDS` and the code
of :data:`LIFT_CODE`.  An evaluation killed halfway (Ctrl-C, a crash, a cluster's time limit) therefore relifts
only the jobs that had not finished when it is run again, and an evaluation after a change that leaves a job's key
alone serves that job (``--ablations`` after a plain run serves the Syn-Pl jobs; another ``eval_poses`` spreads the
poses anew, so few jobs stay the same).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tasks.artifacts import Manifest, atomic_write_json, digest, valid_manifest
from tasks.specialists import SPECIALIST_CODE_DIRS
from tasks.units import UnitOutput, UnitSpec, make_spec, run_unit

#: Stage folder of the lift jobs under ``<workdir>/stages/``.
STAGE = "evaluate-execution"
#: Code whose version keys every lift job: the specialists' (env, hand, objects), this module and the reach.
LIFT_CODE = (*SPECIALIST_CODE_DIRS, "tasks/lift_jobs.py", "tasks/reach.py")
#: Fields of the specialists section that change a lift job's outcomes (the policy itself counts by its file).
EVALUATION_FIELDS = ("eval_trials", "eval_seed", "scripted_force_fraction", "squeeze_joints", "squeeze_action",
                     "squeeze_force_fraction", "gifs_per_outcome")
RESULT_FILE = "result.json"


@dataclass
class LiftJob:
    """One specialist lifting some of its poses (picklable: a worker process builds the env from ``factory``)."""

    label: str
    factory: Any
    policy: str
    keys: list[int]
    stage: Any
    joint_names: list[str] | None
    scripted: bool
    gif_folder: str | None
    spec: UnitSpec | None = None
    """The job's unit (:func:`lift_unit_spec`); None: lifted without a cache (``generate --lift``)."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Kept in the unit's manifest: ``config_key``, the evaluation key of the results file whose evaluation lifted
    it first (:func:`finished_jobs` counts a config's finished jobs by it)."""


@dataclass
class LiftJobResult:
    policy: list[int]
    wo_rl: list[int] | None = None
    squeeze: list[int] | None = None
    gifs: list[str] = field(default_factory=list)


def lift_unit_spec(*, workdir: Path, label: str, first: int, setting: str, policy_digest: str, encoder_key: str,
                   records: list[dict], keys: list[int], code: str) -> UnitSpec:
    """The unit of a job of specialist ``label`` over ``records`` (as dicts, before any reach; their seed ``keys``):
    ``setting`` is the digest of the settings its outcomes depend on (module docstring), ``policy_digest`` the
    sha256 of the specialist's policy file, ``code`` :func:`code_version` of :data:`LIFT_CODE` (both computed once
    per evaluated split by the caller, not per job), ``first`` the index of the job's first pose among the
    specialist's poses (a name for the log, part of the key)."""
    name = "lift-" + label.replace("/", "-")
    return make_spec(stage=STAGE, unit=f"{name}-{first}", section_digest=setting,
                     upstream={"policy": policy_digest[:20], "pointnet": encoder_key[:20],
                               "poses": digest({"records": records, "keys": keys})[:20]},
                     code=code, workdir=workdir)


def finished_result(spec: UnitSpec) -> LiftJobResult | None:
    """The result of a job whose unit finished and verifies, else None (to be lifted)."""
    manifest = valid_manifest(spec.folder)
    return None if manifest is None else read_result(manifest)


def finished_jobs(workdir: Path, config_key: str) -> int:
    """How many lift jobs in ``workdir`` an evaluation with this ``config_key`` lifted first and finished (their
    manifests are read, not verified: a count for ``status``, not a cache check).  Jobs it was served from another
    config's evaluation are not counted, so this is at least what a rerun of the evaluation serves."""
    from tasks.artifacts import read_manifest, unit_folder

    stage_dir = unit_folder(Path(workdir), STAGE, "_").parent
    folders = [p for p in stage_dir.iterdir() if p.is_dir()] if stage_dir.is_dir() else []
    return sum(1 for folder in folders
               if (manifest := read_manifest(folder)) is not None and manifest.meta.get("config_key") == config_key)


def read_result(manifest: Manifest) -> LiftJobResult:
    data = json.loads(manifest.path("result").read_text())
    gifs = [str(Path(manifest.folder) / name) for name in data.pop("gifs")]
    return LiftJobResult(**data, gifs=gifs)


def run_lift_job(job: LiftJob, progress: Any = None) -> LiftJobResult:
    """Lift a job into its unit (served from the unit when it finished before), or without one when ``spec`` is
    None.  Runs in a worker process or in the command's."""
    if job.spec is None:
        return lift_job(job, progress)

    def body(folder: Path) -> UnitOutput:
        gifs = str(folder / "gifs") if job.gif_folder is not None else None
        result = lift_job(dataclasses.replace(job, gif_folder=gifs), progress)
        names = [str(Path(g).relative_to(folder)) for g in result.gifs]
        path = atomic_write_json(folder / RESULT_FILE, {**dataclasses.asdict(result), "gifs": names})
        return UnitOutput(files={"result": path, **{f"gif:{n}": folder / n for n in names}},
                          metrics={"poses": len(job.keys), "policy_successes": sum(result.policy)},
                          meta={"specialist": job.label, **job.meta})

    return read_result(run_unit(job.spec, body))


def lift_job(job: LiftJob, progress: Any = None) -> LiftJobResult:
    """Lift a job's poses with its specialist (``eval_trials`` seeded trials each) and, with ``scripted``, with the
    paper's ``w/o RL`` (no grasp closure) and the scripted squeeze on the same trials; GIFs into ``gif_folder``.
    ``progress``: :class:`flows.evaluate_execution._Progress`-like (``on_rollout(label, phase, poses)``)."""
    from components.execution.evaluation import ScriptedLift, evaluate_lift, rollout_gif, trial_seed
    from components.execution.ppo import load_actor
    from tasks.specialists import squeeze_lift

    stage, keys, n = job.stage, job.keys, len(job.keys)

    def hook(phase: str):
        return progress.on_rollout(job.label, phase, n) if progress is not None else None

    env = job.factory()
    try:
        actor = load_actor(Path(job.policy), env)
        result = evaluate_lift(env, actor, trials=stage.eval_trials, seed=stage.eval_seed, seed_keys=keys,
                               on_rollout=hook("policy"))
        out = LiftJobResult(policy=list(result.successes_per_pose))
        if job.gif_folder is not None:
            out.gifs = [str(p) for p in outcome_gifs(env, actor, result, stage, Path(job.gif_folder), rollout_gif,
                                                       trial_seed)]
        if job.scripted:  # w/o RL: the paper's straight lift from the pre-grasp itself, without the grasp closure
            paper = without_closure(job.factory)
            plain = env if paper is job.factory else paper()
            try:
                base = evaluate_lift(plain, ScriptedLift(stage.scripted_force_fraction), trials=stage.eval_trials,
                                     seed=stage.eval_seed, seed_keys=keys, on_rollout=hook("w/o RL"))
            finally:
                if plain is not env:
                    plain.close()
            held = evaluate_lift(env, squeeze_lift(stage, job.joint_names), trials=stage.eval_trials,
                                 seed=stage.eval_seed, seed_keys=keys, on_rollout=hook("squeeze"))
            out.wo_rl, out.squeeze = list(base.successes_per_pose), list(held.successes_per_pose)
        return out
    finally:
        env.close()


def without_closure(factory):
    """The env factory of the paper's ``w/o RL``: the same env, starting at the pre-grasp itself (``closure_steps``
    0; the factory itself when its env already does)."""
    from components.execution import LiftEnvConfig

    if LiftEnvConfig(**factory.lift_cfg).closure_steps == 0:  # a missing key is the config's default
        return factory
    return dataclasses.replace(factory, lift_cfg={**factory.lift_cfg, "closure_steps": 0})


def outcome_gifs(env, actor, result, stage, folder: Path, rollout_gif, trial_seed) -> list[Path]:
    """GIFs of up to ``stage.gifs_per_outcome`` successful and failed trials of one job's poses.  The trials are
    seeded, so a replay has the evaluated outcome; poses whose trials all had an outcome whose quota is full are
    skipped."""
    left = {True: stage.gifs_per_outcome, False: stage.gifs_per_outcome}
    out = []
    for pose, wins in enumerate(result.successes_per_pose):
        for trial in range(result.trials):
            possible = {True} if wins == result.trials else {False} if wins == 0 else {True, False}
            if not any(left[o] for o in possible):
                break
            path, success = rollout_gif(env, actor, pose, trial_seed(stage.eval_seed, result.seed_keys[pose], trial),
                                        folder / f"pose{pose}_trial{trial}.gif")
            if left[success]:
                left[success] -= 1
                final = path.with_name(f"{'success' if success else 'failure'}_{path.name}")
                out.append(path.replace(final))
            else:
                path.unlink()
    return out
