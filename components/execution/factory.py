"""A picklable recipe for lift environments (collector workers build their own env from it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch

from components.execution.lift_config import LiftEnvConfig
from components.execution.lift_env import LiftEnv
from components.execution.pointnet import load_encoder
from components.execution.start_sampling import FileLock
from components.execution.records import load_records


@dataclass(frozen=True)
class LiftEnvFactory:
    """Everything a worker needs to build a :class:`LiftEnv`: configs as dicts, files as paths.

    ``records``: a records JSON (:mod:`components.execution.records`); ``encoder``: a saved PointNet
    (:func:`components.execution.pointnet.save_encoder`); ``urdf``: the hand URDF; ``objects_cache``:
    the object library's cache folder (SDF grids, decompositions); ``threads``: torch threads per env;
    ``start_counts``: a file of N records x 2 int64 (episodes, successes; :func:`open_start_counts`) that the envs
    of every worker map into memory, count their training episodes into and draw from (``lift.start_sampling``
    'learnability').  A file rather than a shared tensor: torchrl pickles the factory to its workers by value
    (cloudpickle), which copies a tensor, while a path maps the same pages in every process."""

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
    start_counts: Optional[str] = None

    def __call__(self) -> LiftEnv:
        from components.hand import HandConfig, HandModel
        from components.objects import ObjectLibrary, ObjectsConfig

        torch.set_num_threads(self.threads)
        hand = HandModel(HandConfig(**self.hand_cfg))
        library = ObjectLibrary(ObjectsConfig(**self.objects_cfg), cache_dir=Path(self.objects_cache))
        encoder, _ = load_encoder(Path(self.encoder))
        shared = self.start_counts is not None
        return LiftEnv(hand, library, Path(self.urdf), load_records(Path(self.records)),
                       LiftEnvConfig(**self.lift_cfg), encoder, record_order=self.record_order, seed=self.seed,
                       start_counts=open_start_counts(Path(self.start_counts)) if shared else None,
                       start_counts_lock=FileLock(self.start_counts) if shared else None)


def open_start_counts(path: Path, n_records: Optional[int] = None) -> np.ndarray:
    """The (N, 2) int64 memory map of a start-counts file (``LiftEnvFactory.start_counts``).  With ``n_records`` the
    file is created with zeros when it is missing or does not hold N x 2 counts (a resumed training keeps its counts);
    without it the file must exist."""
    if n_records is not None and (not path.is_file() or path.stat().st_size != n_records * 2 * 8):
        np.zeros((n_records, 2), dtype=np.int64).tofile(path)
    size = path.stat().st_size // 16
    return np.memmap(path, dtype=np.int64, mode="r+", shape=(size, 2))
