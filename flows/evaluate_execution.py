"""``multigrasp evaluate execution``: lift success of the specialists on the evaluation pre-grasps.

Settings (paper §"Experiments"): ``Syn-Pl`` / ``Syn-Com`` / ``Syn-Geo`` = the synthesised dual-object pre-grasps
of the ``Pl`` / ``Com`` / ``Geo`` scene splits (same ``specialists.records_source`` rule as training; the splits'
singles are left out, as the paper's table is about two objects), ``specialists.eval_poses`` of each, evenly spread
over the split's pre-grasps in scene order (:func:`tasks.specialists.spread_records`), so every combination keeps its
share (until the nineteenth session: the first ``eval_poses``, i.e. the first few combinations).  Each pre-grasp is lifted by its *matching specialist*: the one of its
own bin when it exists (unseen placements of seen combinations), else the largest specialist of the same
placement sector and object count (unseen combinations / geometries), else the largest of the same object
count.  Every pre-grasp gets ``eval_trials`` seeded, perturbed trials (:func:`evaluate_lift`, seeded by
:func:`pose_key`: the same perturbations for the same pose in every row and ablation), from the pre-grasp
itself or, with ``specialists.eval_after_reach``, from where the reach stage's planned reach (``reach.reaching``,
run once per pose in PyBullet: :func:`tasks.reach.reach_records`) left the hand and the objects.

Writes ``<workdir>/results/execution.json`` ``{"rows": [{"setting", "succ", "n_poses", "trials"}]}`` and
``ablation_execution.json`` with ``Ours`` (= Syn-Pl), ``w/o RL`` (the paper's: the scripted straight lift from
the pre-grasp itself, on the same poses, without the env's grasp closure), ``Scripted squeeze-lift`` (not in the
paper: the env's grasp closure, ``lift.closure_*``, then the constant squeeze-and-lift controller that PPO starts
from with ``specialists.init_policy: squeeze_lift``, on the same poses, so a reader sees what PPO added) and,
with ``--ablations``, ``w/o Goal``, ``w/o Spe-Pl``, ``w/o Spe-Com``, ``w/o Spe``: the specialists stage is run
with the overrides of :data:`ABLATIONS` (its own cached units) and evaluated on Syn-Pl the same way;
without the flag those rows have ``succ: null`` and say how to get them.  Both files, and a
markdown table, are logged to their own MLflow run.

The poses are lifted in cached jobs of ``specialists.eval_chunk_poses`` (:mod:`tasks.lift_jobs`): an evaluation
killed halfway relifts only the jobs that had not finished.  :func:`lift_pool` chooses where they run
(``run.runner``: spawned processes, or Ray tasks).
"""

from __future__ import annotations

import contextlib
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from components.errors import MultigraspError
from flows.paper import PAPER_EXECUTION_ABLATIONS, execution_paper
from flows.config import PipelineConfig, evaluation_key, results_stamp, section_digest, with_overrides
from tasks.artifacts import atomic_write_json, atomic_write_text

EXECUTION_SETTINGS = (("Syn-Pl", "Pl"), ("Syn-Com", "Com"), ("Syn-Geo", "Geo"))
#: Objects per evaluated pre-grasp (the paper's execution table is dual-object grasping).
EVALUATED_OBJECTS = 2
#: Ablation row of the scripted squeeze-and-lift (not in the paper; the PPO start of ``init_policy: squeeze_lift``).
SQUEEZE_ROW = "Scripted squeeze-lift"
#: The ablations that need differently trained specialists: config overrides of each (paper Table "ablations").
ABLATIONS: dict[str, dict[str, Any]] = {
    "w/o Goal": {"lift.goal_observations": False},
    "w/o Spe-Pl": {"specialists.clustering.mode": "combination"},
    "w/o Spe-Com": {"specialists.clustering.mode": "placement"},
    "w/o Spe": {"specialists.clustering.mode": "single"},
}


@dataclass
class ExecutionReport:
    rows: list[dict[str, Any]]
    ablation_rows: list[dict[str, Any]]
    json_path: Path
    ablation_path: Path
    markdown: str


def matching_specialist(label: str, index: dict[str, dict]) -> str | None:
    """The index label that lifts a pre-grasp of bin ``label`` (module docstring)."""
    if label in index:
        return label
    def size(k: str) -> int:
        return int(index[k]["metrics"].get("records", 0))
    count = label.split("/")[0].count("+") + 1
    same_count = [k for k in index if k.split("/")[0].count("+") + 1 == count]
    sector = label.rsplit("/", 1)[-1] if "/" in label else None
    same_sector = [k for k in same_count if sector is not None and k.rsplit("/", 1)[-1] == sector]
    for pool in (same_sector, same_count):
        if pool:
            return max(pool, key=lambda k: (size(k), k))
    return None


def match_kind(label: str, match: str) -> str:
    """How :func:`matching_specialist` matched a pre-grasp of bin ``label`` to ``match``: 'own bin', 'same sector'
    or 'same object count' (recorded per setting as ``matched_by``)."""
    if match == label:
        return "own bin"
    if "/" in label and "/" in match and label.rsplit("/", 1)[-1] == match.rsplit("/", 1)[-1]:
        return "same sector"
    return "same object count"


@dataclass
class SplitResult:
    """Success of the specialists (and optionally the scripted baseline) on one split's pre-grasps."""

    wins: int = 0
    total: int = 0
    poses: int = 0
    scripted_wins: int = 0
    scripted_total: int = 0
    squeeze_wins: int = 0
    squeeze_total: int = 0
    unmatched: int = 0
    reached: int = 0  # poses lifted from their end-of-reach state (specialists.eval_after_reach)
    used: tuple[str, ...] = ()
    gifs: tuple[Path, ...] = ()
    matched_by: dict[str, int] = field(default_factory=dict)  # poses per match_kind
    outcomes: list[dict] = field(default_factory=list)  # one row per pose: successes of each controller (outcomes.json)

    @staticmethod
    def rate(wins: int, total: int) -> float | None:
        return round(wins / total, 4) if total else None


def _stage_outputs(cfg: PipelineConfig, purpose: str = "evaluate execution"):
    """The synthesize, pointnet and specialists outputs a lift needs; a one-line error naming ``purpose`` and the
    command that makes them when one is missing."""
    from flows.pipeline import stage_output

    outputs = {name: stage_output(cfg, name) for name in ("synthesize", "pointnet", "specialists")}
    if any(v is None for v in outputs.values()):
        raise MultigraspError(f"{purpose} needs the synthesize and specialists stages for this config — run "
                              "`multigrasp run --until specialists` first (same --profile / --config / --set)")
    return outputs


def reached_once(group: list, cfg: PipelineConfig, hand, library, urdf: Path, memo: dict) -> list:
    """End-of-reach records of ``group`` (:func:`tasks.reach.reach_records`), each pose reached once per reach /
    lift / hand / objects setting: ``memo`` maps (that setting's digest, the record's digest) to the end-of-reach
    record, so the ablations that only change the specialists lift the Syn-Pl poses from the reaches
    already run instead of planning and executing them again (~2.5 s each)."""
    from components.execution.records import record_to_dict
    from tasks.artifacts import digest
    from tasks.reach import reach_records

    setting = section_digest(cfg, "reach.reaching", "lift", "hand", "objects")
    keys = [(setting, digest(record_to_dict(r))) for r in group]
    todo = [(key, r) for key, r in zip(keys, group) if key not in memo]
    if todo:
        ends = reach_records([r for _, r in todo], cfg.reach.reaching, cfg.lift, hand, library, urdf)
        memo.update({key: end for (key, _), end in zip(todo, ends)})
    return [memo[key] for key in keys]


def evaluate_split(cfg: PipelineConfig, outputs: dict, split: str, scratch: Path, scripted: bool = False,
                   gifs: bool = True, reach_memo: dict | None = None,
                   say: Callable[[str], None] | None = None, title: str = "", records: list | None = None,
                   pool=None, cached: bool = True, results_file: str = "execution.json") -> SplitResult:
    """Lift ``eval_poses`` pre-grasps of ``split`` (evenly spread) with their matching specialists (module docstring).
    ``reach_memo``: end-of-reach records shared between calls (:func:`reached_once`).  ``say``: receives a
    progress line (counts, elapsed, ETA) as each specialist's poses finish.  ``records``: the pre-grasps to lift
    instead of the synthesize stage's (generated ones).  ``pool``: worker processes (:func:`lift_pool`) that lift the
    jobs; without it they are lifted here.  Each specialist's poses are lifted in jobs of ``eval_chunk_poses``;
    ``cached``: each job is a unit (:mod:`tasks.lift_jobs`), so the jobs that finished before (an evaluation killed
    halfway, a rerun) are served from their units and only the others are reached and lifted; a job's manifest
    records the :func:`flows.config.evaluation_key` of ``results_file`` for ``cfg`` (``status`` counts by it)."""
    from components.execution.clustering import bin_label
    from components.execution.records import record_to_dict
    from tasks.preflight import cache_dir
    from components.hand import HandModel
    from components.hand.model import URDF_FILE_NAME
    from tasks.artifacts import code_version, sha256_file
    from tasks.lift_jobs import LIFT_CODE, LiftJob, LiftJobResult, finished_result, lift_unit_spec
    from tasks.specialist_index import read_specialist_index
    from tasks.specialists import select_records, spread_records, squeeze_lift

    stage = cfg.specialists
    index = read_specialist_index(outputs["specialists"])
    # the URDF of this checkout (mesh paths of the installed package), not the copy in the specialist's folder, whose
    # mesh paths name the installation that trained it
    hand = HandModel(cfg.hand)
    urdf = hand.export_urdf(cache_dir(cfg.run.workdir) / "hand" / URDF_FILE_NAME)
    groups: dict[str, list] = {}
    out = SplitResult()
    if scripted:
        squeeze_lift(stage, hand.actuated_joint_names)  # an unknown squeeze joint: one line before any lift
    if records is None:
        records = select_records(outputs["synthesize"], stage, [split])
    records = [r for r in records if len(r.scene.objects) == EVALUATED_OBJECTS]
    for record in spread_records(records, stage.eval_poses):
        label = bin_label(record, stage.clustering)
        match = matching_specialist(label, index)
        if match is None:
            out.unmatched += 1
        else:
            groups.setdefault(match, []).append(record)
            kind = match_kind(label, match)
            out.matched_by[kind] = out.matched_by.get(kind, 0) + 1
    out.used = tuple(sorted(groups))
    if stage.eval_after_reach:  # lift from where the planned reach left hand and objects
        from components.objects import ObjectLibrary

        reach_memo = {} if reach_memo is None else reach_memo
        library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    settings = {g: lift_setting(cfg, scripted, g) for g in (False, True)} if cached else {False: "", True: ""}
    wider = {g: wider_settings(cfg, scripted, g) for g in (False, True)} if cached else {False: [], True: []}
    code = code_version(*LIFT_CODE) if cached else ""
    policy_digests = {label: sha256_file(Path(index[label]["policy"])) for label in groups} if cached else {}
    meta = {"config_key": evaluation_key(cfg, results_file)} if cached else {}
    jobs: list[tuple[list[str], LiftJob]] = []  # (combinations, job), in specialist and pose order
    done: dict[int, LiftJobResult] = {}  # job index -> result served from its unit
    for label, group in sorted(groups.items()):
        entry, name = index[label], label.replace("/", "_")
        keys = [pose_key(record, i) for i, record in enumerate(group)]  # of the pre-grasps, before any reach
        combinations = [record.meta.get("combination") or "+".join(record.scene.names) for record in group]
        for a, b in pose_chunks(len(group), stage.eval_chunk_poses):
            gif_job = gifs and a == 0 and stage.gifs_per_outcome > 0  # GIFs of the first job of each specialist
            unit = dict(workdir=cfg.run.workdir, label=label, first=a, policy_digest=policy_digests.get(label, ""),
                        encoder_key=outputs["pointnet"].key, records=[record_to_dict(r) for r in group[a:b]],
                        keys=keys[a:b], code=code)
            spec = lift_unit_spec(setting=settings[gif_job], **unit) if cached else None
            job = LiftJob(label=label, factory=None, policy=str(entry["policy"]), keys=keys[a:b], stage=stage,
                          joint_names=list(hand.actuated_joint_names) if scripted else None, scripted=scripted,
                          gif_folder=str(scratch / name) if gif_job else None, spec=spec, meta=meta)
            result = finished_result(spec) if spec is not None else None
            for setting in wider[gif_job] if result is None else ():  # a finished job that lifted more serves it too
                found = finished_result(lift_unit_spec(setting=setting, **unit))
                if found is not None:
                    result = LiftJobResult(policy=found.policy, wo_rl=found.wo_rl if scripted else None,
                                           squeeze=found.squeeze if scripted else None,
                                           gifs=found.gifs if gif_job else [])
                    break
            if result is not None:
                done[len(jobs)] = result
            else:
                chunk = group[a:b]
                if stage.eval_after_reach:
                    chunk = reached_once(chunk, cfg, hand, library, urdf, reach_memo)
                job.factory = lift_env_factory(cfg, outputs, urdf, chunk, scratch / f"{name}.{a}-{b}.json")
            if stage.eval_after_reach:
                out.reached += b - a
            jobs.append((combinations[a:b], job))
    progress = _Progress(say, title or split, sum(map(len, groups.values())), stage.eval_trials, len(groups),
                         passes=3 if scripted else 1, every=stage.eval_progress_every)
    if done:
        progress.served(sum(len(jobs[i][1].keys) for i in done), len(done))
    results = run_lift_jobs([job for _, job in jobs], pool, progress, done)
    gifs_out: list[Path] = []
    for (combinations, job), result in zip(jobs, results):
        _count(out, job, result)
        out.poses += len(result.policy)
        gifs_out += _gifs_beside_results(job, result, scratch)
        for i, key in enumerate(job.keys):
            row = {"specialist": job.label, "combination": combinations[i], "pose_key": key, "policy": result.policy[i]}
            if scripted:
                row.update({"w/o RL": result.wo_rl[i], "squeeze": result.squeeze[i]})
            out.outcomes.append(row)
    out.gifs = tuple(gifs_out)
    return out


def lift_setting(cfg: PipelineConfig, scripted: bool, gifs: bool) -> str:
    """The config part of a lift job's key (:mod:`tasks.lift_jobs`): the lift, hand and objects sections, the
    evaluation fields of the specialists section (``gifs_per_outcome`` only for a job that makes GIFs), the reach
    setting when the poses are reached first, and which controllers and GIFs the job makes."""
    from tasks.lift_jobs import EVALUATION_FIELDS

    stage = cfg.specialists
    fields = {name: getattr(stage, name) for name in EVALUATION_FIELDS if gifs or name != "gifs_per_outcome"}
    extra = {"fields": fields, "scripted": scripted, "gifs": gifs,
             "reach": cfg.reach.reaching.model_dump(mode="json") if stage.eval_after_reach else None}
    return section_digest(cfg, "lift", "hand", "objects", extra=extra)


def wider_settings(cfg: PipelineConfig, scripted: bool, gifs: bool) -> list[str]:
    """The settings (:func:`lift_setting`) of jobs that lift everything a job of ``(scripted, gifs)`` lifts and
    more, on the same poses and seeded trials: with the scripted baselines as well, or with GIFs as well.  The policy
    is lifted first in each (:func:`tasks.lift_jobs.lift_job`, from its own env), so its outcomes are the same, and a
    finished one serves the narrower job: ``evaluate curriculum``'s ``w/o Adpt`` row, say, is served by ``evaluate
    execution --source generated``'s jobs.  Nearest first: the GIF variant before the scripted ones."""
    pairs = [(s, g) for s in (scripted, True) for g in (gifs, True)]
    return [lift_setting(cfg, s, g) for s, g in dict.fromkeys(pairs) if (s, g) != (scripted, gifs)]


def lift_env_factory(cfg: PipelineConfig, outputs: dict, urdf: Path, records: list, records_file: Path):
    """The env factory of a job over ``records`` (saved to ``records_file``, which a worker process reads)."""
    from components.execution.factory import LiftEnvFactory
    from components.execution.records import save_records
    from tasks.preflight import cache_dir

    return LiftEnvFactory(hand_cfg=cfg.hand.model_dump(mode="json"), objects_cfg=cfg.objects.model_dump(mode="json"),
                          objects_cache=str(cache_dir(cfg.run.workdir)), urdf=str(urdf),
                          records=str(save_records(records_file, records)),
                          lift_cfg=cfg.lift.model_dump(mode="json"), encoder=str(outputs["pointnet"].path("encoder")))


def _gifs_beside_results(job, result, scratch: Path) -> list[Path]:
    """A job's GIFs (in its unit) copied under ``scratch/<specialist>/``, where the evaluation's results are browsed;
    the copies are what MLflow logs."""
    import shutil

    out = []
    for gif in map(Path, result.gifs):
        target = scratch / job.label.replace("/", "_") / gif.name
        if gif.parent != target.parent:
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(gif, target)
        out.append(target)
    return out


def evaluation_workers(run) -> int:
    """Processes that lift an evaluation's poses (``run``: the config's ``run`` section): ``run.max_workers``, at most
    the machine's cores."""
    import os

    return max(1, min(run.max_workers, os.cpu_count() or 1))


def pose_chunks(n: int, size: int) -> list[tuple[int, int]]:
    """``[a, b)`` ranges that split one specialist's ``n`` poses into consecutive jobs of at most ``size`` poses, as
    near-equal as that allows (one empty range when ``n`` is 0).  They do not depend on the number of workers, so
    neither do the jobs' keys."""
    pieces = max(1, -(-n // max(1, size)))
    bounds = [round(i * n / pieces) for i in range(pieces + 1)]
    return [(bounds[i], bounds[i + 1]) for i in range(pieces)]


def _worker_init() -> None:
    import signal

    import torch

    from flows.library_logs import quiet_handled_warnings

    torch.set_num_threads(1)  # the workers share the cores
    quiet_handled_warnings()  # spawned: the CLI's logger levels are not inherited
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the command stops them


@contextlib.contextmanager
def lift_pool(run):
    """Where :func:`run_lift_jobs` lifts the jobs of a whole command, by ``run.runner``: ``ray``, as tasks of the
    invocation's Ray (:class:`RayLiftPool`: a local Ray, or the cluster of ``run.ray_address``); otherwise in
    ``run.max_workers`` spawned processes (at most the machine's cores: :func:`evaluation_workers`), started once
    (each imports torch and PyBullet: seconds), or None with one worker (lifted in the command's process).
    PyBullet holds the GIL, so the ``threads`` runner's threads would gain nothing here."""
    if run.runner == "ray":
        with RayLiftPool.session(run) as pool:
            yield pool
        return
    workers = evaluation_workers(run)
    if workers <= 1:
        yield None
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init)
    try:
        yield pool
    except BaseException:  # Ctrl-C / SIGTERM or an error: the finished jobs are in their units, so stop the workers
        # now instead of letting them lift every queued job first
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


class RayLiftPool:
    """Lift jobs as Ray tasks (one CPU each) of the invocation's Ray, with the ``submit(fn, *args)`` ->
    ``concurrent.futures.Future`` of a process pool.  The jobs are cached units in the work dir, so on a cluster the
    work dir must be on storage every node sees (as for the stages).  Evaluation is not a Prefect flow (its results
    are not cached stage outputs), so its jobs go to Ray directly rather than through prefect-ray's task runner;
    the Ray is the one :func:`flows.runtime.ray_session` starts or joins for the stages."""

    def __init__(self, ray):
        self._ray, self._remote, self.refs = ray, {}, []

    @classmethod
    @contextlib.contextmanager
    def session(cls, run):
        from flows.runtime import ray_session
        from tasks.units import records_dir

        with ray_session(run, records_dir(run.workdir)):  # without Ray installed: one line naming the extra
            import ray

            pool = cls(ray)
            try:
                yield pool
            except BaseException:  # Ctrl-C or an error: the finished jobs are in their units; stop the others
                pool.cancel()
                raise

    def submit(self, fn, *args):
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(num_cpus=1)(fn)
        ref = self._remote[fn].remote(*args)
        self.refs.append(ref)
        return ref.future()

    def cancel(self) -> None:
        for ref in self.refs:
            self._ray.cancel(ref, force=True)


def run_lift_jobs(jobs: list, pool, progress: "_Progress", done: dict | None = None) -> list:
    """The jobs' results (:class:`tasks.lift_jobs.LiftJobResult`) in job order: those in ``done`` (job index ->
    result served from its unit) as they are, the others lifted (:func:`tasks.lift_jobs.run_lift_job`) in this
    process without a ``pool`` (:func:`lift_pool`) or with one job to lift (a progress line every
    ``eval_progress_every`` poses of each pass), else in the pool's processes (a line per finished job).  Every trial
    is seeded by its pose and an episode does not depend on the episodes before it, so the outcomes are the same
    either way."""
    from tasks.lift_jobs import run_lift_job

    done = dict(done or {})
    results: list = [done.get(i) for i in range(len(jobs))]
    todo = [i for i in range(len(jobs)) if i not in done]
    tally = SplitResult()
    for index in done:
        _count(tally, jobs[index], done[index])

    def finished(index: int, result) -> None:
        results[index] = result
        _count(tally, jobs[index], result)
        progress.specialist_done(jobs[index].label, len(jobs[index].keys), tally, jobs[index].scripted)

    if pool is None or len(todo) <= 1:
        for index in todo:
            finished(index, run_lift_job(jobs[index], progress))
        return results
    from concurrent.futures import as_completed

    futures = {pool.submit(run_lift_job, jobs[index]): index for index in todo}
    for future in as_completed(futures):
        finished(futures[future], future.result())
    return results


def _count(tally: SplitResult, job, result) -> None:
    tally.wins += sum(result.policy)
    tally.total += len(result.policy) * job.stage.eval_trials
    if job.scripted:
        tally.scripted_wins += sum(result.wo_rl)
        tally.scripted_total += len(result.wo_rl) * job.stage.eval_trials
        tally.squeeze_wins += sum(result.squeeze)
        tally.squeeze_total += len(result.squeeze) * job.stage.eval_trials


def write_outcomes(path: Path, res: SplitResult, trials: int) -> Path:
    """``outcomes.json`` of one setting: per evaluated pose its specialist, combination, seed key and the successes
    (of ``trials``) of the policy and, on Syn-Pl, of ``w/o RL`` and the squeeze.  Two runs evaluated with the same
    ``specialists.eval_*`` lift the same poses with the same perturbations, so ``python -m benchmarks.paired_execution
    A B`` compares them pose by pose (paired standard errors of 0.8-1.2 points on 100 poses x 5 trials in the
    forty-second session, against ~3 points for the difference of two separate rates)."""
    return atomic_write_json(path, {"trials": trials, "poses": res.outcomes})


def pose_key(record, index: int) -> int:
    """The integer a pre-grasp's trial seeds derive from: its scene id and table row, so the same pose gets the
    same perturbations whichever specialist (or ablation, or bin grouping) lifts it, and the rows of the ablation
    table are paired comparisons; records without them fall back to their index."""
    meta = getattr(record, "meta", None) or {}
    if "scene_id" not in meta or "row" not in meta:
        return index
    return zlib.crc32(f"{meta['scene_id']}#{meta['row']}".encode())


class _Progress:
    """Log lines of one evaluated split: what it will do, a line every ``every`` poses of each pass (the specialist,
    and with the scripted rows w/o RL and the squeeze: ``passes`` 3), and counts, elapsed and ETA per specialist."""

    def __init__(self, say: Callable[[str], None] | None, title: str, poses: int, trials: int, specialists: int,
                 passes: int = 1, every: int = 0):
        self.say, self.title, self.poses, self.done = say or (lambda _: None), title, poses, 0
        self.trials, self.passes, self.every, self.pass_poses = trials, passes, every, 0  # pose-passes finished
        self.skipped = 0  # poses served from finished lift jobs: done, but in no time (left out of the ETA's rate)
        self.start = time.monotonic()
        self.say(f"[bold cyan]evaluate execution[/] {title}: {poses} pose(s) x {trials} trial(s) with "
                 f"{specialists} specialist(s)")

    def _eta(self) -> str:
        elapsed, total = time.monotonic() - self.start, self.poses * self.passes
        lifted = self.pass_poses - self.skipped * self.passes
        left = f", ETA {elapsed / lifted * (total - self.pass_poses):.0f}s" if lifted > 0 and self.pass_poses < total else ""
        return f"elapsed {elapsed:.0f}s{left}"

    def on_rollout(self, label: str, phase: str, poses: int) -> Callable[[int, int, object], None]:
        """The ``evaluate_lift(on_rollout=...)`` of one pass over ``poses`` poses: counts a pose when its last trial ends and says a line
        every ``every`` poses."""
        count = [0]

        def seen(pose: int, trial: int, rollout: object) -> None:
            if trial != self.trials - 1:
                return
            count[0] += 1
            self.pass_poses += 1
            if self.every and count[0] % self.every == 0:
                self.say(f"[bold cyan]evaluate execution[/] {self.title}, specialist {label}, {phase}: "
                         f"{count[0]}/{poses} poses, {self._eta()}")
        return seen

    def served(self, poses: int, jobs: int) -> None:
        """``poses`` of ``jobs`` lift jobs finished before (their units): counted done, not lifted again."""
        self.done += poses
        self.skipped += poses
        self.pass_poses = self.done * self.passes
        self.say(f"[bold cyan]evaluate execution[/] {self.title}: {poses}/{self.poses} poses served from {jobs} "
                 "finished lift job(s)")

    def specialist_done(self, label: str, poses: int, out: SplitResult, scripted: bool) -> None:
        self.done += poses
        self.pass_poses = self.done * self.passes
        elapsed = time.monotonic() - self.start
        lifted = self.done - self.skipped
        eta = f", ETA {elapsed / lifted * (self.poses - self.done):.0f}s" if 0 < lifted and self.done < self.poses else ""
        extra = (f", w/o RL {out.scripted_wins}/{out.scripted_total}, squeeze {out.squeeze_wins}/{out.squeeze_total}"
                 if scripted else "")
        self.say(f"[bold cyan]evaluate execution[/] {self.title} {self.done}/{self.poses} poses (specialist {label}): "
                 f"lifted {out.wins}/{out.total}{extra}, elapsed {elapsed:.0f}s{eta}")


def evaluate_execution(cfg: PipelineConfig, ablations: bool = False, parent_run_id: str | None = None) -> ExecutionReport:
    """Write the execution tables (module docstring).  With ``ablations`` the specialists of every
    :data:`ABLATIONS` config are trained first (the specialists stage with those overrides: cached units)."""
    from flows.runtime import make_console

    say = make_console().print
    outputs = _stage_outputs(cfg)
    scratch = cfg.run.workdir / "results" / "execution"
    with lift_pool(cfg.run) as pool:  # started once: each worker imports torch and PyBullet
        rows, ablation, gifs = _evaluate_settings(cfg, ablations, outputs, scratch, say, pool)
    return _write_execution(cfg, outputs, rows, ablation, gifs, ablations, parent_run_id)


def _evaluate_settings(cfg: PipelineConfig, ablations: bool, outputs: dict, scratch: Path, say, pool):
    from flows import specialists as specialists_stage
    from flows.pipeline import run_pipeline

    stage = cfg.specialists
    rows, ablation, gifs = [], [], []
    reach_memo: dict = {}  # with eval_after_reach: each pose is reached once for all the rows below
    for setting, split in EXECUTION_SETTINGS:
        res = evaluate_split(cfg, outputs, split, scratch / setting, scripted=setting == "Syn-Pl", reach_memo=reach_memo,
                             say=say, title=setting, pool=pool)
        gifs += res.gifs
        write_outcomes(scratch / setting / "outcomes.json", res, stage.eval_trials)
        row = {"setting": setting, "succ": res.rate(res.wins, res.total), "n_poses": res.poses,
               "trials": stage.eval_trials, "unmatched_poses": res.unmatched, "specialists_used": list(res.used),
               "matched_by": res.matched_by,
               "after_reach": stage.eval_after_reach, "reached_poses": res.reached}
        rows.append(row)
        if setting == "Syn-Pl":
            ablation.append({"setting": "Ours", "succ": row["succ"], "n_poses": res.poses, "trials": stage.eval_trials})
            ablation.append({"setting": "w/o RL", "succ": res.rate(res.scripted_wins, res.scripted_total),
                             "n_poses": res.poses, "trials": stage.eval_trials,
                             "note": "the paper's: lift straight from the pre-grasp (no grasp closure), "
                                     f"specialists.scripted_force_fraction={stage.scripted_force_fraction}"})
            ablation.append({"setting": SQUEEZE_ROW, "succ": res.rate(res.squeeze_wins, res.squeeze_total),
                             "n_poses": res.poses, "trials": stage.eval_trials,
                             "note": "not in the paper: the scripted squeeze-and-lift (specialists.squeeze_*) after the env's "
                                     f"grasp closure (lift.closure_steps={cfg.lift.closure_steps}), PPO's starting mean "
                                     f"when specialists.init_policy=squeeze_lift (here: {stage.init_policy})"})
    for name, overrides in ABLATIONS.items():
        if not ablations:
            ablation.append({"setting": name, "succ": None, "n_poses": 0, "trials": stage.eval_trials,
                             "missing": f"run with --ablations (trains specialists with {overrides})"})
            continue
        variant = with_overrides(cfg, overrides)
        run_pipeline(variant, [specialists_stage], command=f"ablation:{name}")
        folder = scratch / "ablations" / name.replace("/", "").replace(" ", "_")
        res = evaluate_split(variant, _stage_outputs(variant), "Pl", folder, gifs=False, reach_memo=reach_memo,
                             say=say, title=name, pool=pool, results_file="ablation_execution.json")
        write_outcomes(folder / "outcomes.json", res, stage.eval_trials)
        ablation.append({"setting": name, "succ": res.rate(res.wins, res.total), "n_poses": res.poses,
                         "trials": stage.eval_trials, "overrides": overrides})
    return rows, ablation, gifs


def _write_execution(cfg: PipelineConfig, outputs: dict, rows: list, ablation: list, gifs: list,
                     ablations: bool, parent_run_id: str | None = None) -> ExecutionReport:
    """The execution tables (JSON, markdown) under ``results/`` and their MLflow run."""
    from flows.runtime import make_tracker, start_evaluation_run

    stage = cfg.specialists
    results = cfg.run.workdir / "results"
    specialists = outputs["specialists"]
    provenance = {"profile": cfg.profile, "records_source": stage.records_source, "after_reach": stage.eval_after_reach,
                  "specialists_manifest": str(Path(specialists.folder) / "manifest.json"),
                  "ablations": ablations}
    rows = [{**r, "paper": execution_paper(r["setting"])} for r in rows]
    ablation = [{**r, "paper": execution_paper("Syn-Pl" if r["setting"] == "Ours" else r["setting"])} for r in ablation]
    json_path = atomic_write_json(results / "execution.json", {"rows": rows, **provenance,
                                                                **results_stamp(cfg, "execution.json")})
    ablation_path = atomic_write_json(results / "ablation_execution.json",
                                      {"rows": ablation, **provenance,
                                       **results_stamp(cfg, "ablation_execution.json")})
    markdown = execution_markdown(rows, ablation, stage.records_source)
    markdown_path = atomic_write_text(results / "execution.md", markdown)

    tracker = make_tracker(cfg)
    run_id = start_evaluation_run(tracker, cfg, "evaluate:execution", "execution.json", parent_run_id,
                                  tags={"command": "evaluate", "evaluation": "execution", "profile": cfg.profile})
    tracker.log_metrics(run_id, {f"{r['setting']}/succ": r["succ"] for r in rows + ablation if r["succ"] is not None})
    for path in (json_path, ablation_path, markdown_path):
        tracker.log_artifact(run_id, path, "results")
    for path in gifs:
        tracker.log_artifact(run_id, path, "rollouts")
    tracker.end_run(run_id)
    return ExecutionReport(rows=rows, ablation_rows=ablation, json_path=json_path, ablation_path=ablation_path,
                           markdown=markdown)


def _pct(value) -> str:
    return "—" if value is None else f"{100 * value:.1f} %"


def execution_markdown(rows: list[dict], ablation: list[dict], source: str) -> str:
    """The execution and ablation tables, each row beside the paper's figure (Table I specialists, Table II)."""
    lines = ["| setting | succ | poses x trials | paper (specialists) |", "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['setting']} | {_pct(r['succ'])} | {r['n_poses']} x {r['trials']} | "
                     f"{_pct(execution_paper(r['setting']))} |")
    lines += ["", "| ablation (Syn-Pl) | succ | paper | note |", "|---|---|---|---|"]
    for r in ablation:
        paper = execution_paper("Syn-Pl" if r["setting"] == "Ours" else r["setting"])
        lines.append(f"| {r['setting']} | {_pct(r['succ'])} | {_pct(paper)} | {r.get('missing', r.get('note', ''))} |")
    bases = sorted({v["base"] for k, v in PAPER_EXECUTION_ABLATIONS.items() if any(r["setting"] == k for r in ablation)})
    if bases:
        lines += ["", "The paper's ablation rows are not measured on Syn-Pl; their bases: " + "; ".join(bases) + "."]
    if source != "accepted":
        lines += ["", f"records_source = {source}: plumbing check only, not a result."]
    return "\n".join(lines) + "\n"
