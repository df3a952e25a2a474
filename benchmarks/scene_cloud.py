"""What one scene feature of the vision-based generalist costs (components/learning/vision.py): the three depth
renders, the even re-sampling and the PointNet forward, at several image sizes.

    python -m benchmarks.scene_cloud --json OUT [--repeats 5] [--sizes 80x60,160x120] [--threads 1]

The scene: the cube and the sphere of the lift env's tests, the open hand above them (``preview_hand_pose``), in a
:class:`components.execution.LiftEnv`.  Per image size: the median seconds of the renders (every camera) and of the
whole feature (renders, voxel thinning, farthest points, encoder), and how many pixels show the objects and the hand.
The default encoder is an untrained PointNet of the default widths (its cost does not depend on its weights).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path


def measure(sizes: list[tuple[int, int]], repeats: int, threads: int) -> dict:
    import numpy as np
    import torch

    from components.execution import GraspRecord, LiftEnv, LiftEnvConfig
    from components.execution.cameras import CameraConfig, preview_hand_pose
    from components.execution.pointnet import PointNetConfig, PointNetEncoder
    from components.hand import HandConfig, HandModel
    from components.learning.vision import SceneCameras, VisionConfig, camera_points
    from components.objects import ObjectLibrary, ObjectsConfig, Placement, Scene

    torch.set_num_threads(threads)
    folder = Path(tempfile.mkdtemp(prefix="scene_cloud_"))
    hand, library = HandModel(HandConfig()), ObjectLibrary(ObjectsConfig(), cache_dir=folder / "cache")
    identity = (0.0, 0.0, 0.0, 1.0)
    scene = Scene(objects=(Placement("cube", (0.0, -0.03, 0.02), identity),
                           Placement("sphere", (0.0, 0.035, 0.025), identity)))
    p, R, q = preview_hand_pose(hand, scene, CameraConfig(), library)
    env = LiftEnv(hand, library, hand.export_urdf(folder), [GraspRecord(scene=scene, p=p, R=R, q=q.astype(np.float64))],
                  LiftEnvConfig(closure_steps=0), PointNetEncoder(PointNetConfig()).eval())
    env.reset()
    rows = []
    try:
        for width, height in sizes:
            cfg = VisionConfig(width=width, height=height)
            cameras = SceneCameras(cfg)
            target = np.mean([pl.position for pl in scene.objects], axis=0) + np.array([0.0, 0.0, cfg.target_height_m])
            objects, everything = set(env.world.objects), {env.world.body, *env.world.objects}
            cameras.feature(env.world, env.featurizer.features)  # warm-up
            renders, features = [], []
            for _ in range(repeats):
                start = time.perf_counter()
                for yaw in cfg.camera_yaws_deg:
                    camera_points(env.world.client, target, yaw, cfg, everything)
                renders.append(time.perf_counter() - start)
                start = time.perf_counter()
                cameras.feature(env.world, env.featurizer.features)
                features.append(time.perf_counter() - start)
            rows.append({"width": width, "height": height, "cameras": len(cfg.camera_yaws_deg),
                         "render_s": round(statistics.median(renders), 4),
                         "feature_s": round(statistics.median(features), 4),
                         "object_pixels": sum(len(camera_points(env.world.client, target, yaw, cfg, objects))
                                              for yaw in cfg.camera_yaws_deg),
                         "scene_pixels": sum(len(camera_points(env.world.client, target, yaw, cfg, everything))
                                             for yaw in cfg.camera_yaws_deg),
                         "scene_points": cfg.scene_points})
    finally:
        env.close()
    return {"repeats": repeats, "threads": threads, "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, help="output JSON file")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--sizes", default="80x60,160x120", help="comma-separated WIDTHxHEIGHT")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    sizes = [tuple(int(v) for v in item.split("x")) for item in args.sizes.split(",")]
    result = measure(sizes, args.repeats, args.threads)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    json.dump(result, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
