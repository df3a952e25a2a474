"""HandModel: the Shadow Hand for grasp synthesis (DexGraspNet-style), in torch.

A hand pose is H = (p, R, q): ``p`` (B, 3) and ``R`` (B, 3, 3) are the position and orientation of
the **palm frame** in the world, ``q`` (B, 22) the finger joint angles in ``joint_names`` order
(radians).  The palm frame is the MJCF body ``robot0:palm`` (origin on the wrist axis at the base
of the palm, +z towards the middle finger, +x towards the thumb side, -y = palm normal); see
:mod:`components.hand.kinematics`.

Pieces: :mod:`~components.hand.mjcf` (compose + compile the MJCF), :mod:`~components.hand.kinematics`
(FK, coupling), :mod:`~components.hand.geometry` (primitives and distances),
:mod:`~components.hand.regions` (contact candidates, keypoints), :mod:`~components.hand.urdf`.
Every method is batched over B and differentiable wrt p, R and q; nothing loops over the batch.
"""

from pathlib import Path
from typing import Optional

import torch
from torch import Tensor

from components.hand.config import HandConfig
from components.hand.geometry import HandCollision, Primitives
from components.hand.kinematics import HandKinematics, transform_points
from components.hand.mjcf import WRIST_BODIES, HandSpec, load_hand_spec
from components.hand.regions import DEFAULT_ASSETS_DIR, load_contact_candidates, load_keypoints
from components.fileio import atomic_write_text
from components.hand.urdf import build_urdf, pybullet_indices

#: File name used by :meth:`HandModel.export_urdf` when it is given a folder.
URDF_FILE_NAME = "shadow_hand.urdf"


def world_from_palm(p: Tensor, R: Tensor, frames: Tensor) -> Tensor:
    """Palm-frame transforms to world transforms:  T_world = [R p; 0 1] T_palm.
    p (B, 3), R (B, 3, 3), frames (B, L, 4, 4) -> (B, L, 4, 4)."""
    rot = R.unsqueeze(1) @ frames[..., :3, :3]  # (B, L, 3, 3)
    pos = (R.unsqueeze(1) @ frames[..., :3, 3:]).squeeze(-1) + p.unsqueeze(1)  # (B, L, 3)
    top = torch.cat([rot, pos.unsqueeze(-1)], dim=-1)  # (B, L, 3, 4)
    bottom = frames[..., 3:, :]  # (B, L, 1, 4) = [0 0 0 1]
    return torch.cat([top, bottom], dim=-2)


def palm_from_world(points: Tensor, p: Tensor, R: Tensor) -> Tensor:
    """World points in the palm frame:  x_palm = R^T (x - p).   points (B, N, 3) -> (B, N, 3)."""
    return (points - p.unsqueeze(1)) @ R


class HandModel:
    """The Shadow Hand: FK, coupling, contact candidates, keypoints, distances, URDF (module docstring)."""

    def __init__(self, cfg: HandConfig, device="cpu", dtype=torch.float32):
        self.cfg, self.device, self.dtype = cfg, torch.device(device), dtype
        self.spec: HandSpec = load_hand_spec()
        self.kinematics = HandKinematics(self.spec, cfg.include_forearm, device=self.device, dtype=dtype)

        self.joint_names: list = self.kinematics.joint_names  # (22,) FK order
        self.actuated_joint_names: list = self.kinematics.actuated_joint_names  # (18,)
        self.joint_limits: Tensor = self.kinematics.joint_limits  # (22, 2) rad
        self.link_names: list = self.kinematics.link_names  # (L,) palm, 22 finger bodies[, wrist, forearm]
        link_index = {n: i for i, n in enumerate(self.link_names)}

        geoms = [g for g in self.spec.collision_geoms if cfg.include_forearm or g.body not in WRIST_BODIES]
        self.collision = HandCollision(self.spec, geoms, self.link_names, eps=cfg.distance_epsilon,
                                       parallel_eps=cfg.parallel_epsilon, iterations=cfg.golden_section_iterations,
                                       screen_samples=cfg.self_collision_screen_samples,
                                       compile_kernels=cfg.compile_distance_kernels, device=self.device, dtype=dtype)
        self.collision_geom_names: list = self.collision.geom_names  # order of geom_lowest_heights

        assets = Path(cfg.assets_dir) if cfg.assets_dir is not None else DEFAULT_ASSETS_DIR
        candidates = load_contact_candidates(self.spec, assets, cfg.contact_points_per_region)
        self.region_names: list = list(dict.fromkeys(candidates.names))  # (17,)
        self.contact_region_of = torch.tensor([self.region_names.index(n) for n in candidates.names],
                                              dtype=torch.long, device=self.device)  # (K,)
        self._candidate_link = torch.tensor([link_index[n] for n in candidates.link_names], device=self.device)
        self._candidate_local = torch.tensor(candidates.points, dtype=dtype, device=self.device)  # (K, 3)
        self._candidate_normal_local = torch.tensor(candidates.normals, dtype=dtype, device=self.device)  # (K, 3)

        keypoints = load_keypoints(self.spec, assets)
        self.keypoint_names: list = keypoints.names  # (31,)
        self._keypoint_link = torch.tensor([link_index[n] for n in keypoints.link_names], device=self.device)
        self._keypoint_local = torch.tensor(keypoints.points, dtype=dtype, device=self.device)  # (31, 3)

    # ================================================================ joints
    def expand_actuated(self, q18: Tensor) -> Tensor:
        """(..., 18) actuated angles -> (..., 22): J0 = clamp(ratio * J1, J0 range) on FF/MF/RF/LF (MJCF tendon)."""
        return self.kinematics.expand_actuated(q18)

    def actuated(self, q22: Tensor) -> Tensor:
        """(..., 22) -> (..., 18): drop the coupled J0s."""
        return self.kinematics.actuated(q22)

    def open_pose(self) -> Tensor:
        """The flat open hand: every joint at 0 (inside every range; fingers straight, thumb in the palm
        plane, no self-penetration).   -> (22,)"""
        return torch.zeros(len(self.joint_names), dtype=self.dtype, device=self.device)

    def sample_joint_angles(self, n: int, generator: Optional[torch.Generator] = None) -> Tensor:
        """n poses: the 18 actuated angles uniform in their ranges, each J0 from the coupling (it sits at
        its upper limit when J1 > 1.571 / 1.1418 = 1.376 rad).   -> (n, 22)."""
        lower, upper = self.kinematics.actuated(self.joint_limits.T)  # (18,), (18,)
        u = torch.rand(n, len(self.actuated_joint_names), generator=generator, dtype=self.dtype,
                       device=self.device if generator is None else generator.device)
        return self.expand_actuated(lower + u.to(self.device) * (upper - lower))

    def joint_limit_violation(self, q: Tensor) -> Tensor:
        """Prior energy of joint limits:  E_prior = sum_j relu(q_j - upper_j) + relu(lower_j - q_j).
        (B, 22) -> (B,)."""
        lower, upper = self.joint_limits.unbind(-1)
        return (torch.relu(q - upper) + torch.relu(lower - q)).sum(-1)

    # ================================================================ kinematics
    def forward_kinematics(self, q: Tensor) -> Tensor:
        """Every link frame (``link_names`` order) in the palm frame.   q (B, 22) -> (B, L, 4, 4)."""
        return self.kinematics.forward_kinematics(q)

    def link_poses(self, p: Tensor, R: Tensor, q: Tensor) -> Tensor:
        """Every link frame in the world for H = (p, R, q).   -> (B, L, 4, 4)."""
        return world_from_palm(p, R, self.forward_kinematics(q))

    def _points_on_links(self, link: Tensor, local: Tensor, p: Tensor, R: Tensor, q: Tensor) -> Tensor:
        """World positions of points fixed on links.   link (K,), local (K, 3) -> (B, K, 3)."""
        frames = self.forward_kinematics(q)[:, link]  # (B, K, 4, 4) in the palm frame
        palm = transform_points(frames, local)  # (B, K, 3)
        return palm @ R.transpose(1, 2) + p.unsqueeze(1)

    def contact_candidates(self, p: Tensor, R: Tensor, q: Tensor, frames: Optional[Tensor] = None) -> Tensor:
        """All contact candidate points in the world; region of each: ``contact_region_of``.   -> (B, K, 3).
        ``frames``: this q's ``forward_kinematics`` when the caller already has it (saves one FK)."""
        if frames is None:
            return self._points_on_links(self._candidate_link, self._candidate_local, p, R, q)
        palm = transform_points(frames[:, self._candidate_link], self._candidate_local)
        return palm @ R.transpose(1, 2) + p.unsqueeze(1)

    def contact_candidates_and_normals(self, p: Tensor, R: Tensor, q: Tensor) -> tuple[Tensor, Tensor]:
        """Contact candidates (B, K, 3) and their outward unit surface normals (B, K, 3) in the world."""
        frames = self.forward_kinematics(q)[:, self._candidate_link]  # (B, K, 4, 4) in the palm frame
        points = transform_points(frames, self._candidate_local) @ R.transpose(1, 2) + p.unsqueeze(1)
        normals = (frames[..., :3, :3] @ self._candidate_normal_local.unsqueeze(-1)).squeeze(-1) @ R.transpose(1, 2)
        return points, normals

    def keypoints(self, p: Tensor, R: Tensor, q: Tensor) -> Tensor:
        """The 31 keypoints (``keypoint_names`` order) in the world.   -> (B, 31, 3)."""
        return self._points_on_links(self._keypoint_link, self._keypoint_local, p, R, q)

    # ================================================================ geometry
    def collision_primitives(self, p: Tensor, R: Tensor, q: Tensor) -> Primitives:
        """The collision capsules and prisms (boxes, forearm cylinder) posed in the world (for custom terms)."""
        return self.collision.pose(self.link_poses(p, R, q))

    def signed_distance(self, points: Tensor, p: Tensor, R: Tensor, q: Tensor) -> Tensor:
        """Signed distance (m) from world points to the hand's collision primitives, negative inside:
        d(x) = min over geoms g of d_g(R^T (x - p)) with the geoms posed by FK in the palm frame.
        points (B, N, 3) -> (B, N)."""
        prims = self.collision.pose(self.forward_kinematics(q))
        return self.collision.signed_distance(palm_from_world(points, p, R), prims)

    def self_penetration(self, q: Tensor) -> Tensor:
        """Self-penetration:  sum over checked geom pairs of relu(-d_pair)  (m).   q (B, 22) -> (B,).

        Pairs: every two geoms not on the same rigid body and not parent/child in the tree of bodies
        that carry collision geometry (:func:`components.hand.geometry.self_collision_pairs`; names in
        ``self.collision.pair_names``).  Capsule-capsule: closed-form segment-segment distance.
        Capsule-box and capsule-cylinder: exact, the boxes and the cylinder are *not* approximated
        (golden-section search of their convex SDF along the capsule axis, to
        ``golden_section_iterations``), run only on the pairs that a cheap lower bound cannot rule out
        (``self_collision_screen_samples``; :func:`components.hand.geometry.capsule_prism_penetrating_distance`).
        No box-box pair exists under the adjacency rule.
        """
        return self.collision.self_penetration(self.collision.pose(self.forward_kinematics(q)))

    def geom_lowest_heights(self, p: Tensor, R: Tensor, q: Tensor) -> Tensor:
        """World height (z) of the lowest point of each collision geom (``collision_geom_names``).  -> (B, G)."""
        return self.collision.lowest_heights(self.collision_primitives(p, R, q))

    # ================================================================ URDF / PyBullet
    def urdf_text(self) -> str:
        """The URDF of this model (see :mod:`components.hand.urdf`)."""
        return build_urdf(self.spec, self.link_names, self.collision.geoms, self.cfg.urdf_robot_name,
                          self.cfg.urdf_joint_velocity_limit)

    def export_urdf(self, path: Path) -> Path:
        """Write the URDF (atomically) to ``path``, or to ``path / shadow_hand.urdf`` if ``path`` is a folder."""
        path = Path(path)
        if path.is_dir():
            path = path / URDF_FILE_NAME
        return atomic_write_text(path, self.urdf_text())

    def pybullet_joint_indices(self, body_id: int, client_id: int = 0) -> list:
        """PyBullet joint index of each of the 22 ``joint_names`` for a hand loaded from the URDF."""
        joints, _ = pybullet_indices(body_id, client_id)
        return [joints[n] for n in self.joint_names]

    def pybullet_link_indices(self, body_id: int, client_id: int = 0) -> list:
        """PyBullet link index of each of ``link_names`` (-1 = the base, the palm)."""
        _, links = pybullet_indices(body_id, client_id)
        return [links[n] for n in self.link_names]
