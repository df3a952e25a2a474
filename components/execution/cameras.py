"""PyBullet tabletop worlds and CPU camera renders (scene previews, later rollout GIFs).

A world = a table whose top is the plane z = 0, the objects of a :class:`Scene` at their
placements, and optionally the Shadow Hand (URDF exported from the same MJCF as the FK)
at a pose ``H = (p, R, q)``.  Renders use PyBullet's CPU renderer (``ER_TINY_RENDERER``),
which needs no display or GPU.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as pb
import torch
from pydantic import Field
from scipy.spatial.transform import Rotation

from components.config_base import Section


class CameraConfig(Section):
    """A look-at camera for previews, and where the preview puts the open hand."""

    width: int = Field(320, ge=16, le=4096, description="Image width in pixels.")
    height: int = Field(240, ge=16, le=4096, description="Image height in pixels.")
    fov_deg: float = Field(50.0, gt=1.0, lt=170.0, description="Vertical field of view (degrees).")
    distance_m: float = Field(0.42, gt=0.0, description="Camera distance from the target point (m).")
    yaw_deg: float = Field(40.0, description="Camera yaw about world z (degrees).")
    pitch_deg: float = Field(-35.0, ge=-89.0, le=89.0, description="Camera pitch (degrees, negative looks down).")
    target_height_m: float = Field(0.05, description="Height of the look-at point above the objects' centre (m).")
    near_m: float = Field(0.01, gt=0.0, description="Near clipping plane (m).")
    far_m: float = Field(5.0, gt=0.0, description="Far clipping plane (m).")
    hand_clearance_m: float = Field(
        0.03, ge=0.0, description="Preview hand: gap between the tallest object and the lowest hand point (m).")
    table_half_extent_m: float = Field(0.25, gt=0.0, description="Half side of the square table top (m).")
    table_thickness_m: float = Field(0.02, gt=0.0, description="Table thickness (m); its top is z = 0.")
    table_rgba: tuple[float, float, float, float] = Field((0.78, 0.66, 0.5, 1.0), description="Table colour.")


# --------------------------------------------------------------------------- world building


def add_table(client: int, cam: CameraConfig) -> int:
    """A static box whose top face is the plane z = 0."""
    half = [cam.table_half_extent_m, cam.table_half_extent_m, cam.table_thickness_m / 2]
    col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client)
    vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=list(cam.table_rgba), physicsClientId=client)
    return pb.createMultiBody(0.0, col, vis, basePosition=[0, 0, -cam.table_thickness_m / 2], physicsClientId=client)


def add_scene_objects(client: int, library, scene) -> list[int]:
    """Create every object of ``scene`` in ``client`` at its placement; returns body ids."""
    return [library.get(p.name).pybullet_body(client, p.position, p.quat_xyzw) for p in scene.objects]


def hand_joint_indices(client: int, body: int) -> dict[str, int]:
    """URDF joint name → PyBullet joint index for the revolute joints of the hand."""
    out = {}
    for index in range(pb.getNumJoints(body, physicsClientId=client)):
        info = pb.getJointInfo(body, index, physicsClientId=client)
        if info[2] == pb.JOINT_REVOLUTE:
            out[info[1].decode()] = index
    return out


def add_hand(client: int, urdf: Path, hand, p: np.ndarray, R: np.ndarray, q: np.ndarray, fixed: bool = True) -> int:
    """Load the hand URDF with its palm frame at (p, R) and joints at q (22, radians)."""
    quat = Rotation.from_matrix(R).as_quat()  # x, y, z, w
    body = pb.loadURDF(str(urdf), basePosition=list(map(float, p)), baseOrientation=list(map(float, quat)),
                       useFixedBase=fixed, flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
    joints = hand_joint_indices(client, body)
    for name, angle in zip(hand.joint_names, q):
        pb.resetJointState(body, joints[name], float(angle), physicsClientId=client)
    return body


# --------------------------------------------------------------------------- preview pose


def palm_axes(hand) -> tuple[np.ndarray, np.ndarray]:
    """Palmar normal and finger direction of the hand, in the palm frame (unit vectors).

    The finger direction points from the palm origin to the mean keypoint of the open hand;
    the palmar normal is the direction the keypoints move when every joint goes from the
    open pose to the middle of its range (fingers curl toward the palm), made orthogonal
    to the finger direction.
    """
    eye = torch.eye(3, dtype=hand.dtype).unsqueeze(0)
    zero = torch.zeros(1, 3, dtype=hand.dtype)
    q_open = hand.open_pose().to(hand.dtype).unsqueeze(0)
    q_mid = hand.joint_limits.to(hand.dtype).mean(-1).unsqueeze(0)
    open_pts = hand.keypoints(zero, eye, q_open)[0].detach().cpu().numpy()
    curled = hand.keypoints(zero, eye, q_mid)[0].detach().cpu().numpy()
    finger = open_pts.mean(0)
    finger /= np.linalg.norm(finger)
    normal = (curled - open_pts).mean(0)
    normal -= normal.dot(finger) * finger
    return normal / np.linalg.norm(normal), finger


def preview_hand_pose(hand, scene, cam: CameraConfig, library) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An open hand, palm down, centred above the objects with ``hand_clearance_m`` to spare."""
    normal, finger = palm_axes(hand)
    side = np.cross(normal, finger)
    # R maps palm-frame axes to world: normal → −z, finger → +x, side → normal × finger mapped consistently
    palm_basis = np.stack([finger, side, normal], axis=1)          # columns in the palm frame
    world_basis = np.stack([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]], axis=1)
    R = world_basis @ palm_basis.T
    q = hand.open_pose().detach().cpu().numpy()
    eye = torch.eye(3, dtype=hand.dtype).unsqueeze(0)
    pts = hand.keypoints(torch.zeros(1, 3, dtype=hand.dtype), eye,
                         torch.as_tensor(q, dtype=hand.dtype).unsqueeze(0))[0].detach().cpu().numpy()
    centre_xy = np.mean([p.position[:2] for p in scene.objects], axis=0)
    top = max(_object_top(library, p) for p in scene.objects)
    world_pts = pts @ R.T
    p = np.zeros(3)
    p[:2] = centre_xy - world_pts.mean(0)[:2]
    p[2] = top + cam.hand_clearance_m - world_pts[:, 2].min()
    return p, R, q


def _object_top(library, placement) -> float:
    mesh = library.get(placement.name).mesh
    rot = Rotation.from_quat(placement.quat_xyzw).as_matrix()
    return float((mesh.vertices @ rot.T)[:, 2].max() + placement.position[2])


# --------------------------------------------------------------------------- rendering


def render_rgb(client: int, target: np.ndarray, cam: CameraConfig) -> np.ndarray:
    """An RGB image (H, W, 3) uint8 from a yaw/pitch orbit camera around ``target``."""
    view = pb.computeViewMatrixFromYawPitchRoll(cameraTargetPosition=list(map(float, target)),
                                                distance=cam.distance_m, yaw=cam.yaw_deg, pitch=cam.pitch_deg,
                                                roll=0.0, upAxisIndex=2, physicsClientId=client)
    proj = pb.computeProjectionMatrixFOV(fov=cam.fov_deg, aspect=cam.width / cam.height, nearVal=cam.near_m,
                                         farVal=cam.far_m, physicsClientId=client)
    _, _, rgba, _, _ = pb.getCameraImage(cam.width, cam.height, view, proj, renderer=pb.ER_TINY_RENDERER,
                                         physicsClientId=client)
    return np.asarray(rgba, dtype=np.uint8).reshape(cam.height, cam.width, 4)[..., :3]


def render_scene_png(path: Path, library, scene, hand, urdf: Path, cam: CameraConfig,
                     hand_pose: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> Path:
    """Render table + objects + hand (default: open, palm down, above the objects) to a PNG."""
    from PIL import Image

    client = pb.connect(pb.DIRECT)
    try:
        add_table(client, cam)
        add_scene_objects(client, library, scene)
        p, R, q = hand_pose if hand_pose is not None else preview_hand_pose(hand, scene, cam, library)
        add_hand(client, urdf, hand, p, R, q)
        centre = np.mean([pl.position for pl in scene.objects], axis=0)
        rgb = render_rgb(client, centre + np.array([0.0, 0.0, cam.target_height_m]), cam)
    finally:
        pb.disconnect(client)
    tmp = Path(path).with_suffix(".tmp.png")
    Image.fromarray(rgb).save(tmp)
    tmp.replace(path)
    return Path(path)
