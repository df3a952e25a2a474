"""The ``merge`` unit of the ``synthesize`` stage: accepted / rejected tables, statistics, report,
energy histograms and render grids (see :mod:`tasks.synthesize`).

Kept apart from the shard code: the shards' cache keys cover ``tasks/synthesize.py``, the merge's
cover this file, so changing a report or a render recomputes only the merge, never hours of synthesis.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task

from components.execution.cameras import CameraConfig
from components.objects.config import ObjectsConfig
from tasks.artifacts import Manifest, atomic_write_json, atomic_write_text, atomic_write_with
from tasks.preflight import cache_dir
from tasks.scenes import RENDER_CODE_DIRS, SPLITS
from tasks.synthesize import SynthesisStageConfig, write_parquet
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

MERGE_CODE_DIRS = ("tasks/synthesize.py", "tasks/synthesize_merge.py", *RENDER_CODE_DIRS)
#: Smallest value shown on the log-scale energy histograms (terms are >= 0; exact zeros land here).
HISTOGRAM_FLOOR = 1e-8


# --------------------------------------------------------------------------- merge: statistics


SUMMARY_COLUMNS = ("scene_id", "split", "combination", "accepted", "reason", "q1", "pn_mm")
#: Summary columns a table may lack (written by newer shard code only): used when present.
OPTIONAL_SUMMARY_COLUMNS = ("q1_objects", "q1_group")


def _mean_or_none(values) -> float | None:
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(values.mean()) if len(values) else None


def summarize(frame) -> dict[str, Any]:
    """Counts, accept rate, rejection reasons and mean Q1 / PN (accepted rows) of a group of candidates."""
    accepted = frame[frame["accepted"]]
    reasons = frame.loc[~frame["accepted"], "reason"].value_counts()
    candidates = int(len(frame))
    return {"scenes": int(frame["scene_id"].nunique()), "candidates": candidates, "accepted": int(len(accepted)),
            "accept_rate": len(accepted) / candidates if candidates else 0.0,
            "reasons": {str(k): int(v) for k, v in sorted(reasons.items())},
            "mean_q1": _mean_or_none(accepted["q1"]), "mean_pn_mm": _mean_or_none(accepted["pn_mm"]),
            **_group_fields(frame, accepted)}


def _group_fields(frame, accepted) -> dict[str, Any]:
    """With group-force-closure rows (``q1_group``): ``mean_q1`` is their group Q1, so also report the hand-alone
    ``mean_q1_objects`` (min over objects of the per-object Q1) and how many rows are group rows."""
    if "q1_group" not in frame or not frame["q1_group"].fillna(False).astype(bool).any():
        return {}
    return {"q1_group_rows": int(frame["q1_group"].fillna(False).astype(bool).sum()),
            "mean_q1_objects": _mean_or_none(accepted["q1_objects"])}


def grasp_statistics(frame) -> dict[str, Any]:
    """``stats.json``: overall, per split and per ``split/combination`` summaries."""
    splits = {s: summarize(group) for s, group in frame.groupby("split", sort=False)}
    combos = {f"{s}/{c}": summarize(group) for (s, c), group in frame.groupby(["split", "combination"], sort=False)}
    order = {s: i for i, s in enumerate(SPLITS)}
    return {"overall": summarize(frame),
            "splits": dict(sorted(splits.items(), key=lambda kv: order.get(kv[0], len(order)))),
            "combinations": dict(sorted(combos.items(), key=lambda kv: (order.get(kv[0].split("/")[0], len(order)),
                                                                          kv[0])))}


def report_line(name: str, summary: dict[str, Any]) -> str:
    """One human line: ``Pl/cube+cylinder: 0/16 accepted (0.0 %) — rejected: fc 12, penetration 4``."""
    line = (f"{name}: {summary['accepted']}/{summary['candidates']} accepted ({100 * summary['accept_rate']:.1f} %) "
            f"in {summary['scenes']} scene(s)")
    if summary["accepted"]:
        q1, pn = summary["mean_q1"], summary["mean_pn_mm"]
        group = summary.get("q1_group_rows")
        line += f", mean Q1 {q1:.3f}" if q1 is not None else ""
        if group and q1 is not None:
            alone = summary.get("mean_q1_objects")
            line += (f" (group Q1 on {group} row(s) of fc_mode 'group'; the hand alone, min over objects: "
                     f"{alone:.3f})" if alone is not None else " (group Q1 on fc_mode 'group' rows)")
        line += f", mean PN {pn:.2f} mm" if pn is not None else ""
    if summary["reasons"]:
        line += " — rejected: " + ", ".join(f"{r} {n}" for r, n in
                                             sorted(summary["reasons"].items(), key=lambda kv: -kv[1]))
    return line


def report_markdown(stats: dict[str, Any]) -> str:
    lines = ["# synthesize: accepted grasps", "", report_line("all", stats["overall"]), "", "## Per split", ""]
    lines += [f"- {report_line(s, v)}" for s, v in stats["splits"].items()]
    lines += ["", "## Per combination", ""]
    lines += [f"- {report_line(c, v)}" for c, v in stats["combinations"].items()]
    zero = [c for c, v in stats["combinations"].items() if v["accepted"] == 0]
    if zero:
        lines += ["", f"{len(zero)} combination(s) with 0 accepted grasps: {', '.join(zero)}"]
    return "\n".join(lines) + "\n"


def stage_metrics(stats: dict[str, Any]) -> dict[str, float]:
    """Flat MLflow metrics: overall and per split (counts, accept rate, mean Q1 / PN, reasons)."""
    metrics: dict[str, float] = {}

    def add(prefix: str, summary: dict[str, Any]) -> None:
        for key in ("scenes", "candidates", "accepted", "accept_rate", "mean_q1", "mean_pn_mm"):
            if summary[key] is not None:
                metrics[f"{prefix}{key}"] = float(summary[key])
        for reason, count in summary["reasons"].items():
            metrics[f"{prefix}rejected_{reason}"] = float(count)

    add("", stats["overall"])
    for split, summary in stats["splits"].items():
        add(f"{split}.", summary)
    metrics["combinations_zero_accepted"] = float(sum(v["accepted"] == 0 for v in stats["combinations"].values()))
    return metrics


# --------------------------------------------------------------------------- merge: figures


def _term_values(table, name: str) -> np.ndarray:
    """Every value of a (possibly list) numeric column, one row's list flattened; (rows,) or (sum of lengths,)."""
    import pyarrow as pa

    column = table.column(name).combine_chunks()
    if pa.types.is_list(column.type) or pa.types.is_large_list(column.type):
        column = column.flatten()
    return np.asarray(column.to_numpy(zero_copy_only=False), dtype=float)


def plot_energy_terms(path: Path, table, bins: int) -> Path:
    """Histograms (log10 of the value) of the energy and every ``term_*`` column, accepted vs rejected."""
    import pyarrow.compute as pc
    from matplotlib.figure import Figure  # no pyplot: no global state, safe in worker threads

    names = [n for n in table.column_names if n == "energy" or n.startswith("term_")]
    cols = 4
    rows = max(1, math.ceil(len(names) / cols))
    fig = Figure(figsize=(4 * cols, 2.6 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    accepted = table.filter(table.column("accepted"))
    rejected = table.filter(pc.invert(table.column("accepted")))
    for ax, name in zip(axes.flat, names):
        for part, label, colour in ((rejected, "rejected", "tab:red"), (accepted, "accepted", "tab:green")):
            values = _term_values(part, name) if part.num_rows else np.zeros(0)
            values = values[np.isfinite(values)]
            if len(values):
                ax.hist(np.log10(np.maximum(values, HISTOGRAM_FLOOR)), bins=bins, alpha=0.6, label=label, color=colour)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("log10(value)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    if names:
        axes.flat[0].legend(fontsize=7, loc="upper right")  # "best" searches the bars: slow, and warns
    fig.suptitle(f"energy terms of {table.num_rows} candidates ({accepted.num_rows} accepted)")
    fig.tight_layout()
    return atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))


def render_grasp_rgb(library, hand, urdf: Path, row: dict[str, Any], cam: CameraConfig) -> np.ndarray:
    """One accepted grasp: table, the scene's objects and the hand at (p, R, q); RGB (H, W, 3) uint8."""
    import pybullet as pb

    from components.execution.cameras import add_hand, add_scene_objects, add_table, render_rgb
    from components.objects import Scene

    scene = Scene.from_arrays(row["object_names"], row["object_positions"], row["object_quats_xyzw"])
    positions = np.array([pl.position for pl in scene.objects])
    client = pb.connect(pb.DIRECT)
    try:
        add_table(client, cam)
        add_scene_objects(client, library, scene)
        add_hand(client, urdf, hand, np.asarray(row["p"]), np.asarray(row["R"]).reshape(3, 3), np.asarray(row["q"]))
        return render_rgb(client, positions.mean(0) + np.array([0.0, 0.0, cam.target_height_m]), cam)
    finally:
        pb.disconnect(client)


def render_grid(path: Path, tiles: list[np.ndarray]) -> Path:
    """Tiles side by side in a near-square grid (16 tiles: 4 x 4), written as PNG."""
    from PIL import Image

    cols = math.ceil(math.sqrt(len(tiles)))
    rows = math.ceil(len(tiles) / cols)
    h, w, _ = tiles[0].shape
    grid = np.full((rows * h, cols * w, 3), 255, dtype=np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, cols)
        grid[r * h:(r + 1) * h, c * w:(c + 1) * w] = tile
    return atomic_write_with(path, lambda tmp: Image.fromarray(grid).save(tmp, format="PNG"))


def render_combinations(folder: Path, accepted, stage: SynthesisStageConfig, objects: ObjectsConfig, hand_cfg,
                        cache: Path) -> dict[str, Path]:
    """Per (split, combination) with accepted grasps: a grid of the lowest-energy ones."""
    from components.hand import HandModel
    from components.objects import ObjectLibrary

    if accepted.num_rows == 0 or stage.renders_per_combination == 0:
        return {}
    library = ObjectLibrary(objects, cache_dir=cache)
    hand = HandModel(hand_cfg)
    urdf = hand.export_urdf(cache / "hand" / "shadow_hand.urdf")
    columns = ["split", "combination", "energy", "object_names", "object_positions", "object_quats_xyzw", "p", "R", "q"]
    frame = accepted.select(columns).to_pandas()
    files = {}
    for (split, combo), group in frame.groupby(["split", "combination"], sort=True):
        best = group.sort_values("energy").head(stage.renders_per_combination)
        tiles = [render_grasp_rgb(library, hand, urdf, row, stage.camera) for row in best.to_dict("records")]
        name = f"{split}_{combo}"
        files[f"render_{name}"] = render_grid(folder / "renders" / f"{name}.png", tiles)
    return files


# --------------------------------------------------------------------------- merge unit


def merge_grasps(folder: Path, shards: list[Manifest], stage: SynthesisStageConfig, objects: ObjectsConfig,
                 hand_cfg, cache: Path, render: bool) -> UnitOutput:
    """Concatenate the shards, split accepted / rejected rows, statistics, histograms, renders."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    tables = [pq.read_table(shard.path("grasps")) for shard in shards]
    tables = [t for t in tables if t.num_rows]
    if tables:
        table = pa.concat_tables(tables, promote_options="default")
    else:  # no scene selected: empty outputs with the summary columns, not a crash
        table = pa.table({"scene_id": pa.array([], pa.string()), "split": pa.array([], pa.string()),
                          "combination": pa.array([], pa.string()), "accepted": pa.array([], pa.bool_()),
                          "reason": pa.array([], pa.string()), "q1": pa.array([], pa.float64()),
                          "pn_mm": pa.array([], pa.float64())})
    accepted = table.filter(table.column("accepted"))
    rejected = table.filter(pc.invert(table.column("accepted")))
    files: dict[str, Path] = {"grasps": write_parquet(folder / "grasps.parquet", accepted),
                              "rejected": write_parquet(folder / "rejected.parquet", rejected)}
    columns = list(SUMMARY_COLUMNS) + [c for c in OPTIONAL_SUMMARY_COLUMNS if c in table.column_names]
    stats = grasp_statistics(table.select(columns).to_pandas())
    files["stats"] = atomic_write_json(folder / "stats.json", stats)
    report = report_markdown(stats)
    files["report"] = atomic_write_text(folder / "report.md", report)
    if table.num_rows:
        files["energy_terms"] = plot_energy_terms(folder / "energy_terms.png", table, stage.histogram_bins)
    if render:
        files.update(render_combinations(folder, accepted, stage, objects, hand_cfg, cache))
    report_lines = [report_line(s, v) for s, v in stats["splits"].items()]
    zero = [report_line(c, v) for c, v in stats["combinations"].items() if v["accepted"] == 0]
    metrics = stage_metrics(stats)
    return UnitOutput(files=files, metrics=metrics,
                      meta={"split_lines": report_lines, "zero_accepted_lines": zero})


@task(name="synthesize-merge", cache_policy=VerifiedUnitCache(), persist_result=True)
def synthesize_merge_task(spec: UnitSpec, shards: list[Manifest], stage: SynthesisStageConfig,
                          objects: ObjectsConfig, hand_cfg, render: bool) -> Manifest:
    """Prefect unit: merge shards, statistics, histograms and render grids."""
    return run_unit(spec, lambda folder: merge_grasps(folder, shards, stage, objects, hand_cfg,
                                                      cache_dir(Path(spec.workdir)), render))
