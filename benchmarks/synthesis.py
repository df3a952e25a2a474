"""Benchmark: multi-object grasp synthesis throughput (``multigrasp bench synthesis``).

Workload: one fixed dual-object scene — cube + cylinder placed by
:func:`components.objects.sample_scene` with ``numpy`` seed :data:`SEED` — and one call of
:func:`components.synthesis.synthesize` with :data:`BATCH` = 256 candidates and the ``bench``
profile's optimiser (its approach / MALA / refinement step counts, times ``steps_scale``; 1 = as in the
profile).  Reported:

* ``accepted_per_s`` — accepted grasps per second of that call, ``accept_rate``;
* ``step_ms`` — median wall time of one annealed MALA step (energy + gradient, proposal,
  Metropolis test, contact switching) at B = 256, measured from the optimiser's progress
  callback over intervals of :data:`PROGRESS_EVERY` steps (fewer on very short runs), so it
  holds whatever the inside of the optimiser becomes;
* ``fk_ms`` — median FK of all links at B = 256 over ``repeats`` timed runs after a warm-up;
* ``seconds`` — the whole call (initialisation, MALA, refinement, filter);
* ``q1`` / ``pn_mm`` / ``div_deg`` — the paper's pre-grasp metrics (``components.metrics``, the
  ``bench`` profile's metric settings) over the accepted grasps (the first :data:`QUALITY_MAX` of
  them; ``None`` when none is accepted), so a throughput figure always comes with its quality.

The synthesis itself runs once (it is long); the step and FK figures are medians.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.timing import median_ms

BATCH = 256
BENCH_OBJECTS = ("cube", "cylinder")
SEED = 0
PROGRESS_EVERY = 10
#: At most this many accepted grasps are scored with Q1 / PN / Div (Q1 costs ~0.5 s a grasp on one core).
QUALITY_MAX = 64
#: Profile whose optimiser settings (step counts, weights, schedule) the benchmark uses.
PROFILE = "bench"


def bench_optimizer(cfg, steps_scale: float):
    """The profile's optimiser ``cfg`` at B = 256 with its step counts (approach, MALA, refinement) scaled
    (at least 1 MALA step)."""
    mala_steps = max(1, round(cfg.mala_steps * steps_scale))
    return cfg.model_copy(update={"batch_size": BATCH, "mala_steps": mala_steps,
                                  "approach_steps": max(0, round(cfg.approach_steps * steps_scale)),
                                  "refine_steps": max(0, round(cfg.refine_steps * steps_scale)),
                                  "progress_every": max(1, min(PROGRESS_EVERY, mala_steps // 4))})  # >= 3 intervals


def accepted_quality(hand, library, scene, result, metrics, group: bool = False) -> dict:
    """Mean Q1, mean PN (mm) and Div (deg) of the first :data:`QUALITY_MAX` accepted grasps of a
    :class:`~components.synthesis.SynthesisResult` (``None`` each when none is accepted; Div needs two),
    and ``quality_n``, how many were scored.  ``q1`` is always the min over objects (the hand alone) and
    ``q1_per_object`` the mean over the grasps of each object's Q1 (scene order: which object limits ``q1``); with
    ``group`` (``fc_mode='group'``) ``q1_group`` is the objects-as-one-body Q1 too."""
    from components.metrics import joint_diversity_deg, penetration_depth, q1_grasps
    from components.synthesis import SceneObjects

    index = result.accepted.nonzero().flatten()[:QUALITY_MAX]
    if not len(index):
        return {"q1": None, "q1_per_object": None, "pn_mm": None, "div_deg": None, "quality_n": 0}
    objects = SceneObjects(library, scene, hand.device, hand.dtype)
    p, R, q = result.p[index], result.R[index], result.q[index]
    measured, per_object = q1_grasps(hand, objects, p, R, q, metrics, group=group)
    extra = {"q1_group": round(float(measured.mean()), 4)} if group else {}
    return {"q1": round(float(per_object.amin(-1).mean()), 4),
            "q1_per_object": [round(float(v), 4) for v in per_object.mean(0)], **extra,
            "pn_mm": round(float(penetration_depth(hand, objects, p, R, q, metrics).pn_mm.mean()), 3),
            "div_deg": round(float(joint_diversity_deg(q.cpu())), 3) if len(index) > 1 else None,
            "quality_n": len(index)}


def run_synthesis_benchmark(repeats: int = 7, threads: int = 0, device: str = "cpu", steps_scale: float = 1.0) -> dict:
    """Run the workload (module docstring); returns the JSON-able result."""
    from components.hand import HandConfig, HandModel
    from components.objects import ObjectLibrary, ObjectsConfig, ScenesConfig, sample_scene
    from components.synthesis import synthesize
    from flows.config import load_config

    if threads:
        torch.set_num_threads(threads)
    dev = torch.device(device)
    sync = (lambda: torch.cuda.synchronize()) if dev.type == "cuda" else (lambda: None)
    hand = HandModel(HandConfig(), device=dev, dtype=torch.float32)
    profile = load_config(PROFILE).synthesis  # the optimiser and the metric settings, read once
    cfg = bench_optimizer(profile.optimizer_for(len(BENCH_OBJECTS)), steps_scale)  # the stage's optimiser for a pair
    ticks: list[tuple[int, float]] = []

    def progress(step: int, total: int, info: dict) -> None:
        if info.get("stage") == "mala":
            sync()
            ticks.append((step, time.perf_counter()))

    with tempfile.TemporaryDirectory() as tmp:
        library = ObjectLibrary(ObjectsConfig(), cache_dir=Path(tmp))
        scene = sample_scene(library, list(BENCH_OBJECTS), np.random.default_rng(SEED), ScenesConfig())
        start = time.perf_counter()
        result = synthesize(hand, library, scene, cfg, torch.Generator().manual_seed(SEED), progress)
        sync()
        seconds = time.perf_counter() - start
        quality = accepted_quality(hand, library, scene, result, profile.metrics)

    step_ms = [(t1 - t0) * 1000.0 / (s1 - s0) for (s0, t0), (s1, t1) in zip(ticks, ticks[1:]) if s1 > s0]
    q = hand.sample_joint_angles(BATCH, generator=torch.Generator().manual_seed(SEED)).to(dev)
    with torch.no_grad():
        fk_ms = median_ms(lambda: hand.forward_kinematics(q), repeats, sync)
    accepted = int(result.accepted.sum())
    return {"accepted_per_s": round(accepted / seconds, 4), "accept_rate": round(result.accept_rate, 4),
            "accepted": accepted, "step_ms": round(statistics.median(step_ms), 3) if step_ms else None,
            "fk_ms": round(fk_ms, 3), "seconds": round(seconds, 2), "threads": torch.get_num_threads(),
            "device": str(dev), "repeats": repeats, "torch": torch.__version__, **quality,
            "workload": {"objects": list(BENCH_OBJECTS), "scene": scene.to_dict(), "scene_seed": SEED,
                         "batch": BATCH, "profile": PROFILE, "steps_scale": steps_scale,
                         "approach_steps": cfg.approach_steps, "mala_steps": cfg.mala_steps,
                         "refine_steps": cfg.refine_steps,
                         "reasons": result.reason_counts()}}
