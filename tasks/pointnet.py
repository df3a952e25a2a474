"""The ``pointnet`` stage: pre-train the frozen PointNet that encodes hand and object point clouds for the
lift policies (paper §"Learning a Multi-Object Lifting Policy": "a pre-trained PointNet").

One unit, ``stage``: build a training set of clouds in the palm frame -- the hand's cloud
(:class:`components.execution.clouds.CloudFeaturizer`, the same points the env encodes) at random joint
angles, and each library object's cloud at a random orientation and a random position in front of the
palm -- pre-train :func:`components.execution.pointnet.pretrain_pointnet` (denoising autoencoder, Chamfer
loss) and write ``encoder.pt``, ``history.json`` and ``loss.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from prefect import task
from pydantic import Field

from components.config_base import Section
from components.execution.lift_config import LiftEnvConfig
from components.execution.pointnet import PointNetConfig
from components.objects.config import ObjectsConfig
from tasks.artifacts import Manifest, atomic_write_json, atomic_write_with
from tasks.preflight import cache_dir
from tasks.units import UnitOutput, UnitSpec, VerifiedUnitCache, run_unit

POINTNET_CODE_DIRS = ("components/execution/pointnet.py", "components/execution/clouds.py", "components/hand",
                      "assets/hand", "components/objects", "assets/objects", "tasks/pointnet.py")


class PointNetStageConfig(Section):
    """The pointnet stage: the encoder / pretraining config and its training clouds."""

    encoder: PointNetConfig = Field(default_factory=PointNetConfig, description="Encoder widths and autoencoder pretraining.")
    hand_clouds: int = Field(256, ge=1, description="Hand clouds in the training set (random joint angles in the limits).")
    object_clouds_per_object: int = Field(64, ge=1, description="Clouds per library object (random pose in front of the palm).")
    object_offset_min_m: tuple[float, float, float] = Field(
        (-0.04, -0.09, 0.02),
        description="Object centres are uniform in the palm-frame box [min, max] (x across the palm, -y out of the "
        "palm, z along the fingers), where the pre-grasps hold them.")
    object_offset_max_m: tuple[float, float, float] = Field((0.04, -0.02, 0.11), description="...its upper corner.")
    seed: int = Field(0, ge=0, description="Seed of the training clouds.")


def training_clouds(hand, library, lift: LiftEnvConfig, stage: PointNetStageConfig):
    """(S, N, 3) float32 clouds in the palm frame (module docstring)."""
    import torch
    from scipy.spatial.transform import Rotation

    from components.execution.clouds import CloudFeaturizer

    rng = np.random.default_rng(stage.seed)
    featurizer = CloudFeaturizer(hand, library, lift, encoder=None)
    n = lift.hand_cloud_points
    q = hand.sample_joint_angles(stage.hand_clouds, torch.Generator().manual_seed(stage.seed))
    eye = torch.eye(3, dtype=hand.dtype).expand(stage.hand_clouds, 3, 3)
    frames = hand.link_poses(torch.zeros(stage.hand_clouds, 3, dtype=hand.dtype), eye, q).detach().cpu().numpy()
    clouds = [featurizer.clouds(f, np.zeros(3), np.eye(3), [], np.zeros((0, 3)), np.zeros((0, 3, 3)))[0] for f in frames]
    low, high = np.array(stage.object_offset_min_m), np.array(stage.object_offset_max_m)
    for name in dict.fromkeys(library.train + library.ood):  # the objects the pipeline uses
        local = featurizer.object_local(name)
        for _ in range(stage.object_clouds_per_object):
            rot = Rotation.random(random_state=rng).as_matrix()
            cloud = local @ rot.T + rng.uniform(low, high)
            clouds.append(cloud[np.arange(n) % len(cloud)])
    return torch.as_tensor(np.stack(clouds), dtype=torch.float32)


def plot_history(path: Path, history: list[dict], ylabel: str = "Chamfer loss (coordinates / input_scale_m)") -> Path:
    """Loss per step (log scale) as a PNG."""
    from matplotlib.figure import Figure  # no pyplot: no global state

    fig = Figure(figsize=(5, 3))
    ax = fig.add_subplot()
    ax.plot([h["step"] for h in history], [h["loss"] for h in history])
    ax.set_xlabel("step")
    ax.set_ylabel(ylabel)
    ax.set_yscale("log")
    fig.tight_layout()
    return atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))


def pretrain_unit(folder: Path, stage: PointNetStageConfig, lift: LiftEnvConfig, objects: ObjectsConfig, hand_cfg,
                  torch_threads: int, cache: Path) -> UnitOutput:
    import torch

    from components.execution.pointnet import pretrain_pointnet, save_encoder
    from components.hand import HandModel
    from components.objects import ObjectLibrary

    if torch_threads:
        torch.set_num_threads(torch_threads)
    hand = HandModel(hand_cfg)
    library = ObjectLibrary(objects, cache_dir=cache)
    data = training_clouds(hand, library, lift, stage)

    def progress(step: int, total: int, info: dict) -> None:
        print(f"pointnet step {step}/{total} loss {info['loss']:.2e} ETA {info['eta_s']:.0f}s", file=sys.stderr, flush=True)

    encoder, history = pretrain_pointnet(data, stage.encoder, progress)
    encoder_path = save_encoder(folder / "encoder.pt", encoder, stage.encoder)
    history_path = atomic_write_json(folder / "history.json", history)
    plot = plot_history(folder / "loss.png", history)
    first, last = history[0]["loss"], history[-1]["loss"]
    return UnitOutput(files={"encoder": encoder_path, "history": history_path, "loss_plot": plot},
                      metrics={"clouds": int(data.shape[0]), "loss_first": round(first, 9), "loss_last": round(last, 9)})


@task(name="pointnet-pretrain", cache_policy=VerifiedUnitCache(), persist_result=True)
def pretrain_task(spec: UnitSpec, stage: PointNetStageConfig, lift: LiftEnvConfig, objects: ObjectsConfig, hand_cfg,
                  torch_threads: int) -> Manifest:
    """Prefect unit: the pre-trained, frozen point-cloud encoder."""
    return run_unit(spec, lambda folder: pretrain_unit(folder, stage, lift, objects, hand_cfg, torch_threads,
                                                       cache_dir(Path(spec.workdir))))
