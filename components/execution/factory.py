"""A picklable recipe for lift environments (collector workers build their own env from it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from components.execution.lift_config import LiftEnvConfig
from components.execution.lift_env import LiftEnv
from components.execution.pointnet import load_encoder
from components.execution.records import load_records


@dataclass(frozen=True)
class LiftEnvFactory:
    """Everything a worker needs to build a :class:`LiftEnv`: configs as dicts, files as paths.

    ``records``: a records JSON (:mod:`components.execution.records`); ``encoder``: a saved PointNet
    (:func:`components.execution.pointnet.save_encoder`); ``urdf``: the hand URDF; ``objects_cache``:
    the object library's cache folder (SDF grids, decompositions); ``threads``: torch threads per env."""

    hand_cfg: dict
    objects_cfg: dict
    objects_cache: str
    urdf: str
    records: str
    lift_cfg: dict
    encoder: str
    seed: int = 0
    threads: int = 1
    record_order: str = "random"

    def __call__(self) -> LiftEnv:
        from components.hand import HandConfig, HandModel
        from components.objects import ObjectLibrary, ObjectsConfig

        torch.set_num_threads(self.threads)
        hand = HandModel(HandConfig(**self.hand_cfg))
        library = ObjectLibrary(ObjectsConfig(**self.objects_cfg), cache_dir=Path(self.objects_cache))
        encoder, _ = load_encoder(Path(self.encoder))
        return LiftEnv(hand, library, Path(self.urdf), load_records(Path(self.records)),
                       LiftEnvConfig(**self.lift_cfg), encoder, record_order=self.record_order, seed=self.seed)
