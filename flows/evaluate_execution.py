"""``multigrasp evaluate execution``: lift success of the specialists on the evaluation pre-grasps.

Settings (paper §"Experiments"): ``Syn-Pl`` / ``Syn-Com`` / ``Syn-Geo`` = the synthesised pre-grasps of the
``Pl`` / ``Com`` / ``Geo`` scene splits (same ``specialists.records_source`` rule as training), the first
``specialists.eval_poses`` of each.  Each pre-grasp is lifted by its *matching specialist*: the one of its
own bin when it exists (unseen placements of seen combinations), else the largest specialist of the same
placement sector and object count (unseen combinations / geometries), else the largest of the same object
count.  Every pre-grasp gets ``eval_trials`` seeded, perturbed trials (:func:`evaluate_lift`).

Writes ``<workdir>/results/execution.json`` ``{"rows": [{"setting", "succ", "n_poses", "trials"}]}`` and
``ablation_execution.json`` with ``Ours`` (= Syn-Pl) and ``w/o RL`` (the scripted lift on the same poses);
the ablations that need policies trained differently (``w/o Goal``, ``w/o Spe-Pl``, ``w/o Spe-Com``,
``w/o Spe``) are listed with ``succ: null`` and the reason until the stage trains them.  Both files, and a
markdown table, are logged to their own MLflow run.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from components.errors import MultigraspError
from flows.config import PipelineConfig
from tasks.artifacts import atomic_write_json, atomic_write_text

EXECUTION_SETTINGS = (("Syn-Pl", "Pl"), ("Syn-Com", "Com"), ("Syn-Geo", "Geo"))
#: Paper (Table "execution", specialists, Syn rows) for comparison only.
PAPER_SPECIALIST_SUCC = {"Syn-Pl": 0.6834}
NOT_TRAINED = {"w/o Goal": "needs specialists trained with lift.goal_observations=false",
               "w/o Spe-Pl": "needs specialists trained with specialists.clustering.mode=combination",
               "w/o Spe-Com": "needs specialists trained with specialists.clustering.mode=placement",
               "w/o Spe": "needs one policy trained with specialists.clustering.mode=single"}


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


def evaluate_execution(cfg: PipelineConfig) -> ExecutionReport:
    from components.execution.clustering import bin_label
    from components.execution.evaluation import LiftEvaluation, ScriptedLift, evaluate_lift, rollout_gif, trial_seed
    from components.execution.factory import LiftEnvFactory
    from components.execution.ppo import load_actor
    from components.execution.records import save_records
    from flows.pipeline import stage_output
    from flows.runtime import make_tracker
    from tasks.preflight import cache_dir
    from tasks.specialists import select_records

    stage = cfg.specialists
    synthesis, specialists = stage_output(cfg, "synthesize"), stage_output(cfg, "specialists")
    if synthesis is None or specialists is None:
        raise MultigraspError("evaluate execution needs the synthesize and specialists stages for this config — run "
                              "`multigrasp run --until specialists` first (same --profile / --config / --set)")
    index = json.loads(specialists.path("index").read_text())
    results = cfg.run.workdir / "results"
    scratch = results / "execution"
    rows, ablation, gifs = [], [], []
    for setting, split in EXECUTION_SETTINGS:
        records = select_records(synthesis, stage, [split])[: stage.eval_poses]
        groups: dict[str, list] = {}
        unmatched = 0
        for record in records:
            match = matching_specialist(bin_label(record, stage.clustering), index)
            if match is None:
                unmatched += 1
            else:
                groups.setdefault(match, []).append(record)
        wins = total = poses = 0
        scripted_wins = scripted_total = 0
        for label, group in sorted(groups.items()):
            entry = index[label]
            path = save_records(scratch / setting / f"{label.replace('/', '_')}.json", group)
            factory = LiftEnvFactory(hand_cfg=cfg.hand.model_dump(mode="json"), objects_cfg=cfg.objects.model_dump(mode="json"),
                                     objects_cache=str(cache_dir(cfg.run.workdir)),
                                     urdf=str(Path(entry["folder"]) / "hand.urdf"), records=str(path),
                                     lift_cfg=cfg.lift.model_dump(mode="json"),
                                     encoder=str(stage_output(cfg, "pointnet").path("encoder")))
            env = factory()
            try:
                actor = load_actor(Path(entry["policy"]), env)
                result: LiftEvaluation = evaluate_lift(env, actor, trials=stage.eval_trials, seed=stage.eval_seed)
                gifs += _outcome_gifs(env, actor, result, stage, scratch / setting / label.replace("/", "_"),
                                      rollout_gif, trial_seed)
                wins += sum(result.successes_per_pose)
                total += result.n_poses * result.trials
                poses += result.n_poses
                if setting == "Syn-Pl":
                    scripted = evaluate_lift(env, ScriptedLift(stage.scripted_force_fraction), trials=stage.eval_trials,
                                             seed=stage.eval_seed)
                    scripted_wins += sum(scripted.successes_per_pose)
                    scripted_total += scripted.n_poses * scripted.trials
            finally:
                env.close()
        row = {"setting": setting, "succ": round(wins / total, 4) if total else None, "n_poses": poses,
               "trials": stage.eval_trials, "unmatched_poses": unmatched, "specialists_used": sorted(groups)}
        rows.append(row)
        if setting == "Syn-Pl":
            ablation.append({"setting": "Ours", "succ": row["succ"], "n_poses": poses, "trials": stage.eval_trials})
            ablation.append({"setting": "w/o RL", "succ": round(scripted_wins / scripted_total, 4) if scripted_total else None,
                             "n_poses": poses, "trials": stage.eval_trials})
    ablation += [{"setting": name, "succ": None, "n_poses": 0, "trials": stage.eval_trials, "missing": why}
                 for name, why in NOT_TRAINED.items()]
    provenance = {"profile": cfg.profile, "records_source": stage.records_source,
                  "specialists_manifest": str(Path(specialists.folder) / "manifest.json")}
    json_path = atomic_write_json(results / "execution.json", {"rows": rows, **provenance})
    ablation_path = atomic_write_json(results / "ablation_execution.json", {"rows": ablation, **provenance})
    markdown = execution_markdown(rows, ablation, stage.records_source)
    markdown_path = atomic_write_text(results / "execution.md", markdown)

    tracker = make_tracker(cfg)
    run_id = tracker.start_run("evaluate:execution", tags={"command": "evaluate", "evaluation": "execution",
                                                           "profile": cfg.profile})
    tracker.log_metrics(run_id, {f"{r['setting']}/succ": r["succ"] for r in rows + ablation if r["succ"] is not None})
    for path in (json_path, ablation_path, markdown_path):
        tracker.log_artifact(run_id, path, "results")
    for path in gifs:
        tracker.log_artifact(run_id, path, "rollouts")
    tracker.end_run(run_id)
    return ExecutionReport(rows=rows, ablation_rows=ablation, json_path=json_path, ablation_path=ablation_path,
                           markdown=markdown)


def _outcome_gifs(env, actor, result, stage, folder: Path, rollout_gif, trial_seed) -> list[Path]:
    """GIFs of up to ``stage.gifs_per_outcome`` successful and failed trials of one specialist's poses.  The
    trials are seeded, so a replay has the evaluated outcome; poses whose trials all had an outcome whose
    quota is full are skipped."""
    left = {True: stage.gifs_per_outcome, False: stage.gifs_per_outcome}
    out = []
    for pose, wins in enumerate(result.successes_per_pose):
        for trial in range(result.trials):
            possible = {True} if wins == result.trials else {False} if wins == 0 else {True, False}
            if not any(left[o] for o in possible):
                break
            path, success = rollout_gif(env, actor, pose, trial_seed(stage.eval_seed, pose, trial),
                                        folder / f"pose{pose}_trial{trial}.gif")
            if left[success]:
                left[success] -= 1
                final = path.with_name(f"{'success' if success else 'failure'}_{path.name}")
                out.append(path.replace(final))
            else:
                path.unlink()
    return out


def _pct(value) -> str:
    return "—" if value is None else f"{100 * value:.1f} %"


def execution_markdown(rows: list[dict], ablation: list[dict], source: str) -> str:
    lines = ["| setting | succ | poses x trials | paper (specialists) |", "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['setting']} | {_pct(r['succ'])} | {r['n_poses']} x {r['trials']} | "
                     f"{_pct(PAPER_SPECIALIST_SUCC.get(r['setting']))} |")
    lines += ["", "| ablation (Syn-Pl) | succ | note |", "|---|---|---|"]
    for r in ablation:
        lines.append(f"| {r['setting']} | {_pct(r['succ'])} | {r.get('missing', '')} |")
    if source != "accepted":
        lines += ["", f"records_source = {source}: plumbing check only, not a result."]
    return "\n".join(lines) + "\n"
