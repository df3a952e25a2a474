"""What a synthesize stage has produced so far, finished or not: accept rate, rejection reasons, Q1, PN and
Div per combination and for singles / pairs / more, from the shard tables on disk.

    python -m benchmarks.synthesis_progress --stage-dir runs/stages/synthesize --json OUT

Reads every ``<stage-dir>/*/grasps.parquet`` written by a shard (the merge unit's table, which repeats the
accepted rows, is skipped), so it can be pointed at a running or interrupted stage.  Q1 / PN are the
shards' own (``synthesis.metrics``), Div is :func:`components.metrics.joint_diversity_deg` over the accepted q;
``lineages`` (tables that have the column) counts the distinct MALA chains among the accepted rows, fewer than
them when ``synthesis.optimizer.resample_at`` copied chains, and ``siblings_joint_diff_deg_median`` says how far
apart two accepted copies of one chain ended (``others_...``: two rows of different chains of one scene).
A scene synthesised by several shards (an earlier config or code version in the same work dir) counts once, from
the newest shard table (``superseded_rows`` says how many older rows were dropped); ``--split`` keeps some splits.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from benchmarks.grasp_tables import finish_tool, row_report
from components.errors import MultigraspError

COLUMNS = ["combination", "accepted", "reason", "q1", "pn_mm", "q"]
#: Read too where the table has them: the split filter and the one-row-per-candidate rule use them.
OPTIONAL_COLUMNS = ["split", "scene_id", "row", "lineage"]
GROUPS = {1: "singles", 2: "pairs"}


def quality_summary(frame) -> dict:
    """Candidates, accepted, accept rate, rejection reasons and the accepted rows' Q1 / PN / Div of a table."""
    import numpy as np
    import torch

    from components.metrics import joint_diversity_deg

    accepted = frame[frame.accepted]
    out = {"candidates": len(frame), "accepted": int(len(accepted)),
           "accept_rate": round(len(accepted) / max(len(frame), 1), 4),
           "reasons": {k: int(v) for k, v in frame["reason"].value_counts().items() if k != "accepted"},
           "q1": None, "q1_positive": None, "pn_mm": None, "div_deg": None}
    if len(accepted):
        out.update(q1=round(float(accepted.q1.mean()), 4), q1_positive=round(float((accepted.q1 > 0).mean()), 4),
                   pn_mm=round(float(accepted.pn_mm.mean()), 3),
                   div_deg=round(joint_diversity_deg(torch.as_tensor(np.stack(accepted.q.to_numpy()))), 2))
        if {"scene_id", "lineage"} <= set(accepted.columns):  # tables since resample_at: distinct chains accepted
            out["lineages"] = int(len(accepted[["scene_id", "lineage"]].drop_duplicates()))
            out.update(sibling_spread(accepted))
    return out


def lineage_pairs(lineage) -> tuple:
    """Upper-triangle masks (N, N) of the row pairs of one scene that share a lineage (copies made by
    ``resample_at``) and of those that do not.  lineage (N,) -> (siblings, others)."""
    import numpy as np

    lineage = np.asarray(lineage)
    upper = np.triu(np.ones((len(lineage), len(lineage)), dtype=bool), k=1)
    same = lineage[:, None] == lineage[None, :]
    return upper & same, upper & ~same


def joint_differences_deg(q):
    """Mean |q_a - q_b| over the joints, in degrees, of every pair of rows.  q (N, J) rad -> (N, N)."""
    import numpy as np

    q = np.degrees(np.asarray(q, dtype=float))
    return np.abs(q[:, None, :] - q[None, :, :]).mean(-1)


def median_or_none(values, digits: int):
    import numpy as np

    return round(float(np.median(values)), digits) if len(values) else None


def sibling_spread(accepted) -> dict:
    """Median mean-|dq| (deg) between two accepted rows of one scene that share a lineage (copies made by
    ``resample_at``), and between two of one scene that do not; None where there is no such pair."""
    import numpy as np

    same, other = [], []
    for _, scene in accepted.groupby("scene_id"):
        diff = joint_differences_deg(np.stack(scene.q.to_numpy()))
        siblings, others = lineage_pairs(scene.lineage.to_numpy())
        same.append(diff[siblings])
        other.append(diff[others])
    same, other = np.concatenate(same), np.concatenate(other)
    return {"sibling_pairs": int(len(same)), "siblings_joint_diff_deg_median": median_or_none(same, 3),
            "others_joint_diff_deg_median": median_or_none(other, 3)}


def shard_tables(stage_dir: Path) -> list[Path]:
    """The shards' ``grasps.parquet`` under a synthesize stage folder (the merge's, beside its
    ``rejected.parquet``, left out); a one-line error when there is none."""
    tables = sorted(p for p in stage_dir.glob("*/grasps.parquet") if not (p.parent / "rejected.parquet").exists())
    if not tables:
        raise MultigraspError(f"no shard tables under {stage_dir} — give a synthesize stage folder "
                              "(<workdir>/stages/synthesize) after at least one shard finished")
    return tables


def read_tables(tables: list[Path]):
    """The shard tables as one frame, oldest first, each candidate (scene id, row) once: the newest table's."""
    import pandas as pd
    import pyarrow.parquet as pq

    frames = []
    for path in sorted(tables, key=lambda p: p.stat().st_mtime):
        names = set(pq.read_schema(path).names)
        frames.append(pd.read_parquet(path, columns=COLUMNS + [c for c in OPTIONAL_COLUMNS if c in names]))
    frame = pd.concat(frames, ignore_index=True)
    before = len(frame)
    if {"scene_id", "row"} <= set(frame.columns):
        frame = frame.drop_duplicates(["scene_id", "row"], keep="last")
    return frame, before - len(frame)


def run(stage_dir: Path, splits: list[str] | None = None) -> dict:
    tables = shard_tables(stage_dir)
    frame, superseded = read_tables(tables)
    if splits:
        if "split" not in frame.columns:
            raise MultigraspError(f"the shard tables under {stage_dir} have no split column; run without --split")
        frame = frame[frame.split.isin(splits)]
        if not len(frame):
            raise MultigraspError(f"no rows of split(s) {', '.join(splits)} under {stage_dir}; check --split")
    objects = frame["combination"].str.count(r"\+") + 1
    rows = [{"combination": name, **quality_summary(group)} for name, group in frame.groupby("combination")]
    rows.sort(key=lambda r: (r["combination"].count("+"), r["combination"]))
    groups = {GROUPS.get(n, f"{n} objects"): {"combinations": int(frame[objects == n].combination.nunique()),
                                              **quality_summary(frame[objects == n])} for n in sorted(objects.unique())}
    return {"stage_dir": str(stage_dir), "shards": len(tables), "splits": splits or "all",
            "superseded_rows": int(superseded), "groups": groups, "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.synthesis_progress", description=__doc__.split("\n\n")[0])
    parser.add_argument("--stage-dir", type=Path, required=True, help="<workdir>/stages/synthesize")
    parser.add_argument("--json", type=Path, required=True, help="write the result here")
    parser.add_argument("--split", action="append", default=None,
                        help="keep only this split's scenes (train, Pl, Com, Geo, many); repeat for several")
    args = parser.parse_args(argv)
    return finish_tool(args.json, lambda: run(args.stage_dir, args.split), row_report(
        lambda row: f"{row['combination']:28s} {row['accepted']:4d}/{row['candidates']:<4d} Q1 {row['q1']}  "
                    f"PN {row['pn_mm']}  rejected {row['reasons']}"))


if __name__ == "__main__":
    sys.exit(main())
