"""``multigrasp report``: a work dir's evaluation results beside the paper's Tables I and II, in one file.

It reads what ``evaluate`` wrote under ``<workdir>/results/`` (``pregrasp_synthetic.json``,
``pregrasp_generated.json``, ``execution.json``, ``ablation_generator.json``, ``ablation_execution.json``,
``execution_generated.json``) and writes ``results/report.md``: Table I's rows (Syn / Gen × Pl / Com / Geo: Q1,
PN, Div, time per 256, success) and Table II's ablations, each cell as ``this run (paper)``.  A table whose evaluation has not run names the command
that makes it; every source says which profile and when it was evaluated, since one work dir can hold several
profiles' runs and ``results/`` keeps the latest evaluation of each kind.  Nothing is recomputed.
"""

from __future__ import annotations

import datetime
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from components.errors import MultigraspError
from flows.paired import paired_cell
from flows.paper import (PAPER_CURRICULUM_ABLATIONS, PAPER_EXECUTION, PAPER_EXECUTION_ABLATIONS, PAPER_GENERALIST,
                         PAPER_GENERATOR_ABLATIONS, PAPER_PREGRASP)
from flows.paper import number_cell as _num
from tasks.artifacts import atomic_write_text

#: results file → the command that writes it.
SOURCES = {
    "pregrasp_synthetic.json": "multigrasp evaluate pregrasp --source synthetic",
    "pregrasp_generated.json": "multigrasp evaluate pregrasp --source generated",
    "execution.json": "multigrasp evaluate execution",
    "execution_generated.json": "multigrasp evaluate execution --source generated",
    "ablation_generator.json": "multigrasp evaluate pregrasp --source generated --ablations",
    "ablation_execution.json": "multigrasp evaluate execution --ablations",
    "execution_generalist.json": "multigrasp evaluate generalist",
    "ablation_curriculum.json": "multigrasp evaluate curriculum",
}

#: the results files of Table I (``run --evaluate`` computes them; the ablation files need ``--ablations``).
TABLE_ONE_FILES = ("pregrasp_synthetic.json", "pregrasp_generated.json", "execution.json", "execution_generated.json",
                   "execution_generalist.json")


@dataclass
class Report:
    path: Path
    markdown: str
    missing: list[str]
    """The results files not found (their commands are in the report)."""
    csv_path: Path | None = None
    run_id: str | None = None
    """The MLflow run the report and its CSV were logged to."""


def _load(results: Path, name: str) -> dict[str, Any] | None:
    path = results / name
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise MultigraspError(f"{path} is not readable JSON ({type(exc).__name__}) — run `{SOURCES[name]}` again "
                              "to rewrite it") from None
    if not isinstance(data, dict) or not isinstance(data.get("rows"), list):
        raise MultigraspError(f"{path} has no 'rows' list — run `{SOURCES[name]}` again to rewrite it")
    data["_written"] = _evaluated_at(data, path)
    return data


def _evaluated_at(data: dict[str, Any], path: Path) -> str:
    """When a results file was evaluated, in local time: its ``evaluated_at`` field
    (:func:`flows.config.results_stamp`), else (a file written before that field, or hand-edited) its mtime, which a
    copy that does not keep times changes."""
    try:
        when = datetime.datetime.fromisoformat(data["evaluated_at"]).astimezone()
    except (KeyError, TypeError, ValueError):
        when = datetime.datetime.fromtimestamp(path.stat().st_mtime)
    return when.strftime("%Y-%m-%d %H:%M")


def _rows(data: dict[str, Any] | None) -> dict[str, dict[str, Any]]:
    return {row.get("setting"): row for row in (data or {}).get("rows", [])}


def _pct(value: Any) -> str:
    return "–" if value is None else f"{100 * value:.1f} %"


def _cell(here: str, paper: str) -> str:
    return f"{here} ({paper})"


#: Marks a success figure lifted from candidates other than accepted pre-grasps (:func:`plumbing_only`).
PLUMBING_MARK = " †"


def plumbing_only(data: dict[str, Any] | None) -> str | None:
    """The ``records_source`` of an execution results file whose poses were not accepted pre-grasps (the smoke
    profile lifts each scene's lowest-energy candidates, since its short synthesis accepts none), or None: such a
    success rate checks the plumbing and is not a result."""
    source = (data or {}).get("records_source")
    return source if source not in (None, "accepted") else None


def _plumbing_note(source: str) -> str:
    return (f"†: lifted from each scene's candidates by `records_source = {source}` (the smoke profile's plumbing "
            "check: its short synthesis accepts no pre-grasp), not from accepted pre-grasps — not a result.")


def table_one(pregrasp: dict[str, dict], execution: dict[str, dict], marked: frozenset[str] = frozenset(),
              generalist: dict[str, dict] | None = None, generalist_marked: bool = False) -> list[str]:
    """Table I: pre-grasp quality and execution success per setting, this run (paper); the success of the settings
    in ``marked`` carries :data:`PLUMBING_MARK`.  ``generalist``: the distilled generalist's rows (the paper's figure
    after the slash), a column of their own, marked too with ``generalist_marked``."""
    generalist = generalist or {}
    lines = ["| setting | Q1 ↑ | PN (mm) ↓ | Div (deg) | s per 256 ↓ | succ ↑ | generalist succ ↑ | accepted / kept | n |",
             "|---|---|---|---|---|---|---|---|---|"]
    for setting, paper in PAPER_PREGRASP.items():
        row = pregrasp.get(setting, {})
        time_here = _num(row.get("time_256_s"), 2)
        time_paper = _num(paper.get("time_256_s"), 2) if "time_256_s" in paper else "≈ 1000 total"
        succ_row = execution.get(setting, {})
        gen_succ = generalist.get(setting, {}).get("succ")
        lines.append(
            f"| {setting} | {_cell(_num(row.get('q1'), 3), _num(paper['q1'], 2))} | "
            f"{_cell(_num(row.get('pn_mm'), 2), _num(paper['pn_mm'], 2))} | "
            f"{_cell(_num(row.get('div_deg'), 2), _num(paper['div_deg'], 2))} | {_cell(time_here, time_paper)} | "
            f"{_cell(_pct(succ_row.get('succ')) + _mark(setting in marked, succ_row.get('succ')), _pct(PAPER_EXECUTION.get(setting)))} | "
            f"{_cell(_pct(gen_succ) + _mark(generalist_marked, gen_succ), _pct(PAPER_GENERALIST.get(setting)))} | "
            f"{_pct(row.get('accept_rate'))} | {row.get('n', '–')} |")
    return lines


def _mark(marked: bool, value: Any) -> str:
    return PLUMBING_MARK if marked and value is not None else ""


def table_two(generator: dict[str, dict], execution: dict[str, dict], syn_pl: dict[str, Any],
              marked: bool = False, syn_pl_marked: bool = False) -> list[str]:
    """Table II: the generator's ablations (a) and the execution ablations (b, c), this run (paper).  ``marked``:
    the execution ablations' poses were not accepted pre-grasps (``syn_pl_marked``: Table I's Syn-Pl row's, which
    stands for Ours when the ablation file has no Ours row); their figures carry :data:`PLUMBING_MARK`."""
    lines = ["**(a) Generative model** (Gen-Pl, grasps kept by the protocol filter)", "",
             "| setting | Q1 ↑ | PN (mm) ↓ | kept | paper succ |", "|---|---|---|---|---|"]
    for setting, paper in PAPER_GENERATOR_ABLATIONS.items():
        row = generator.get(setting, {})
        lines.append(f"| {setting} | {_cell(_num(row.get('q1'), 3), _num(paper['q1'], 2))} | "
                     f"{_cell(_num(row.get('pn_mm'), 2), _num(paper['pn_mm'], 2))} | {_pct(row.get('accept_rate'))} | "
                     f"{_pct(paper['succ'])} |")
    lines += ["", "**(b, c) Execution** (this run: Syn-Pl pre-grasps; the paper's bases are in the last column)", "",
              "| setting | succ ↑ | paper's base |", "|---|---|---|"]
    ours = execution.get("Ours", syn_pl)
    ours_mark = _mark(marked if "Ours" in execution else syn_pl_marked, ours.get("succ"))
    lines.append(f"| Ours | {_cell(_pct(ours.get('succ')) + ours_mark, _pct(PAPER_EXECUTION['Syn-Pl']))} | "
                 "Table I, Syn-Pl |")
    for setting, paper in PAPER_EXECUTION_ABLATIONS.items():
        row = execution.get(setting, {})
        here = _pct(row.get("succ")) + _mark(marked, row.get("succ"))
        lines.append(f"| {setting} | {_cell(here, _pct(paper['succ']))} | {paper['base']} |")
    for setting, row in execution.items():
        if setting not in PAPER_EXECUTION_ABLATIONS and setting != "Ours":
            lines.append(f"| {setting} | {_pct(row.get('succ')) + _mark(marked, row.get('succ'))} | not in the paper |")
    return lines


def table_curriculum(rows: dict[str, dict]) -> list[str]:
    """Table II(c)'s adaptation rows: the curriculum's specialists against w/o Adpt and w/o Curr on Gen-Pl."""
    lines = ["**(c) Adaptation** (Gen-Pl, `multigrasp evaluate curriculum`; the paper's Ours* is on a subset of "
             "objects; vs Ours: the row minus Ours pose by pose, ± its standard error over poses)", "",
             "| setting | succ ↑ | vs Ours, paired (points) |", "|---|---|---|"]
    for setting, paper in PAPER_CURRICULUM_ABLATIONS.items():
        row = rows.get(setting, {})
        lines.append(f"| {setting} | {_cell(_pct(row.get('succ')), _pct(paper))} | {paired_cell(row.get('vs_ours'))} |")
    return lines


def write_report(workdir: Path, parent_run_id: str | None = None, experiment: str | None = None) -> Report:
    """Write ``<workdir>/results/report.md`` from the evaluation results there (module docstring)."""
    results = Path(workdir) / "results"
    data = _results(workdir)
    missing = [name for name, value in data.items() if value is None]
    csv_text = _csv_of(data)
    pregrasp = {**_rows(data["pregrasp_synthetic.json"]), **_rows(data["pregrasp_generated.json"])}
    execution = {**_rows(data["execution.json"]), **_rows(data["execution_generated.json"])}
    ablation_execution = _rows(data["ablation_execution.json"])
    lines = ["# This work dir against the paper", "",
             f"Work dir `{Path(workdir).resolve()}`. Each cell: this run (the paper's figure, Li et al., RA-L 2024). "
             "`–`: not measured here, or not in the paper.", "", "## Sources", "",
             "| results file | profile | evaluated | command |", "|---|---|---|---|"]
    for name, value in data.items():
        if value is None:
            lines.append(f"| {name} | – | not yet | `{SOURCES[name]}` |")
        else:
            lines.append(f"| {name} | {value.get('profile', '?')} | {value['_written']} | `{SOURCES[name]}` |")
    syn_source = plumbing_only(data["execution.json"])
    ablation_source = plumbing_only(data["ablation_execution.json"])
    marked = frozenset(_rows(data["execution.json"])) if syn_source else frozenset()
    generalist_source = plumbing_only(data["execution_generalist.json"])
    lines += ["", "## Table I: pre-grasp quality and execution", ""] + table_one(
        pregrasp, execution, marked, _rows(data["execution_generalist.json"]), bool(generalist_source))
    lines += ["", "Q1: mean over the accepted (generated: kept) grasps of the minimum over a grasp's objects; the "
                  "paper gives no Q1 constants (README 'Reading Q1'). succ: the specialists' success (all objects "
                  "above 10 cm), 5 trials per pose; the Gen rows' are the same specialists lifting the generator's "
                  "kept pre-grasps, as the paper's. generalist succ: the distilled vision-based student on the same "
                  "Syn poses and trials (`multigrasp evaluate generalist`); the paper gives it for Syn-Pl and Gen-Pl "
                  "only."]
    if syn_source or generalist_source:
        lines += ["", _plumbing_note(syn_source or generalist_source)]
    lines += ["", "## Table II: ablations", ""] + table_two(_rows(data["ablation_generator.json"]), ablation_execution,
                                                          execution.get("Syn-Pl", {}), marked=bool(ablation_source),
                                                          syn_pl_marked=bool(syn_source))
    if ablation_source or (syn_source and "Ours" not in ablation_execution):
        lines += ["", _plumbing_note(ablation_source or syn_source)]
    lines += [""] + table_curriculum(_rows(data["ablation_curriculum.json"]))
    markdown = "\n".join(lines) + "\n"
    path = atomic_write_text(results / "report.md", markdown)
    csv_path = atomic_write_text(results / "report.csv", csv_text)
    return Report(path=path, markdown=markdown, missing=missing, csv_path=csv_path,
                  run_id=_log_report(workdir, path, csv_path, data, parent_run_id, experiment))


def _results(workdir: Path) -> dict[str, dict[str, Any] | None]:
    """Every results file of ``workdir/results`` (None where missing), or a one-line error where there is none."""
    results = Path(workdir) / "results"
    if not results.is_dir():
        raise MultigraspError(f"no results in {workdir} (no results/ folder) — run `multigrasp evaluate …` first, or "
                              "point at the work dir that holds them")
    data = {name: _load(results, name) for name in SOURCES}
    if all(value is None for value in data.values()):
        raise MultigraspError(f"no evaluation results in {results} — run `{SOURCES['pregrasp_synthetic.json']}` (and "
                              "the other `multigrasp evaluate` commands) first")
    return data


def _csv_of(data: dict[str, dict[str, Any] | None]) -> str:
    """:func:`report_csv` of a work dir's results files (:func:`_results`)."""
    syn_source = plumbing_only(data["execution.json"])
    return report_csv({**_rows(data["pregrasp_synthetic.json"]), **_rows(data["pregrasp_generated.json"])},
                      {**_rows(data["execution.json"]), **_rows(data["execution_generated.json"])},
                      _rows(data["ablation_execution.json"]), _rows(data["ablation_generator.json"]),
                      frozenset(_rows(data["execution.json"])) if syn_source else frozenset(),
                      plumbing_only(data["ablation_execution.json"]), syn_source,
                      _rows(data["execution_generalist.json"]), _rows(data["ablation_curriculum.json"]),
                      plumbing_only(data["execution_generalist.json"]))


def figures(data: dict[str, dict[str, Any] | None]) -> list[dict[str, str]]:
    """The rows of a work dir's report (``table``, ``setting``, ``metric``, ``here``, ``paper``, ``note``; its
    ``report.csv``) from its results files (:func:`_results`); nothing is written."""
    import csv
    import io

    return list(csv.DictReader(io.StringIO(_csv_of(data))))


def compare_markdown(workdirs: list[Path], labels: list[str] | None = None) -> str:
    """Several work dirs' report figures side by side: one row per figure that any of them has (table, setting,
    metric), one column per work dir (its folder name, or ``labels``), and the paper's.  A figure lifted from
    unaccepted candidates (the smoke profile's plumbing check) carries a †.  Nothing is recomputed or written."""
    labels = labels or [Path(w).name or str(w) for w in workdirs]
    if len(labels) != len(workdirs):
        raise MultigraspError(f"--label was given {len(labels)} time(s) for {len(workdirs)} work dir(s); give one per "
                              "work dir, in the same order, or none")
    results = [_results(w) for w in workdirs]  # each work dir's files read once
    tables = [{(r["table"], r["setting"], r["metric"]): r for r in figures(data)} for data in results]
    keys = list(dict.fromkeys(k for table in tables for k in table))
    lines = ["# Work dirs compared", "",
             "One column per work dir (its `results/`, as `multigrasp report` reads it), the paper's last. `–`: not "
             "measured there. †: lifted from unaccepted candidates (a plumbing check, not a result).", "",
             "| table | setting | metric | " + " | ".join(labels) + " | paper |",
             "|---|---|---|" + "---|" * len(labels) + "---|"]
    for key in keys:
        cells = []
        for table in tables:
            row = table.get(key)
            value = row["here"] if row else ""
            dagger = " †" if row and row["note"] and value else ""
            cells.append((_figure(key[2], value) or "–") + dagger)
        if all(cell == "–" for cell in cells):
            continue
        paper = next((t[key]["paper"] for t in tables if key in t and t[key]["paper"]), "")
        lines.append(f"| {key[0]} | {key[1]} | {key[2]} | " + " | ".join(cells) + f" | {_figure(key[2], paper) or '–'} |")
    lines += ["", "Work dirs: " + "; ".join(f"{label} = `{Path(w).resolve()}` (profile {_profiles(data)})"
                                            for label, w, data in zip(labels, workdirs, results))]
    return "\n".join(lines) + "\n"


def _figure(metric: str, value: str) -> str:
    """A CSV figure as the report prints it: rates as percentages, the rest as written."""
    if not value or metric not in ("succ", "accept_rate"):
        return value
    return _pct(float(value))


def _profiles(data: dict[str, dict[str, Any] | None]) -> str:
    """The profiles a work dir's results files (:func:`_results`) were evaluated under, in order of first appearance."""
    found = [value.get("profile", "?") for value in data.values() if value is not None]
    return ", ".join(dict.fromkeys(found))


def report_csv(pregrasp: dict[str, dict], execution: dict[str, dict], ablation_execution: dict[str, dict],
               generator: dict[str, dict], marked: frozenset[str] = frozenset(), ablation_source: str | None = None,
               syn_source: str | None = None, generalist: dict[str, dict] | None = None,
               curriculum: dict[str, dict] | None = None, generalist_source: str | None = None) -> str:
    """The report's figures as long-format CSV: ``table,setting,metric,here,paper,note`` (empty where not measured).
    ``note`` names a success figure's ``records_source`` where its poses were not accepted pre-grasps (Table I's
    settings in ``marked``; the execution ablations under ``ablation_source``; Ours from Table I under
    ``syn_source``): a plumbing check, not a result."""
    import csv
    import io

    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["table", "setting", "metric", "here", "paper", "note"])

    def put(table: str, setting: str, metric: str, here: Any, paper: Any, source: str | None = None) -> None:
        note = f"plumbing check (records_source={source}), not a result" if source and here is not None else ""
        writer.writerow([table, setting, metric, "" if here is None else here, "" if paper is None else paper, note])

    for setting, paper in PAPER_PREGRASP.items():
        row = pregrasp.get(setting, {})
        for metric in ("q1", "pn_mm", "div_deg", "time_256_s", "accept_rate"):
            put("I", setting, metric, row.get(metric), paper.get(metric))
        put("I", setting, "succ", execution.get(setting, {}).get("succ"), PAPER_EXECUTION.get(setting),
            syn_source if setting in marked else None)
        put("I", setting, "succ_generalist", (generalist or {}).get(setting, {}).get("succ"),
            PAPER_GENERALIST.get(setting), generalist_source)
    for setting, paper in PAPER_GENERATOR_ABLATIONS.items():
        row = generator.get(setting, {})
        for metric in ("q1", "pn_mm"):
            put("II(a)", setting, metric, row.get(metric), paper[metric])
    put("II(b,c)", "Ours", "succ", ablation_execution.get("Ours", execution.get("Syn-Pl", {})).get("succ"),
        PAPER_EXECUTION["Syn-Pl"], ablation_source if "Ours" in ablation_execution else syn_source)
    for setting, paper in PAPER_EXECUTION_ABLATIONS.items():
        put("II(b,c)", setting, "succ", ablation_execution.get(setting, {}).get("succ"), paper["succ"], ablation_source)
    for setting, paper in PAPER_CURRICULUM_ABLATIONS.items():
        put("II(c)", setting, "succ", (curriculum or {}).get(setting, {}).get("succ"), paper)
    return out.getvalue()


def _log_report(workdir: Path, markdown: Path, csv_path: Path, data: dict[str, Any], parent_run_id: str | None = None,
                experiment: str | None = None) -> str:
    """A run ``report`` in the work dir's MLflow store (or ``MLFLOW_TRACKING_URI``'s) with both files, tagged with the
    profile of each source."""
    from tasks.tracking import DEFAULT_EXPERIMENT, Tracker, default_tracking_uri

    tracker = Tracker(default_tracking_uri(Path(workdir)), experiment or DEFAULT_EXPERIMENT, Path(workdir))
    tags = {"command": "report", **{f"source.{name}": value.get("profile", "?")
                                    for name, value in data.items() if value is not None}}
    run_id = tracker.start_run("report", parent_run_id, tags=tags)
    for path in (markdown, csv_path):
        tracker.log_artifact(run_id, path, "results")
    tracker.end_run(run_id)
    return run_id


#: results file → (the provenance field naming a stage output's manifest, that stage), for :func:`evaluation_status`.
EVALUATED_FROM = {
    "pregrasp_synthetic.json": [("synthesize_manifest", "synthesize")],
    "pregrasp_generated.json": [("generator_manifest", "train-generator")],
    "execution.json": [("specialists_manifest", "specialists")],
    "execution_generated.json": [("specialists_manifest", "specialists"), ("generator_manifest", "train-generator")],
    "ablation_execution.json": [("specialists_manifest", "specialists")],
    "ablation_generator.json": [("generator_manifest", "train-generator")],
    "execution_generalist.json": [("distill_manifest", "distill")],
    "ablation_curriculum.json": [("curriculum_manifest", "curriculum")],
}


@dataclass
class EvaluationStatus:
    name: str
    state: str  # current | stale | unknown | missing
    detail: str
    ablations: bool = False
    """``ablation_execution.json``: written by ``evaluate execution --ablations`` (every ablation row), not only
    with the rows ``evaluate execution`` always writes (Ours, w/o RL, the squeeze)."""


def evaluation_status(cfg, finals: dict[str, str | None] | None = None) -> list[EvaluationStatus]:
    """Whether each evaluation under ``results/`` was made from this config's stage outputs now and under its settings
    (``current``), from others (``stale``: a stage was recomputed, or another config evaluated last), or cannot say
    (``unknown``: a file from before evaluations recorded their settings).  Stage outputs are compared by their unit
    key (the folder name) and settings by :func:`flows.config.evaluation_key`, so a moved work dir stays current.  ``finals``: each
    stage's output folder as ``status`` found it (None: not done), so its files are not verified a second time."""
    from flows.pipeline import stage_output

    from flows.config import evaluation_key

    results = cfg.run.workdir / "results"
    outputs: dict[str, Any] = {}
    if finals is not None:
        outputs = {stage: (Path(folder) if folder else None) for stage, folder in finals.items()}
    rows = []
    for name, command in SOURCES.items():
        path = results / name
        if not path.is_file():
            rows.append(EvaluationStatus(name, "missing", f"`{command}`"))
            continue
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            rows.append(EvaluationStatus(name, "unknown", f"unreadable — run `{command}` again"))
            continue
        checks = EVALUATED_FROM[name]
        stale = []
        for field_name, stage in checks:
            if stage not in outputs:
                found = stage_output(cfg, stage)
                outputs[stage] = Path(found.folder) if found is not None else None
            made_from = data.get(field_name)
            now = outputs[stage]
            if not made_from or now is None or Path(made_from).parent.name != now.name:
                stale.append(stage)
        profile = f"{data.get('profile', '?')}, evaluated {_evaluated_at(data, path)}"
        settings = data.get("config_key")
        if stale:
            rows.append(EvaluationStatus(name, "stale", f"profile {profile}; not from this config's {', '.join(stale)} "
                                                        f"output now — run `{command}` again"))
        elif settings is not None and settings != evaluation_key(cfg, name):
            rows.append(EvaluationStatus(name, "stale", f"profile {profile}; evaluated under other settings than this "
                                                        f"config's — run `{command}` again"))
        elif (outdated := _outdated(name, data)) is not None:
            rows.append(EvaluationStatus(name, "stale", f"profile {profile}; {outdated} — run `{command}` again"))
        elif settings is None:
            rows.append(EvaluationStatus(name, "unknown", f"profile {profile}; it records no config key (written "
                                                          f"before the fiftieth session) — run `{command}` again to be "
                                                          "sure"))
        else:
            partial = name == "ablation_execution.json" and not data.get("ablations")
            detail = f"profile {profile}" + (f"; Ours, w/o RL and the squeeze only — `{command}` for every row"
                                             if partial else "")
            rows.append(EvaluationStatus(name, "current", detail, ablations=not partial))
    return [_with_lift_jobs(cfg, row) for row in rows]


def _outdated(name: str, data: dict[str, Any]) -> str | None:
    """Why a results file written by an older evaluation reports a figure that means something else now, or None."""
    if name == "pregrasp_generated.json" and any(row.get("time_256_s") is not None and "time_batch" not in row
                                                 for row in data.get("rows", [])):
        return ("its time per 256 was scaled from smaller batches (before the fifty-second session), not timed on a "
                "batch of 256")
    return None


#: Results files whose evaluation lifts in cached jobs (:mod:`tasks.lift_jobs`).
LIFTED = ("execution.json", "execution_generated.json")


def _with_lift_jobs(cfg, row: EvaluationStatus) -> EvaluationStatus:
    """A lift evaluation that is not current, with how many of its lift jobs already finished (an evaluation killed
    halfway): its rerun serves them."""
    from dataclasses import replace

    from flows.config import evaluation_key
    from tasks.lift_jobs import finished_jobs

    if row.name not in LIFTED or row.state == "current":
        return row
    done = finished_jobs(cfg.run.workdir, evaluation_key(cfg, row.name))
    if not done:
        return row
    return replace(row, detail=f"{row.detail}; {done} lift job(s) of this config finished; a rerun serves them")
