"""``multigrasp evaluate generalist``: lift success of the distilled vision-based generalist (the figure after the
slash in the paper's Table I: Syn-Pl 68.34 % specialists / 44.13 % generalist, Gen-Pl 40.20 / 30.24 %).

The poses and trials are those of ``evaluate execution`` (:mod:`flows.evaluate_execution`): per setting
(Syn-Pl / Syn-Com / Syn-Geo) ``specialists.eval_poses`` dual-object pre-grasps of the split, evenly spread,
``specialists.eval_trials`` trials each, seeded by the same pose keys; and those of ``evaluate execution --source
generated`` (Gen-Pl / Gen-Com / Gen-Geo: the generator's pre-grasps of each split's first ``generator.eval_scenes``
dual-object scenes that the paper's protocol filter keeps, generated again by the same seeded procedure).  One policy lifts them all: the student of the
distill stage, which sees the scene through the cameras of ``distill.vision`` instead of the objects' states.  The
poses are lifted in cached jobs (:mod:`tasks.generalist_jobs`), in the evaluation's worker processes (``run.runner``
as ``evaluate execution``), so a killed evaluation relifts only the jobs that had not finished.

Writes ``<workdir>/results/execution_generalist.json`` ``{"rows": [{"setting", "succ", "n_poses", "trials",
"paper"}], ...}``, ``execution_generalist.md`` and per setting ``results/generalist/<setting>/outcomes.json`` (per
pose, for ``python -m benchmarks.paired_execution`` against the specialists'), logged to their own MLflow run;
``multigrasp report`` shows the rates after the specialists' in Table I's success column.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from components.errors import MultigraspError
from flows.config import PipelineConfig, results_stamp, section_digest
from flows.evaluate_execution import (EVALUATED_OBJECTS, EXECUTION_SETTINGS, SplitResult, lift_env_factory, lift_pool,
                                      pose_chunks, pose_key, reached_once, write_outcomes)
from flows.evaluate_generated_execution import GENERATED_EXECUTION_SETTINGS
from flows.paper import generalist_paper
from tasks.artifacts import atomic_write_json, atomic_write_text

RESULTS_FILE = "execution_generalist.json"


@dataclass
class GeneralistReport:
    rows: list[dict]
    json_path: Path
    markdown: str


def _outputs(cfg: PipelineConfig) -> dict:
    from flows.pipeline import stage_output

    outputs = {name: stage_output(cfg, name) for name in ("synthesize", "pointnet", "specialists", "distill")}
    if any(v is None for v in outputs.values()):
        raise MultigraspError("evaluate generalist needs the distill stage for this config — run "
                              "`multigrasp run --until distill` first (same --profile / --config / --set)")
    return outputs


def plan_jobs(cfg: PipelineConfig, outputs: dict, split: str, scratch: Path, records: list | None = None,
              name: str | None = None, cached: bool = True, reach_memo: dict | None = None) -> list:
    """The generalist's lift jobs of one split (module docstring); ``records``: the pre-grasps to lift instead of the
    synthesize stage's (the generator's), ``name`` the jobs' unit name part (default: the split); ``cached``: False
    for a one-off lift (``generate --lift``), whose jobs have no unit.  With ``specialists.eval_after_reach`` each pose
    is reached first, once per ``reach_memo`` (:func:`flows.evaluate_execution.reached_once`), and lifted from where
    the reach left hand and objects, as the specialists lift it."""
    from components.execution.records import record_to_dict
    from components.hand import HandModel
    from components.hand.model import URDF_FILE_NAME
    from components.objects import ObjectLibrary
    from tasks.artifacts import code_version, sha256_file, valid_manifest
    from tasks.generalist_jobs import GENERALIST_LIFT_CODE, GeneralistJob, job_spec
    from tasks.preflight import cache_dir
    from tasks.specialists import select_records, spread_records

    stage = cfg.specialists
    if records is None:
        records = select_records(outputs["synthesize"], stage, [split])
    records = [r for r in records if len(r.scene.objects) == EVALUATED_OBJECTS]
    records = spread_records(records, stage.eval_poses)
    hand = HandModel(cfg.hand)
    urdf = hand.export_urdf(cache_dir(cfg.run.workdir) / "hand" / URDF_FILE_NAME)
    student = outputs["distill"].path("student")
    extra = {"trials": stage.eval_trials, "seed": stage.eval_seed}
    if stage.eval_after_reach:  # (only then, so that the keys of jobs lifted from the pre-grasps stay as they were)
        extra["reach"] = cfg.reach.reaching.model_dump(mode="json")
    setting = section_digest(cfg, "lift", "hand", "objects", "distill.vision", extra=extra)
    code, student_digest = code_version(*GENERALIST_LIFT_CODE), sha256_file(Path(student))
    keys = [pose_key(r, i) for i, r in enumerate(records)]  # of the pre-grasps, before any reach
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir)) if stage.eval_after_reach else None
    reach_memo = {} if reach_memo is None else reach_memo
    jobs = []
    for a, b in pose_chunks(len(records), stage.eval_chunk_poses):
        if a == b:
            continue
        chunk = records[a:b]
        spec = job_spec(workdir=cfg.run.workdir, first=a, setting_digest=setting, student_digest=student_digest,
                        encoder_key=outputs["pointnet"].key, records=[record_to_dict(r) for r in chunk],
                        keys=keys[a:b], code=code, split=name or split) if cached else None
        factory = None
        if spec is None or valid_manifest(spec.folder) is None:  # a finished job is served without its env
            if stage.eval_after_reach:  # as evaluate execution: lift from where the planned reach left them
                chunk = reached_once(chunk, cfg, hand, library, urdf, reach_memo)
            factory = lift_env_factory(cfg, outputs, urdf, chunk, scratch / f"{name or split}.{a}-{b}.json")
        jobs.append(GeneralistJob(factory=factory, student=str(student),
                                  vision=cfg.distill.vision.model_dump(mode="json"), keys=keys[a:b],
                                  trials=stage.eval_trials, seed=stage.eval_seed, spec=spec))
    return jobs


def run_jobs(jobs: list, pool, say, title: str) -> list[list[int]]:
    """Every job's successes per pose, in job order: here without a pool, else in its processes."""
    import time

    from tasks.generalist_jobs import run_job

    start, done, results = time.monotonic(), 0, [None] * len(jobs)
    total = sum(len(job.keys) for job in jobs)

    def finished(index: int, successes: list[int]) -> None:
        nonlocal done
        results[index] = successes
        done += len(successes)
        elapsed = time.monotonic() - start
        eta = f", ETA {elapsed / done * (total - done):.0f}s" if done < total else ""
        say(f"[bold cyan]evaluate generalist[/] {title} {done}/{total} poses, elapsed {elapsed:.0f}s{eta}")

    if pool is None or len(jobs) <= 1:
        for index, job in enumerate(jobs):
            finished(index, run_job(job))
        return results
    from concurrent.futures import as_completed

    futures = {pool.submit(run_job, job): index for index, job in enumerate(jobs)}
    for future in as_completed(futures):
        finished(futures[future], future.result())
    return results


def evaluate_generalist(cfg: PipelineConfig, parent_run_id: str | None = None) -> GeneralistReport:
    """Write the generalist's execution table (module docstring)."""
    from flows.runtime import make_console, make_tracker, start_evaluation_run

    say = make_console().print
    outputs = _outputs(cfg)
    stage = cfg.specialists
    scratch = cfg.run.workdir / "results" / "generalist"
    rows = []
    generated = _generated_records(cfg, say)
    with lift_pool(cfg.run) as pool:
        for setting, split in (*EXECUTION_SETTINGS, *GENERATED_EXECUTION_SETTINGS):
            records = generated.get(setting) if setting.startswith("Gen-") else None
            if setting.startswith("Gen-") and records is None:
                continue  # no generator: the Gen rows are left out (the distill stage needs one, so never here)
            jobs = plan_jobs(cfg, outputs, split, scratch, records, setting)
            say(f"[bold cyan]evaluate generalist[/] {setting}: {sum(len(j.keys) for j in jobs)} pose(s) x "
                f"{stage.eval_trials} trial(s), {len(jobs)} job(s)")
            per_job = run_jobs(jobs, pool, say, setting)
            successes = [s for job_successes in per_job for s in job_successes]
            # per pose, in the specialists' layout (benchmarks.paired_execution compares the two pose by pose)
            write_outcomes(scratch / setting / "outcomes.json", SplitResult(outcomes=[
                {"specialist": "generalist", "pose_key": key, "policy": s}
                for job, job_successes in zip(jobs, per_job) for key, s in zip(job.keys, job_successes)]),
                stage.eval_trials)
            trials = len(successes) * stage.eval_trials
            rows.append({"setting": setting, "succ": round(sum(successes) / trials, 4) if trials else None,
                         "n_poses": len(successes), "trials": stage.eval_trials, "paper": generalist_paper(setting)})
    results = cfg.run.workdir / "results"
    json_path = atomic_write_json(results / RESULTS_FILE, {
        "rows": rows, "profile": cfg.profile, "records_source": stage.records_source,
        "after_reach": stage.eval_after_reach,
        "distill_manifest": str(Path(outputs["distill"].folder) / "manifest.json"),
        **results_stamp(cfg, RESULTS_FILE)})
    markdown = generalist_markdown(rows, stage.records_source)
    markdown_path = atomic_write_text(results / "execution_generalist.md", markdown)
    tracker = make_tracker(cfg)
    run_id = start_evaluation_run(tracker, cfg, "evaluate:generalist", RESULTS_FILE, parent_run_id,
                                  tags={"command": "evaluate", "evaluation": "generalist", "profile": cfg.profile})
    tracker.log_metrics(run_id, {f"{r['setting']}/succ_generalist": r["succ"] for r in rows if r["succ"] is not None})
    for path in (json_path, markdown_path):
        tracker.log_artifact(run_id, path, "results")
    tracker.end_run(run_id)
    return GeneralistReport(rows=rows, json_path=json_path, markdown=markdown)


def _generated_records(cfg: PipelineConfig, say, settings=GENERATED_EXECUTION_SETTINGS) -> dict[str, list]:
    """The Gen rows' pre-grasps: per Gen setting the generator's kept pre-grasps of that split's first
    ``generator.eval_scenes`` dual-object scenes, as ``evaluate execution --source generated`` picks them (the same
    procedure and seeds, :func:`flows.evaluate_generated.generated_table`)."""
    import sys

    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from flows.evaluate_generated import generated_table, load_generator_for
    from tasks.preflight import cache_dir
    from tasks.specialists import records_from_table
    from tasks.synthesize import read_scene_records

    scenes, _, model = load_generator_for(cfg, None, "evaluate generalist")
    hand, library = HandModel(cfg.hand), ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    scene_records = read_scene_records(scenes)
    out = {}
    for setting, split in settings:
        picked = [r for r in scene_records
                  if r["split"] == split and len(r["objects"]) == EVALUATED_OBJECTS][: cfg.generator.eval_scenes]
        frame, _ = generated_table(cfg, model, hand, library, picked, with_q1=False,
                                   progress=lambda line, setting=setting: print(f"{setting}: {line}", file=sys.stderr,
                                                                                flush=True))
        kept = frame[frame["accepted"].astype(bool)]
        out[setting] = records_from_table(kept) if len(kept) else []
        say(f"[bold cyan]evaluate generalist[/] {setting}: {len(kept)} of {len(frame)} generated pre-grasps kept")
    return out


def generalist_markdown(rows: list[dict], source: str) -> str:
    def pct(value) -> str:
        return "—" if value is None else f"{100 * value:.1f} %"

    lines = ["| setting | generalist succ | poses x trials | paper (generalist) |", "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['setting']} | {pct(r['succ'])} | {r['n_poses']} x {r['trials']} | {pct(r['paper'])} |")
    if source != "accepted":
        lines += ["", f"records_source = {source}: plumbing check only, not a result."]
    return "\n".join(lines) + "\n"
