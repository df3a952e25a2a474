"""The ``specialists`` stage: one TorchRL PPO lift policy per bin of pre-grasps (paper §"Learning a
Generalist from Specialists", §"Learning a Multi-Object Lifting Policy").

Records: the synthesised pre-grasps of the training split (``records_source='accepted'``: the
accepted ones; ``'lowest_energy'``: per scene the lowest-energy candidates whatever the filter said --
only for the smoke profile, whose tiny synthesis budget accepts none, so that the stage's plumbing runs
end to end; never for numbers), with at most ``max_objects`` objects, split into bins by
:mod:`components.execution.clustering`.

Units:
- ``bin-<label>`` -- the bin's records (``records.json``), PPO training (:func:`components.execution.ppo.train_ppo`)
  with its checkpoint ``policy.pt`` kept in the unit folder, so a killed run resumes from the last
  checkpoint; ``history.json``, ``validations.json`` (the deterministic policy's success on the bin's
  validation pre-grasps before training and every ``ppo.validate_every`` iterations; the best validated actor
  is the one evaluated, :class:`BinValidation`) and ``learning_curve.png``.
- ``merge`` -- ``index.json``: bin label -> policy, records, number of records and final metrics.

Training longer: a bin unit without a checkpoint of its own starts from the checkpoint of the same bin's finished
unit with the most iterations, up to ``ppo.iterations``, that differs only in ``ppo.iterations`` /
``checkpoint_every`` (same records, encoder, code and every other setting: :func:`longest_finished_bin`), so
``--set specialists.ppo.iterations=200`` after a 100-iteration run trains 100 more, not 200.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path
from typing import Any, Literal

import numpy as np
from prefect import task
from pydantic import Field, model_validator

from components.config_base import Section
from components.errors import MultigraspError
from components.execution.clustering import ClusteringConfig
from components.execution.lift_config import LiftEnvConfig
from components.execution.lift_sim import GraspRecord
from components.execution.ppo_config import EXTENDABLE_FIELDS, PPOConfig
from components.objects import Scene
from components.objects.config import ObjectsConfig
from tasks.artifacts import Manifest, atomic_write_json, atomic_write_with, digest, read_manifest, verify
from tasks.grasp_tables import RecordsSource, grasp_rows
from tasks.preflight import cache_dir
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

#: Default ``squeeze_joints``: the flexion joints of the Shadow Hand that close a grasp.
SQUEEZE_JOINTS = ("FFJ2", "FFJ1", "MFJ2", "MFJ1", "RFJ2", "RFJ1", "LFJ2", "LFJ1", "THJ3")

SPECIALIST_CODE_DIRS = ("components/execution", "components/hand", "assets/hand", "components/objects",
                        "assets/objects", "tasks/specialists.py", "tasks/grasp_tables.py")
# Fields of the specialists section, outside ``ppo``, that change what a bin trains (its start, its selection): part of
# every bin's cache key with specialists.ppo, lift, hand and objects.  Which records a bin gets (splits, records_source,
# clustering, ...) reaches the key through the records' digest; eval_* / gifs_* / max_bins do not change a bin.
TRAINING_FIELDS = ("init_policy", "squeeze_joints", "squeeze_action", "squeeze_force_fraction",
                   "validation_poses", "validation_trials", "validation_seed")


class SpecialistsStageConfig(Section):
    """Which pre-grasps, how they are binned, and the PPO of every specialist."""

    ppo: PPOConfig = Field(default_factory=PPOConfig, description="PPO of each specialist.")
    clustering: ClusteringConfig = Field(default_factory=ClusteringConfig, description="How pre-grasps are split into bins.")
    records_source: RecordsSource = Field(
        "accepted",
        description="accepted: the synthesis stage's accepted grasps. lowest_energy: per scene the lowest-energy "
        "candidates whatever the filter said -- for the smoke profile only (its budget accepts none), so the "
        "stage runs end to end; results from it mean nothing.")
    lowest_energy_per_scene: int = Field(2, ge=1, description="With records_source=lowest_energy: candidates taken per scene.")
    splits: list[str] = Field(default_factory=lambda: ["train"], description="Synthesis splits the specialists train on.")
    max_objects: int = Field(2, ge=1, description="Pre-grasps of scenes with more objects are left out (the paper's specialists: 1-2 objects).")
    min_objects: int = Field(
        1, ge=1,
        description="Pre-grasps of scenes with fewer objects are left out.  The bench profile sets 2: its max_bins "
        "takes the largest bins, which are single objects otherwise (singles accept more grasps), and evaluate "
        "execution lifts dual-object pre-grasps, which need a two-object specialist.")
    min_records_per_bin: int = Field(1, ge=1, description="Bins with fewer pre-grasps get no specialist.")
    max_bins: int = Field(0, ge=0, description="Train at most this many bins, the largest first (0 = every bin).")
    validation_poses: int = Field(
        30, ge=1,
        description="Best-policy selection (ppo.validate_every): pre-grasps of the bin's own training records, evenly "
        "spread, that the deterministic policy lifts at every validation; the best validated actor is the specialist.  "
        "The evaluation's Syn-Pl / Syn-Com / Syn-Geo poses are other scenes, never used to select.")
    validation_trials: int = Field(2, ge=1, description="Best-policy selection: seeded trials per validation pre-grasp.")
    validation_seed: int = Field(1, ge=0, description="Best-policy selection: seed of the validation trials' perturbations.")
    eval_poses: int = Field(100, ge=1, description="multigrasp evaluate execution: pre-grasps per setting (the paper: 512).")
    eval_trials: int = Field(5, ge=1, description="Trials per pre-grasp, each from a seeded perturbation (the paper: 5).")
    eval_seed: int = Field(0, ge=0, description="Seed of the evaluation's trial perturbations.")
    eval_after_reach: bool = Field(
        False, description="multigrasp evaluate execution: reach each evaluated pre-grasp first (the reach stage's "
        "planned path from an open hand, run in PyBullet with reach.reaching) and lift from the end-of-reach state, "
        "objects where the reach left them (paper §'Execution Policy': reaching, then lifting).  False: lift from the "
        "pre-grasp itself.")
    eval_chunk_poses: int = Field(
        10, ge=1,
        description="multigrasp evaluate execution: poses per lift job, the unit an evaluation caches and a worker "
        "lifts (tasks/lift_jobs.py).  An evaluation killed halfway relifts at most this many poses per job that was "
        "running; the outcomes do not depend on it (each trial is seeded by its pose).")
    eval_progress_every: int = Field(
        10, ge=0,
        description="multigrasp evaluate execution: a progress line (poses done, elapsed, ETA) every this many "
        "evaluated poses of each pass (specialist, w/o RL, squeeze), besides one per specialist; 0: per specialist only.")
    gifs_per_outcome: int = Field(
        2, ge=0, description="multigrasp evaluate execution: GIFs of this many successful and this many failed trials "
        "per specialist, logged to MLflow (each replays a trial with the CPU renderer, ~1 s).")
    scripted_force_fraction: float = Field(
        0.5, gt=0.0, le=1.0, description="The 'w/o RL' baseline's upward base force, as a fraction of lift.max_base_force_n.")
    squeeze_joints: list[str] = Field(
        default_factory=lambda: list(SQUEEZE_JOINTS),
        description="Actuated joints the scripted squeeze-and-lift closes: positive targets flex them on the Shadow "
        "Hand (the MCP and PIP flexion of the four fingers, the thumb's THJ3).")
    squeeze_action: float = Field(
        0.0, gt=-1.0, lt=1.0,
        description="Squeeze-and-lift: joint action on squeeze_joints at every step (their targets close by this x "
        "lift.joint_delta_rad per step until the joint limits).  0: the env's grasp closure (lift.closure_steps) has "
        "already pressed the fingers in, and closing further sweeps the objects away: on 100 bench Syn-Pl pre-grasps "
        "after the closure, 0 lifts 10 %, 0.3 1 %, 0.9 3 % (force fraction 0.2; README 'Grasp closure').  Without "
        "the closure (closure_steps 0), 0.9 lifted 10/60 bench singles, 0.3 3/60.")
    squeeze_force_fraction: float = Field(
        0.2, gt=0.0, le=1.0,
        description="Squeeze-and-lift: upward base force as a fraction of lift.max_base_force_n (0.2: 4 N, the hand "
        "rises at ~0.8 m/s^2; the straight lift's 0.5 lifted 1/60 of the bench singles, 0.1 3/60).")
    init_policy: Literal["zero", "squeeze_lift"] = Field(
        "squeeze_lift",
        description="Mean action of the untrained PPO actor.  zero: stand still (PPO from scratch, the paper with 512 "
        "Isaac Gym envs for ~4 h); squeeze_lift: the scripted squeeze-and-lift above, so that PPO explores around "
        "a controller that already lifts some pre-grasps.  On 60 bench singles with the bench PPO, 120 k frames "
        "(python -m benchmarks.ppo_experiment): zero 0/60 -> 1/60 lifted by the deterministic policy, squeeze_lift "
        "5/60 -> 7/60 (README, 'Lifting the bench pre-grasps').")

    @model_validator(mode="after")
    def _object_counts(self) -> "SpecialistsStageConfig":
        if self.min_objects > self.max_objects:
            raise ValueError(f"min_objects ({self.min_objects}) exceeds max_objects ({self.max_objects}): no "
                             "pre-grasp would be kept")
        return self


# --------------------------------------------------------------------------- records from the synthesis tables


def records_from_table(frame) -> list[GraspRecord]:
    """GraspRecords of the rows of a synthesis table (``tasks.synthesize`` layout)."""
    out = []
    for row in frame.itertuples(index=False):
        scene = Scene.from_arrays(row.object_names, row.object_positions, row.object_quats_xyzw)
        out.append(GraspRecord(scene=scene, p=np.asarray(row.p, float), R=np.asarray(row.R, float).reshape(3, 3),
                               q=np.asarray(row.q, float),
                               meta={"scene_id": row.scene_id, "split": row.split, "row": int(row.row),
                                     "combination": row.combination, "accepted": bool(row.accepted)}))
    return out


def select_records(synthesis: Manifest, stage: SpecialistsStageConfig, splits: list[str]) -> list[GraspRecord]:
    """The pre-grasps of ``splits`` per ``records_source`` (module docstring), scene and row order."""
    frame = grasp_rows(synthesis, stage.records_source, stage.lowest_energy_per_scene, splits, stage.max_objects,
                       stage.min_objects)
    return records_from_table(frame) if len(frame) else []


def spread_records(records: list, n: int) -> list:
    """At most ``n`` of ``records``, evenly spread over the list (in scene order, so every combination keeps its
    share: the first ``n`` would be the first few combinations only); all of them when ``n`` is 0 or covers them."""
    if not n or len(records) <= n:
        return list(records)
    picked = np.linspace(0, len(records) - 1, n).round().astype(int)
    return [records[i] for i in picked]


# --------------------------------------------------------------------------- scripted controllers


def squeeze_lift(stage: SpecialistsStageConfig, actuated_joint_names: list[str]):
    """The scripted squeeze-and-lift of ``stage`` (a :class:`ScriptedLift`); one-line error for an unknown joint."""
    from components.execution.evaluation import ScriptedLift

    unknown = [n for n in stage.squeeze_joints if n not in actuated_joint_names]
    if unknown:
        raise MultigraspError(f"specialists.squeeze_joints: {', '.join(unknown)} not among the hand's actuated joints "
                              f"({', '.join(actuated_joint_names)}); fix the config")
    joints = [actuated_joint_names.index(n) for n in stage.squeeze_joints]
    return ScriptedLift(stage.squeeze_force_fraction, stage.squeeze_action, joints)


def initial_action(stage: SpecialistsStageConfig, actuated_joint_names: list[str]):
    """The untrained actor's mean action per ``stage.init_policy`` (None: the action box's centre)."""
    if stage.init_policy == "zero":
        return None
    return squeeze_lift(stage, actuated_joint_names).action


# --------------------------------------------------------------------------- one bin


class BinValidation:
    """The specialists' best-policy selection (``ppo.validate_every``): the deterministic actor lifts
    ``validation_poses`` of the bin's training records (evenly spread), ``validation_trials`` seeded trials each, in
    one env built on first use; returns the success rate and the mean final lift."""

    def __init__(self, factory, n_records: int, stage: SpecialistsStageConfig):
        self.factory, self.stage = factory, stage
        self.poses = spread_records(list(range(n_records)), stage.validation_poses)
        self.env = None

    def __call__(self, actor) -> dict:
        from components.execution.evaluation import evaluate_lift

        if self.env is None:
            self.env = self.factory()
        result = evaluate_lift(self.env, actor, trials=self.stage.validation_trials, seed=self.stage.validation_seed,
                               poses=self.poses)
        return {"success": result.succ, "lift": float(np.mean(result.final_lifts))}

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


def plot_learning_curve(path: Path, history: list[dict], title: str, validations: list[dict] = ()) -> Path:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 3))
    ax = fig.add_subplot(1, 2, 1)
    ax.plot([h["frames"] for h in history], [h["reward"] for h in history])
    ax.set_xlabel("frames")
    ax.set_ylabel("mean reward per step")
    ax2 = fig.add_subplot(1, 2, 2)
    rows = [h for h in history if "success" in h]
    ax2.plot([h["frames"] for h in rows], [h["success"] for h in rows], label="sampled episodes")
    if validations:  # iteration -> frames of that iteration (0 before the first)
        frames = {0: 0, **{h["iteration"]: h["frames"] for h in history}}
        ax2.plot([frames.get(v["iteration"], 0) for v in validations], [v["success"] for v in validations], "o-",
                 label="validation (deterministic)")
        ax2.legend(fontsize=7)
    ax2.set_xlabel("frames")
    ax2.set_ylabel("success")
    fig.suptitle(title)
    fig.tight_layout()
    return atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))


def training_digest(stage: SpecialistsStageConfig, lift: LiftEnvConfig, objects: ObjectsConfig, hand_cfg) -> str:
    """Digest of everything in the config that shapes a bin's training except the extendable PPO fields
    (:data:`components.execution.ppo.EXTENDABLE_FIELDS`); stored in the bin manifest's meta as ``training``.  User
    meshes no split uses, and where the files lie, do not count (:meth:`ObjectsConfig.key_dump`)."""
    ppo = {k: v for k, v in stage.ppo.model_dump(mode="json").items() if k not in EXTENDABLE_FIELDS}
    fields = {name: getattr(stage, name) for name in TRAINING_FIELDS}
    return digest({"ppo": ppo, "fields": fields, "lift": lift.model_dump(mode="json"),
                   "objects": objects.key_dump(), "hand": hand_cfg.model_dump(mode="json")})


def longest_finished_bin(spec: UnitSpec, training: str, iterations: int) -> tuple[Manifest, int] | None:
    """The finished unit of the same bin beside ``spec.folder`` that a training of ``iterations`` can continue: same
    unit name, records and encoder (``upstream``), code version and ``training`` digest, at most ``iterations``
    iterations, intact files; the one with the most iterations, and that count.  None if there is none."""
    best = None
    for other in sorted(spec.folder.parent.iterdir()) if spec.folder.parent.is_dir() else []:
        manifest = read_manifest(other) if other != spec.folder and other.is_dir() else None
        if manifest is None or manifest.unit != spec.unit or manifest.code_version != spec.code \
                or manifest.upstream != dict(spec.upstream) or manifest.meta.get("training") != training \
                or "policy" not in manifest.files or verify(manifest):
            continue
        done = int(manifest.metrics.get("iterations", 0))
        if done <= iterations and (best is None or done > best[1]):
            best = (manifest, done)
    return best


def write_start_counts(path: Path, counts) -> tuple[Path, dict]:
    """``start_counts.json``: the training episodes and successes of every record of the bin (``lift.start_sampling``
    'learnability', counted by all workers since the bin's training began; a resume keeps them), and metrics: records never tried, tried and never
    lifted, always lifted, and mixed (the ones learnability sampling favours), with the share of episodes each got."""
    rows = np.asarray(counts).tolist()
    episodes = sum(e for e, _ in rows) or 1
    kinds = {"untried": [r for r in rows if r[0] == 0], "never_lifted": [r for r in rows if r[0] and r[1] == 0],
             "always_lifted": [r for r in rows if r[0] and r[1] == r[0]],
             "mixed": [r for r in rows if 0 < r[1] < r[0]]}
    metrics = {}
    for kind, members in kinds.items():
        metrics[f"start_records_{kind}"] = len(members)
        metrics[f"start_episode_share_{kind}"] = round(sum(e for e, _ in members) / episodes, 4)
    path = atomic_write_json(path, {"columns": ["episodes", "successes"], "records": rows, "summary": metrics})
    return path, metrics


def train_bin(folder: Path, label: str, records: list[dict[str, Any]], stage: SpecialistsStageConfig,
              lift: LiftEnvConfig, objects: ObjectsConfig, hand_cfg, encoder: Path, cache: Path,
              spec: UnitSpec) -> UnitOutput:
    from components.execution.factory import LiftEnvFactory, open_start_counts
    from components.execution.ppo import train_ppo
    from components.execution.records import record_from_dict, save_records
    from components.hand import HandModel

    unit, training, extended_from = spec.unit, training_digest(stage, lift, objects, hand_cfg), ""
    if not (folder / "policy.pt").exists():  # no checkpoint of its own yet: continue a shorter finished training
        found = longest_finished_bin(spec, training, stage.ppo.iterations)
        if found is not None:
            shutil.copyfile(found[0].path("policy"), folder / "policy.pt")
            extended_from = found[0].key
            print(f"specialists {unit} ({label}): continuing the finished {found[1]}-iteration training "
                  f"{found[0].folder} to {stage.ppo.iterations} iterations", file=sys.stderr, flush=True)
    records_path = save_records(folder / "records.json", [record_from_dict(r) for r in records])
    hand = HandModel(hand_cfg)
    urdf = hand.export_urdf(folder / "hand.urdf")
    counts_path = folder / "start_counts.i64" if lift.start_sampling == "learnability" else None
    # (episodes, successes) per record, shared by the workers; kept in the unit folder, so a resume keeps them
    start_counts = None if counts_path is None else open_start_counts(counts_path, len(records))
    factory = LiftEnvFactory(hand_cfg=hand_cfg.model_dump(mode="json"), objects_cfg=objects.model_dump(mode="json"),
                             objects_cache=str(cache), urdf=str(urdf), records=str(records_path),
                             lift_cfg=lift.model_dump(mode="json"), encoder=str(encoder), seed=stage.ppo.seed,
                             start_counts=None if counts_path is None else str(counts_path))

    def progress(iteration: int, total: int, info: dict) -> None:
        if "reward" not in info:  # the validation of the untrained actor
            check = info["validation"]
            print(f"specialists {unit} ({label}) validation before training: success {check['success']:.2f} "
                  f"lift {check['lift']:.3f} m ({check['validate_s']:.0f}s)", file=sys.stderr, flush=True)
            return
        success = f" success {info['success']:.2f}" if "success" in info else ""
        validated = f" validation {info['val_success']:.2f}" if "val_success" in info else ""
        starts = ""
        if start_counts is not None:  # learnability sampling: how many records have shown both outcomes so far
            mixed = (start_counts[:, 1] > 0) & (start_counts[:, 1] < start_counts[:, 0])
            starts = f" mixed starts {int(mixed.sum())}/{len(start_counts)}"
        print(f"specialists {unit} ({label}) iteration {iteration}/{total} reward {info['reward']:.3f}{success}"
              f"{validated}{starts} ETA {info['eta_s']:.0f}s", file=sys.stderr, flush=True)

    init = initial_action(stage, hand.actuated_joint_names)
    validation = BinValidation(factory, len(records), stage)
    try:
        result = train_ppo(factory, stage.ppo, folder / "policy.pt", progress, init_action=init, validate=validation)
    finally:
        validation.close()
    history = atomic_write_json(folder / "history.json", result.history)
    validations = atomic_write_json(folder / "validations.json", {"best": result.best, "rows": result.validations})
    curve = plot_learning_curve(folder / "learning_curve.png", result.history, f"{label} ({len(records)} pre-grasps)",
                                result.validations)
    last = result.history[-1] if result.history else {}
    metrics = {"records": len(records), "iterations": len(result.history), "frames": int(last.get("frames", 0)),
               "final_reward": round(float(last.get("reward", 0.0)), 6)}
    if "success" in last:
        metrics["final_success"] = round(float(last["success"]), 6)
    files = {"policy": folder / "policy.pt", "records": records_path, "history": history,
             "validations": validations, "learning_curve": curve, "urdf": urdf}
    if start_counts is not None:
        files["start_counts"], counted = write_start_counts(folder / "start_counts.json", start_counts)
        metrics.update(counted)
    if result.best is not None:
        metrics.update(best_iteration=int(result.best["iteration"]),
                       best_validation_success=round(float(result.best["success"]), 6),
                       start_validation_success=round(float(result.validations[0]["success"]), 6))
    return UnitOutput(files=files, metrics=metrics, meta={"bin": label, "resumed_from": result.resumed_from,
                                             "extended_from": extended_from, "training": training})


@task(name="specialist-bin", cache_policy=VerifiedUnitCache(), persist_result=True)
def train_bin_task(spec: UnitSpec, label: str, records: list[dict[str, Any]], stage: SpecialistsStageConfig,
                   lift: LiftEnvConfig, objects: ObjectsConfig, hand_cfg, encoder_path: str) -> Manifest:
    """Prefect unit: one specialist (PPO checkpoint kept in the unit folder: a rerun after a crash resumes)."""
    return run_unit(spec, lambda folder: train_bin(folder, label, records, stage, lift, objects, hand_cfg,
                                                   Path(encoder_path), cache_dir(Path(spec.workdir)), spec))


@task(name="specialists-merge", cache_policy=VerifiedUnitCache(), persist_result=True)
def merge_task(spec: UnitSpec, bins: list[Manifest]) -> Manifest:
    """Prefect unit: ``index.json`` of the specialists."""
    def body(folder: Path) -> UnitOutput:
        index = {m.meta["bin"]: {"unit": m.unit, "folder": str(m.folder), "policy": str(m.path("policy")),
                                 "records": str(m.path("records")), "metrics": m.metrics} for m in bins}
        path = atomic_write_json(folder / "index.json", index)
        metrics = {"bins": len(bins), "records": sum(int(m.metrics.get("records", 0)) for m in bins)}
        return UnitOutput(files={"index": path}, metrics=metrics)

    return run_unit(spec, body)
