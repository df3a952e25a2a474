"""Benchmark: lift-environment speed against bare PyBullet stepping (``multigrasp bench sim``).

Workload: the cube + cylinder scene of :func:`components.objects.sample_scene` with ``numpy`` seed
:data:`SEED`, the open hand posed above the objects (``cameras.preview_hand_pose``), the default
:class:`LiftEnvConfig` (the pipeline's ``lift`` section) and a PointNet encoder of the configured size
(untrained: it costs what the pre-trained one costs).  Zero actions, so the env and the bare loop
simulate the same motion.  Reported (medians over ``repeats``):

* ``env_steps_per_s`` -- :class:`LiftEnv` steps per second (action, ``substeps`` physics steps, state
  reads, observation with point-cloud features every ``feature_period`` steps, reward), 1 torch thread;
* ``env_steps_per_s_2workers`` -- the same in 2 processes at once, steps of both per wall second;
* ``raw_physics_steps_per_s`` -- bare ``stepSimulation`` of the same world (:meth:`LiftWorld.step_raw`),
  measured in the same run, interleaved with the env's steps (below);
* ``overhead_ratio`` = env_steps_per_s * substeps / raw_physics_steps_per_s (1 = the env costs nothing on top of
  the physics), the median over repeats (``overhead_ratio_runs``).  Each repeat runs one episode from a reset in
  chunks of ``CHUNK`` env steps, each chunk followed by ``CHUNK * substeps`` bare physics steps of the same world
  (hand hovering, objects at rest), the chunks' order alternating (env first, then bare first); the ratio is
  of the summed times.  The development machine's speed drifts by up to 2x within minutes, so an env run and a
  bare run timed a second apart (the pairing used until the fifteenth session) gave per-repeat ratios from 0.52 to
  1.24 in one invocation; ~30 ms chunks see the same machine (per-repeat ratios now span at most 0.08).  The env's
  first step after a bare chunk asks PyBullet once more for the link states (the hand moved), a cost a plain
  rollout does not have;
* ``physics_share`` -- the fraction of the env's own wall time spent in its physics substeps (wrench +
  ``stepSimulation``, :attr:`LiftWorld.physics_seconds`), median over repeats: measured on the same steps, so
  no drift between two runs enters it.  It equals ``overhead_ratio`` when the physics runs as fast between
  env work as in the bare loop (it can run slower: the env's Python evicts its caches).
"""

from __future__ import annotations

import multiprocessing as mp
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

SEED = 0
BENCH_OBJECTS = ("cube", "cylinder")
#: Environment steps per timed run (one episode of the default config, 2.5 s).
STEPS = 100
#: Env steps per interleaved chunk (each followed by CHUNK * substeps bare physics steps): ~30 ms of each.
CHUNK = 10


def _make_env(cache_dir: str):
    """The benchmark's env and its pre-grasp record (in any process)."""
    import torch

    from components.execution import LiftEnv, LiftEnvConfig
    from components.execution.cameras import CameraConfig, preview_hand_pose
    from components.execution.lift_sim import GraspRecord
    from components.execution.pointnet import PointNetConfig, PointNetEncoder
    from components.hand import HandConfig, HandModel
    from components.objects import ObjectLibrary, ObjectsConfig, ScenesConfig, sample_scene

    torch.set_num_threads(1)
    cfg = LiftEnvConfig()
    hand = HandModel(HandConfig())
    library = ObjectLibrary(ObjectsConfig(), cache_dir=Path(cache_dir))
    scene = sample_scene(library, list(BENCH_OBJECTS), np.random.default_rng(SEED), ScenesConfig())
    p, R, q = preview_hand_pose(hand, scene, CameraConfig(), library)
    urdf = hand.export_urdf(Path(cache_dir) / f"hand-{mp.current_process().pid}")
    encoder = PointNetEncoder(PointNetConfig(feature_dim=cfg.feature_dim)).freeze()  # as load_encoder gives it
    record = GraspRecord(scene=scene, p=p, R=R, q=q.astype(np.float64))
    return LiftEnv(hand, library, urdf, [record], cfg, encoder), cfg


def _time_env(env, steps: int, shares: list | None = None) -> float:
    """Env steps per second over ``steps`` zero-action steps from a reset; appends to ``shares`` the fraction of
    that time spent in the physics substeps (:attr:`LiftWorld.physics_seconds`)."""
    import torch

    zero = torch.zeros(env.action_spec.shape)
    td = env.reset()
    physics = env.world.physics_seconds
    start = time.perf_counter()
    for _ in range(steps):
        td["action"] = zero
        td = env.step(td)["next"]
    elapsed = time.perf_counter() - start
    if shares is not None:
        shares.append((env.world.physics_seconds - physics) / elapsed)
    return steps / elapsed


def _worker(cache_dir: str, steps: int, barrier, out) -> None:
    env, _ = _make_env(cache_dir)
    _time_env(env, 10)  # warm-up
    barrier.wait()
    out.put(_time_env(env, steps))
    env.close()


def _time_interleaved(env, steps: int, substeps: int, env_first: bool, shares: list) -> tuple[float, float]:
    """One repeat: from a reset, ``steps`` zero-action env steps in chunks of :data:`CHUNK`, each chunk next to
    ``CHUNK * substeps`` bare physics steps of the same world (the env's first when ``env_first``, then
    alternating).  Appends the env's physics share to ``shares``.  -> (env seconds, bare physics seconds)."""
    import torch

    zero = torch.zeros(env.action_spec.shape)
    td = env.reset()
    physics = env.world.physics_seconds
    env_seconds = raw_seconds = 0.0
    for k, start in enumerate(range(0, steps, CHUNK)):
        n = min(CHUNK, steps - start)
        env_turn_first = env_first == (k % 2 == 0)
        if not env_turn_first:
            raw_seconds += env.world.step_raw(n * substeps)
        begin = time.perf_counter()
        for _ in range(n):
            td["action"] = zero
            td = env.step(td)["next"]
        env_seconds += time.perf_counter() - begin
        if env_turn_first:
            raw_seconds += env.world.step_raw(n * substeps)
    shares.append((env.world.physics_seconds - physics) / env_seconds)
    return env_seconds, raw_seconds


def run_sim_benchmark(repeats: int = 5, steps: int = STEPS) -> dict:
    """Run the workload (module docstring) with ``steps`` env steps per repeat; returns the JSON-able result."""
    with tempfile.TemporaryDirectory() as tmp:
        env, cfg = _make_env(tmp)
        _time_env(env, 10)  # warm-up
        env_rates, raw_rates, ratios, shares = [], [], [], []
        for k in range(repeats):
            env_seconds, raw_seconds = _time_interleaved(env, steps, cfg.substeps, k % 2 == 0, shares)
            env_rates.append(steps / env_seconds)
            raw_rates.append(steps * cfg.substeps / raw_seconds)
            ratios.append(raw_seconds / env_seconds)  # = env rate * substeps / raw rate
        env.close()
        ctx = mp.get_context("spawn")
        two = []
        for _ in range(max(1, repeats // 2)):
            barrier, out = ctx.Barrier(2), ctx.Queue()
            procs = [ctx.Process(target=_worker, args=(tmp, steps, barrier, out)) for _ in range(2)]
            for proc in procs:
                proc.start()
            rates = [out.get() for _ in procs]
            for proc in procs:
                proc.join()
            two.append(sum(rates))
    return {"env_steps_per_s": round(statistics.median(env_rates), 1),
            "env_steps_per_s_2workers": round(statistics.median(two), 1),
            "raw_physics_steps_per_s": round(statistics.median(raw_rates), 1), "substeps": cfg.substeps,
            "overhead_ratio": round(statistics.median(ratios), 3),
            "overhead_ratio_runs": [round(x, 3) for x in ratios],
            "physics_share": round(statistics.median(shares), 3), "physics_share_runs": [round(x, 3) for x in shares],
            "repeats": repeats,
            "workload": {"objects": list(BENCH_OBJECTS), "scene_seed": SEED, "steps": steps, "chunk": CHUNK,
                         "physics_hz": cfg.physics_hz, "feature_period": cfg.feature_period,
                         "feature_dim": cfg.feature_dim, "actions": "zero"}}
