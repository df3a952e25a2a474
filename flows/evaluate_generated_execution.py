"""``multigrasp evaluate execution --source generated``: the specialists lifting the generator's pre-grasps (the
paper's Table I, Gen rows' success: 40.20 / 23.32 / 15.65 % on Gen-Pl / Com / Geo).

For each setting ``Gen-Pl`` / ``Gen-Com`` / ``Gen-Geo``, the first ``generator.eval_scenes`` dual-object scenes of
that split (the ``scenes`` stage's) each get ``generator.eval_grasps_per_scene`` generated, IK-solved and refined
pre-grasps by the same procedure as ``evaluate pregrasp --source generated``
(:func:`flows.evaluate_generated.generated_table`; not always the same grasps: the noise is seeded by a scene's place
in its list, and that list has no singles here; Q1 is not computed, the filter does not need it); the ones the paper's protocol keeps (``generator.eval_filter``:
penetration and contact ratio) are lifted as the synthesised ones are by ``evaluate execution``
(:func:`flows.evaluate_execution.evaluate_split`: ``specialists.eval_poses`` of them evenly spread, the matching
specialist, ``eval_trials`` seeded perturbed trials, from the end of the planned reach with
``specialists.eval_after_reach``).  On Gen-Pl the same trials are also lifted by ``w/o RL`` and the scripted squeeze.

Writes ``<workdir>/results/execution_generated.json`` (``{"rows": [{"setting", "succ", "n_poses", "trials",
"generated", "kept", …, "paper"}]}``), ``execution_generated.md`` and per setting
``results/execution_generated/<setting>/outcomes.json``; logged to their own MLflow run.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from components.errors import MultigraspError
from flows.config import PipelineConfig, results_stamp
from flows.evaluate_execution import (EVALUATED_OBJECTS, SQUEEZE_ROW, _pct, _stage_outputs, evaluate_split,
                                      lift_pool, write_outcomes)
from flows.paper import execution_paper
from tasks.artifacts import atomic_write_json, atomic_write_text

GENERATED_EXECUTION_SETTINGS = (("Gen-Pl", "Pl"), ("Gen-Com", "Com"), ("Gen-Geo", "Geo"))


@dataclass
class GeneratedExecutionReport:
    rows: list[dict[str, Any]]
    json_path: Path
    markdown: str


def generated_execution_markdown(rows: list[dict[str, Any]]) -> str:
    lines = ["| setting | succ | poses x trials | kept / generated | w/o RL | squeeze | paper (specialists) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['setting']} | {_pct(r['succ'])} | {r['n_poses']} x {r['trials']} | "
                     f"{r['kept']} / {r['generated']} | {_pct(r.get('w/o RL'))} | {_pct(r.get(SQUEEZE_ROW))} | "
                     f"{_pct(r['paper'])} |")
    lines += ["", "Pre-grasps: the generator's, refined, kept by the paper's protocol filter (generator.eval_filter); "
                  "lifted by the specialists trained on synthesised pre-grasps. w/o RL and the scripted squeeze lift "
                  "the same Gen-Pl trials."]
    return "\n".join(lines) + "\n"


def evaluate_generated_execution(cfg: PipelineConfig, parent_run_id: str | None = None) -> GeneratedExecutionReport:
    """Write the Gen execution table (module docstring)."""
    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from flows.evaluate_generated import load_generator_for
    from flows.runtime import make_console, make_tracker, start_evaluation_run
    from tasks.preflight import cache_dir
    from tasks.synthesize import read_scene_records

    outputs = _stage_outputs(cfg)
    scenes, generator, model = load_generator_for(cfg, None, "evaluate execution --source generated")
    stage = cfg.specialists
    hand = HandModel(cfg.hand)
    library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
    results = cfg.run.workdir / "results"
    with lift_pool(cfg.run) as pool:  # started once: each worker imports torch and PyBullet
        rows, gifs = _evaluate_generated(cfg, outputs, model, hand, library, read_scene_records(scenes),
                                         results / "execution_generated", make_console().print, pool)
    if not any(r["generated"] for r in rows):
        raise MultigraspError("evaluate execution --source generated found no dual-object Pl / Com / Geo scene in this "
                              "config's scenes stage — give the splits pair scenes (scenes.per_combination)")
    provenance = {"profile": cfg.profile, "source": "generated", "after_reach": stage.eval_after_reach,
                  "specialists_manifest": str(Path(outputs["specialists"].folder) / "manifest.json"),
                  "generator_manifest": str(Path(generator.folder) / "manifest.json"),
                  **results_stamp(cfg, "execution_generated.json")}
    json_path = atomic_write_json(results / "execution_generated.json", {"rows": rows, **provenance})
    markdown = generated_execution_markdown(rows)
    markdown_path = atomic_write_text(results / "execution_generated.md", markdown)
    tracker = make_tracker(cfg)
    run_id = start_evaluation_run(tracker, cfg, "evaluate:execution:generated", "execution_generated.json",
                                  parent_run_id, tags={"command": "evaluate", "evaluation": "execution",
                                                       "source": "generated", "profile": cfg.profile})
    metrics = {f"{r['setting']}/{key}": r[key] for r in rows for key in ("succ", "kept", "w/o RL", SQUEEZE_ROW)
               if r.get(key) is not None}
    tracker.log_metrics(run_id, metrics)
    for path in (json_path, markdown_path):
        tracker.log_artifact(run_id, path, "results")
    for path in gifs:
        tracker.log_artifact(run_id, path, "rollouts")
    tracker.end_run(run_id)
    return GeneratedExecutionReport(rows=rows, json_path=json_path, markdown=markdown)


def _evaluate_generated(cfg: PipelineConfig, outputs: dict, model, hand, library, scene_records: list,
                        scratch: Path, say, pool) -> tuple[list[dict[str, Any]], list[Path]]:
    """Generate, keep and lift the pre-grasps of each Gen setting: its table row, and the rollout GIFs."""
    from flows.evaluate_generated import generated_table
    from tasks.specialists import records_from_table

    stage = cfg.specialists
    rows, gifs = [], []
    reach_memo: dict = {}
    for setting, split in GENERATED_EXECUTION_SETTINGS:
        picked = [r for r in scene_records
                  if r["split"] == split and len(r["objects"]) == EVALUATED_OBJECTS][: cfg.generator.eval_scenes]
        frame, seconds = generated_table(cfg, model, hand, library, picked, with_q1=False,  # the filter needs no Q1
                                         progress=lambda line: print(f"{setting}: {line}", file=sys.stderr, flush=True))
        kept = frame[frame["accepted"].astype(bool)]
        records = records_from_table(kept) if len(kept) else []
        scripted = setting == "Gen-Pl"
        res = evaluate_split(cfg, outputs, split, scratch / setting, scripted=scripted, reach_memo=reach_memo,
                             say=say, title=setting, records=records, pool=pool,
                             results_file="execution_generated.json")
        gifs += res.gifs
        write_outcomes(scratch / setting / "outcomes.json", res, stage.eval_trials)
        row = {"setting": setting, "succ": res.rate(res.wins, res.total), "n_poses": res.poses,
               "trials": stage.eval_trials, "scenes": len(picked), "generated": len(frame), "kept": len(kept),
               "generation_s": round(seconds, 2), "unmatched_poses": res.unmatched,
               "specialists_used": list(res.used), "matched_by": res.matched_by,
               "after_reach": stage.eval_after_reach, "reached_poses": res.reached,
               "paper": execution_paper(setting)}
        if scripted:
            row["w/o RL"] = res.rate(res.scripted_wins, res.scripted_total)
            row[SQUEEZE_ROW] = res.rate(res.squeeze_wins, res.squeeze_total)
        rows.append(row)
    return rows, gifs
