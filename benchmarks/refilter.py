"""A synthesize stage's candidates re-filtered under other filter settings, without synthesising again.

    python -m benchmarks.refilter --stage-dir runs/stages/synthesize --profile bench --workdir runs \\
        --filter filter_contact_distance_reduce=mean --json OUT

Every shard table keeps each candidate's filter terms (``term_fc_per_object``, ``term_contact_distance_max``,
``term_contact_distance_per_object``, ``term_penetration_depth_max``, ``term_prior``).  This tool applies
:func:`components.synthesis.filtering.filter_grasps` to them with the profile's ``synthesis.optimizer`` plus the
``--filter`` overrides (and, for scenes of n objects, the ``synthesis.optimizer_by_object_count`` fields of n), scores the rows that only the new filter accepts with the stage's metrics (Q1 / PN, as
the shards score theirs; ``--max-new`` caps that cost, ~0.6 s a grasp) and summarises, per singles / pairs / more
as :mod:`benchmarks.synthesis_progress` does, the stored filter, the new one and the newly accepted rows
alone (``newly_accepted``).  Rows the new filter rejects keep their
stored Q1 / PN out of the summary.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks.grasp_tables import finish_tool, scene_batches
from benchmarks.synthesis_progress import GROUPS, quality_summary, shard_tables
from components.errors import MultigraspError

#: filter input -> stored column
TERM_COLUMNS = {"fc_per_object": "term_fc_per_object", "contact_distance_max": "term_contact_distance_max",
                "contact_distance_per_object": "term_contact_distance_per_object",
                "penetration_depth_max": "term_penetration_depth_max", "prior": "term_prior"}
ROW_COLUMNS = ["scene_id", "combination", "object_names", "object_positions", "object_quats_xyzw", "p", "R", "q",
               "accepted", "reason", "q1", "pn_mm"]


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


def run(stage_dir: Path, cfg, max_new: int) -> dict:
    import pandas as pd

    from components.hand import HandModel
    from components.metrics import penetration_depth, q1_grasps
    from components.objects import ObjectLibrary
    from tasks.preflight import cache_dir

    tables = shard_tables(stage_dir)
    frame = pd.concat([pd.read_parquet(p, columns=ROW_COLUMNS + list(TERM_COLUMNS.values())) for p in tables],
                      ignore_index=True)
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
    after = frame.assign(accepted=accepted, reason=reasons)
    only_new = after[accepted & ~frame["accepted"].to_numpy()]
    objects = frame["combination"].str.count(r"\+") + 1
    groups = {}
    for n in sorted(objects.unique()):
        name = GROUPS.get(n, f"{n} objects")
        groups[name] = {"stored": quality_summary(frame[objects == n]), "refiltered": quality_summary(after[objects == n]),
                        "newly_accepted": quality_summary(only_new[objects[only_new.index] == n]),
                        "newly_rejected": int((~accepted & frame["accepted"].to_numpy())[objects == n].sum())}
    return {"stage_dir": str(stage_dir), "shards": len(tables), "filter": filter_settings(cfg.synthesis.optimizer),
            "groups": groups, "rows": [{"group": k, **v} for k, v in groups.items()]}


def filter_settings(optimizer) -> dict:
    return {k: v for k, v in optimizer.model_dump().items() if k.startswith("filter_")}


def main(argv: list[str] | None = None) -> int:
    from flows.config import load_config

    parser = argparse.ArgumentParser(prog="python -m benchmarks.refilter", description=__doc__.split("\n\n")[0])
    parser.add_argument("--stage-dir", type=Path, required=True, help="<workdir>/stages/synthesize")
    parser.add_argument("--profile", default="bench", help="profile whose synthesis.optimizer / metrics apply (default: bench)")
    parser.add_argument("--workdir", type=Path, help="work dir whose object cache is used (default: the profile's)")
    parser.add_argument("--filter", action="append", default=[], dest="filters",
                        help="KEY=VALUE of synthesis.optimizer, e.g. filter_contact_distance_reduce=mean")
    parser.add_argument("--max-new", type=int, default=2000, help="refuse to score more newly accepted rows than this")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    args = parser.parse_args(argv)

    def compute() -> dict:
        sets = [f"synthesis.optimizer.{item}" for item in args.filters]
        cfg = load_config(args.profile, None, sets, **({"workdir": args.workdir} if args.workdir else {}))
        return run(args.stage_dir, cfg, args.max_new)

    def report(result: dict) -> None:
        for row in result["rows"]:
            before, after = row["stored"], row["refiltered"]
            print(f"{row['group']:10s} stored {before['accepted']}/{before['candidates']} (Q1 {before['q1']}, PN "
                  f"{before['pn_mm']} mm) -> refiltered {after['accepted']}/{after['candidates']} (Q1 {after['q1']}, "
                  f"PN {after['pn_mm']} mm, Div {after['div_deg']})")

    return finish_tool(args.json, compute, report)


if __name__ == "__main__":
    sys.exit(main())
