"""Self-collision with and without the capsule-prism screen (sixty-eighth session), forward and backward, on the 256
generated grasps of `bench generation` (untrained generator, bench sampler and IK), 2 threads, one process alternating
the two: 5 rounds of the median of 15 calls each.  Prints one JSON line.
Usage: python benchmarks/results/sixtyeighth/screen/self_collision.py
"""
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))
from components.generation import GeneratorConfig, posed_clouds  # noqa: E402
from components.generation.denoiser import ObjectInputs  # noqa: E402
from components.generation.representation import from_representation  # noqa: E402
from components.generation.training import build_generator  # noqa: E402
from components.hand import HandConfig, HandModel  # noqa: E402
from components.objects import ObjectLibrary, ObjectsConfig, ScenesConfig, sample_scene  # noqa: E402
from flows.config import load_config  # noqa: E402


def median_ms(fn, n: int = 15) -> float:
    times = []
    for _ in range(n):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def main() -> None:
    torch.set_num_threads(2)
    stage = load_config("bench", None, []).generator
    cfg = GeneratorConfig()
    hand = HandModel(HandConfig(), device="cpu")
    model = build_generator(cfg).eval()
    with tempfile.TemporaryDirectory() as tmp:
        library = ObjectLibrary(ObjectsConfig(), cache_dir=Path(tmp))
        scene = sample_scene(library, ["cube", "cylinder"], np.random.default_rng(0), ScenesConfig())
        positions = np.array([pl.position for pl in scene.objects])
        quats = np.array([pl.quat_xyzw for pl in scene.objects])
        clouds, mask = posed_clouds(library, scene.names, positions, quats, cfg.points_per_object, cfg.max_objects)
    inputs = ObjectInputs(torch.as_tensor(clouds, dtype=torch.float32)[None], torch.as_tensor(mask)[None])
    with torch.no_grad():
        x = model.sample(inputs, 256, torch.Generator().manual_seed(0), stage.sampler, None)
    _, _, q = from_representation(hand, x, cfg.representation, stage.ik)
    q = q.detach().clone().requires_grad_(True)
    col = hand.collision
    prims = col.pose(hand.forward_kinematics(q))

    def full():
        torch.autograd.grad(torch.relu(-col.pair_signed_distances(prims)).sum(), q, retain_graph=True)

    def screened():
        torch.autograd.grad(torch.relu(-col.pair_penetrating_distances(prims)).sum(), q, retain_graph=True)

    out = {"full_ms": [], "screened_ms": []}
    for _ in range(5):
        out["full_ms"].append(round(median_ms(full), 2))
        out["screened_ms"].append(round(median_ms(screened), 2))
    with torch.no_grad():
        d = col.pair_signed_distances(prims)[:, col.capsule_pairs.shape[0]:]
    out["overlapping_prism_pairs"] = float((d < 0).float().mean())
    print(json.dumps(out))


if __name__ == "__main__":
    main()
