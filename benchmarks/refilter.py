"""A synthesize stage's candidates re-filtered under other filter settings, without synthesising again.

    python -m benchmarks.refilter --profile bench --workdir runs --set KEY=VALUE ... \\
        --filter filter_contact_distance_reduce=mean --json OUT [--write-grasps FILE]
    python -m benchmarks.refilter ... --rescore fc_friction=0.5 --json OUT

Which candidates: by default every candidate of the synthesize stage of the config (``--profile`` / ``--config`` /
``--set`` / ``--workdir``, as ``multigrasp run``; its merge's ``grasps.parquet`` + ``rejected.parquet``).
``--stage-dir`` names a folder instead: a merge folder (those two files), or ``<workdir>/stages/synthesize``,
whose shard tables are all read (a work dir that ran several configs mixes them there).

Every candidate keeps its filter terms (``term_fc_per_object``, ``term_contact_distance_max``,
``term_contact_distance_per_object``, ``term_penetration_depth_max``, ``term_prior``).  This tool applies
:func:`components.synthesis.filtering.filter_grasps` to them with the config's ``synthesis.optimizer`` plus the
``--filter`` overrides (and, for scenes of n objects, the ``synthesis.optimizer_by_object_count`` fields of n).
``--rescore KEY=VALUE`` (fields of ``synthesis.optimizer`` the energy reads, e.g. ``fc_friction``) first
recomputes every candidate's terms at its stored pose and contacts under the changed optimizer -- a setting the
candidates were optimised under, accepted under another; before that it checks that the config reproduces the
first scene's stored terms (one-line error otherwise: pass the ``--set`` options the stage was made with).
The rows that only the new filter accepts are scored with the stage's metrics (Q1 / PN, as the shards score
theirs; ``--max-new`` caps that cost, ~0.6 s a grasp); the JSON summarises, per singles / pairs / more as
:mod:`benchmarks.synthesis_progress` does, the stored filter, the new one and the newly accepted rows alone
(``newly_accepted``).  Rows the new filter rejects keep their stored Q1 / PN out of the summary.  With
``synthesis.min_q1`` set, rows whose Q1 is not above it are rejected with reason ``q1``, as the stage does.
``--write-grasps FILE`` writes the accepted rows after re-filtering (every column, ``term_*`` rescored where
``--rescore`` asked) as a grasps table the other tools read with ``--grasps`` (``benchmarks.lift_failures``,
``benchmarks.scripted_lift``, ``benchmarks.q1_conventions``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import finish_tool, scene_batches
from benchmarks.synthesis_progress import GROUPS, quality_summary, shard_tables
from components.errors import MultigraspError

#: filter input -> stored column
TERM_COLUMNS = {"fc_per_object": "term_fc_per_object", "contact_distance_max": "term_contact_distance_max",
                "contact_distance_per_object": "term_contact_distance_per_object",
                "penetration_depth_max": "term_penetration_depth_max", "prior": "term_prior"}


def refiltered(frame, optimizer_for) -> tuple[np.ndarray, list[str]]:
    """(accepted (N,), reasons) of ``frame``'s rows from the stored terms, the rows of n objects under the filter
    of ``optimizer_for(n)`` (``SynthesisStageConfig.optimizer_for``: the stage's per-object-count settings);
    rows are filtered per object count (the per-object terms have one entry per object)."""
    import torch

    from components.synthesis.filtering import filter_grasps

    accepted, reasons = np.zeros(len(frame), dtype=bool), [""] * len(frame)
    counts = frame["term_fc_per_object"].map(len).to_numpy()
    for count in np.unique(counts):
        rows = np.flatnonzero(counts == count)
        part = frame.iloc[rows]
        terms = {key: torch.as_tensor(np.stack(part[column].to_numpy()).astype(np.float64))
                 for key, column in TERM_COLUMNS.items()}
        ok, why = filter_grasps(terms, optimizer_for(int(count)))
        accepted[rows] = ok.numpy()
        for row, reason in zip(rows, why):
            reasons[row] = reason
    return accepted, reasons


#: Stored term columns compared by the reproduction check of ``--rescore``: |stored - recomputed| <= atol + rtol |stored|.
CHECKED_TERMS = ("term_fc_per_object", "term_penetration_depth_max", "term_contact_distance_max")
REPRODUCE_ATOL, REPRODUCE_RTOL = 1e-5, 1e-3


def read_candidates(stage_dir: Path):
    """(every candidate of ``stage_dir`` as one frame, the tables read): a merge folder's ``grasps.parquet`` +
    ``rejected.parquet``, or every shard table under ``<workdir>/stages/synthesize``."""
    import pandas as pd

    merged = [stage_dir / "grasps.parquet", stage_dir / "rejected.parquet"]
    tables = merged if all(p.is_file() for p in merged) else shard_tables(stage_dir)
    return pd.concat([pd.read_parquet(p) for p in tables], ignore_index=True), tables


def stage_candidates(cfg):
    """The candidates of the synthesize stage of ``cfg`` (:func:`read_candidates` of its merge folder)."""
    from flows.pipeline import stage_output

    manifest = stage_output(cfg, "synthesize")
    if manifest is None:
        raise MultigraspError("no synthesize stage output for this config — run `multigrasp run --until synthesize` "
                              "first (same --profile / --config / --set / --workdir), or pass --stage-dir")
    return read_candidates(manifest.path("grasps").parent)


def scene_terms(frame, cfg, hand, library) -> Iterator[tuple[np.ndarray, dict]]:
    """Per scene of ``frame``: (row positions, the filter terms of :func:`components.synthesis.energy.energy` at the
    rows' stored poses and contacts, as numpy arrays keyed by ``TERM_COLUMNS`` column), under ``cfg``'s optimiser for
    the scene's object count."""
    import torch

    from components.synthesis.energy import GraspProblem, energy
    from components.synthesis.pose import pack

    for rows, objects, p, R, q in scene_batches(frame, hand, library):
        problem = GraspProblem.build(hand, objects, cfg.synthesis.optimizer_for(objects.n_objects))
        contacts = torch.as_tensor(np.stack(frame["contacts"].iloc[rows].to_numpy()).astype(np.int64))
        with torch.no_grad():
            _, terms = energy(problem, pack(p, R, q), contacts.reshape(len(rows), objects.n_objects, -1))
        yield rows, {column: terms[key].double().numpy() for key, column in TERM_COLUMNS.items()}


def rescored(frame, base_cfg, cfg):
    """``frame`` with every candidate's ``TERM_COLUMNS`` recomputed under ``cfg`` (module docstring), after checking
    that ``base_cfg`` (the config the stage was made with) reproduces the first scene's stored terms."""
    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from tasks.preflight import cache_dir

    if "contacts" not in frame:
        raise MultigraspError("--rescore needs the candidates' contacts, which these tables lack — rerun the "
                              "synthesize stage with this version")
    hand = HandModel(base_cfg.hand)
    library = ObjectLibrary(base_cfg.objects, cache_dir=cache_dir(base_cfg.run.workdir))
    first = frame[frame["scene_id"] == frame["scene_id"].iloc[0]]
    for rows, terms in scene_terms(first, base_cfg, hand, library):
        for column in CHECKED_TERMS:
            stored = np.stack(first[column].iloc[rows].to_numpy()).astype(np.float64).reshape(terms[column].shape)
            error = float(np.abs(stored - terms[column]).max())
            if not np.allclose(terms[column], stored, atol=REPRODUCE_ATOL, rtol=REPRODUCE_RTOL):
                raise MultigraspError(f"this config does not reproduce the stored {column} of scene "
                                      f"{first['scene_id'].iloc[0]} (max |difference| {error:.3g}) — pass the --config "
                                      "/ --set options the stage was made with")
    columns: dict[str, list] = {column: [None] * len(frame) for column in TERM_COLUMNS.values()}
    for rows, terms in scene_terms(frame, cfg, hand, library):
        for column, values in terms.items():
            for row, value in zip(rows, values):
                columns[column][row] = value if np.ndim(value) else float(value)
    return frame.assign(**columns)


def run(frame, tables: list[Path], cfg, max_new: int, write_grasps: Path | None = None) -> dict:
    """Re-filter the candidates ``frame`` (read from ``tables``) under ``cfg``, score the newly accepted rows and
    summarise (module docstring); ``write_grasps``: where the accepted rows go."""
    from components.hand import HandModel
    from components.metrics import penetration_depth, q1_grasps
    from components.objects import ObjectLibrary
    from tasks.preflight import cache_dir
    from tasks.synthesize import reject_weak

    frame = frame.reset_index(drop=True)
    accepted, reasons = refiltered(frame, cfg.synthesis.optimizer_for)
    new = frame[accepted & ~frame["accepted"].to_numpy()]
    if len(new) > max_new:
        raise MultigraspError(f"the new filter accepts {len(new)} rows the stage rejected; scoring them takes "
                              f"~{0.6 * len(new) / 60:.0f} min — raise --max-new to at least {len(new)} to go on")
    scored = new.reset_index()
    if len(scored):
        hand, metrics = HandModel(cfg.hand), cfg.synthesis.metrics
        library = ObjectLibrary(cfg.objects, cache_dir=cache_dir(cfg.run.workdir))
        q1, pn = np.zeros(len(scored)), np.zeros(len(scored))
        for rows, objects, p, R, q in scene_batches(scored, hand, library):
            q1[rows] = q1_grasps(hand, objects, p, R, q, metrics)[0].numpy()
            pn[rows] = penetration_depth(hand, objects, p, R, q, metrics).pn_mm.detach().double().numpy()
        frame.loc[scored["index"].to_numpy(), ["q1", "pn_mm"]] = np.stack([q1, pn], axis=1)
    # the stage's synthesis.min_q1, as the shards apply it (rows it rejected come back here with their Q1 scored)
    kept = reject_weak({"accepted": accepted, "reasons": np.array(reasons, dtype=object)}, frame["q1"].to_numpy(),
                       cfg.synthesis.min_q1)
    accepted, reasons = kept["accepted"], list(kept["reasons"])
    after = frame.assign(accepted=accepted, reason=reasons)
    if write_grasps is not None:
        write_grasps.parent.mkdir(parents=True, exist_ok=True)
        after[accepted].sort_values(["scene_id", "row"]).reset_index(drop=True).to_parquet(write_grasps)
    only_new = after[accepted & ~frame["accepted"].to_numpy()]
    objects = frame["combination"].str.count(r"\+") + 1
    groups = {}
    for n in sorted(objects.unique()):
        name = GROUPS.get(n, f"{n} objects")
        groups[name] = {"stored": quality_summary(frame[objects == n]), "refiltered": quality_summary(after[objects == n]),
                        "newly_accepted": quality_summary(only_new[objects[only_new.index] == n]),
                        "newly_rejected": int((~accepted & frame["accepted"].to_numpy())[objects == n].sum())}
    return {"tables": [str(p) for p in tables], "filter": filter_settings(cfg.synthesis.optimizer),
            "written": None if write_grasps is None else str(write_grasps),
            "groups": groups, "rows": [{"group": k, **v} for k, v in groups.items()]}


def filter_settings(optimizer) -> dict:
    return {k: v for k, v in optimizer.model_dump().items() if k.startswith("filter_")}


def main(argv: list[str] | None = None) -> int:
    from flows.config import load_config

    parser = argparse.ArgumentParser(prog="python -m benchmarks.refilter", description=__doc__.split("\n\n")[0])
    parser.add_argument("--stage-dir", type=Path,
                        help="a merge folder, or <workdir>/stages/synthesize (default: the stage of the config)")
    parser.add_argument("--profile", default="bench", help="profile whose synthesis.optimizer / metrics apply (default: bench)")
    parser.add_argument("--config", type=Path, help="YAML config file on top of the profile")
    parser.add_argument("--set", action="append", default=[], dest="sets",
                        help="KEY=VALUE override of the config the stage was made with, as for multigrasp run")
    parser.add_argument("--workdir", type=Path, help="work dir of the stage (default: the profile's)")
    parser.add_argument("--filter", action="append", default=[], dest="filters",
                        help="KEY=VALUE of synthesis.optimizer, e.g. filter_contact_distance_reduce=mean")
    parser.add_argument("--rescore", action="append", default=[], dest="rescores",
                        help="KEY=VALUE of synthesis.optimizer under which every candidate's terms are recomputed, "
                             "e.g. fc_friction=0.5")
    parser.add_argument("--max-new", type=int, default=2000, help="refuse to score more newly accepted rows than this")
    parser.add_argument("--write-grasps", type=Path, help="write the accepted rows after re-filtering here (Parquet)")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)

    def compute() -> dict:
        overrides = {"workdir": args.workdir} if args.workdir else {}
        base = load_config(args.profile, args.config, args.sets, **overrides)
        changed = [f"synthesis.optimizer.{item}" for item in args.rescores + args.filters]
        cfg = load_config(args.profile, args.config, args.sets + changed, **overrides)
        frame, tables = read_candidates(args.stage_dir) if args.stage_dir else stage_candidates(base)
        if args.rescores:
            frame = rescored(frame, base, cfg)
        result = run(frame, tables, cfg, args.max_new, args.write_grasps)
        return {**result, "rescore": args.rescores, "set": args.sets}

    def report(result: dict) -> None:
        for row in result["rows"]:
            before, after = row["stored"], row["refiltered"]
            print(f"{row['group']:10s} stored {before['accepted']}/{before['candidates']} (Q1 {before['q1']}, PN "
                  f"{before['pn_mm']} mm) -> refiltered {after['accepted']}/{after['candidates']} (Q1 {after['q1']}, "
                  f"PN {after['pn_mm']} mm, Div {after['div_deg']})")
        if result["written"]:
            print(f"accepted rows written to {result['written']}")

    return finish_tool(args.json, compute, report)


if __name__ == "__main__":
    sys.exit(main())
