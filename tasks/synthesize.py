"""The ``synthesize`` stage: multi-object pre-grasps for every settled scene (paper §Preliminaries).

Units:
- ``shard-<scene id>`` — run :func:`components.synthesis.synthesize` on a few scenes of the ``scenes``
  stage (each scene seeded from ``run.seed`` and its id), measure Q1 and PN of the accepted
  candidates (NaN for rejected ones) and write every candidate row to ``grasps.parquet``.
- ``merge`` (:mod:`tasks.synthesize_merge`, its own module so that editing reports or renders never
  invalidates the shards' cache keys) — concatenate the shards into ``grasps.parquet`` (accepted rows) and
  ``rejected.parquet`` (rejected rows, with their reason), compute ``stats.json`` and
  ``report.md`` per split and per combination, plot the energy terms (``energy_terms.png``)
  and render a grid of accepted grasps per combination (``renders/<split>_<combination>.png``).

Parquet layout (one row per candidate): ``scene_id``, ``split``, ``combination``
(``"cube+cylinder"``), ``scene_index``, ``row`` (candidate index), ``seed``, ``object_names``,
``object_positions`` (n_obj x 3, flattened), ``object_quats_xyzw`` (n_obj x 4, flattened), then
every array of :meth:`SynthesisResult.to_numpy` under its own name (``p``, ``R``, ``q``,
``contact_regions``, ``energy``, ``term_*``, …; ``reasons`` becomes ``reason``), and ``q1``,
``pn_mm``, ``q1_objects`` (min over objects of the per-object Q1) and ``q1_group`` (true where ``q1`` is the
group Q1 of ``fc_mode='group'``; then ``q1_objects`` is what the hand alone holds).  Arrays with more than one axis per row are stored flattened in C order as list
columns: ``R`` is 3 x 3, per-object arrays are ``n_obj x …`` with ``n_obj = len(object_names)``.
"""

from __future__ import annotations

import json
import sys
import time
import zlib
from pathlib import Path
from typing import Any, Literal, Optional, Union

import numpy as np
from prefect import task
from pydantic import Field, NonNegativeInt, PositiveInt, ValidationError, model_validator

from components.config_base import Section
from components.execution.cameras import CameraConfig
from components.metrics import MetricsConfig
from components.objects.config import ObjectsConfig
from components.synthesis.config import SynthesisConfig
from tasks.artifacts import Manifest, atomic_write_with
from tasks.preflight import cache_dir
from tasks.scenes import SPLITS
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

SYNTHESIS_CODE_DIRS = ("components/synthesis", "components/metrics", "components/hand", "assets/hand",
                       "components/objects", "assets/objects", "tasks/synthesize.py")
SplitName = Literal["train", "Pl", "Com", "Geo", "many"]
ACCEPTED_REASON = "accepted"


def _render_camera() -> CameraConfig:
    return CameraConfig(width=192, height=144, distance_m=0.38, pitch_deg=-40.0, target_height_m=0.03)


class SynthesisStageConfig(Section):
    """The synthesize stage: the optimiser, the metrics, which scenes, sharding and renders."""

    optimizer: SynthesisConfig = Field(default_factory=SynthesisConfig,
                                       description="Multi-object DFC synthesis (energy, MALA, refinement, filter).")
    metrics: MetricsConfig = Field(default_factory=MetricsConfig,
                                   description="How Q1 and PN of the accepted grasps are measured.")
    optimizer_by_object_count: dict[PositiveInt, dict[str, Any]] = Field(
        default_factory=dict,
        description="Per number of objects in a scene, fields of ``optimizer`` to replace for such scenes, e.g. "
        "{3: {w_pen: 1000, approach_steps: 800}}: the setting tuned for pairs leaves three small cylinders "
        "interpenetrating (0/32 accepted, penetration median 12 mm) where a stronger w_pen / w_prior and longer "
        "approach accept some (README 'Synthesis settings: what was measured'). Empty = one setting for all scenes.")
    min_q1: Optional[float] = Field(
        None, ge=0.0,
        description="Also reject (reason 'q1') a grasp that passes the optimiser's filter but whose Q1 (``metrics``) "
        "is not above this; 0 keeps only grasps in force closure under the metric. None = off (the paper's filter "
        "only). Measured on the mini run's Pl grasps: half have Q1 = 0 under the default metric.")
    splits: list[SplitName] = Field(default_factory=lambda: list(SPLITS),
                                    description="Scene splits of the scenes stage to synthesise grasps for.")
    max_scenes_per_combination: Union[NonNegativeInt, dict[SplitName, NonNegativeInt]] = Field(
        0, description="At most this many scenes per (split, combination) from the scenes stage (0 = all): one "
        "number for every split, or a mapping split -> number, e.g. {train: 2, Pl: 1} (a split it does not name: "
        "all of its scenes).")

    @model_validator(mode="after")
    def _check_overrides(self) -> "SynthesisStageConfig":
        for count in self.optimizer_by_object_count:
            self.optimizer_for(count)
        return self

    def optimizer_for(self, n_objects: int) -> SynthesisConfig:
        """``optimizer`` with the ``optimizer_by_object_count`` fields of scenes of ``n_objects`` objects."""
        override = self.optimizer_by_object_count.get(n_objects)
        if not override:
            return self.optimizer
        try:
            return SynthesisConfig(**{**self.optimizer.model_dump(), **override})
        except ValidationError as exc:
            problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or '?'}: {e['msg']}" for e in exc.errors())
            raise ValueError(f"optimizer_by_object_count[{n_objects}] is not a valid synthesis.optimizer override "
                             f"({problems}); use fields of synthesis.optimizer (SynthesisConfig)") from None

    def scene_cap(self, split: str) -> int:
        """The ``max_scenes_per_combination`` of one split (0 = all)."""
        cap = self.max_scenes_per_combination
        return cap.get(split, 0) if isinstance(cap, dict) else cap
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
                 pn_mm: np.ndarray, q1_objects: np.ndarray | None = None,
                 q1_group: bool = False) -> dict[str, list | np.ndarray]:
    """Columns of one scene's candidates (module docstring); every result array becomes a column.  ``q1`` is the
    group Q1 when the scene's optimiser has ``fc_mode='group'`` (column ``q1_group`` true), the min over objects
    otherwise; ``q1_objects`` is always the min over objects of the per-object Q1 (the hand alone)."""
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
    columns["q1_objects"] = q1 if q1_objects is None else q1_objects
    columns["q1_group"] = np.full(batch, q1_group)
    return columns


def _table(columns: dict[str, list | np.ndarray]):
    import pyarrow as pa

    return pa.table({name: pa.array(value) for name, value in columns.items()})


def write_parquet(path: Path, table) -> Path:
    import pyarrow.parquet as pq

    return atomic_write_with(path, lambda tmp: pq.write_table(table, tmp))


def reject_weak(arrays: dict[str, np.ndarray], q1: np.ndarray, min_q1: float | None) -> dict[str, np.ndarray]:
    """With ``min_q1`` set, rows accepted by the optimiser's filter whose Q1 is not above it become rejected with
    reason ``"q1"`` (``SynthesisStageConfig.min_q1``); a NaN Q1 (not measured) is never above.  Returns ``arrays``."""
    if min_q1 is None:
        return arrays
    weak = arrays["accepted"] & ~(q1 > min_q1)
    arrays["accepted"] = arrays["accepted"] & ~weak
    arrays["reasons"] = np.where(weak, "q1", arrays["reasons"])
    return arrays


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
    tables, candidates, accepted_total = [], 0, 0
    seconds = {"synthesis": 0.0, "metrics": 0.0}
    start = time.perf_counter()
    for number, record in enumerate(records, 1):
        scene = Scene.from_dict(record["scene"])
        seed = scene_seed(base_seed, record["id"])
        t0 = time.perf_counter()
        optimizer = stage.optimizer_for(len(scene.objects))
        group = optimizer.fc_mode == "group"
        result = synthesize(hand, library, scene, optimizer, torch.Generator().manual_seed(seed))
        t1 = time.perf_counter()
        batch = int(result.accepted.shape[0])
        q1 = np.full(batch, np.nan)
        q1_objects = np.full(batch, np.nan)
        pn_mm = np.full(batch, np.nan)
        rows = result.accepted.nonzero().flatten()
        if len(rows):
            scene_objects = SceneObjects(library, scene, hand.device, hand.dtype)
            p, R, q = result.p[rows].detach(), result.R[rows].detach(), result.q[rows].detach()
            index = rows.cpu().numpy()
            measured, per_object = q1_grasps(hand, scene_objects, p, R, q, stage.metrics, q1_surface, group=group)
            q1[index], q1_objects[index] = measured.numpy(), per_object.amin(-1).numpy()
            pn_mm[index] = penetration_depth(hand, scene_objects, p, R, q, stage.metrics,
                                             pn_surface).pn_mm.detach().cpu().double().numpy()
        t2 = time.perf_counter()
        seconds["synthesis"] += t1 - t0
        seconds["metrics"] += t2 - t1
        arrays = reject_weak(result.to_numpy(), q1, stage.min_q1)
        n_accepted = int(arrays["accepted"].sum())
        tables.append(_table(_row_columns(record, arrays, seed, q1, pn_mm, q1_objects, group)))
        candidates += batch
        accepted_total += n_accepted
        elapsed = time.perf_counter() - start
        eta = elapsed / number * (len(records) - number)
        print(f"synthesize {label} scene {number}/{len(records)} {record['id']}: {n_accepted}/{batch} accepted "
              f"({t1 - t0:.1f}s synthesis, {t2 - t1:.1f}s metrics), shard ETA {eta:.0f}s", file=sys.stderr, flush=True)
    table = pa.concat_tables(tables, promote_options="default") if tables else _table({})
    path = write_parquet(folder / "grasps.parquet", table)
    return UnitOutput(files={"grasps": path},
                      metrics={"scenes": len(records), "candidates": candidates, "accepted": accepted_total},
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


def read_scene_records(scenes_manifest: Manifest) -> list[dict[str, Any]]:
    """The scene records (``id``, ``split``, ``objects``, ``index``, ``scene``) of the scenes stage."""
    return json.loads(scenes_manifest.path("scenes").read_text())["scenes"]
