"""The ``train-generator`` stage: the diffusion pre-grasp generator trained on the synthesised grasps
(paper §"Multi-object Grasp Generation"), and the ``multigrasp generate`` command's work.

One unit, ``stage``: the palm-aligned dataset of the synthesis table's grasps of ``generator.splits``
(:class:`components.generation.GraspDataset`), :func:`components.generation.train_generator` with its
checkpoint ``generator.pt`` in the unit folder -- written every ``model.checkpoint_every`` steps, so a
killed training resumes from the last checkpoint (and a finished one is served from cache) --
``history.json`` and ``loss.png``.  A longer training (``model.train_steps`` raised, nothing else of the model
changed) starts from the longest finished one on the same data and code (:func:`longest_finished_training`,
:func:`training_data_digest`;
the manifest's ``meta.extended_from`` names it) instead of from step 0: same weights, less time.

``records_source='lowest_energy'`` (smoke profile only, like the specialists stage) trains on the
lowest-energy candidates of each scene when the tiny smoke synthesis accepts none: plumbing, not results.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from prefect import task
from pydantic import Field

from components.config_base import Section
from components.generation.config import GeneratedFilterConfig, GeneratorConfig, IKConfig, RefineConfig, SamplerConfig
from components.objects.config import ObjectsConfig
from tasks.artifacts import Manifest, atomic_write_json, digest, read_manifest, verify
from tasks.grasp_tables import RecordsSource, grasp_rows
from tasks.pointnet import plot_history
from tasks.preflight import cache_dir
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

GENERATOR_CODE_DIRS = ("components/generation", "components/hand", "assets/hand", "components/objects",
                       "assets/objects", "tasks/generator.py", "tasks/grasp_tables.py")


class GeneratorStageConfig(Section):
    """The generator: model and training, which grasps it learns from, IK and refinement of its samples."""

    model: GeneratorConfig = Field(default_factory=GeneratorConfig, description="Network, diffusion and training.")
    sampler: SamplerConfig = Field(
        default_factory=SamplerConfig, description="Reverse process at generation time (ddpm: the paper's 100 "
        "ancestral steps; ddim: strided, fewer denoiser calls).")
    ik: IKConfig = Field(default_factory=IKConfig, description="Keypoints -> (p, R, q).")
    refine: RefineConfig = Field(default_factory=RefineConfig, description="Refinement of generated grasps.")
    splits: list[str] = Field(default_factory=lambda: ["train"], description="Synthesis splits the generator learns from.")
    records_source: RecordsSource = Field(
        "accepted", description="accepted: the synthesis stage's accepted grasps. lowest_energy: per scene the "
        "lowest-energy candidates (smoke profile only: its synthesis accepts none; results mean nothing).")
    lowest_energy_per_scene: int = Field(2, ge=1, description="With records_source=lowest_energy: candidates per scene.")
    eval_scenes: int = Field(16, ge=1, description="evaluate pregrasp --source generated: scenes per split (Pl / Com / Geo).")
    eval_grasps_per_scene: int = Field(16, ge=1, description="...and grasps generated per scene.")
    eval_filter: GeneratedFilterConfig = Field(
        default_factory=GeneratedFilterConfig,
        description="evaluate pregrasp --source generated: which generated grasps are kept (the paper's protocol "
        "discards those with significant penetration or insufficient contact ratio); rows report both.")


def training_frame(synthesis: Manifest, stage: GeneratorStageConfig):
    """The synthesis rows the generator learns from (:func:`tasks.grasp_tables.grasp_rows`); with
    ``records_source='lowest_energy'`` they are marked accepted, since the dataset keeps accepted rows."""
    frame = grasp_rows(synthesis, stage.records_source, stage.lowest_energy_per_scene, stage.splits,
                       stage.model.max_objects)
    if stage.records_source == "lowest_energy" and len(frame):
        frame = frame.assign(accepted=True)
    return frame


def training_data_digest(stage: GeneratorStageConfig, objects: ObjectsConfig, hand_cfg) -> str:
    """Digest of the config that decides what the generator is trained on besides the synthesis output: which
    rows (``splits``, ``records_source``, ``lowest_energy_per_scene``), the hand (keypoints) and the objects
    (clouds).  Stored in the manifest's meta as ``data``."""
    return digest({"splits": list(stage.splits), "records_source": stage.records_source,
                   "lowest_energy_per_scene": stage.lowest_energy_per_scene,
                   "hand": hand_cfg.model_dump(mode="json"), "objects": objects.key_dump()})


def longest_finished_training(folder: Path, synthesis: Manifest, data: str, code: str, cfg: GeneratorConfig
                              ) -> tuple[Manifest, int] | None:
    """The finished ``train-generator`` unit beside ``folder`` (same stage directory) that a training of ``cfg``
    can continue from -- same synthesis output, same training data config (``data``, :func:`training_data_digest`),
    same code version, same generator config apart from ``train_steps`` / ``log_every`` / ``checkpoint_every``,
    at most ``cfg.train_steps`` steps -- with the most steps, and that step; None if there is none.  Since step
    s's minibatch, noise and timesteps depend only on (seed, s) and the learning rate is constant, continuing it
    gives the weights of a training from scratch."""
    from components.generation import extendable_step

    folder = Path(folder)
    best = None
    for other in sorted(folder.parent.iterdir()):
        manifest = read_manifest(other) if other != folder and other.is_dir() else None
        if manifest is None or manifest.code_version != code or manifest.upstream.get("synthesize") != synthesis.hash \
                or manifest.meta.get("data") != data or "generator" not in manifest.files or verify(manifest):
            continue
        step = extendable_step(manifest.path("generator"), cfg)
        if step is not None and (best is None or step > best[1]):
            best = (manifest, step)
    return best


def train_unit(folder: Path, synthesis: Manifest, stage: GeneratorStageConfig, objects: ObjectsConfig, hand_cfg,
               device: str, torch_threads: int, cache: Path, code: str) -> UnitOutput:
    import torch

    from components.generation import GraspDataset, train_generator
    from components.hand import HandModel
    from components.objects import ObjectLibrary

    if torch_threads:
        torch.set_num_threads(torch_threads)
    extended_from, data = "", training_data_digest(stage, objects, hand_cfg)
    if not (folder / "generator.pt").exists():  # no checkpoint of its own yet: continue a shorter finished training
        found = longest_finished_training(folder, synthesis, data, code, stage.model)
        if found is not None:
            shutil.copyfile(found[0].path("generator"), folder / "generator.pt")
            extended_from = found[0].key
            print(f"train-generator: continuing the finished {found[1]}-step training {found[0].folder} "
                  f"to {stage.model.train_steps} steps", file=sys.stderr, flush=True)
    hand = HandModel(hand_cfg)
    library = ObjectLibrary(objects, cache_dir=cache)
    dataset = GraspDataset.from_frame(training_frame(synthesis, stage), library, hand, stage.model)

    def progress(step: int, total: int, info: dict) -> None:
        print(f"train-generator step {step}/{total} loss {info['loss']:.4f} ETA {info['eta_s']:.0f}s",
              file=sys.stderr, flush=True)

    result = train_generator(dataset, stage.model, folder / "generator.pt", progress, device=device)
    history = atomic_write_json(folder / "history.json", result.history)
    plot = plot_history(folder / "loss.png", result.history, ylabel=f"denoising loss ({stage.model.prediction} MSE)")
    last = result.history[-1]["loss"] if result.history else float("nan")
    return UnitOutput(files={"generator": folder / "generator.pt", "history": history, "loss_plot": plot},
                      metrics={"grasps": len(dataset), "scenes": dataset.scenes, "loss_last": round(float(last), 6)},
                      meta={"resumed_from": result.resumed_from, "extended_from": extended_from, "data": data})


@task(name="train-generator", cache_policy=VerifiedUnitCache(), persist_result=True)
def train_task(spec: UnitSpec, synthesis: Manifest, stage: GeneratorStageConfig, objects: ObjectsConfig, hand_cfg,
               device: str, torch_threads: int) -> Manifest:
    """Prefect unit: the trained generator (checkpoint kept in the unit folder: a rerun after a crash resumes)."""
    return run_unit(spec, lambda folder: train_unit(folder, synthesis, stage, objects, hand_cfg, device, torch_threads,
                                                    cache_dir(Path(spec.workdir)), spec.code))
