"""What the vision-based generalist sees (paper §"Learning a Multi-Object Lifting Policy", DAgger paragraph): the
hand-object scene captured by three simulated RGB-D cameras, fused into one point cloud, re-sampled to an even
distribution, expressed in the palm frame and encoded by the frozen PointNet of the lift policies.

    cameras = SceneCameras(VisionConfig())
    cloud = cameras.scene_cloud(world)          # (scene_points, 3) in the palm frame
    feature = cameras.feature(world, encoder)   # (feature_dim,)

Each camera looks at the objects' centre from ``distance_m`` at its own yaw (three around the table, 120 degrees
apart by default) and ``pitch_deg``; PyBullet's CPU renderer (``ER_TINY_RENDERER``: no display, no GPU) gives the
depth buffer and the segmentation mask.  A pixel is kept when the mask says it shows the hand or an object (the
table and the background are dropped, as a real set-up crops them by a plane fit and a workspace box), and
back-projected to the world by the inverse of the camera's projection x view matrix:

    ndc = (2 u / W - 1,  1 - 2 (v + 1) / H,  2 d - 1,  1),   x_world ~ (P V)^-1 ndc   (homogeneous),

u the column and v the row of the pixel, d its depth-buffer value: the tiny renderer samples each pixel at this corner
(a box's faces come back to 1e-7 m with it, against ~1 mm with pixel centres; ``tests/test_distill.py``).

The three views' points are merged, thinned on a voxel grid of ``voxel_m`` (one point per occupied voxel: dense
near-camera surfaces no longer outweigh far ones, the paper's "re-sampled to ensure even point distribution") and
brought to exactly ``scene_points`` points by farthest-point sampling (or by repetition when fewer are visible).
Unlike the state-based specialists, the student is never told where the objects are: it sees them only through
this cloud.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pybullet as pb
from pydantic import Field

from components.config_base import Section


class VisionConfig(Section):
    """The generalist's cameras and scene point cloud."""

    camera_yaws_deg: list[float] = Field(
        default_factory=lambda: [0.0, 120.0, 240.0],
        description="Yaw of each camera about the world z axis (degrees): three cameras around the table, as the paper's.")
    pitch_deg: float = Field(-40.0, ge=-89.0, le=-1.0, description="Camera pitch (degrees, negative looks down).")
    distance_m: float = Field(0.4, gt=0.0, description="Camera distance from the objects' centre (m).")
    target_height_m: float = Field(0.06, description="Height of the look-at point above the objects' start centre (m).")
    width: int = Field(
        160, ge=8, le=1024,
        description="Depth image width (pixels).  160 x 120 at 0.4 m and 45 degrees: ~2.7 mm per pixel at the objects, "
        "771 object pixels of 10,955 in the three views of a dual-object pre-grasp; the three renders take 42 ms and the "
        "whole feature (renders, re-sampling, encoder) 114 ms on one core, against 185 object pixels and 44 / 91 ms at "
        "80 x 60 (python -m benchmarks.scene_cloud, medians of 5, the other core busy; fifty-eighth session).")
    height: int = Field(120, ge=8, le=1024, description="Depth image height (pixels).")
    fov_deg: float = Field(45.0, gt=1.0, lt=170.0, description="Vertical field of view (degrees).")
    near_m: float = Field(0.05, gt=0.0, description="Near clipping plane (m).")
    far_m: float = Field(2.0, gt=0.0, description="Far clipping plane (m); pixels at it see nothing.")
    voxel_m: float = Field(0.005, gt=0.0, description="Voxel size of the even re-sampling (m): one point per occupied voxel.")
    scene_points: int = Field(512, ge=8, description="Points of the scene cloud given to the encoder (the hand's surface is most of the scene: the objects get a few dozen of them).")


def _matrix(values: Sequence[float]) -> np.ndarray:
    """A PyBullet 4 x 4 matrix (16 floats, column-major) as a numpy array."""
    return np.asarray(values, dtype=np.float64).reshape(4, 4, order="F")


def camera_points(client: int, target: np.ndarray, yaw_deg: float, cfg: VisionConfig, keep: set[int]) -> np.ndarray:
    """World points (n, 3) of the pixels of one camera that show a body in ``keep`` (module docstring)."""
    view = pb.computeViewMatrixFromYawPitchRoll(cameraTargetPosition=[float(x) for x in target],
                                                distance=cfg.distance_m, yaw=yaw_deg, pitch=cfg.pitch_deg, roll=0.0,
                                                upAxisIndex=2, physicsClientId=client)
    proj = pb.computeProjectionMatrixFOV(fov=cfg.fov_deg, aspect=cfg.width / cfg.height, nearVal=cfg.near_m,
                                         farVal=cfg.far_m, physicsClientId=client)
    _, _, _, depth, seg = pb.getCameraImage(cfg.width, cfg.height, view, proj, renderer=pb.ER_TINY_RENDERER,
                                            physicsClientId=client)
    depth = np.asarray(depth, dtype=np.float64).reshape(cfg.height, cfg.width)
    seg = np.asarray(seg, dtype=np.int64).reshape(cfg.height, cfg.width)
    bodies = np.where(seg >= 0, seg & ((1 << 24) - 1), -1)  # the mask packs the link above bit 24
    mask = np.isin(bodies, list(keep)) & (depth < 1.0 - 1e-6)
    if not mask.any():
        return np.zeros((0, 3))
    v, u = np.nonzero(mask)
    ndc = np.stack([2.0 * u / cfg.width - 1.0, 1.0 - 2.0 * (v + 1.0) / cfg.height,
                    2.0 * depth[v, u] - 1.0, np.ones(len(u))], axis=1)
    world = ndc @ np.linalg.inv(_matrix(proj) @ _matrix(view)).T
    return world[:, :3] / world[:, 3:4]


def voxel_thin(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point per occupied voxel of side ``voxel`` (the first of each), in a stable order."""
    if len(points) == 0:
        return points
    cells = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    return points[np.sort(first)]


def farthest_points(points: np.ndarray, n: int) -> np.ndarray:
    """``n`` of ``points`` by farthest-point sampling from the first one (all of them, repeated in turn to ``n``, when
    there are no more than ``n``; zeros when there are none)."""
    if len(points) == 0:
        return np.zeros((n, 3))
    if len(points) <= n:
        return points[np.arange(n) % len(points)]
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = 0
    distance = np.linalg.norm(points - points[0], axis=1)
    for k in range(1, n):
        chosen[k] = int(np.argmax(distance))
        distance = np.minimum(distance, np.linalg.norm(points - points[chosen[k]], axis=1))
    return points[chosen]


class SceneCameras:
    """The three cameras of :class:`VisionConfig` around a :class:`components.execution.lift_sim.LiftWorld`."""

    def __init__(self, cfg: VisionConfig):
        self.cfg = cfg

    def world_cloud(self, world) -> np.ndarray:
        """The fused, evenly re-sampled scene cloud in world coordinates, (scene_points, 3)."""
        record = world.record
        target = np.mean([p.position for p in record.scene.objects], axis=0) + np.array([0.0, 0.0, self.cfg.target_height_m])
        keep = {world.body, *world.objects}
        views = [camera_points(world.client, target, yaw, self.cfg, keep) for yaw in self.cfg.camera_yaws_deg]
        merged = np.concatenate(views) if views else np.zeros((0, 3))
        return farthest_points(voxel_thin(merged, self.cfg.voxel_m), self.cfg.scene_points)

    def scene_cloud(self, world) -> np.ndarray:
        """:meth:`world_cloud` in the palm frame:  x_palm = R_palm^T (x_world - p_palm)."""
        p, R = world.palm_pose()
        return (self.world_cloud(world) - p) @ R

    def feature(self, world, featurize) -> np.ndarray:
        """``featurize(clouds (1, N, 3)) -> (1, F)`` of the palm-frame scene cloud, as (F,) float32."""
        return np.asarray(featurize(self.scene_cloud(world)[None]), dtype=np.float32)[0]
