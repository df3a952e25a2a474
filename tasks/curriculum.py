"""The ``curriculum`` stage: every specialist adapted to imprecise pre-grasps in three phases (paper §"Learning from
Imprecise Poses"; the phases and pools: :mod:`components.learning.curriculum`).

Units:

- ``bin-<label>``, one per specialist: its pools of starts and the three phases of PPO.
  1. ``synthetic``: the bin's training pre-grasps (the specialist's ``records.json``); ``reached``: those of them the
     reach stage reached (its end-of-reach states, matched by scene id and table row); ``generated``: new settled
     placements of the bin's objects (``generated_scenes``, seeded by the bin), ``generated_per_scene`` pre-grasps
     each from the trained generator (sampling, IK, refinement as ``generator.*``) that fall in the bin's placement
     sector (all of the combination's when none does; with ``filter_generated`` only those the paper's protocol
     filter keeps, ``generator.eval_filter``), each reached from an open hand in PyBullet (``reach.reaching``) ->
     ``generated.json``.
  2. PPO continues from the specialist's checkpoint (``policy.pt``, copied) with ``specialists.ppo``, for
     ``phase_iterations[k]`` iterations per phase over that phase's starts (``phase<k>.json``).  Each phase selects
     its best validated actor afresh on its own starts (``specialists.validation_*``), so the adapted specialist is
     the best on phase 3's mostly generated, displaced starts.
  A killed unit resumes: ``generated.json`` is kept, and the checkpoint's iteration says which phase to continue.
- ``merge``: ``index.json`` in the specialists stage's layout (bin -> policy, records), so what reads specialists
  reads the adapted ones.
"""

from __future__ import annotations

import json
import shutil
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task

from components.execution.lift_config import LiftEnvConfig
from components.learning.curriculum import PHASES, CurriculumConfig, phase_starts
from components.objects.config import ObjectsConfig
from tasks.artifacts import Manifest, atomic_write_json
from tasks.preflight import cache_dir
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

CURRICULUM_CODE_DIRS = ("components/learning", "components/execution", "components/generation", "components/synthesis",
                        "components/metrics", "components/hand", "assets/hand", "components/objects",
                        "assets/objects", "tasks/curriculum.py", "tasks/reach.py", "tasks/specialists.py")


def generated_starts(label: str, synthetic: list, stage: CurriculumConfig, generator_stage, synthesis_stage,
                     sampling, reaching, clustering, lift: LiftEnvConfig, hand, library, generator_path: Path,
                     urdf: Path, progress=print) -> list:
    """The bin's generated, kept, reached pre-grasps (module docstring, pool ``generated``) as GraspRecords."""
    import torch

    from components.execution.clustering import bin_label
    from components.execution.lift_sim import GraspRecord
    from components.generation import (contact_ratio, generate_grasps, keep_generated, load_generator, posed_clouds,
                                       refine_grasps)
    from components.metrics import penetration_depth
    from components.objects import sample_settled_scenes
    from components.synthesis import SceneObjects
    from tasks.reach import reach_records

    names = list(synthetic[0].scene.names)
    rng = np.random.default_rng([stage.seed, zlib.crc32(label.encode())])
    model = load_generator(generator_path)
    synthesis = synthesis_stage.optimizer_for(len(names))
    kept: list = []
    for number, (scene, _) in enumerate(sample_settled_scenes(library, names, stage.generated_scenes, rng, sampling)):
        positions = np.array([pl.position for pl in scene.objects])
        quats = np.array([pl.quat_xyzw for pl in scene.objects])
        clouds, mask = posed_clouds(library, scene.names, positions, quats, generator_stage.model.points_per_object,
                                    generator_stage.model.max_objects)
        n = stage.generated_per_scene
        gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
        objects = SceneObjects(library, scene, hand.device, hand.dtype)
        with torch.no_grad():
            p, R, q = generate_grasps(model, hand, torch.as_tensor(clouds, dtype=torch.float32)[None].expand(n, -1, -1, -1),
                                      torch.rand(n, generator=gen) * 2.0 * np.pi, generator_stage.ik,
                                      torch.as_tensor(mask)[None].expand(n, -1), generator=gen,
                                      sampler=generator_stage.sampler, distance=lambda x: objects.sdf(x).amin(-1),
                                      table_height=objects.table_height)
        refined = refine_grasps(hand, objects, p.detach(), R.detach(), q.detach(), generator_stage.refine,
                                synthesis=synthesis)
        pn = torch.as_tensor(penetration_depth(hand, objects, refined.p, refined.R, refined.q,
                                               synthesis_stage.metrics).pn_mm, dtype=torch.float64)
        ratio = contact_ratio(hand, objects, refined.p, refined.R, refined.q, synthesis,
                              generator_stage.eval_filter.contact_distance_m)
        keep = keep_generated(pn.to(ratio.dtype), ratio, generator_stage.eval_filter) if stage.filter_generated \
            else torch.ones_like(ratio, dtype=torch.bool)
        for i in np.flatnonzero(keep.numpy()):
            kept.append(GraspRecord(scene=scene, p=refined.p[i].detach().numpy().astype(float),
                                    R=refined.R[i].detach().numpy().astype(float),
                                    q=refined.q[i].detach().numpy().astype(float),
                                    meta={"source": "generated", "scene_id": f"{label}#generated{number}", "row": int(i),
                                          "combination": "+".join(names)}))
        progress(f"{int(keep.sum())}/{n} generated pre-grasps kept on placement {number + 1}/{stage.generated_scenes}"
                 f"{' (the protocol filter)' if stage.filter_generated else ' (unfiltered: curriculum.filter_generated)'}"
                 f", PN median {float(pn.median()):.1f} mm")
    in_bin = [r for r in kept if bin_label(r, clustering) == label]
    chosen = in_bin or kept
    if not chosen:
        return []
    progress(f"reaching {len(chosen)} generated pre-grasp(s) ({len(in_bin)} in the bin's sector)")
    return reach_records(chosen, reaching, lift, hand, library, urdf)


def adapt_bin(folder: Path, label: str, entry: dict[str, Any], reached: list[dict[str, Any]], stage: CurriculumConfig,
              specialists_stage, generator_stage, synthesis_stage, sampling, reaching, lift: LiftEnvConfig,
              objects: ObjectsConfig, hand_cfg, generator_path: Path, encoder: Path, cache: Path,
              unit: str) -> UnitOutput:
    """One specialist through the curriculum (module docstring)."""
    import io

    import torch

    from components.execution.factory import LiftEnvFactory
    from components.execution.ppo import load_checkpoint, train_ppo
    from components.execution.records import load_records, record_from_dict, save_records
    from components.fileio import atomic_write_bytes
    from components.hand import HandModel
    from components.objects import ObjectLibrary
    from tasks.specialists import BinValidation, plot_learning_curve

    def say(line: str) -> None:
        print(f"curriculum {unit} ({label}): {line}", file=sys.stderr, flush=True)

    hand = HandModel(hand_cfg)
    urdf = hand.export_urdf(folder / "hand.urdf")
    library = ObjectLibrary(objects, cache_dir=cache)
    synthetic = load_records(Path(entry["records"]))
    records_path = save_records(folder / "records.json", synthetic)
    wanted = {(r.meta.get("scene_id"), r.meta.get("row")) for r in synthetic}
    reached_records = [record_from_dict(r) for r in reached
                       if (r["meta"].get("scene_id"), r["meta"].get("row")) in wanted]
    generated_path = folder / "generated.json"
    if generated_path.is_file():  # a resumed unit keeps the pre-grasps it generated and reached
        generated = load_records(generated_path)
    else:
        generated = generated_starts(label, synthetic, stage, generator_stage, synthesis_stage, sampling, reaching,
                                     specialists_stage.clustering, lift, hand, library, generator_path, urdf, say)
        save_records(generated_path, generated)
    say(f"{len(synthetic)} synthetic, {len(reached_records)} reached, {len(generated)} generated and reached start(s)")
    checkpoint = folder / "policy.pt"
    if not checkpoint.exists():
        shutil.copyfile(entry["policy"], checkpoint)
    phases_path = folder / "phases.json"
    if phases_path.is_file():
        base = int(json.loads(phases_path.read_text())["specialist_iterations"])
    else:
        base = int(load_checkpoint(checkpoint)["iteration"])
        atomic_write_json(phases_path, {"specialist_iterations": base, "phase_iterations": stage.phase_iterations})
    ends = [base + sum(stage.phase_iterations[:k + 1]) for k in range(PHASES)]
    files: dict[str, Path] = {}
    result = None
    for phase in range(1, PHASES + 1):
        starts = phase_starts(phase, synthetic, reached_records, generated, stage)
        files[f"phase{phase}"] = save_records(folder / f"phase{phase}.json", starts)
        state = load_checkpoint(checkpoint)
        begin = ends[phase - 2] if phase > 1 else base
        if int(state["iteration"]) == begin and state.get("validations"):  # a fresh phase selects on its own starts
            state["validations"], state["best"] = [], None
            buffer = io.BytesIO()
            torch.save(state, buffer)
            atomic_write_bytes(checkpoint, buffer.getvalue())
        factory = LiftEnvFactory(hand_cfg=hand_cfg.model_dump(mode="json"), objects_cfg=objects.model_dump(mode="json"),
                                 objects_cache=str(cache), urdf=str(urdf), records=str(files[f"phase{phase}"]),
                                 lift_cfg=lift.model_dump(mode="json"), encoder=str(encoder),
                                 seed=specialists_stage.ppo.seed + phase)

        def progress(iteration: int, total: int, info: dict, phase: int = phase) -> None:
            if "reward" not in info:
                say(f"phase {phase} validation before training: success {info['validation']['success']:.2f}")
                return
            checked = f" validation {info['val_success']:.2f}" if "val_success" in info else ""
            say(f"phase {phase} iteration {iteration}/{total} reward {info['reward']:.3f}{checked} ETA {info['eta_s']:.0f}s")

        validation = BinValidation(factory, len(starts), specialists_stage)
        try:
            result = train_ppo(factory, specialists_stage.ppo.model_copy(update={"iterations": ends[phase - 1]}),
                               checkpoint, progress, validate=validation)
        finally:
            validation.close()
    history = atomic_write_json(folder / "history.json", result.history)
    validations = atomic_write_json(folder / "validations.json", {"best": result.best, "rows": result.validations})
    curve = plot_learning_curve(folder / "learning_curve.png", result.history,
                                f"{label}: specialist, then phases 1-3 from iteration {base}", result.validations)
    metrics = {"records": len(synthetic), "reached_starts": len(reached_records), "generated_starts": len(generated),
               "iterations": len(result.history), "specialist_iterations": base}
    if result.best is not None:
        metrics.update(best_iteration=int(result.best["iteration"]),
                       best_validation_success=round(float(result.best["success"]), 6))
    return UnitOutput(files={"policy": checkpoint, "records": records_path, "generated": generated_path,
                             "phases": phases_path, "history": history, "validations": validations,
                             "learning_curve": curve, "urdf": urdf, **files},
                      metrics=metrics, meta={"bin": label})


@task(name="curriculum-bin", cache_policy=VerifiedUnitCache(), persist_result=True)
def adapt_bin_task(spec: UnitSpec, label: str, entry: dict[str, Any], reached: list[dict[str, Any]],
                   stage: CurriculumConfig, specialists_stage, generator_stage, synthesis_stage, sampling, reaching,
                   lift: LiftEnvConfig, objects: ObjectsConfig, hand_cfg, generator_path: str,
                   encoder_path: str) -> Manifest:
    """Prefect unit: one adapted specialist (its PPO checkpoint kept in the unit folder: a rerun resumes)."""
    return run_unit(spec, lambda folder: adapt_bin(folder, label, entry, reached, stage, specialists_stage,
                                                   generator_stage, synthesis_stage, sampling, reaching, lift, objects,
                                                   hand_cfg, Path(generator_path), Path(encoder_path),
                                                   cache_dir(Path(spec.workdir)), spec.unit))
