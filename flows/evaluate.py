"""Evaluation commands: result tables written to ``<workdir>/results/`` and logged to MLflow.

``multigrasp evaluate pregrasp --source synthetic`` — pre-grasp quality of the ``synthesize``
stage's accepted grasps per evaluation setting (paper Table "pre-grasp quality", DESIGN §6):

* ``q1``   mean Ferrari–Canny Q1 of the accepted grasps (min over objects; higher is better),
* ``pn_mm`` mean maximal penetration depth (mm; lower is better),
* ``div_deg`` Div = mean per-joint standard deviation of q over the accepted grasps (deg),
* ``accept_rate`` accepted / synthesised candidates, ``n`` the number of accepted grasps.

Settings: ``Syn-Pl``, ``Syn-Com``, ``Syn-Geo`` = the dual-object combinations of that scene split, as the
paper's table (its rows are dual-object grasps; the splits here also hold singles, which accept 2-3x as often
and would flatter the row); ``Syn-Pl-singles`` / ``Syn-Geo-singles`` = the single-object combinations of
those splits, reported beside them; ``Syn-train-pairs`` = the dual-object combinations of the ``train``
split (the data the generator learns from).  A setting without accepted grasps gives a
row with ``n = 0`` and nulls.  Other sources (``generated``, issue 4) plug into :data:`SOURCES`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from components.errors import MultigraspError
from flows.config import PipelineConfig, results_stamp
from tasks.artifacts import atomic_write_json, atomic_write_text

from flows.paper import PAPER_GENERATOR_ABLATIONS, pregrasp_paper
from flows.paper import number_cell as _fmt


@dataclass(frozen=True)
class Setting:
    """One row of the table: which scene split, restricted to combinations of which sizes (None = all)."""

    name: str
    split: str
    n_objects: int | None = None


SYNTHETIC_SETTINGS = (Setting("Syn-Pl", "Pl", 2), Setting("Syn-Com", "Com", 2), Setting("Syn-Geo", "Geo", 2),
                      Setting("Syn-train-pairs", "train", 2), Setting("Syn-Pl-singles", "Pl", 1),
                      Setting("Syn-Geo-singles", "Geo", 1))


@dataclass
class PregraspReport:
    rows: list[dict[str, Any]]
    json_path: Path
    markdown_path: Path
    markdown: str


# --------------------------------------------------------------------------- metrics of a setting


def setting_row(setting: Setting, accepted, candidates: int) -> dict[str, Any]:
    """Mean Q1 / PN, Div and accept rate of one setting from its accepted rows (a pandas frame)."""
    import numpy as np
    import torch

    from components.metrics import joint_diversity_deg

    n = int(len(accepted))
    row: dict[str, Any] = {"setting": setting.name, "split": setting.split, "n": n, "candidates": int(candidates),
                           "accept_rate": n / candidates if candidates else None,
                           "q1": None, "pn_mm": None, "div_deg": None}
    if n:
        q1 = accepted["q1"].to_numpy(dtype=float)
        pn = accepted["pn_mm"].to_numpy(dtype=float)
        row["q1"] = float(np.nanmean(q1)) if np.isfinite(q1).any() else None
        row["pn_mm"] = float(np.nanmean(pn)) if np.isfinite(pn).any() else None
        q = torch.as_tensor(np.stack([np.asarray(v, dtype=float) for v in accepted["q"]]))  # (n, 22)
        row["div_deg"] = joint_diversity_deg(q)
    return row


def _in_setting(frame, setting: Setting):
    mask = frame["split"] == setting.split
    if setting.n_objects is not None:
        mask &= frame["combination"].str.count(r"\+") + 1 == setting.n_objects
    return frame[mask]


def synthetic_rows(cfg: PipelineConfig) -> tuple[list[dict[str, Any]], dict[str, str]]:
    """Rows of the synthesize stage's output for this config (module docstring) and provenance tags."""
    import pyarrow.parquet as pq

    from flows.pipeline import stage_output

    manifest = stage_output(cfg, "synthesize")
    if manifest is None:
        raise MultigraspError("evaluate pregrasp --source synthetic needs the synthesize stage for this config — "
                              "run `multigrasp run --until synthesize` first (same --profile / --config / --set)")
    accepted = pq.read_table(manifest.path("grasps"), columns=_present(manifest.path("grasps"),
                                                                       ["split", "combination", "q1", "pn_mm", "q"])
                             ).to_pandas()
    rejected = pq.read_table(manifest.path("rejected"), columns=["split", "combination"]).to_pandas()
    rows = []
    for setting in SYNTHETIC_SETTINGS:
        mine = _in_setting(accepted, setting)
        candidates = len(mine) + len(_in_setting(rejected, setting))
        rows.append(setting_row(setting, mine, candidates))
    return rows, {"synthesize_manifest": str(Path(manifest.folder) / "manifest.json"),
                  "synthesize_run": manifest.producer_run_id or ""}


def _present(path: Path, wanted: list[str]) -> list[str]:
    """Columns of ``wanted`` that the Parquet file has (an empty stage output has no ``q``)."""
    import pyarrow.parquet as pq

    names = set(pq.read_schema(path).names)
    return [c for c in wanted if c in names]


#: ``--source`` → rows builder (issue 4 adds ``generated``).
def _generated_rows(cfg: PipelineConfig) -> tuple[list[dict[str, Any]], dict[str, str]]:
    from flows.evaluate_generated import generated_rows

    return generated_rows(cfg)


SOURCES: dict[str, Callable[[PipelineConfig], tuple[list[dict[str, Any]], dict[str, str]]]] = {
    "synthetic": synthetic_rows,
    "generated": _generated_rows,
}


# --------------------------------------------------------------------------- the table


def _paper_cell(setting: str) -> str:
    paper = pregrasp_paper(setting)
    if paper is None:
        return "–"
    cell = f"{paper['q1']:.2f} / {paper['pn_mm']:.2f} / {paper['div_deg']:.2f}"
    return cell + (f" / {paper['time_256_s']:.2f} s" if "time_256_s" in paper else "")


def with_paper(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` with the paper's Table I figures of each setting under ``paper`` (null where it has none)."""
    return [{**row, "paper": pregrasp_paper(row["setting"])} for row in rows]


def pregrasp_markdown(rows: list[dict[str, Any]], source: str) -> str:
    """The table of ``rows``, each beside the paper's figures for the same setting (Table I)."""
    every = any("q1_all" in row for row in rows)  # generated rows: also the figures over every generated grasp
    timed = any("time_256_s" in row for row in rows)
    head = "| setting | Q1 ↑ | PN (mm) ↓ | Div (deg) ↑ | accept rate | n |"
    extra_head = (" Q1, all generated | PN (mm), all generated |" if every else "") + (" s / 256 |" if timed else "")
    lines = [f"# Pre-grasp quality ({source})", "",
             head + extra_head + " paper: Q1 / PN / Div" + (" / s per 256" if timed else "") + " |",
             "|---|---|---|---|---|---|" + ("---|---|" if every else "") + ("---|" if timed else "") + "---|"]
    for row in rows:
        rate = "–" if row["accept_rate"] is None else f"{100 * row['accept_rate']:.1f} %"
        line = (f"| {row['setting']} | {_fmt(row['q1'], 3)} | {_fmt(row['pn_mm'], 2)} | "
                f"{_fmt(row['div_deg'], 2)} | {rate} | {row['n']} |")
        if every:
            line += f" {_fmt(row.get('q1_all'), 3)} | {_fmt(row.get('pn_mm_all'), 2)} |"
        if timed:
            line += f" {_fmt(row.get('time_256_s'), 2)} |"
        lines.append(line + f" {_paper_cell(row['setting'])} |")
    lines += ["", "Q1: mean over accepted grasps (min over objects). PN: mean maximal penetration. "
                  "Div: mean per-joint std of the accepted q. `–`: no accepted grasp in that setting, or no such "
                  "row in the paper (Li et al. 2024, Table I; its Syn rows are dual-object grasps)."]
    if every:
        lines += ["Generated grasps are accepted as in the paper's protocol (generator.eval_filter: PN and contact "
                  "ratio); the 'all generated' columns are over every generated grasp."]
    if timed:
        lines += ["s / 256: wall time of sampling, IK and refinement of one batch of 256 grasps for the setting's "
                  "first scene (the paper's Time; its figures are on an RTX 3090 Ti)."]
    return "\n".join(lines) + "\n"


def generator_ablation_markdown(rows: list[dict[str, Any]]) -> str:
    """The generator ablations (Gen-Pl, kept grasps) beside the paper's Table II(a)."""
    lines = ["## Generator ablations (Gen-Pl)", "",
             "| setting | Q1 ↑ | PN (mm) ↓ | kept | Q1, all | PN (mm), all | paper: Q1 / PN / succ |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        paper = row.get("paper")
        cell = "–" if not paper else f"{paper['q1']:.2f} / {paper['pn_mm']:.2f} / {100 * paper['succ']:.1f} %"
        kept = "–" if row.get("accept_rate") is None else f"{100 * row['accept_rate']:.1f} %"
        lines.append(f"| {row['setting']} | {_fmt(row.get('q1'), 3)} | {_fmt(row.get('pn_mm'), 2)} | {kept} | "
                     f"{_fmt(row.get('q1_all'), 3)} | {_fmt(row.get('pn_mm_all'), 2)} | {cell} |")
    lines += ["", "The paper's succ column is the execution success of each generator's grasps (Table II(a)); "
                  "here `evaluate execution --source generated` lifts those of Ours, not of the ablation variants."]
    return "\n".join(lines) + "\n"


def evaluate_pregrasp(cfg: PipelineConfig, source: str, ablations: bool = False,
                      parent_run_id: str | None = None) -> PregraspReport:
    """Write ``results/pregrasp_<source>.json`` + ``.md`` and log both to their own MLflow run; with
    ``ablations`` (source ``generated``) also ``results/ablation_generator.json``."""
    from flows.runtime import make_tracker, start_evaluation_run

    if source not in SOURCES:
        raise MultigraspError(f"unknown pre-grasp source '{source}' — choose one of {', '.join(SOURCES)}")
    rows, tags = SOURCES[source](cfg)
    rows = with_paper(rows)
    results = cfg.run.workdir / "results"
    json_path = atomic_write_json(results / f"pregrasp_{source}.json",
                                  {"rows": rows, "source": source, "profile": cfg.profile,
                                   **results_stamp(cfg, f"pregrasp_{source}.json"), **tags})
    markdown = pregrasp_markdown(rows, source)
    markdown_path = atomic_write_text(results / f"pregrasp_{source}.md", markdown)
    extra = []
    if ablations:
        if source != "generated":
            raise MultigraspError("--ablations applies to --source generated (the generator's ablations)")
        from flows.evaluate_generated import generator_ablation_rows

        ablation_rows = generator_ablation_rows(cfg, ours=next((r for r in rows if r["setting"] == "Gen-Pl"), None))
        ablation_rows = [{**r, "paper": PAPER_GENERATOR_ABLATIONS.get(r["setting"])} for r in ablation_rows]
        extra.append(atomic_write_json(results / "ablation_generator.json",
                                       {"rows": ablation_rows, "profile": cfg.profile,
                                        **results_stamp(cfg, "ablation_generator.json"),
                                        **{k: v for k, v in tags.items() if k == "generator_manifest"}}))
        rows_for_metrics = [{**r, "setting": f"ablation {r['setting']}"} for r in ablation_rows]
        markdown += "\n" + generator_ablation_markdown(ablation_rows)
        markdown_path = atomic_write_text(markdown_path, markdown)
    else:
        rows_for_metrics = []

    tracker = make_tracker(cfg)
    run_id = start_evaluation_run(tracker, cfg, f"evaluate:pregrasp:{source}", f"pregrasp_{source}.json", parent_run_id,
                                  tags={"command": "evaluate", "evaluation": "pregrasp", "source": source,
                                        "profile": cfg.profile, **tags})
    metrics = {f"{row['setting']}/{key}": row[key] for row in rows + rows_for_metrics
               for key in ("q1", "pn_mm", "div_deg", "accept_rate", "n", "time_256_s", "q1_all", "pn_mm_all")
               if row.get(key) is not None}
    tracker.log_metrics(run_id, metrics)
    tracker.log_artifact(run_id, json_path, "results")
    tracker.log_artifact(run_id, markdown_path, "results")
    for path in extra:
        tracker.log_artifact(run_id, path, "results")
    tracker.end_run(run_id)
    return PregraspReport(rows=rows, json_path=json_path, markdown_path=markdown_path, markdown=markdown)
