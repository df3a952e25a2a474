"""Benchmark: batched FK and hand–object distances (``multigrasp bench kinematics``).

Workload (issue "Foundation", item 10): 1024 random hand poses; two objects of the
library (cube, cylinder) side by side on the table, 512 surface points each (1024 in
all); FK of every link, then signed distances from all 1024 points to every collision
geom of the hand for every pose.  Each figure is the median of ``repeats`` timed runs
after one warm-up run.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import torch

from benchmarks.timing import median_ms

BATCH = 1024
POINTS_PER_OBJECT = 512
BENCH_OBJECTS = ("cube", "cylinder")
OBJECT_OFFSETS_M = ((-0.03, 0.0, 0.03), (0.03, 0.0, 0.03))
SEED = 0


def run_kinematics_benchmark(repeats: int = 7, threads: int = 0, device: str = "cpu") -> dict:
    """Time FK and hand–object distances; returns the JSON-able result."""
    from components.hand import HandConfig, HandModel
    from components.objects import ObjectLibrary, ObjectsConfig

    if threads:
        torch.set_num_threads(threads)
    dev = torch.device(device)
    sync = (lambda: torch.cuda.synchronize()) if dev.type == "cuda" else (lambda: None)
    hand = HandModel(HandConfig(), device=dev, dtype=torch.float32)
    gen = torch.Generator().manual_seed(SEED)
    q = hand.sample_joint_angles(BATCH, generator=gen).to(dev)
    p = (torch.rand(BATCH, 3, generator=gen) * 0.1 - 0.05).to(dev)
    rot = torch.linalg.qr(torch.randn(BATCH, 3, 3, generator=gen))[0]
    rot = (rot * torch.linalg.det(rot).sign()[:, None, None]).to(dev)
    with tempfile.TemporaryDirectory() as tmp:
        library = ObjectLibrary(ObjectsConfig(), cache_dir=Path(tmp))
        clouds = [library.get(name).sample_surface(POINTS_PER_OBJECT, seed=SEED) + np.asarray(offset)
                  for name, offset in zip(BENCH_OBJECTS, OBJECT_OFFSETS_M)]
    points = torch.as_tensor(np.concatenate(clouds), dtype=torch.float32, device=dev)
    points = points.unsqueeze(0).expand(BATCH, -1, -1)  # (B, 1024, 3)

    with torch.no_grad():
        fk_ms = median_ms(lambda: hand.forward_kinematics(q), repeats, sync)
        dist_ms = median_ms(lambda: hand.signed_distance(points, p, rot, q), repeats, sync)
    return {"fk_ms_1024": round(fk_ms, 3), "hand_object_distance_ms_1024": round(dist_ms, 3),
            "threads": torch.get_num_threads(), "device": str(dev), "repeats": repeats,
            "batch": BATCH, "points": int(points.shape[1]), "objects": list(BENCH_OBJECTS),
            "torch": torch.__version__}
