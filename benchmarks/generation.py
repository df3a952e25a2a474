"""Benchmark: time to produce 256 dual-object pre-grasps on the CPU (``multigrasp bench generation``).

Workload: the cube + cylinder scene of :func:`components.objects.sample_scene` with ``numpy`` seed
:data:`SEED`; a generator of the default :class:`GeneratorConfig` (freshly initialised: sampling costs the
same whatever the weights), 256 grasps = the paper's timing batch.  The sampler, IK and refinement settings
are the ``generator`` stage's of ``profile`` (bench: strided DDIM with 25 denoiser calls and 50 refinement
steps; paper: the paper's 100-step ancestral DDPM and 200 refinement steps), changed with
``--set sampler.steps=10``-style overrides of :class:`GeneratorStageConfig`.
Reported (medians over ``repeats``):

* ``sample_s`` -- sampling 256 keypoint sets (objects encoded once);
* ``ik_s`` -- keypoints -> (p, R, q) for the 256;
* ``refine_s`` -- the refinement of the 256 (the paper's steps and, where the profile turns it on, the
  force-closure refinement, ``refine.fc_steps``);
* ``time_256_s`` = sample_s + ik_s + refine_s (the paper: 12.28 s on an RTX 3090 Ti), ``threads``.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

SEED = 0
BENCH_OBJECTS = ("cube", "cylinder")
BATCH = 256


def run_generation_benchmark(repeats: int = 3, threads: int = 0, device: str = "cpu", batch: int = BATCH,
                             sets: tuple[str, ...] = (), profile: str = "bench") -> dict:
    """``profile``: whose ``generator`` settings; ``sets``: ``KEY=VALUE`` overrides of that section
    (``sampler.steps=25``, ``refine.steps=50``, ...)."""
    import torch

    from flows.config import load_config

    from components.generation import GeneratorConfig, posed_clouds, refine_grasps
    from components.generation.canonical import AlignedFrame
    from components.generation.denoiser import ObjectInputs
    from components.generation.generator import guidance_hook
    from components.generation.representation import from_representation
    from components.generation.training import build_generator
    from components.hand import HandConfig, HandModel
    from components.objects import ObjectLibrary, ObjectsConfig, ScenesConfig, sample_scene
    from components.synthesis import SceneObjects

    if threads:
        torch.set_num_threads(threads)
    full = load_config(profile, None, [f"generator.{item}" for item in sets])
    stage = full.generator
    cfg, sampler, ik, refine = GeneratorConfig(), stage.sampler, stage.ik, stage.refine
    hand = HandModel(HandConfig(), device=device)
    model = build_generator(cfg).to(device).eval()
    with tempfile.TemporaryDirectory() as tmp:
        library = ObjectLibrary(ObjectsConfig(), cache_dir=Path(tmp))
        scene = sample_scene(library, list(BENCH_OBJECTS), np.random.default_rng(SEED), ScenesConfig())
        positions = np.array([pl.position for pl in scene.objects])
        quats = np.array([pl.quat_xyzw for pl in scene.objects])
        clouds, mask = posed_clouds(library, scene.names, positions, quats, cfg.points_per_object, cfg.max_objects)
        inputs = ObjectInputs(torch.as_tensor(clouds, dtype=torch.float32, device=device)[None],
                              torch.as_tensor(mask, device=device)[None])
        objects = SceneObjects(library, scene, hand.device, hand.dtype)
        guide = None
        if sampler.guidance.scale > 0.0:  # the clouds are used as they are: the identity is their aligned frame
            identity = AlignedFrame.from_yaw(torch.zeros(batch, device=device))
            guide = guidance_hook(model, hand, sampler, identity, lambda x: objects.sdf(x).amin(-1),
                                  objects.table_height)
        times: dict[str, list[float]] = {"sample_s": [], "ik_s": [], "refine_s": []}
        for r in range(repeats):
            gen = torch.Generator(device=device).manual_seed(SEED + r)
            t0 = time.perf_counter()
            with torch.no_grad():
                x = model.sample(inputs, batch, gen, sampler, guide)
            t1 = time.perf_counter()
            p, R, q = from_representation(hand, x, cfg.representation, ik)
            t2 = time.perf_counter()
            refine_grasps(hand, objects, p.detach(), R.detach(), q.detach(), refine,
                          synthesis=full.synthesis.optimizer_for(len(scene.objects)))
            t3 = time.perf_counter()
            times["sample_s"].append(t1 - t0)
            times["ik_s"].append(t2 - t1)
            times["refine_s"].append(t3 - t2)
    med = {k: round(statistics.median(v), 3) for k, v in times.items()}
    total = round(sum(med.values()), 3)
    return {"time_256_s": total if batch == BATCH else None, "time_s": total, **med, "threads": torch.get_num_threads(), "device": device,
            "repeats": repeats, "workload": {"objects": list(BENCH_OBJECTS), "scene_seed": SEED, "batch": batch,
                                             "diffusion_steps": cfg.diffusion_steps, "sampler": sampler.method,
                                             "denoiser_calls": (min(sampler.steps, cfg.diffusion_steps)
                                                                if sampler.method == "ddim" else cfg.diffusion_steps),
                                             "profile": profile, "overrides": list(sets),
                                             "ik_steps": ik.steps, "refine_lr": refine.lr,
                                             "refine_steps": refine.steps, "fc_steps": refine.fc_steps,
                                             "fc_lr": refine.fc_lr, "fc_w_pen": refine.fc_w_pen,
                                             "guidance_scale": sampler.guidance.scale,
                                             "weights": "untrained (sampling and IK cost the same; the refinement depends on how much the samples penetrate)"},
            "paper_time_256_s": 12.28}
