"""Points on the surface of the hand's collision geometry (capsules, boxes, forearm cylinder).

Used where the hand must be tested against the *objects'* SDFs (hand points inside objects in the
energy, Q1 contacts and PN in :mod:`components.metrics`).  Every primitive of ``HandModel.collision``
is covered by a deterministic, evenly spread set of points lying exactly on its surface, about
``spacing`` apart, fixed to its link:

* capsule (segment [a, b] grown by r): rings of ``ceil(2 pi r / s)`` points every ~s along the axis
  (alternate rings offset by half a step), plus a Fibonacci sphere of ``ceil(4 pi r^2 / s^2)`` points
  split into the two end caps (a direction u goes to b + r u if u.(b - a) >= 0, else to a + r u);
* box (half extents h): a cell-centred grid of step <= s on each of the 6 faces;
* cylinder (radius rho, half length h): rings on the side like the capsule, and a sunflower disc of
  ``ceil(pi rho^2 / s^2)`` points on each cap.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

from components.hand import HandModel

#: The golden angle (rad): successive Fibonacci / sunflower points turn by it.
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (Fibonacci lattice):  z_k = 1 - (2k + 1) / n,  phi_k = k * golden angle.  -> (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    rho = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    phi = GOLDEN_ANGLE * np.arange(n)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def sunflower_disc(n: int, radius: float) -> np.ndarray:
    """n nearly uniform points of the disc of ``radius`` in the xy plane:  r_k = R sqrt((k + 1/2) / n).  -> (n, 2)."""
    k = np.arange(n)
    r = radius * np.sqrt((k + 0.5) / n)
    return np.stack([r * np.cos(GOLDEN_ANGLE * k), r * np.sin(GOLDEN_ANGLE * k)], axis=1)


def side_rings(radius: float, half_length: float, spacing: float) -> np.ndarray:
    """Points on the lateral surface of the cylinder x^2 + y^2 = r^2, |z| <= h (axis z).  -> (n, 3)."""
    n_axial = max(1, math.ceil(2.0 * half_length / spacing))
    n_around = max(3, math.ceil(2.0 * math.pi * radius / spacing))
    i, j = np.meshgrid(np.arange(n_axial), np.arange(n_around), indexing="ij")
    theta = 2.0 * math.pi * (j + 0.5 * (i % 2)) / n_around
    z = -half_length + 2.0 * half_length * (i + 0.5) / n_axial
    return np.stack([radius * np.cos(theta), radius * np.sin(theta), z], axis=-1).reshape(-1, 3)


def capsule_samples(a: np.ndarray, b: np.ndarray, radius: float, spacing: float) -> np.ndarray:
    """Evenly spread points on the capsule [a, b] grown by ``radius`` (module docstring).  -> (n, 3)."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    w = axis / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(helper, w)
    u /= np.linalg.norm(u)
    frame = np.stack([u, np.cross(w, u), w], axis=1)  # (3, 3): columns = local x, y, z
    side = side_rings(radius, 0.5 * length, spacing) @ frame.T + 0.5 * (a + b)
    dirs = fibonacci_sphere(max(2, math.ceil(4.0 * math.pi * radius ** 2 / spacing ** 2)))
    caps = np.where((dirs @ w >= 0.0)[:, None], b, a) + radius * dirs
    return np.concatenate([side, caps])


def box_samples(half: np.ndarray, spacing: float) -> np.ndarray:
    """Cell-centred grids on the 6 faces of the box |x_k| <= h_k.  -> (n, 3)."""
    faces = []
    for axis in range(3):
        u, v = [k for k in range(3) if k != axis]
        nu, nv = max(1, math.ceil(2.0 * half[u] / spacing)), max(1, math.ceil(2.0 * half[v] / spacing))
        gu = -half[u] + 2.0 * half[u] * (np.arange(nu) + 0.5) / nu
        gv = -half[v] + 2.0 * half[v] * (np.arange(nv) + 0.5) / nv
        uu, vv = np.meshgrid(gu, gv, indexing="ij")
        for sign in (-1.0, 1.0):
            face = np.zeros((nu * nv, 3))
            face[:, axis] = sign * half[axis]
            face[:, u], face[:, v] = uu.ravel(), vv.ravel()
            faces.append(face)
    return np.concatenate(faces)


def cylinder_samples(radius: float, half_length: float, spacing: float) -> np.ndarray:
    """Side rings and sunflower caps of the cylinder x^2 + y^2 <= r^2, |z| <= h.  -> (n, 3)."""
    disc = sunflower_disc(max(1, math.ceil(math.pi * radius ** 2 / spacing ** 2)), radius)
    caps = [np.concatenate([disc, np.full((len(disc), 1), sign * half_length)], axis=1) for sign in (-1.0, 1.0)]
    return np.concatenate([side_rings(radius, half_length, spacing), *caps])


def primitive_samples(hand: HandModel, spacing: float, exclude: Sequence[str] = ()) -> list[tuple[int, int, np.ndarray]]:
    """(geom index, link index, samples (n, 3) in the link frame) for every collision primitive not in ``exclude``."""
    col = hand.collision
    out = []
    for k, gid in enumerate(col.capsule_ids):
        if col.geom_names[gid] in exclude:
            continue
        a = col.capsule_a_local[k].double().cpu().numpy()
        b = col.capsule_b_local[k].double().cpu().numpy()
        out.append((gid, int(col.capsule_link[k]), capsule_samples(a, b, float(col.capsule_radius[k]), spacing)))
    for k, gid in enumerate(col.prism_ids):
        if col.geom_names[gid] in exclude:
            continue
        half = col.prism_half[k].double().cpu().numpy()
        rho = float(col.prism_rounding[k])
        if rho == 0.0:
            local = box_samples(half, spacing)
        elif half[0] == 0.0 and half[1] == 0.0:
            local = cylinder_samples(rho, float(half[2]), spacing)
        else:
            raise ValueError(f"hand primitive {col.geom_names[gid]} is a rounded box; only boxes and cylinders are sampled")
        rot = col.prism_rot_local[k].double().cpu().numpy()
        centre = col.prism_centre_local[k].double().cpu().numpy()
        out.append((gid, int(col.prism_link[k]), local @ rot.T + centre))
    return out


class HandSurface:
    """Fixed surface samples of the hand's collision primitives, posed by FK (module docstring).

    Attributes: ``link`` (M,) link index of each sample, ``local`` (M, 3) its position in that link's
    frame, ``geom`` (M,) index into ``hand.collision_geom_names``.
    """

    def __init__(self, hand: HandModel, spacing: float, exclude: Sequence[str] = ()):
        found = primitive_samples(hand, spacing, exclude)
        self.spacing = spacing
        self.link = torch.as_tensor(np.concatenate([np.full(len(x), link) for _, link, x in found]),
                                    dtype=torch.long, device=hand.device)  # (M,)
        self.local = torch.as_tensor(np.concatenate([x for _, _, x in found]), dtype=hand.dtype, device=hand.device)  # (M, 3)
        self.geom = torch.as_tensor(np.concatenate([np.full(len(x), gid) for gid, _, x in found]),
                                    dtype=torch.long, device=hand.device)  # (M,)
        order = torch.argsort(self.link, stable=True)  # samples of a link contiguous (fast posing)
        self.link, self.local, self.geom = self.link[order], self.local[order], self.geom[order]
        links, counts = torch.unique_consecutive(self.link, return_counts=True)
        self._blocks = list(zip(links.tolist(), torch.split(self.local, counts.tolist())))  # [(link, (M_l, 3))]

    def __len__(self) -> int:
        return len(self.local)

    def from_frames(self, link_frames: Tensor) -> Tensor:
        """Sample positions in the frame of ``link_frames`` (B, L, 4, 4):  y = R_l x + t_l per link.  -> (B, M, 3).
        One (B, 3, 3) x (3, M_l) product per link (a batch of 3x3 products per point is far slower on CPU)."""
        return torch.cat([link_frames[:, link, :3, :3] @ local.T + link_frames[:, link, :3, 3:]
                          for link, local in self._blocks], dim=-1).transpose(1, 2)

    def world(self, hand: HandModel, p: Tensor, R: Tensor, q: Tensor) -> Tensor:
        """Sample positions in the world for H = (p, R, q).   -> (B, M, 3)."""
        return self.from_frames(hand.link_poses(p, R, q))
