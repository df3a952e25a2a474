"""The ``synthesize`` stage: multi-object pre-grasps for every settled scene (paper §Preliminaries).

Units:
- ``shard-NNN`` — run :func:`components.synthesis.synthesize` on a few scenes of the ``scenes``
  stage (each scene seeded from ``run.seed`` and its id), measure Q1 and PN of the accepted
  candidates (NaN for rejected ones) and write every candidate row to ``grasps.parquet``.
- ``merge`` — concatenate the shards into ``grasps.parquet`` (accepted rows) and
  ``rejected.parquet`` (rejected rows, with their reason), compute ``stats.json`` and
  ``report.md`` per split and per combination, plot the energy terms (``energy_terms.png``)
  and render a grid of accepted grasps per combination (``renders/<split>_<combination>.png``).

Parquet layout (one row per candidate): ``scene_id``, ``split``, ``combination``
(``"cube+cylinder"``), ``scene_index``, ``row`` (candidate index), ``seed``, ``object_names``,
``object_positions`` (n_obj x 3, flattened), ``object_quats_xyzw`` (n_obj x 4, flattened), then
every array of :meth:`SynthesisResult.to_numpy` under its own name (``p``, ``R``, ``q``,
``contact_regions``, ``energy``, ``term_*``, …; ``reasons`` becomes ``reason``), and ``q1``,
``pn_mm``.  Arrays with more than one axis per row are stored flattened in C order as list
columns: ``R`` is 3 x 3, per-object arrays are ``n_obj x …`` with ``n_obj = len(object_names)``.
"""

from __future__ import annotations

import json
import math
import sys
import time
import zlib
from pathlib import Path
from typing import Any, Literal

import numpy as np
from prefect import task
from pydantic import Field

from components.config_base import Section
from components.execution.cameras import CameraConfig
from components.metrics import MetricsConfig
from components.objects.config import ObjectsConfig
from components.synthesis.config import SynthesisConfig
from tasks.artifacts import Manifest, atomic_write_json, atomic_write_text, atomic_write_with
from tasks.preflight import cache_dir
from tasks.scenes import RENDER_CODE_DIRS, SPLITS
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

SYNTHESIS_CODE_DIRS = ("components/synthesis", "components/metrics", "components/hand", "assets/hand",
                       "components/objects", "assets/objects", "tasks/synthesize.py")
MERGE_CODE_DIRS = ("tasks/synthesize.py", *RENDER_CODE_DIRS)
SplitName = Literal["train", "Pl", "Com", "Geo", "many"]
ACCEPTED_REASON = "accepted"
#: Smallest value shown on the log-scale energy histograms (terms are >= 0; exact zeros land here).
HISTOGRAM_FLOOR = 1e-8


def _render_camera() -> CameraConfig:
    return CameraConfig(width=192, height=144, distance_m=0.38, pitch_deg=-40.0, target_height_m=0.03)


class SynthesisStageConfig(Section):
    """The synthesize stage: the optimiser, the metrics, which scenes, sharding and renders."""

    optimizer: SynthesisConfig = Field(default_factory=SynthesisConfig,
                                       description="Multi-object DFC synthesis (energy, MALA, refinement, filter).")
    metrics: MetricsConfig = Field(default_factory=MetricsConfig,
                                   description="How Q1 and PN of the accepted grasps are measured.")
    splits: list[SplitName] = Field(default_factory=lambda: list(SPLITS),
                                    description="Scene splits of the scenes stage to synthesise grasps for.")
    max_scenes_per_combination: int = Field(
        0, ge=0, description="At most this many scenes per (split, combination) from the scenes stage (0 = all).")
    scenes_per_shard: int = Field(4, ge=1, le=10_000, description="Scenes synthesised by one cached shard.")
    renders_per_combination: int = Field(
        16, ge=0, le=64,
        description="Accepted grasps (lowest energy first) rendered per combination into one grid PNG (16 = 4x4); 0 = none.")
    camera: CameraConfig = Field(default_factory=_render_camera, description="Camera of the grasp renders (one tile).")
    histogram_bins: int = Field(40, ge=5, le=500, description="Bins of the energy-term histograms.")


def scene_seed(base_seed: int, scene_id: str) -> int:
    """A deterministic, order-independent torch seed for one scene (``run.seed`` and the scene id)."""
    return (int(base_seed) << 32) + zlib.crc32(scene_id.encode())


def combination_name(objects: list[str] | tuple[str, ...]) -> str:
    return "+".join(objects)


# --------------------------------------------------------------------------- shard


def _row_columns(record: dict[str, Any], arrays: dict[str, np.ndarray], seed: int, q1: np.ndarray,
                 pn_mm: np.ndarray) -> dict[str, list | np.ndarray]:
    """Columns of one scene's candidates (module docstring); every result array becomes a column."""
    batch = len(arrays["accepted"])
    placements = record["scene"]["objects"]
    names = [pl["name"] for pl in placements]
    positions = [float(v) for pl in placements for v in pl["position"]]
    quats = [float(v) for pl in placements for v in pl["quat_xyzw"]]
    columns: dict[str, list | np.ndarray] = {
        "scene_id": [record["id"]] * batch, "split": [record["split"]] * batch,
        "combination": [combination_name(record["objects"])] * batch,
        "scene_index": np.full(batch, record["index"], dtype=np.int64), "row": np.arange(batch, dtype=np.int64),
        "seed": np.full(batch, seed, dtype=np.int64), "object_names": [names] * batch,
        "object_positions": [positions] * batch, "object_quats_xyzw": [quats] * batch,
    }
    for key, value in arrays.items():
        name = "reason" if key == "reasons" else key
        value = np.asarray(value)
        if value.dtype.kind in "US":
            columns[name] = [str(v) for v in value]
        elif value.ndim == 1:
            columns[name] = value
        else:
            columns[name] = list(value.reshape(batch, -1))  # (B, prod(rest)) flattened per row
    columns["q1"], columns["pn_mm"] = q1, pn_mm
    return columns


def _table(columns: dict[str, list | np.ndarray]):
    import pyarrow as pa

    return pa.table({name: pa.array(value) for name, value in columns.items()})


def _write_parquet(path: Path, table) -> Path:
    import pyarrow.parquet as pq

    return atomic_write_with(path, lambda tmp: pq.write_table(table, tmp))


def _q1_or_nan(q1_fn, p, R, q) -> tuple[np.ndarray, int]:
    """Q1 of the rows; if the batch fails numerically, row by row with NaN (and a count) for the failing ones.

    Known case: a hand sample where an object's SDF gradient vanishes (deep inside a mesh grid) gets a zero
    normal, and the friction-cone tangents become NaN (SVD does not converge).  One such grasp must not
    discard the shard's other grasps.
    """
    try:
        return q1_fn(p, R, q), 0
    except (ValueError, ArithmeticError, RuntimeError):
        pass
    values = np.full(p.shape[0], np.nan)
    for i in range(p.shape[0]):
        try:
            values[i] = float(q1_fn(p[i:i + 1], R[i:i + 1], q[i:i + 1])[0])
        except (ValueError, ArithmeticError, RuntimeError) as exc:
            print(f"synthesize: Q1 of one grasp failed ({type(exc).__name__}: {exc}); stored as NaN",
                  file=sys.stderr, flush=True)
    return values, int(np.isnan(values).sum())


def synthesize_shard(folder: Path, records: list[dict[str, Any]], stage: SynthesisStageConfig,
                     objects: ObjectsConfig, hand_cfg, base_seed: int, device: str, torch_threads: int,
                     cache: Path, label: str) -> UnitOutput:
    """Synthesise and measure the grasps of a few scenes into ``folder/grasps.parquet``."""
    import pyarrow as pa
    import torch

    from components.hand import HandModel
    from components.metrics import penetration_depth, q1_grasps
    from components.objects import ObjectLibrary, Scene
    from components.synthesis import SceneObjects, synthesize
    from components.synthesis.hand_surface import HandSurface

    if torch_threads:
        torch.set_num_threads(torch_threads)
    library = ObjectLibrary(objects, cache_dir=cache)
    hand = HandModel(hand_cfg, device=device)
    q1_surface = HandSurface(hand, stage.metrics.q1_hand_point_spacing_m)
    pn_surface = HandSurface(hand, stage.metrics.pn_hand_point_spacing_m)
    tables, candidates, accepted_total, q1_failures = [], 0, 0, 0
    seconds = {"synthesis": 0.0, "metrics": 0.0}
    start = time.perf_counter()
    for number, record in enumerate(records, 1):
        scene = Scene.from_dict(record["scene"])
        seed = scene_seed(base_seed, record["id"])
        t0 = time.perf_counter()
        result = synthesize(hand, library, scene, stage.optimizer, torch.Generator().manual_seed(seed))
        t1 = time.perf_counter()
        batch = int(result.accepted.shape[0])
        q1 = np.full(batch, np.nan)
        pn_mm = np.full(batch, np.nan)
        rows = result.accepted.nonzero().flatten()
        if len(rows):
            scene_objects = SceneObjects(library, scene, hand.device, hand.dtype)
            p, R, q = result.p[rows].detach(), result.R[rows].detach(), result.q[rows].detach()
            index = rows.cpu().numpy()
            q1[index], failed = _q1_or_nan(lambda a, b, c: q1_grasps(hand, scene_objects, a, b, c, stage.metrics,
                                                                      q1_surface)[0].numpy(), p, R, q)
            q1_failures += failed
            pn_mm[index] = penetration_depth(hand, scene_objects, p, R, q, stage.metrics,
                                             pn_surface).pn_mm.detach().cpu().double().numpy()
        t2 = time.perf_counter()
        seconds["synthesis"] += t1 - t0
        seconds["metrics"] += t2 - t1
        tables.append(_table(_row_columns(record, result.to_numpy(), seed, q1, pn_mm)))
        candidates += batch
        accepted_total += len(rows)
        elapsed = time.perf_counter() - start
        eta = elapsed / number * (len(records) - number)
        print(f"synthesize {label} scene {number}/{len(records)} {record['id']}: {len(rows)}/{batch} accepted "
              f"({t1 - t0:.1f}s synthesis, {t2 - t1:.1f}s metrics), shard ETA {eta:.0f}s", file=sys.stderr, flush=True)
    table = pa.concat_tables(tables, promote_options="default") if tables else _table({})
    path = _write_parquet(folder / "grasps.parquet", table)
    return UnitOutput(files={"grasps": path},
                      metrics={"scenes": len(records), "candidates": candidates, "accepted": accepted_total,
                               "q1_failures": q1_failures},
                      # timings in meta, not metrics: metrics enter the manifest hash, which must not vary run to run
                      meta={"scene_ids": [r["id"] for r in records], "synthesis_s": seconds["synthesis"],
                            "metrics_s": seconds["metrics"]})


@task(name="synthesize-shard", cache_policy=VerifiedUnitCache(), persist_result=True)
def synthesize_shard_task(spec: UnitSpec, records: list[dict[str, Any]], stage: SynthesisStageConfig,
                          objects: ObjectsConfig, hand_cfg, base_seed: int, device: str,
                          torch_threads: int) -> Manifest:
    """Prefect unit: synthesised + measured grasps of a few scenes."""
    return run_unit(spec, lambda folder: synthesize_shard(folder, records, stage, objects, hand_cfg, base_seed,
                                                          device, torch_threads, cache_dir(Path(spec.workdir)),
                                                          spec.unit))


# --------------------------------------------------------------------------- merge: statistics


SUMMARY_COLUMNS = ("scene_id", "split", "combination", "accepted", "reason", "q1", "pn_mm")


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
            "mean_q1": _mean_or_none(accepted["q1"]), "mean_pn_mm": _mean_or_none(accepted["pn_mm"])}


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
        line += f", mean Q1 {q1:.3f}" if q1 is not None else ""
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
        axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"energy terms of {table.num_rows} candidates ({accepted.num_rows} accepted)")
    fig.tight_layout()
    return atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))


def render_grasp_rgb(library, hand, urdf: Path, row: dict[str, Any], cam: CameraConfig) -> np.ndarray:
    """One accepted grasp: table, the scene's objects and the hand at (p, R, q); RGB (H, W, 3) uint8."""
    import pybullet as pb

    from components.execution.cameras import add_hand, add_scene_objects, add_table, render_rgb
    from components.objects import Placement, Scene

    names = row["object_names"]
    positions = np.asarray(row["object_positions"]).reshape(len(names), 3)
    quats = np.asarray(row["object_quats_xyzw"]).reshape(len(names), 4)
    scene = Scene(tuple(Placement(n, tuple(map(float, x)), tuple(map(float, o))) for n, x, o in zip(names, positions, quats)))
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
    files: dict[str, Path] = {"grasps": _write_parquet(folder / "grasps.parquet", accepted),
                              "rejected": _write_parquet(folder / "rejected.parquet", rejected)}
    stats = grasp_statistics(table.select(list(SUMMARY_COLUMNS)).to_pandas())
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
    metrics["q1_failures"] = float(sum(shard.metrics.get("q1_failures", 0.0) for shard in shards))
    return UnitOutput(files=files, metrics=metrics,
                      meta={"split_lines": report_lines, "zero_accepted_lines": zero})


@task(name="synthesize-merge", cache_policy=VerifiedUnitCache(), persist_result=True)
def synthesize_merge_task(spec: UnitSpec, shards: list[Manifest], stage: SynthesisStageConfig,
                          objects: ObjectsConfig, hand_cfg, render: bool) -> Manifest:
    """Prefect unit: merge shards, statistics, histograms and render grids."""
    return run_unit(spec, lambda folder: merge_grasps(folder, shards, stage, objects, hand_cfg,
                                                      cache_dir(Path(spec.workdir)), render))


def read_scene_records(scenes_manifest: Manifest) -> list[dict[str, Any]]:
    """The scene records (``id``, ``split``, ``objects``, ``index``, ``scene``) of the scenes stage."""
    return json.loads(scenes_manifest.path("scenes").read_text())["scenes"]
